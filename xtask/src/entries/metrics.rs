//! pbdl-metrics's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-metrics's entries.
pub fn tasks() -> CrateTasks {
    pbdl_metrics::tasks()
}
