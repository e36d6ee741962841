//! The ACDM U-Net on the CPU: one training step (forward, smooth-L1 noise loss, backward,
//! Adam update) and one sampling step (forward only), f32, 12 channels (Inc: 3 frames x 4
//! fields), at CPU-sized widths (dim 16 and 32, 64x32, batch 16). The full-size network
//! (dim 128, 128x64, batch 4) runs when `PBDL_BENCH_FULL=1` is set (seconds per step).
//!
//! The PyTorch peer of the same step is `bench/peers/acdm_unet_torch.py`.
#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (see the workspace Cargo.toml).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_diffusion::unet::workload::{UnetFixture, UnetWorkload};

fn workloads() -> Vec<UnetWorkload> {
    let mut w: Vec<UnetWorkload> =
        [16, 32].into_iter().map(|dim| UnetWorkload { dim, channels: 12, batch: 16, height: 64, width: 32 }).collect();
    if std::env::var("PBDL_BENCH_FULL").is_ok_and(|v| v == "1") {
        w.push(UnetWorkload { dim: 128, channels: 12, batch: 4, height: 128, width: 64 });
    }
    w
}

fn unet(c: &mut Criterion) {
    let mut g = c.benchmark_group("acdm_unet_f32");
    g.sample_size(10);
    for w in workloads() {
        let mut fx = UnetFixture::new(&w, 0).unwrap();
        g.bench_function(BenchmarkId::new("train_step", w.label()), |b| b.iter(|| fx.train_step().unwrap()));
        g.bench_function(BenchmarkId::new("sample_step", w.label()), |b| b.iter(|| fx.sample_step().unwrap()));
    }
    g.finish();
}

criterion_group!(benches, unet);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
