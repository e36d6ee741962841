//! Time against error on Sod's shock tube at N = 400 (t = 0.2, `[-0.5, 0.5]`, L1 over
//! `|x| < 0.4`): a rollout of 1D SPH with the round-1 constant viscosity, with the new shock
//! capturing (artificial conductivity + Morris & Monaghan switch, the defaults), and of the
//! first-order HLL finite-volume reference with 400 cells. Each iteration builds the tube and
//! runs it (neighbour search included). After the timing each case prints its steps and L1.
//!
//! Measured 2026-11-29 (release, shared 2-core machine under load ~3, criterion median and
//! range, 10 samples): constant viscosity 416 ms (398-437), 1081 steps, L1 rho 3.61e-3
//! u 7.15e-3 p 4.40e-3; defaults (conductivity + switch) 885 ms (871-901), 1344 steps (the
//! conductivity's signal speed shortens the step), L1 rho 4.41e-3 u 7.37e-3 p 4.52e-3; HLL
//! 17.9 ms (16.9-19.0), 194 steps, L1 rho 8.04e-3 u 9.27e-3 p 5.59e-3.

#![allow(missing_docs)] // criterion_group! generates undocumented items

use criterion::{criterion_group, Criterion};
use pbdl_particles::{hll, Evolve, ShockTube, Sph1dParams};

const N: usize = 400;
const T: f64 = 0.2;

fn sod_rollouts(c: &mut Criterion) {
    let tube = ShockTube::sod();
    let exact = tube.exact().unwrap();
    let reference = |x: f64| exact.at(x, 0.0, T);
    for (name, params) in [
        ("sod_n400_sph_constant_viscosity", Sph1dParams::constant_viscosity()),
        ("sod_n400_sph_defaults", Sph1dParams::default()),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                let mut sim = tube.build(N, params).unwrap();
                sim.run_until(T).unwrap();
                sim.steps()
            })
        });
        let mut sim = tube.build(N, params).unwrap();
        sim.run_until(T).unwrap();
        let e = sim.l1_errors(0.0, 0.4, reference);
        eprintln!("{name}: {} steps, L1 rho {:.3e} u {:.3e} p {:.3e}", sim.steps(), e.rho, e.u, e.p);
    }
    c.bench_function("sod_n400_hll_fv", |b| b.iter(|| hll::solve(&tube, N, T, hll::DEFAULT_CFL).unwrap().steps));
    let fv = hll::solve(&tube, N, T, hll::DEFAULT_CFL).unwrap();
    let e = fv.l1_errors(0.0, 0.4, reference);
    eprintln!("sod_n400_hll_fv: {} steps, L1 rho {:.3e} u {:.3e} p {:.3e}", fv.steps, e.rho, e.u, e.p);
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = sod_rollouts
}
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
