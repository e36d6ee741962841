//! Masked pressure projection (f64, closed cavity + cylinder obstacle, 64^2 / 128^2 / 256^2):
//! sparse Cholesky (factor once, then one solve per projection) against MIC(0) preconditioned CG
//! at relative tolerance 1e-6, cold (zero start) and warm (start from the pressure of a slightly
//! different velocity, as from the previous time step). Both projections share the same
//! divergence / gradient work, so the per-projection difference is the solve.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::DType;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::pressure::{make_incompressible_masked, CgPressureSolver, CgSettings, MaskedPressureSolver};
use pbdl_grid::{Boundaries, Grid, MacField, Obstacle, ObstacleMask};
use std::time::Duration;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn velocity(g: Grid, bc: Boundaries, phase: f64) -> MacField {
    MacField::from_fn(g, bc, DType::F64, |x, y| {
        [(7.0 * x + phase).sin() * (5.0 * y).cos() + x * y, (3.0 * x * y + phase).cos() - y * y]
    })
    .unwrap()
}

fn pressure(c: &mut Criterion) {
    let mut group = c.benchmark_group("pressure_masked_f64");
    group.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    for n in [64, 128, 256] {
        let g = Grid::square(n, 1.0).unwrap();
        let bc = Boundaries::lid_driven_cavity(1.0);
        let mask = ObstacleMask::new(g, &[Obstacle::Cylinder { center: [0.35, 0.5], radius: 0.12 }]).unwrap();
        let (u_prev, u) = (velocity(g, bc, 0.3), velocity(g, bc, 0.31));
        let chol = MaskedPressureSolver::new(g, &bc, &mask).unwrap();
        let cg = CgPressureSolver::new(g, &bc, &mask, CgSettings::default()).unwrap();
        let mut p_prev = Vec::new();
        cg.project(&u_prev, &mut p_prev).unwrap();
        let cold = cg.project(&u, &mut Vec::new()).unwrap().1;
        let warm = cg.project(&u, &mut p_prev.clone()).unwrap().1;
        eprintln!("{n}^2: MIC(0) CG iterations cold {}, warm {}", cold.iterations, warm.iterations);
        group.bench_function(BenchmarkId::new("cholesky_factor", n), |b| {
            b.iter(|| MaskedPressureSolver::new(g, &bc, &mask).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_setup", n), |b| {
            b.iter(|| CgPressureSolver::new(g, &bc, &mask, CgSettings::default()).unwrap())
        });
        group.bench_function(BenchmarkId::new("cholesky_project", n), |b| {
            b.iter(|| make_incompressible_masked(&u, &chol).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_project_cold", n), |b| {
            b.iter(|| cg.project(&u, &mut Vec::new()).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_project_warm", n), |b| {
            b.iter(|| cg.project(&u, &mut p_prev.clone()).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, pressure);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
