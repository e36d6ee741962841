//! The task registry: how a crate contributes tour, bench and stress entries to `cargo xtask`.
//!
//! Each pbdl crate exposes `pub fn tasks() -> CrateTasks` listing its entries; xtask collects
//! one `CrateTasks` per crate and runs them, so adding a method never grows a giant match in
//! xtask. An entry is a plain function of a [`TaskContext`].
//!
//! * A **tour** entry runs a method on its embedded default scene, writes its pictures into
//!   `ctx.out_dir` and returns rows of (item, time, error) plus a markdown section.
//! * A **bench** entry measures run time against error and returns [`BenchRow`]s in the
//!   shared schema.
//! * A **stress** entry runs long or extreme cases and returns invariant checks, each naming the
//!   first step at which it broke, if any.

use crate::bench::BenchRow;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Error type of task entries: any error, with its message kept.
pub type TaskError = Box<dyn std::error::Error + Send + Sync>;
/// Result type of task entries.
pub type TaskResult<T> = std::result::Result<T, TaskError>;

/// What a task entry gets to work with.
#[derive(Clone, Debug)]
pub struct TaskContext {
    /// Directory for the entry's files (PNG, GIF, npz, ...); it exists.
    pub out_dir: PathBuf,
    /// Smaller sizes and fewer repetitions (CI, smoke runs).
    pub quick: bool,
    /// Threads of the global rayon pool.
    pub threads: usize,
}

/// One line of the tour's table.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TourRow {
    /// What was run, e.g. `"conv2d fwd+bwd, 8x32x64x64"`.
    pub item: String,
    /// Wall-clock seconds it took (median where repeated).
    pub seconds: f64,
    /// Error against a reference, if there is one.
    pub error: Option<f64>,
    /// What `error` measures.
    pub error_kind: String,
    /// A short remark (ratio to a peer, files written, ...).
    pub note: String,
}

/// What a tour entry returns.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TourOutcome {
    /// Table rows.
    pub rows: Vec<TourRow>,
    /// Files written, relative to the tour's output directory or absolute.
    pub files: Vec<PathBuf>,
    /// A markdown section for `report.md` (may embed the files as images).
    pub markdown: String,
}

/// One invariant checked by a stress entry.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StressCheck {
    /// The invariant, e.g. `"values finite"` or `"energy does not grow"`.
    pub invariant: String,
    /// Whether it held throughout.
    pub passed: bool,
    /// The first step (or case index) at which it broke.
    pub first_broken_step: Option<u64>,
    /// Numbers that back the verdict.
    pub detail: String,
}

/// A named entry: a function of the context.
pub struct Entry<R> {
    /// Short name, used on the command line and in reports.
    pub name: &'static str,
    /// One sentence on what it does.
    pub about: &'static str,
    /// The work.
    pub run: fn(&TaskContext) -> TaskResult<R>,
}

/// Everything one crate contributes to xtask.
pub struct CrateTasks {
    /// The crate's short name, e.g. `"core"` or `"grid"` (used by `cargo xtask bench grid`).
    pub crate_name: &'static str,
    /// Tour entries.
    pub tour: Vec<Entry<TourOutcome>>,
    /// Bench entries.
    pub bench: Vec<Entry<Vec<BenchRow>>>,
    /// Stress entries.
    pub stress: Vec<Entry<Vec<StressCheck>>>,
}
