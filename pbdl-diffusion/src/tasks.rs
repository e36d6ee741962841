//! pbdl-diffusion's tour, bench and stress entries (see [`pbdl_core::registry`]).
//!
//! Each part of the crate lists its own entries in its `entries` module; this file only
//! collects them in tour order.

use pbdl_core::registry::CrateTasks;

/// The entries of `pbdl-diffusion`.
pub fn tasks() -> CrateTasks {
    let mut tasks = CrateTasks { crate_name: "diffusion", tour: vec![], bench: vec![], stress: vec![] };
    for part in [
        crate::ddpm::entries::entries,
        crate::unet::entries::entries,
        crate::smdp::entries::entries,
        crate::acdm::entries::entries,
        crate::uncertainty::entries::entries,
    ] {
        let (tour, bench, stress) = part();
        tasks.tour.extend(tour);
        tasks.bench.extend(bench);
        tasks.stress.extend(stress);
    }
    tasks
}
