//! pbdl-diffusion's tour, bench and stress entries, one file per part of the crate
//! (DDPM/DDIM samplers, U-Nets, SMDP, ACDM); this module collects them in tour order.
//! The uncertainty surrogate's acceptance run is the ignored test `uncertainty_wake`, run by
//! the stress entry `acceptance` with the other ignored acceptance tests.

pub mod acceptance;
pub mod acdm;
pub mod ddpm;
pub mod smdp;
pub mod unet;

use crate::registry::CrateTasks;

/// The entries of `pbdl-diffusion`.
pub fn tasks() -> CrateTasks {
    let mut tasks = CrateTasks { crate_name: "diffusion", tour: vec![], bench: vec![], stress: vec![] };
    for part in [ddpm::entries, unet::entries, smdp::entries, acdm::entries, acceptance::entries] {
        let (tour, bench, stress) = part();
        tasks.tour.extend(tour);
        tasks.bench.extend(bench);
        tasks.stress.extend(stress);
    }
    tasks
}
