//! pbdl-diffusion's tour, bench and stress entries (see [`pbdl_core::registry`]).

use pbdl_core::registry::CrateTasks;

/// The entries of `pbdl-diffusion`.
pub fn tasks() -> CrateTasks {
    CrateTasks { crate_name: "diffusion", tour: vec![], bench: vec![], stress: vec![] }
}
