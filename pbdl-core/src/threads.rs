//! The one thread policy of every pbdl crate: how many threads, and below which size an
//! operation runs serially.
//!
//! Three thread pools meet in a pbdl process: rayon's global pool (every parallel loop of the
//! pbdl kernels), candle's CPU kernels (which ask `RAYON_NUM_THREADS` on every matmul, and
//! without it count the physical cores by parsing `/proc/cpuinfo` each time: measured, a HIG
//! Jacobian of 512 rows 799 ms without the variable, 275 ms with it) and gemm (which takes its
//! thread count from the caller, here [`crate::matmul`]); candle 0.11 also keeps a pool of its
//! own for large elementwise ops (threads `candle-bp-N`). [`init`] decides once and sets them
//! all: it builds rayon's global pool with [`ThreadPolicy::threads`] threads and writes
//! `RAYON_NUM_THREADS` and `CANDLE_NUM_THREADS` for candle; pbdl's kernels ask [`parallel`] whether a piece of work is
//! big enough to be split at all (a parallel region costs a worker wake-up: on the 2-core
//! development machine a 128^2 Taylor-Green RK4 step took 0.46 ms serial and 0.78 ms on 2
//! threads, so smaller work stays on the calling thread).
//!
//! | setting | environment variable | API | default |
//! |---|---|---|---|
//! | thread count | `PBDL_THREADS` (then `RAYON_NUM_THREADS`) | [`init_with`] | the logical cores |
//! | serial below (elements or cells of one op) | `PBDL_SERIAL_BELOW` | [`init_with`] | [`DEFAULT_SERIAL_BELOW`] = 192^2 |
//!
//! [`init`] and [`init_with`] also tune glibc's `malloc` to keep freed tensor buffers
//! ([`crate::malloc`]; `PBDL_TUNE_MALLOC=0` to skip); the lazy initialisation of library code
//! does not.
//!
//! Call [`init`] (or [`init_with`]) at the start of `main` in binaries, examples and benches,
//! before other threads run (changing the environment while another thread reads it through C's
//! `getenv` is a data race). Library code and tests need not call it: the first [`policy`] or
//! [`parallel`] call initialises from the environment. Once initialised, the policy is fixed
//! for the process.
//!
//! ```
//! use pbdl_core::threads;
//!
//! let policy = threads::init()?; // reads PBDL_THREADS / PBDL_SERIAL_BELOW once
//! assert_eq!(threads::policy(), policy);
//! assert_eq!(std::env::var("RAYON_NUM_THREADS").unwrap(), policy.threads.to_string());
//! assert!(!threads::parallel(64 * 64)); // a 64x64 field stays on the calling thread
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use std::sync::OnceLock;

/// The environment variable that sets the thread count (overrides `RAYON_NUM_THREADS`).
pub const THREADS_ENV: &str = "PBDL_THREADS";
/// The environment variable that sets [`ThreadPolicy::serial_below`].
pub const SERIAL_BELOW_ENV: &str = "PBDL_SERIAL_BELOW";
/// Work (elements or cells of one operation) below which it runs serially: 192^2, the grid
/// size from which a row-parallel stencil pass beat the serial one on 2 threads.
pub const DEFAULT_SERIAL_BELOW: usize = 192 * 192;

/// How many threads, and from which size an operation is split over them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThreadPolicy {
    /// Threads of rayon's global pool, of candle's CPU kernels and of gemm (at least 1).
    pub threads: usize,
    /// Operations on fewer elements (or grid cells) than this run on the calling thread.
    pub serial_below: usize,
}

impl ThreadPolicy {
    /// The policy for these environment values (`None`: unset) on a machine with `cores`
    /// logical cores: `PBDL_THREADS`, else `RAYON_NUM_THREADS`, else `cores`; `PBDL_SERIAL_BELOW`
    /// else [`DEFAULT_SERIAL_BELOW`]. A value that is not a positive integer (a threshold may be
    /// 0: always parallel) is an [`Error::InvalidArgument`] naming the variable.
    pub fn resolve(
        pbdl_threads: Option<&str>,
        rayon_threads: Option<&str>,
        serial_below: Option<&str>,
        cores: usize,
    ) -> Result<Self> {
        let count = |name: &'static str, v: &str| -> Result<usize> {
            match v.trim().parse::<usize>() {
                Ok(n) if n > 0 => Ok(n),
                _ => Err(Error::invalid(
                    "thread policy",
                    name,
                    format!("`{v}` is not a thread count; set {name} to a positive integer such as 2 (or unset it)"),
                )),
            }
        };
        let threads = match (pbdl_threads, rayon_threads) {
            (Some(v), _) => count(THREADS_ENV, v)?,
            (None, Some(v)) => count("RAYON_NUM_THREADS", v)?,
            (None, None) => cores.max(1),
        };
        let serial_below = match serial_below {
            Some(v) => v.trim().parse::<usize>().map_err(|_| {
                Error::invalid(
                    "thread policy",
                    SERIAL_BELOW_ENV,
                    format!("`{v}` is not a size; set {SERIAL_BELOW_ENV} to a number of elements such as 36864 (or unset it)"),
                )
            })?,
            None => DEFAULT_SERIAL_BELOW,
        };
        Ok(Self { threads, serial_below })
    }

    /// The policy the environment of this process asks for.
    pub fn from_env() -> Result<Self> {
        let var = |name| std::env::var(name).ok();
        let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        Self::resolve(
            var(THREADS_ENV).as_deref(),
            var("RAYON_NUM_THREADS").as_deref(),
            var(SERIAL_BELOW_ENV).as_deref(),
            cores,
        )
    }

    /// Whether an operation on `work` elements (or cells) should be split over threads.
    pub fn parallel(&self, work: usize) -> bool {
        self.threads > 1 && work >= self.serial_below
    }
}

static POLICY: OnceLock<ThreadPolicy> = OnceLock::new();

/// Initialises the policy from the environment (see the module docs) unless it is set already,
/// and returns the policy in effect.
///
/// # Errors
/// [`Error::InvalidArgument`] when `PBDL_THREADS`, `RAYON_NUM_THREADS` or `PBDL_SERIAL_BELOW`
/// holds something other than a number; nothing is set then.
pub fn init() -> Result<ThreadPolicy> {
    let policy = match POLICY.get() {
        Some(p) => *p,
        None => install(ThreadPolicy::from_env()?)?,
    };
    tune_malloc_once();
    Ok(policy)
}

/// Initialises the policy with `wanted` (the API override of the environment) and returns the
/// policy in effect: `wanted` if this is the first initialisation and rayon's global pool could
/// still be built with `wanted.threads`; otherwise the policy already fixed (or the pool's
/// actual thread count), which the caller can compare. Also tunes glibc's `malloc` (see
/// [`crate::malloc`]), as [`init`] does.
pub fn init_with(wanted: ThreadPolicy) -> Result<ThreadPolicy> {
    let policy = install(wanted)?;
    tune_malloc_once();
    Ok(policy)
}

/// The explicit initialisations ([`init`], [`init_with`]) also set the process's memory policy;
/// the lazy one of library code ([`policy`]) does not: a program that only links pbdl keeps
/// its allocator settings.
fn tune_malloc_once() {
    static TUNED: std::sync::Once = std::sync::Once::new();
    TUNED.call_once(|| {
        crate::malloc::keep_freed_memory();
    });
}

/// Fixes the thread policy (once per process) and returns the one in effect.
fn install(wanted: ThreadPolicy) -> Result<ThreadPolicy> {
    if wanted.threads == 0 {
        return Err(Error::invalid("threads::init_with", "threads", "use at least 1 thread"));
    }
    Ok(*POLICY.get_or_init(|| {
        // Fails when the global pool exists already (something used rayon first); then that
        // pool's size is what every parallel loop gets, so the policy records it.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(wanted.threads).build_global();
        let threads = rayon::current_num_threads();
        // candle reads this on every CPU matmul; its own pool for elementwise ops
        // (`candle-bp-N` threads, built on first use) reads CANDLE_NUM_THREADS first.
        std::env::set_var("RAYON_NUM_THREADS", threads.to_string());
        std::env::set_var("CANDLE_NUM_THREADS", threads.to_string());
        ThreadPolicy { threads, ..wanted }
    }))
}

/// The policy in effect, initialised from the environment on first use (without the memory
/// policy of [`init`]). An unreadable environment value falls back to the defaults here (with
/// one message on stderr); call [`init`] in `main` to get it as an error instead.
pub fn policy() -> ThreadPolicy {
    if let Some(p) = POLICY.get() {
        return *p;
    }
    match ThreadPolicy::from_env().and_then(install) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("pbdl: {e}; using the default thread policy");
            let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
            install(ThreadPolicy { threads: cores, serial_below: DEFAULT_SERIAL_BELOW })
                .unwrap_or(ThreadPolicy { threads: 1, serial_below: DEFAULT_SERIAL_BELOW })
        }
    }
}

/// Whether an operation on `work` elements (or grid cells) should be split over threads under
/// the process's [`policy`].
pub fn parallel(work: usize) -> bool {
    policy().parallel(work)
}

/// The thread count of the [`policy`].
pub fn count() -> usize {
    policy().threads
}

/// Runs `f` with every rayon-parallel operation inside it (pbdl's kernels, candle's matmuls and
/// gemm calls) on one thread (candle's separate elementwise pool is not rayon and still splits
/// its large broadcast ops): `f` runs on a one-thread rayon pool
/// (built once), where a parallel region runs inline instead of waking a worker. For work made
/// of many small operations (a 64^2 solver run of a data generator, a batch of tiny matrix
/// products), whose regions each cost a wake-up and gain nothing; run independent items of such
/// work side by side instead (one item per thread). Results equal a run with `PBDL_THREADS=1`.
///
/// ```
/// let inside = pbdl_core::threads::serial(rayon::current_num_threads);
/// assert_eq!(inside, 1);
/// ```
pub fn serial<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    static ONE: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    match ONE.get_or_init(|| rayon::ThreadPoolBuilder::new().num_threads(1).build().ok()) {
        Some(pool) => pool.install(f),
        // No thread could be started: run on the caller (its regions then use the global pool).
        None => f(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn environment_values_resolve_in_order_and_bad_ones_name_the_variable() {
        let p = ThreadPolicy::resolve(None, None, None, 8).unwrap();
        assert_eq!(p, ThreadPolicy { threads: 8, serial_below: DEFAULT_SERIAL_BELOW });
        assert_eq!(ThreadPolicy::resolve(None, Some("3"), None, 8).unwrap().threads, 3);
        assert_eq!(
            ThreadPolicy::resolve(Some("2"), Some("3"), Some("0"), 8).unwrap(),
            ThreadPolicy { threads: 2, serial_below: 0 }
        );
        assert_eq!(ThreadPolicy::resolve(None, None, None, 0).unwrap().threads, 1);
        for (t, r, s, name) in [
            (Some("two"), None, None, THREADS_ENV),
            (Some("0"), None, None, THREADS_ENV),
            (None, Some("-1"), None, "RAYON_NUM_THREADS"),
            (None, None, Some("big"), SERIAL_BELOW_ENV),
        ] {
            let e = ThreadPolicy::resolve(t, r, s, 4).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
    }

    #[test]
    fn small_work_or_one_thread_stays_serial() {
        let p = ThreadPolicy { threads: 2, serial_below: 100 };
        assert!(!p.parallel(99) && p.parallel(100));
        assert!(!ThreadPolicy { threads: 1, serial_below: 0 }.parallel(1 << 30));
        assert!(ThreadPolicy { threads: 4, serial_below: 0 }.parallel(0));
    }

    #[test]
    fn the_process_policy_is_fixed_and_set_for_candle() {
        let p = policy();
        assert_eq!(init().unwrap(), p);
        assert_eq!(init_with(ThreadPolicy { threads: p.threads + 1, serial_below: 1 }).unwrap(), p, "fixed once set");
        assert_eq!(p.threads, rayon::current_num_threads());
        assert_eq!(std::env::var("RAYON_NUM_THREADS").unwrap(), p.threads.to_string());
        assert_eq!(std::env::var("CANDLE_NUM_THREADS").unwrap(), p.threads.to_string());
    }
}
