//! Advection kernels, f32, periodic Taylor-Green velocity at CFL ~0.5: semi-Lagrangian and
//! MacCormack of a one-channel centred scalar and of the MAC velocity itself, and the central
//! flux-form tendency for comparison, at 64^2, 128^2, 256^2.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::DType;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_grid::advect::{flux_form, mac_cormack, semi_lagrangian};
use pbdl_grid::{Boundaries, CenteredField, Grid, MacField, ScalarBoundaries};
use std::f64::consts::PI;

fn advection(c: &mut Criterion) {
    let mut g = c.benchmark_group("advect_f32");
    g.sample_size(30);
    for n in [64, 128, 256] {
        let grid = Grid::square(n, 2.0 * PI).unwrap();
        let bc = Boundaries::periodic();
        let u = MacField::from_fn(grid, bc, DType::F32, |x, y| [x.sin() * y.cos(), -x.cos() * y.sin()]).unwrap();
        let q =
            CenteredField::from_fn(grid, ScalarBoundaries::periodic(), 1, DType::F32, |x, y| vec![(x + 2.0 * y).sin()])
                .unwrap();
        let dt = 0.5 * grid.dx();
        g.bench_with_input(BenchmarkId::new("semi_lagrangian_scalar", n), &n, |b, _| {
            b.iter(|| semi_lagrangian(&q, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("mac_cormack_scalar", n), &n, |b, _| {
            b.iter(|| mac_cormack(&q, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("semi_lagrangian_velocity", n), &n, |b, _| {
            b.iter(|| semi_lagrangian(&u, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("mac_cormack_velocity", n), &n, |b, _| {
            b.iter(|| mac_cormack(&u, &u, dt).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("flux_form_velocity", n), &n, |b, _| b.iter(|| flux_form(&u).unwrap()));
    }
    g.finish();
}

criterion_group!(benches, advection);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
