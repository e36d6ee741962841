//! pbdl-particles's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-particles's entries.
pub fn tasks() -> CrateTasks {
    pbdl_particles::tasks()
}
