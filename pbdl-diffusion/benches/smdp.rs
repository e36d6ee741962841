//! SMDP hot paths: the toy's batched Euler-Maruyama simulator, one 1-step and one multi-step
//! (window 8, backprop through the rollout) update of the score MLP at batch 256, one
//! reverse-SDE sample of 1000 points over the full horizon, and the spectral heat step with
//! its gradient on a `[16, 1, 32, 32]` f32 batch.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (see the workspace Cargo.toml).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use candle_core::{DType, Var};
use criterion::{criterion_group, Criterion};
use pbdl_diffusion::smdp::heat::{heat_step, HeatProblem};
use pbdl_diffusion::smdp::loss::{multi_step_loss, one_step_loss, LossWorkspace};
use pbdl_diffusion::smdp::mlp::{paper_adam, ScoreMlp};
use pbdl_diffusion::smdp::sampler::{sample, Sampler};
use pbdl_diffusion::smdp::sde::{two_point_starts, ToySde};

fn smdp(c: &mut Criterion) {
    let sde = ToySde::paper_quadratic();
    let mut g = c.benchmark_group("smdp");
    g.sample_size(10);
    let x0 = vec![1.0; 10_000];
    g.bench_function("toy_forward_sde_10k_paths_500_steps", |b| b.iter(|| sde.endpoints(&x0, 1).unwrap()));

    let paths = sde.simulate(&two_point_starts(256), 2).unwrap();
    let k = |p: usize| 10 + p % 400;
    let x: Vec<f64> = (0..256).map(|p| paths.path(p)[k(p)]).collect();
    let t: Vec<f64> = (0..256).map(|p| k(p) as f64 * sde.dt).collect();
    let targets: Vec<Vec<f64>> = (0..8).map(|m| (0..256).map(|p| paths.path(p)[k(p) - 1 - m]).collect()).collect();
    let mut net = ScoreMlp::paper(0);
    let mut adam = paper_adam(net.num_params(), 1e-5);
    let mut grad = vec![0.0; net.num_params()];
    let mut ws = LossWorkspace::default();
    g.bench_function("toy_one_step_update_b256", |b| {
        b.iter(|| {
            grad.fill(0.0);
            one_step_loss(&net, &sde.drift, sde.dt, &x, &t, &targets[0], Some(&mut grad), &mut ws);
            adam.step(net.params_mut(), &grad).unwrap();
        })
    });
    g.bench_function("toy_multi_step_update_w8_b256", |b| {
        b.iter(|| {
            grad.fill(0.0);
            multi_step_loss(&net, &sde.drift, sde.dt, &x, &t, &targets, false, Some(&mut grad), &mut ws);
            adam.step(net.params_mut(), &grad).unwrap();
        })
    });
    let y: Vec<f64> = (0..1000).map(|i| -0.1 + 0.2 * i as f64 / 999.0).collect();
    g.bench_function("toy_reverse_sde_1000_points", |b| {
        b.iter(|| sample(&sde, &net, &y, Sampler::ReverseSde, 3).unwrap())
    });

    let fields = HeatProblem::default().random_fields(16, DType::F32, 0).unwrap();
    g.bench_function("heat_step_16x32x32_f32", |b| b.iter(|| heat_step(&fields, 0.01).unwrap()));
    let v = Var::from_tensor(&fields).unwrap();
    g.bench_function("heat_step_fwd_bwd_16x32x32_f32", |b| {
        b.iter(|| heat_step(v.as_tensor(), 0.01).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap())
    });
    g.finish();
}

criterion_group!(benches, smdp);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
