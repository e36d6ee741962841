//! One WCSPH dam-break step (Martin & Moyce geometry, Wendland C2, h = 1.3 dx, walls included)
//! at ~2k particles (dx = a/20: 800 fluid + 996 wall) and ~110k particles (dx = a/224), in f64
//! and f32. Each iteration is one kick-drift-kick step at the stable dt, neighbour search
//! included, continuing the same run (the flow develops during the measurement; a few hundred
//! steps move the front by well under a particle spacing at these sizes).
//! Peer: PySPH 1.0b2 dam_break_2d at dx = 0.05, measured on the machine at hand by
//! `bench/peers/particles_run.sh` (`cargo xtask bench particles` shows it with its date).

#![allow(missing_docs)] // criterion_group! generates undocumented items

use criterion::{criterion_group, Criterion};
use pbdl_core::Real;
use pbdl_particles::{DamBreak, WcsphParams};

fn bench_case<T: Real>(c: &mut Criterion, dx: f64, label: &str) {
    let scene = DamBreak { dx, ..Default::default() };
    let mut sim = scene.build_as::<T>(WcsphParams::default()).unwrap();
    let name = format!("wcsph_step_{label}_{}_particles", sim.x.len());
    c.bench_function(&name, |b| {
        b.iter(|| {
            let dt = sim.stable_dt().0;
            sim.step(dt).unwrap();
        })
    });
    eprintln!("{name}: simulated to t = {:.4} s in {} steps, finite: {}", sim.time(), sim.steps(), sim.is_finite());
}

fn wcsph(c: &mut Criterion) {
    bench_case::<f64>(c, 0.05, "f64");
    bench_case::<f32>(c, 0.05, "f32");
    bench_case::<f64>(c, 1.0 / 224.0, "f64");
    bench_case::<f32>(c, 1.0 / 224.0, "f32");
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = wcsph
}
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
