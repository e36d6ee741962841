//! Periodic 3D incompressible Navier-Stokes (`pbdl_grid::grid3d`), ABC flow on [0, 2 pi]^3:
//! the fused momentum right-hand side (flux-form advection + viscosity), the FFT projection,
//! and one full RK4 step (4 right-hand sides, 4 projections), at 32^3 and 64^3, f32 and f64.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::DType;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::grid3d::abc::abc_flow;
use pbdl_grid::grid3d::{momentum, pressure, Grid3d, NavierStokes3d, NavierStokes3dConfig};
use pbdl_grid::Scheme;
use std::f64::consts::PI;
use std::time::Duration;

/// Same allocator as `cargo xtask` and the 2D benches (see docs/candle-traps.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

const NU: f64 = 0.01;

fn ns3d(c: &mut Criterion) {
    for dtype in [DType::F32, DType::F64] {
        let name = format!("{dtype:?}").to_lowercase();
        let mut g = c.benchmark_group(format!("ns3d_{name}"));
        g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
        for n in [32, 64] {
            let grid = Grid3d::cube(n, 2.0 * PI).unwrap();
            // CFL 0.5 on the largest component (2), as in tests/ns3d.rs.
            let dt = 0.5 * grid.min_spacing() / 2.0;
            let ns = NavierStokes3d::new(grid, NavierStokes3dConfig { nu: NU, dt, scheme: Scheme::Rk4 }).unwrap();
            let u = abc_flow(grid, [1.0, 1.0, 1.0], NU, 0.0, dtype).unwrap();
            g.bench_with_input(BenchmarkId::new("advection_flux_form", n), &u, |b, u| {
                b.iter(|| momentum::flux_form(u).unwrap())
            });
            g.bench_with_input(BenchmarkId::new("momentum_rhs", n), &u, |b, u| {
                b.iter(|| momentum::momentum_rhs(u, NU).unwrap())
            });
            g.bench_with_input(BenchmarkId::new("projection_fft", n), &u, |b, u| {
                b.iter(|| pressure::make_incompressible(u, ns.solver()).unwrap())
            });
            g.bench_with_input(BenchmarkId::new("step_rk4", n), &u, |b, u| b.iter(|| ns.step(u).unwrap()));
        }
        g.finish();
    }
}

criterion_group!(benches, ns3d);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
