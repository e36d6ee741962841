//! LSiM per pair (128x128 -> 224, default options) and SSIM 2D on a batch of 16 fields of 128x128.
//!
//! The LSiM case needs `LSiM.safetensors` in `$PBDL_WEIGHTS_DIR` or in `../shared/weights` beside
//! the checkout (as the weight tests); without it the case is skipped with a message. Run with `cargo bench -p pbdl-metrics --bench lsim`.
// criterion's macros generate undocumented functions.
#![allow(missing_docs)]

use candle_core::{DType, Device};
use criterion::{criterion_group, Criterion};
use pbdl_core::seed;
use pbdl_metrics::classic::{ssim2d, SsimConfig};
use pbdl_metrics::Lsim;
use std::hint::black_box;
use std::time::Duration;

fn bench_lsim(c: &mut Criterion) {
    let dir = pbdl_metrics::weights::weights_dir().unwrap_or_default();
    let lsim = match Lsim::load(dir.join(pbdl_metrics::weights::LSIM_FILE)) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("skipping lsim/pair_128_to_224: {e} (set PBDL_WEIGHTS_DIR)");
            return;
        }
    };
    let dev = Device::Cpu;
    let a = seed::rand_uniform((1, 1, 128, 128), 0.0, 1.0, DType::F32, &dev, 10).unwrap();
    let b = seed::rand_uniform((1, 1, 128, 128), 0.0, 1.0, DType::F32, &dev, 11).unwrap();
    let mut g = c.benchmark_group("lsim");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.bench_function("pair_128_to_224", |bch| bch.iter(|| black_box(lsim.distance(&a, &b).unwrap())));
    g.finish();
}

fn bench_ssim(c: &mut Criterion) {
    let dev = Device::Cpu;
    let a = seed::randn((16, 1, 128, 128), 0.0, 1.0, DType::F32, &dev, 1).unwrap();
    let b = (&a + seed::randn((16, 1, 128, 128), 0.0, 0.1, DType::F32, &dev, 2).unwrap()).unwrap();
    let cfg = SsimConfig::default();
    let mut g = c.benchmark_group("ssim2d");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    g.bench_function("batch16_128x128", |bch| bch.iter(|| black_box(ssim2d(&a, &b, &cfg).unwrap())));
    g.finish();
}

criterion_group!(benches, bench_lsim, bench_ssim);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
