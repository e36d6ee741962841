//! pbdl-core's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-core's entries.
pub fn tasks() -> CrateTasks {
    pbdl_core::tasks()
}
