//! 3D scalar transport of the smoke plume's density, f32, a swirling velocity at CFL ~0.5 in a
//! closed box: the conservative flux-corrected scheme (`grid3d::conservative`) against the
//! semi-Lagrangian and MacCormack schemes it replaces when `density_advection = "conservative"`,
//! at 32^3 and 64^3.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::{DType, Device, Tensor};
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::grid3d::advect::{mac_cormack_scalar, semi_lagrangian_scalar};
use pbdl_grid::grid3d::{Conservative3d, Grid3d, MacField3d};
use std::f64::consts::PI;

fn advection3d(c: &mut Criterion) {
    let mut g = c.benchmark_group("advect3d_scalar_f32");
    g.sample_size(20);
    for n in [32, 64] {
        let grid = Grid3d::cube(n, 1.0).unwrap();
        let u = MacField3d::from_fn(grid, DType::F32, |x, y, z| {
            let (sx, sy, sz) = ((PI * x).sin(), (PI * y).sin(), (PI * z).sin());
            [sx * (PI * y).cos() * sz, -(PI * x).cos() * sy * sz, 0.3 * sx * sy]
        })
        .unwrap();
        let values: Vec<f32> = (0..n * n * n).map(|i| ((i * 7919) % 101) as f32 / 100.0).collect();
        let q = Tensor::from_vec(values, grid.shape(1, 1).to_vec(), &Device::Cpu).unwrap();
        let dt = 0.5 / n as f64;
        let fct = Conservative3d::closed_box();
        g.bench_with_input(BenchmarkId::new("conservative_fct", n), &n, |b, _| {
            b.iter(|| fct.step(&q, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("semi_lagrangian", n), &n, |b, _| {
            b.iter(|| semi_lagrangian_scalar(&q, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("mac_cormack", n), &n, |b, _| {
            b.iter(|| mac_cormack_scalar(&q, &u, dt).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, advection3d);
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
