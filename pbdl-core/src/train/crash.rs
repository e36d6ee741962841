//! A kill -9 harness for resume tests: kill a training process at random times and inside
//! checkpoint writes, resume it, and compare the result with a run that was never stopped.
//!
//! A test binary plays both roles. Its child test trains in the directory that
//! [`child_dir`] names (and does nothing in a normal test run); the parent test
//! ([`CrashTest::run`]) re-executes the binary on that one test:
//!
//! 1. a reference run, uninterrupted, gives the expected [`Fingerprint`] (loss curve, every
//!    checkpoint's tensors) and the number of atomic writes a full run makes;
//! 2. then, over and over, a child is started in a crash directory and SIGKILLed
//!    (`Child::kill`), either at a random time (seeded) or held inside a chosen atomic write,
//!    after its temporary file is complete and before the rename ([`crate::io::atomic::CRASH_HOLD_ENV`]),
//!    so that the kill lands in the write window for certain, not by timing;
//! 3. after every kill the directory must hold only loadable checkpoints (every sidecar loads
//!    with its weights); leftovers of the interrupted write may remain (temporary files,
//!    weights whose commit did not happen) and the next run removes them;
//! 4. each time a child runs to its end, the directory must equal the reference bit for bit
//!    and hold no leftovers; the next kills start a new crash directory.
//!
//! Children run with one thread (`PBDL_THREADS=1`), so reductions sum in a fixed order.
//!
//! ```no_run
//! use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
//!
//! #[test]
//! fn crash_child() {
//!     child(|dir| -> pbdl_core::Result<()> { /* train into `dir`, resuming */ Ok(()) });
//! }
//!
//! #[test]
//! fn kill_and_resume() {
//!     let root = tempfile::tempdir().unwrap();
//!     let report = CrashTest::new("crash_child", root.path(), 3, 7).run(Fingerprint::of_run_dir).unwrap();
//!     assert_eq!(report.kills, 3);
//! }
//! ```

use crate::io::atomic::CRASH_HOLD_ENV;
use crate::io::{is_temp_file, list_checkpoints, load_checkpoint, read_checkpoint_info};
use crate::train::ScalarLog;
use rand::{Rng, SeedableRng};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The environment variable that makes a test process a crash-test child: the run directory.
pub const CHILD_DIR_ENV: &str = "PBDL_CRASH_CHILD_DIR";

/// The line a child prints after a complete run: this tag, then its number of atomic writes.
const WRITES_TAG: &str = "pbdl-crash-test-writes=";

/// The run directory of a crash-test child, `None` in any other process.
pub fn child_dir() -> Option<PathBuf> {
    std::env::var_os(CHILD_DIR_ENV).map(PathBuf::from)
}

/// The child role: in a process started by [`CrashTest::run`], trains with `train(dir)`
/// (which must resume from `dir`) and reports its atomic writes; elsewhere does nothing.
/// Panics (a failed child) when `train` fails.
pub fn child<E: std::fmt::Display>(train: impl FnOnce(&Path) -> Result<(), E>) {
    let Some(dir) = child_dir() else { return };
    if let Err(e) = train(&dir) {
        panic!("crash-test child in {}: {e}", dir.display());
    }
    println!("{WRITES_TAG}{}", crate::io::atomic::atomic_write_count());
}

/// What a [`CrashTest`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CrashReport {
    /// Children killed while they ran (`in_write + in_training`).
    pub kills: usize,
    /// Kills inside an atomic write: temporary file complete, rename not done.
    pub in_write: usize,
    /// Kills at a random time.
    pub in_training: usize,
    /// Children that finished before their planned kill.
    pub missed: usize,
    /// Child processes started, the reference run included.
    pub child_runs: usize,
    /// Interrupted runs taken to their end and compared with the reference.
    pub rounds: usize,
}

/// The outcome of a run directory that must not depend on interruptions: named byte strings
/// (tensors of checkpoints, loss columns, whatever a test adds).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Fingerprint {
    /// Key to bytes.
    pub entries: BTreeMap<String, Vec<u8>>,
}

impl Fingerprint {
    /// Every complete checkpoint of `dir` (by file name: its step and every tensor's dtype,
    /// shape and bytes) and every column of `dir/loss.csv` but the wall-clock `seconds` (steps
    /// and value bits).
    pub fn of_run_dir(dir: &Path) -> Result<Self, String> {
        let mut f = Self::default();
        f.add_checkpoints(dir)?;
        let log = dir.join("loss.csv");
        if log.exists() {
            let log = ScalarLog::read(&log).map_err(|e| e.to_string())?;
            for c in log.columns().iter().filter(|c| *c != "seconds") {
                let column = log.column(c);
                let bytes = column.iter().flat_map(|(s, v)| [s.to_le_bytes(), v.to_bits().to_le_bytes()]).flatten();
                f.entries.insert(format!("loss.csv/{c}"), bytes.collect());
            }
        }
        Ok(f)
    }

    /// Adds every complete checkpoint of `dir` (see [`Fingerprint::of_run_dir`]).
    pub fn add_checkpoints(&mut self, dir: &Path) -> Result<(), String> {
        for (path, info) in list_checkpoints(dir).map_err(|e| e.to_string())? {
            let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let (tensors, _) = load_checkpoint(&path, &candle_core::Device::Cpu).map_err(|e| e.to_string())?;
            self.entries.insert(format!("{name}/step"), info.step.to_le_bytes().to_vec());
            for (t, v) in tensors {
                let mut bytes = format!("{:?} {:?}:", v.dtype(), v.dims()).into_bytes();
                v.write_bytes(&mut bytes).map_err(|e| e.to_string())?;
                self.entries.insert(format!("{name}/{t}"), bytes);
            }
        }
        Ok(())
    }

    /// The first difference from `expected`, `None` when equal.
    pub fn diff(&self, expected: &Fingerprint) -> Option<String> {
        let keys: std::collections::BTreeSet<&String> = self.entries.keys().chain(expected.entries.keys()).collect();
        keys.into_iter().find_map(|k| match (self.entries.get(k), expected.entries.get(k)) {
            (Some(a), Some(b)) if a == b => None,
            (Some(_), Some(_)) => Some(format!("`{k}` differs from the uninterrupted run")),
            (None, _) => Some(format!("`{k}` is missing (the uninterrupted run has it)")),
            (_, None) => Some(format!("`{k}` is extra (the uninterrupted run lacks it)")),
        })
    }
}

/// Checks what must hold right after a kill: every sidecar in `dir` that reads as a pbdl
/// sidecar loads with its weights, and the listed checkpoints load.
pub fn check_after_kill(dir: &Path) -> Result<(), String> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    for entry in entries {
        let path = entry.map_err(|e| e.to_string())?.path();
        if is_temp_file(&path) || path.extension().is_none_or(|e| e != "json") {
            continue;
        }
        if read_checkpoint_info(&path).is_ok() {
            load_checkpoint(&path, &candle_core::Device::Cpu)
                .map_err(|e| format!("a committed checkpoint does not load after a kill: {e}"))?;
        }
    }
    list_checkpoints(dir).map_err(|e| e.to_string())?;
    Ok(())
}

/// Checks a run directory after a complete run: no temporary files, no weights without a
/// sidecar, `loss.csv` (if any) reads.
pub fn check_complete(dir: &Path) -> Result<(), String> {
    for entry in std::fs::read_dir(dir).map_err(|e| e.to_string())? {
        let path = entry.map_err(|e| e.to_string())?.path();
        if is_temp_file(&path) {
            return Err(format!("{} is left over after a complete run", path.display()));
        }
        if path.extension().is_some_and(|e| e == "safetensors") && !path.with_extension("json").exists() {
            return Err(format!("{} has no sidecar after a complete run", path.display()));
        }
    }
    let log = dir.join("loss.csv");
    if log.exists() {
        ScalarLog::read(&log).map_err(|e| format!("loss.csv after a complete run: {e}"))?;
    }
    Ok(())
}

/// A kill -9 test; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct CrashTest {
    /// The name of the child test in this test binary (run with `--exact`).
    pub child_test: String,
    /// Where the run directories go (`reference`, `crash-<n>`).
    pub root: PathBuf,
    /// Kills to land (children killed while running).
    pub kills: usize,
    /// Seed of the kill schedule.
    pub seed: u64,
    /// Give up after this many child processes (a guard against a schedule that never kills).
    pub max_children: usize,
    /// The share of kills inside a write (the others at a random time). Default 0.5.
    pub in_write_share: f64,
    /// The first atomic write (counted from 0 in each child) that may be held for a kill.
    /// Default 0.
    pub min_hold_write: u64,
}

impl CrashTest {
    /// A test of `kills` kills with seed `seed`, children running `child_test`, directories under `root`.
    pub fn new(child_test: &str, root: &Path, kills: usize, seed: u64) -> Self {
        Self {
            child_test: child_test.into(),
            root: root.into(),
            kills,
            seed,
            max_children: 4 * kills + 8,
            in_write_share: 0.5,
            min_hold_write: 0,
        }
    }

    fn spawn(&self, dir: &Path, hold: Option<(u64, &Path)>) -> Result<Child, String> {
        let exe = std::env::current_exe().map_err(|e| e.to_string())?;
        let mut cmd = Command::new(exe);
        cmd.args([self.child_test.as_str(), "--exact", "--nocapture", "--test-threads=1"])
            .env(CHILD_DIR_ENV, dir)
            .env(crate::threads::THREADS_ENV, "1")
            .env("RAYON_NUM_THREADS", "1")
            .env_remove(CRASH_HOLD_ENV)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if let Some((n, marker)) = hold {
            cmd.env(CRASH_HOLD_ENV, format!("{n}:{}", marker.display()));
        }
        cmd.spawn().map_err(|e| format!("cannot start the child test: {e}"))
    }

    /// Waits for a child that ended by itself; `Ok(writes)` when it succeeded.
    fn finished(out: Output) -> Result<u64, String> {
        let stdout = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            let stderr = String::from_utf8_lossy(&out.stderr);
            let tail = |s: &str| s.chars().rev().take(3000).collect::<Vec<_>>().into_iter().rev().collect::<String>();
            return Err(format!("child failed ({}):\n{}\n{}", out.status, tail(&stdout), tail(&stderr)));
        }
        stdout
            .lines()
            // libtest prints the test's name on the same line.
            .find_map(|l| l.split(WRITES_TAG).nth(1).and_then(|n| n.split_whitespace().next()?.parse().ok()))
            .ok_or_else(|| format!("the child test did not train (no `crash::child` call in it?):\n{stdout}"))
    }

    /// Runs the test; `outcome(dir)` reads what a complete run must reproduce. Errors describe
    /// the first violation (a child failure, a checkpoint that does not load after a kill, a
    /// leftover after a complete run, an outcome that differs from the reference).
    pub fn run(&self, outcome: impl Fn(&Path) -> Result<Fingerprint, String>) -> Result<CrashReport, String> {
        let mut report = CrashReport::default();
        let reference_dir = self.root.join("reference");
        let started = Instant::now();
        let child = self.spawn(&reference_dir, None)?;
        report.child_runs += 1;
        let writes = Self::finished(child.wait_with_output().map_err(|e| e.to_string())?)?;
        let duration = started.elapsed();
        check_complete(&reference_dir)?;
        let expected = outcome(&reference_dir)?;
        if writes == 0 {
            return Err("the reference run made no atomic writes: nothing to interrupt".into());
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed);
        let mut round = 0;
        let mut dir = self.root.join(format!("crash-{round}"));
        let complete = |dir: &Path, report: &mut CrashReport| -> Result<(), String> {
            check_complete(dir)?;
            if let Some(d) = outcome(dir)?.diff(&expected) {
                return Err(format!("after {} kills, {}: {d}", report.kills, dir.display()));
            }
            report.rounds += 1;
            Ok(())
        };
        while report.kills < self.kills {
            if report.child_runs >= self.max_children {
                return Err(format!(
                    "{} children started but only {} killed: {report:?}",
                    report.child_runs, report.kills
                ));
            }
            let in_write = rng.random_bool(self.in_write_share);
            let marker = self.root.join(format!("hold-{}", report.child_runs));
            let mut child = if in_write {
                self.spawn(&dir, Some((rng.random_range(self.min_hold_write.min(writes - 1)..writes), &marker)))?
            } else {
                self.spawn(&dir, None)?
            };
            report.child_runs += 1;
            let deadline = Instant::now() + duration.mul_f64(rng.random_range(0.0..1.0));
            let killed = loop {
                if child.try_wait().map_err(|e| e.to_string())?.is_some() {
                    break false;
                }
                if (in_write && marker.exists()) || (!in_write && Instant::now() >= deadline) {
                    child.kill().map_err(|e| e.to_string())?;
                    break true;
                }
                std::thread::sleep(Duration::from_millis(1));
            };
            let out = child.wait_with_output().map_err(|e| e.to_string())?;
            if killed {
                report.kills += 1;
                if in_write {
                    report.in_write += 1;
                    // The held write's temporary file is complete and was never renamed.
                    let target = std::fs::read_to_string(&marker).map_err(|e| e.to_string())?;
                    let name =
                        Path::new(&target).file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                    let left = std::fs::read_dir(&dir).map_err(|e| e.to_string())?.filter_map(|e| e.ok()).any(|e| {
                        is_temp_file(e.path()) && e.file_name().to_string_lossy().starts_with(&format!(".{name}."))
                    });
                    if !left {
                        return Err(format!("the kill inside the write of {target} left no temporary file"));
                    }
                } else {
                    report.in_training += 1;
                }
                check_after_kill(&dir)?;
            } else {
                report.missed += 1;
                Self::finished(out)?;
                complete(&dir, &mut report)?;
                round += 1;
                dir = self.root.join(format!("crash-{round}"));
            }
        }
        // Resume the last interrupted run to its end.
        let child = self.spawn(&dir, None)?;
        report.child_runs += 1;
        Self::finished(child.wait_with_output().map_err(|e| e.to_string())?)?;
        complete(&dir, &mut report)?;
        Ok(report)
    }
}
