//! pbdl-grid's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-grid's entries.
pub fn tasks() -> CrateTasks {
    pbdl_grid::tasks()
}
