//! Walled-box pressure projection in 3D (closed unit cube, 32^3 and 64^3): the factor-once sparse
//! Cholesky (`CholeskyBox3d`: factor time and factor size printed once, then one solve per
//! projection) against MIC(0)-preconditioned CG (`CgBox3d`, tau = 0.97) at relative tolerance
//! 1e-6, cold (zero start) and warm (start from the pressure of a slightly different velocity, as
//! from the previous time step). Both paths share the divergence / gradient work, so the
//! difference is the solve. f64 input; f32 input for the cold paths (the solvers work in f64,
//! so f32 only adds the conversions).
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::DType;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::grid3d::box_pressure::make_incompressible_box;
use pbdl_grid::grid3d::{BoxSolver, CgBox3d, CholeskyBox3d, Grid3d, MacField3d};
use pbdl_grid::pressure::CgSettings;
use std::time::{Duration, Instant};

/// Same allocator as `cargo xtask` and the other benches.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn velocity(g: Grid3d, phase: f64, dtype: DType) -> MacField3d {
    MacField3d::from_fn(g, dtype, |x, y, z| {
        [
            (7.0 * x + phase).sin() * (5.0 * y).cos() * (3.0 * z).cos() + x * y,
            (3.0 * x * y + phase).cos() - y * z,
            (4.0 * y + 2.0 * z + phase).sin() * x,
        ]
    })
    .unwrap()
}

fn pressure3d(c: &mut Criterion) {
    let mut group = c.benchmark_group("pressure3d_walls");
    group.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    let settings = CgSettings::default();
    assert_eq!(settings.rel_tol, 1e-6);
    for n in [32, 64] {
        let g = Grid3d::cube(n, 1.0).unwrap();
        let (u_prev, u) = (velocity(g, 0.3, DType::F64), velocity(g, 0.31, DType::F64));
        let u32 = velocity(g, 0.31, DType::F32);
        let t = Instant::now();
        let chol = CholeskyBox3d::new(g).unwrap();
        let factor_s = t.elapsed().as_secs_f64();
        eprintln!(
            "{n}^3: Cholesky ({:?} order) factored in {factor_s:.2} s; factor entries {} ({:.1} per cell, {:.0} MiB of values)",
            chol.ordering(),
            chol.factor_entries(),
            chol.factor_entries() as f64 / g.cells() as f64,
            chol.factor_entries() as f64 * 8.0 / (1024.0 * 1024.0)
        );
        let t = Instant::now();
        let cg = CgBox3d::new(g, settings).unwrap();
        eprintln!("{n}^3: CG set-up {:.3} s", t.elapsed().as_secs_f64());
        let mut p_prev = Vec::new();
        cg.project(&u_prev, &mut p_prev).unwrap();
        let cold = cg.project(&u, &mut Vec::new()).unwrap().1;
        let warm = cg.project(&u, &mut p_prev.clone()).unwrap().1;
        eprintln!("{n}^3: MIC(0) CG iterations cold {}, warm {}", cold.iterations, warm.iterations);
        let (chol, cg_op) = (BoxSolver::Cholesky(chol), BoxSolver::Cg(cg.clone()));
        group.bench_function(BenchmarkId::new("cholesky_project", n), |b| {
            b.iter(|| make_incompressible_box(&u, &chol).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_project_cold", n), |b| {
            b.iter(|| make_incompressible_box(&u, &cg_op).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_project_warm", n), |b| {
            b.iter(|| cg.project(&u, &mut p_prev.clone()).unwrap())
        });
        group.bench_function(BenchmarkId::new("cholesky_project_f32", n), |b| {
            b.iter(|| make_incompressible_box(&u32, &chol).unwrap())
        });
        group.bench_function(BenchmarkId::new("cg_project_cold_f32", n), |b| {
            b.iter(|| make_incompressible_box(&u32, &cg_op).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, pressure3d);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
