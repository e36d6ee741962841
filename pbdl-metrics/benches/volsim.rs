//! VolSiM (3-scale weights) per pair at 64^3, native and from 48^3 with the cubic-spline resize
//! to 64^3, and the resize alone.
//!
//! Needs `VolSiM_MS_3scales.safetensors` in `$PBDL_WEIGHTS_DIR` or in `../shared/weights` beside
//! the checkout; without it the VolSiM cases are skipped with a message. Run with
//! `cargo bench -p pbdl-metrics --bench volsim`.
// criterion's macros generate undocumented functions.
#![allow(missing_docs)]

use candle_core::{DType, Device};
use criterion::{criterion_group, Criterion};
use pbdl_core::sample::spline_zoom;
use pbdl_core::seed;
use pbdl_metrics::volsim::VOLSIM_RESIZE;
use pbdl_metrics::Volsim;
use std::hint::black_box;
use std::time::Duration;

fn bench_volsim(c: &mut Criterion) {
    let dev = Device::Cpu;
    let vol = |n: usize, s: u64| seed::rand_uniform((1, 1, n, n, n), 0.0, 1.0, DType::F32, &dev, s).unwrap();
    let (s48, t48) = (vol(48, 3), vol(48, 4));
    let mut g = c.benchmark_group("volsim");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    let x = s48.repeat((1, 3, 1, 1, 1)).unwrap().to_dtype(DType::F64).unwrap();
    g.bench_function("spline_zoom_48_to_64_3ch_f64", |b| b.iter(|| black_box(spline_zoom(&x, &[64, 64, 64]).unwrap())));
    let dir = pbdl_metrics::weights::weights_dir().unwrap_or_default();
    let v = match Volsim::load(dir.join(pbdl_metrics::weights::VOLSIM_FILE)) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("skipping volsim/pair_64: {e} (set PBDL_WEIGHTS_DIR)");
            g.finish();
            return;
        }
    };
    let (a, b) = (vol(64, 1), vol(64, 2));
    g.bench_function("pair_64", |bch| bch.iter(|| black_box(v.distance(&a, &b).unwrap())));
    let r = v.with_resize(Some(VOLSIM_RESIZE)).unwrap();
    g.bench_function("pair_48_resize_64", |bch| bch.iter(|| black_box(r.distance(&s48, &t48).unwrap())));
    g.finish();
}

criterion_group!(benches, bench_volsim);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
