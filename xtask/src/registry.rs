//! The entry registry: the types of tour, bench and stress entries, and the list of crates
//! whose entries xtask runs (one line per crate in [`all`]).
//!
//! * A **tour** entry runs a method on its embedded default scene, writes its pictures into
//!   `ctx.out_dir` and returns rows of (item, time, error) plus a markdown section.
//! * A **bench** entry measures run time against error and returns [`BenchRow`]s in the
//!   shared schema.
//! * A **stress** entry runs long or extreme cases and returns invariant checks, each naming the
//!   first step at which it broke, if any.

use crate::bench_schema::BenchRow;
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
    /// The number the aggregate report (`target/pbdl/stress/summary.md`) collects, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measure: Option<StressMeasure>,
}

/// A number a stress check measured that `cargo xtask stress` collects across crates into its
/// summary: the longest stable rollout, the largest stable time-step multiple.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StressMeasure {
    /// A rollout that kept its invariants for this many steps (or outputs, as the check says).
    StableSteps(u64),
    /// The largest multiple of the default time step that stayed stable and accurate.
    DtMultiple(f64),
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

/// Every crate's contribution, in tour order.
pub fn all() -> Vec<CrateTasks> {
    vec![
        crate::entries::core::tasks(),
        crate::entries::grid::tasks(),
        crate::entries::metrics::tasks(),
        crate::entries::optim::tasks(),
        crate::entries::particles::tasks(),
        crate::entries::particles3d::tasks(),
        crate::entries::diffusion::tasks(),
        crate::entries::nets::tasks(),
        crate::entries::pconv::tasks(),
        crate::entries::latent::tasks(),
        crate::entries::temporal::tasks(),
        crate::entries::sol::tasks(),
        crate::entries::weather::tasks(),
    ]
}

/// The crates selected by an optional name; an unknown name lists the known ones.
pub fn select(krate: Option<&str>) -> anyhow::Result<Vec<CrateTasks>> {
    let all = all();
    match krate {
        None => Ok(all),
        Some(name) => {
            let names: Vec<&str> = all.iter().map(|c| c.crate_name).collect();
            let known = names.join(", ");
            let picked: Vec<CrateTasks> = all.into_iter().filter(|c| c.crate_name == name).collect();
            anyhow::ensure!(!picked.is_empty(), "unknown crate `{name}`; known crates: {known}");
            Ok(picked)
        }
    }
}

/// With `only` set, checks that one of `crates` has an entry of that name (`names` lists a
/// crate's entries of the kind being run); otherwise lists the known names.
pub fn check_entry(
    crates: &[CrateTasks],
    only: Option<&str>,
    names: impl Fn(&CrateTasks) -> Vec<&'static str>,
) -> anyhow::Result<()> {
    let Some(name) = only else { return Ok(()) };
    let known: Vec<&str> = crates.iter().flat_map(&names).collect();
    anyhow::ensure!(known.contains(&name), "unknown entry `{name}`; entries here: {}", known.join(", "));
    Ok(())
}

/// Prints every registered entry.
pub fn print_list() {
    for c in all() {
        println!("{}", c.crate_name);
        for e in &c.tour {
            println!("  tour   {:<24} {}", e.name, e.about);
        }
        for e in &c.bench {
            println!("  bench  {:<24} {}", e.name, e.about);
        }
        for e in &c.stress {
            println!("  stress {:<24} {}", e.name, e.about);
        }
    }
}
