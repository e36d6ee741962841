//! The thread count candle's CPU kernels use, fixed once per process.
//!
//! candle (0.11) asks for its thread count on every CPU matmul. Without `RAYON_NUM_THREADS` in
//! the environment that query counts the physical cores, which on Linux reads and parses
//! `/proc/cpuinfo` each time: for networks made of many small matmuls (BPTT controllers, score
//! MLPs, per-row Jacobians) this dominated the run time (measured: a HIG Jacobian of 512 rows
//! 799 ms without the variable, 275 ms with it). [`pin_thread_count`] sets the variable once, to
//! the count rayon's global pool already uses, so the numbers do not change, only the cost.

/// Sets `RAYON_NUM_THREADS` to rayon's global thread count when it is not set (a value the user
/// set is kept) and returns the count in effect.
///
/// Call it at the start of `main` (binaries, examples, benches), before other threads run:
/// changing the environment while another thread reads it is a data race in glibc.
///
/// ```
/// let n = pbdl_core::threads::pin_thread_count();
/// assert_eq!(std::env::var("RAYON_NUM_THREADS").unwrap().parse::<usize>().unwrap(), n);
/// ```
pub fn pin_thread_count() -> usize {
    if let Some(n) = std::env::var("RAYON_NUM_THREADS").ok().and_then(|s| s.parse::<usize>().ok()).filter(|&n| n > 0) {
        return n;
    }
    // Initialises rayon's global pool from the unset variable (all logical cores), then records
    // that count so candle finds it without counting cores again.
    let n = rayon::current_num_threads();
    std::env::set_var("RAYON_NUM_THREADS", n.to_string());
    n
}
