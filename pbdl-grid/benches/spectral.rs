//! Pseudo-spectral Navier-Stokes (`pbdl_grid::spectral`): one fast-path step (CN-RK4, f32) of
//! decaying 2D turbulence at 64^2 and 128^2 and of the 3D ABC flow at 32^3, and one step of the
//! differentiable 2D path at 64^2 (candle graph, for the cost of gradients).
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use candle_core::{DType, Device, Tensor};
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_core::stepper::Stepper;
use pbdl_grid::grid3d::Grid3d;
use pbdl_grid::spectral::{SpectralConfig, SpectralNavierStokes, SpectralNavierStokes3d};
use pbdl_grid::Grid;
use std::f64::consts::PI;
use std::time::Duration;

/// Same allocator as `cargo xtask` and the other benches.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn config(dt: f64) -> SpectralConfig {
    SpectralConfig { nu: 1e-3, dt, scheme: Default::default(), drag: 0.0 }
}

fn spectral(c: &mut Criterion) {
    let mut g = c.benchmark_group("spectral_f32");
    g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(3));
    for n in [64usize, 128] {
        let grid = Grid::square(n, 2.0 * PI).unwrap();
        let ns = SpectralNavierStokes::new(grid, config(0.5 * grid.dx() / 3.0)).unwrap();
        let w: Vec<f32> = (0..grid.cells())
            .map(|k| {
                let (x, y) = (((k % n) as f64 + 0.5) * grid.dx(), ((k / n) as f64 + 0.5) * grid.dy());
                ((1.5 * x.cos() + (y + 0.3).sin()).exp() - (1.2 * (x - 2.0 * y).sin()).exp()) as f32
            })
            .collect();
        let w = Tensor::from_vec(w, (n, n), &Device::Cpu).unwrap();
        let mut state = ns.state_from_vorticity(&w, [0.0, 0.0]).unwrap();
        g.bench_function(BenchmarkId::new("step_2d_fast", n), |b| b.iter(|| ns.advance(&mut state, 1).unwrap()));
        if n == 64 {
            let u = ns.velocity(&state).unwrap();
            g.bench_function(BenchmarkId::new("step_2d_differentiable", n), |b| b.iter(|| ns.step(&u).unwrap()));
        }
    }
    let grid = Grid3d::cube(32, 2.0 * PI).unwrap();
    let ns = SpectralNavierStokes3d::new(grid, config(0.25 * grid.min_spacing())).unwrap();
    let u =
        ns.sample_velocity(DType::F32, |x, y, z| [z.sin() + y.cos(), x.sin() + z.cos(), y.sin() + x.cos()]).unwrap();
    let mut state = ns.state_from_velocity(&u).unwrap();
    g.bench_function(BenchmarkId::new("step_3d_fast", 32), |b| b.iter(|| ns.advance(&mut state, 1).unwrap()));
    g.finish();
}

criterion_group!(benches, spectral);

fn main() {
    pbdl_core::threads::init().expect("thread policy");
    benches();
    Criterion::default().configure_from_args().final_summary();
}
