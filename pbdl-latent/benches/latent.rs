//! The parts of a latent-space physics step against the pressure solve they replace, 2D smoke
//! plume at 32^2, 64^2 and 128^2 (f32, batch 1): the solver's pressure solve + correction
//! (`Fluid::project_keep_pressure`), the correction with a given pressure, the autoencoder's
//! encode and decode, the LSTM's prediction (window 6, 256 / 512 units), a whole solver step
//! and a whole predicted hybrid step. The default architecture with untrained weights: the time
//! does not depend on the weights' values.
//!
//! `PBDL_LATENT_BENCH_N=64` runs one size only.

#![allow(missing_docs)] // criterion_group! generates undocumented items

use candle_core::Tensor;
use criterion::{criterion_group, BenchmarkId, Criterion};
use pbdl_core::stepper::Stepper;
use pbdl_latent::data::PlumeData;
use pbdl_latent::hybrid::{HybridSmoke, HybridState, PressureSource, Schedule};
use pbdl_latent::model::LatentModel;
use std::time::Duration;

/// Same allocator as `cargo xtask` and the other benches.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn bench(c: &mut Criterion) {
    pbdl_core::threads::init().unwrap();
    let sizes: Vec<usize> = match std::env::var("PBDL_LATENT_BENCH_N") {
        Ok(s) => vec![s.parse().expect("PBDL_LATENT_BENCH_N: a size such as 64")],
        Err(_) => vec![32, 64, 128],
    };
    let mut g = c.benchmark_group("latent_step");
    g.sample_size(20).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
    for n in sizes {
        let scene = PlumeData { resolution: n, ..PlumeData::default() }.scene(0.5);
        let fluid = scene.fluid().unwrap();
        let rate = scene.rate().unwrap();
        let m = LatentModel::untrained(n).unwrap();
        let mut state = scene.start(&fluid).unwrap();
        for _ in 0..20 {
            state = fluid.step(&state, Some(&rate)).unwrap();
        }
        let before = fluid.step_unprojected(&state, Some(&rate)).unwrap();
        let (_, pressure) = fluid.project_keep_pressure(&before.velocity).unwrap();
        let code = m.encode_pressure(pressure.values()).unwrap();
        let history = Tensor::stack(&vec![code.clone(); 6], 1).unwrap();
        g.bench_function(BenchmarkId::new("solver_pressure_solve_and_correct", n), |b| {
            b.iter(|| fluid.project_keep_pressure(&before.velocity).unwrap())
        });
        g.bench_function(BenchmarkId::new("given_pressure_correct", n), |b| {
            b.iter(|| fluid.correct_with_pressure(&before.velocity, &pressure).unwrap())
        });
        g.bench_function(BenchmarkId::new("encode", n), |b| b.iter(|| m.encode_pressure(pressure.values()).unwrap()));
        g.bench_function(BenchmarkId::new("lstm_predict", n), |b| b.iter(|| m.predict(&history).unwrap()));
        g.bench_function(BenchmarkId::new("decode", n), |b| b.iter(|| m.decode_pressure(&code).unwrap()));
        g.bench_function(BenchmarkId::new("solver_step", n), |b| b.iter(|| fluid.step(&state, Some(&rate)).unwrap()));
        let hybrid =
            HybridSmoke::new(scene.fluid().unwrap(), rate.clone(), &m, Schedule { warmup: 6, interval: 1 << 20 })
                .unwrap();
        let mut hs = HybridState::new(state.clone());
        // The warm-up, then the schedule's first solve: the next step predicts.
        for _ in 0..=6 {
            hs = hybrid.step(&hs).unwrap();
        }
        assert_eq!(hybrid.step(&hs).unwrap().last, Some(PressureSource::Predicted));
        g.bench_function(BenchmarkId::new("hybrid_predicted_step", n), |b| b.iter(|| hybrid.step(&hs).unwrap()));
    }
    g.finish();
}

criterion_group!(benches, bench);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
}
