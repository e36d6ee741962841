//! pbdl-optim's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-optim's entries.
pub fn tasks() -> CrateTasks {
    pbdl_optim::tasks()
}
