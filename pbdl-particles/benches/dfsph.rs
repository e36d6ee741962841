//! Time against error, DFSPH against IISPH on the same dam break (Martin & Moyce geometry,
//! dx = a/20: 800 fluid + wall particles, both at their default tolerance 0.1%): each iteration
//! builds the scene and runs it to T = 1 (`Evolve::run_until`), neighbour search included.
//! After the timing each case prints its steps, pressure-solve iterations per step and the
//! largest mean compression of the summation density after any step, measured on one more run.
//!
//! Measured 2026-11-27 (release, shared 2-core machine under load 3.6-5.8, criterion median and
//! range): IISPH 120 ms (99-135) for 46 steps, 5.67 iterations/step, mean compression max
//! 1.080e-3; DFSPH 109 ms (100-124) for 47 steps, 3.57 density + 1.81 divergence iterations/step,
//! mean compression max 1.085e-3. The ranges overlap: no speed difference is shown at this size.
//!
//! Measured 2026-11-29 after issue 24 (walls in `pbdl_particles::walls`, DFSPH's summation-density
//! prediction and particle-deficiency rule; release, shared 2-core machine with two other builds
//! running): IISPH 87.0 ms (76.4-92.4) for 46 steps, 5.67 iterations/step, mean compression max
//! 1.080e-3; DFSPH 85.5 ms (81.2-90.2) for 47 steps, 4.13 density + 1.00 divergence
//! iterations/step, mean compression max 9.148e-4. The ranges overlap again.
//!
//! `dam_break_3d_step_dfsph_a10`: one 3D DFSPH step (`DamBreak3d::build_dfsph`,
//! `DfsphParams::default_3d`) at dx = a/10 (1,000 fluid particles), from a copy of the column 20
//! steps after its release (T ~ 0.4); its per-step numbers are printed after the timing.

#![allow(missing_docs)] // criterion_group! generates undocumented items

use criterion::{criterion_group, BatchSize, Criterion};
use pbdl_particles::dfsph::DfsphParams;
use pbdl_particles::wcsph3d::DamBreak3d;
use pbdl_particles::{DamBreak, Evolve, IisphParams};

const BIG_T: f64 = 1.0;

fn dfsph_vs_iisph(c: &mut Criterion) {
    let scene = DamBreak::default();
    let t_end = scene.physical_time(BIG_T);
    c.bench_function("dam_break_to_T1_iisph", |b| {
        b.iter(|| {
            let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
            sim.run_until(t_end).unwrap();
            sim.steps()
        })
    });
    c.bench_function("dam_break_to_T1_dfsph", |b| {
        b.iter(|| {
            let mut sim = scene.build_dfsph(DfsphParams::default()).unwrap();
            sim.run_until(t_end).unwrap();
            sim.steps()
        })
    });
    // The error side of the rows (one run each, the density checked after every step).
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    let mut worst = 0.0f64;
    while sim.time() < t_end * (1.0 - 1e-14) {
        sim.step(sim.next_dt(t_end)).unwrap();
        worst = worst.max(sim.average_compression().unwrap());
    }
    eprintln!(
        "iisph: {} steps, {:.2} iterations/step, mean compression max {:.3e}",
        sim.steps(),
        sim.total_iterations() as f64 / sim.steps() as f64,
        worst
    );
    let mut sim = scene.build_dfsph(DfsphParams::default()).unwrap();
    let mut worst = 0.0f64;
    while sim.time() < t_end * (1.0 - 1e-14) {
        sim.step(sim.next_dt(t_end)).unwrap();
        worst = worst.max(sim.average_compression().unwrap());
    }
    eprintln!(
        "dfsph: {} steps, {:.2} density + {:.2} divergence iterations/step, mean compression max {:.3e}",
        sim.steps(),
        sim.total_iterations() as f64 / sim.steps() as f64,
        sim.total_divergence_iterations() as f64 / sim.steps() as f64,
        worst
    );
}

fn dfsph_3d_step(c: &mut Criterion) {
    let scene = DamBreak3d { dx: 0.1, ..DamBreak3d::default() };
    let mut sim = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    for _ in 0..20 {
        sim.step(sim.stable_dt()).unwrap();
    }
    let dt = sim.stable_dt();
    c.bench_function("dam_break_3d_step_dfsph_a10", |b| {
        b.iter_batched(|| sim.clone(), |mut s| s.step(dt).unwrap(), BatchSize::LargeInput)
    });
    sim.step(dt).unwrap();
    let s = sim.last_solve();
    eprintln!(
        "dfsph 3D a/10: {} fluid + {} wall particles, dt {dt:.2e} s, {} density + {} divergence iterations, mean compression {:.3e}",
        sim.n_fluid(),
        sim.x.len() - sim.n_fluid(),
        s.iterations,
        s.divergence_iterations,
        sim.average_compression().unwrap()
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = dfsph_vs_iisph, dfsph_3d_step
}
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
