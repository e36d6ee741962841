//! One incompressible Navier-Stokes step (flux-form advection + explicit viscosity + projection
//! per Runge-Kutta stage), f32, the Taylor-Green setup of the tests (periodic, FFT pressure) and
//! the lid-driven cavity (walls, sparse Cholesky pressure).
//!
//! Peers (JAX-CFD FV + RK4 and spectral, PhiFlow) are not quoted here, because quoted times go
//! stale: `bench/peers/run.sh` measures them on the machine at hand and `cargo xtask bench grid`
//! shows them beside pbdl's rows with their date and versions.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::DType;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
use std::f64::consts::PI;

/// Same allocator as `cargo xtask` (see docs/candle-traps.md): candle's per-op output buffers
/// would otherwise go through glibc's mmap path at 128^2+.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn tgv(c: &mut Criterion) {
    let mut g = c.benchmark_group("ns_step_tgv_f32");
    g.sample_size(30);
    for scheme in [Scheme::Rk4, Scheme::SspRk3] {
        for n in [64, 128, 256] {
            let grid = Grid::square(n, 2.0 * PI).unwrap();
            let bc = Boundaries::periodic();
            let probe = NavierStokes::new(grid, bc, NavierStokesConfig { nu: 0.01, dt: 1e-9, scheme }).unwrap();
            let dt = (0.5 * grid.dx()).min(probe.stable_time_step([1.0, 1.0]));
            let ns = NavierStokes::new(grid, bc, NavierStokesConfig { nu: 0.01, dt, scheme }).unwrap();
            let u = MacField::from_fn(grid, bc, DType::F32, |x, y| [x.sin() * y.cos(), -x.cos() * y.sin()]).unwrap();
            g.bench_with_input(BenchmarkId::new(format!("{scheme:?}").to_lowercase(), n), &u, |b, u| {
                b.iter(|| ns.step(u).unwrap())
            });
        }
    }
    g.finish();
}

fn cavity(c: &mut Criterion) {
    let mut g = c.benchmark_group("ns_step_cavity_f32");
    g.sample_size(20);
    for n in [64, 128, 256] {
        let grid = Grid::square(n, 1.0).unwrap();
        let bc = Boundaries::lid_driven_cavity(1.0);
        let cfg = NavierStokesConfig { nu: 0.01, dt: 1e-6, scheme: Scheme::Rk4 };
        let dt = 0.9 * NavierStokes::new(grid, bc, cfg.clone()).unwrap().stable_time_step([1.0, 1.0]);
        let ns = NavierStokes::new(grid, bc, NavierStokesConfig { dt, ..cfg }).unwrap();
        let mut u = MacField::zeros(grid, bc, 1, DType::F32).unwrap();
        for _ in 0..20 {
            u = ns.step(&u).unwrap();
        }
        g.bench_with_input(BenchmarkId::new("rk4", n), &u, |b, u| b.iter(|| ns.step(u).unwrap()));
    }
    g.finish();
}

criterion_group!(benches, tgv, cavity);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
