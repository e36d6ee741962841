//! Sampling cost with the exact Gaussian noise predictor (so the time is the sampler's own plus a
//! cheap predictor): one ancestral DDPM step, a full 20-step DDPM sample (ACDM's R = 20) and a
//! 20-step DDIM sample, each on a `[16, 2, 32, 32]` f32 batch with clean conditioning on one channel.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (see the workspace Cargo.toml).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use candle_core::{DType, Device};
use criterion::{criterion_group, Criterion};
use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle};
use pbdl_diffusion::schedule::NoiseSchedule;

fn sampling(c: &mut Criterion) {
    let dev = Device::Cpu;
    let s = NoiseSchedule::acdm(20).unwrap();
    // Per pixel: condition c ~ N(0, 1), targets correlated with it.
    let cov = vec![1.0, 0.8, 0.0, 0.8, 0.73, 0.0, 0.0, 0.0, 0.25];
    let oracle = GaussianOracle::joint(s.clone(), vec![0.0, 1.0, -0.5], cov).unwrap().with_clean_condition(1).unwrap();
    let d = Diffusion::new(s, Conditioning::Clean);
    let cond = Diffusion::noise(&[16, 1, 32, 32], DType::F32, &dev, 1).unwrap();
    let x = Diffusion::noise(&[16, 2, 32, 32], DType::F32, &dev, 2).unwrap();
    let steps = d.ddim_steps(20).unwrap();
    let mut g = c.benchmark_group("oracle_sampling_b16_c2_32x32");
    g.sample_size(20);
    g.bench_function("ddpm_step", |b| b.iter(|| d.sample_ddpm_step(&oracle, Some(&cond), &x, 10, 3).unwrap()));
    g.bench_function("ddpm_sample_R20", |b| b.iter(|| d.sample_ddpm(&oracle, Some(&cond), &x, 3).unwrap()));
    g.bench_function("ddim_sample_k20", |b| {
        b.iter(|| d.sample_ddim(&oracle, Some(&cond), &x, &steps, 0.0, 3).unwrap())
    });
    g.finish();
}

criterion_group!(benches, sampling);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
