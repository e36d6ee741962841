//! pbdl-diffusion's tour, bench and stress entries.

use crate::registry::CrateTasks;

/// pbdl-diffusion's entries.
pub fn tasks() -> CrateTasks {
    pbdl_diffusion::tasks()
}
