//! Forward + backward of the fused NN kernels against their composed candle versions, and of
//! the real FFT, on the WeatherBench ResNet's activation size (batch 4, 128 channels, 32x64,
//! f32; one conv output of that network).
//!
//! * `leaky_relu` (slope 0.3): `nn::activation::leaky_relu` (fused) vs `leaky_relu_composed`;
//! * `batch_norm_train` (+ LeakyReLU epilogue): fused vs `batch_norm_train_composed`;
//! * `rfft2`: `fft::rfft2` then `irfft2`, forward + backward;
//! * `conv3x3_bias_leaky_relu` (128 -> 128 channels, zero padding in y, periodic in x, as the
//!   ResNet's units): `conv::conv_act` (one op) vs the same inside `nn::with_composed` (conv,
//!   candle's broadcast add of the bias, fused LeakyReLU: three graph nodes).
//!
//! A second group, `nn_small`, times the pieces added for the recurrent and MLP paths:
//! * `linear` (the 1024-unit LSTM's input projection, x [96, 1024], W [4096, 1024] + bias):
//!   `nn::linear` vs `with_composed` (candle's `matmul(w.t())` + broadcast add);
//! * `adamw_step` (40 variables of 128 x 128 x 3 x 3 plus biases, 5.9 M parameters): the
//!   in-place update vs the composed candle-nn expression;
//! * `tanh_1m` (a million f32): `vmath::tanh_in_place` vs libm's `tanh` in a loop.
//!
//! The backward uses a dense random output gradient (`sum(y * r)`). Run with
//! `cargo bench -p pbdl-core --bench nn_layers`.
// criterion's macros generate undocumented functions.
#![allow(missing_docs)]

use candle_core::{DType, Device, Tensor, Var};
use criterion::{criterion_group, Criterion};
use pbdl_core::conv::{conv_act, Conv2dParams, PaddingMode};
use pbdl_core::nn::activation::{leaky_relu, leaky_relu_composed};
use pbdl_core::nn::{batch_norm_train, batch_norm_train_composed, Activation};
use std::hint::black_box;
use std::time::Duration;

const SHAPE: (usize, usize, usize, usize) = (4, 128, 32, 64);

fn randn(shape: (usize, usize, usize, usize), seed: u64) -> Tensor {
    pbdl_core::seed::randn(shape, 0.0, 1.0, DType::F32, &Device::Cpu, seed).unwrap()
}

/// Forward `f` on the variables, then the gradients of `sum(f * r)` with respect to them.
fn fwd_bwd(vars: &[&Var], r: &Tensor, f: &dyn Fn(&[&Tensor]) -> Tensor) {
    let ts: Vec<&Tensor> = vars.iter().map(|v| v.as_tensor()).collect();
    let y = f(&ts);
    let grads = y.mul(r).unwrap().sum_all().unwrap().backward().unwrap();
    black_box(vars.iter().filter(|v| grads.get(v.as_tensor()).is_some()).count());
}

fn bench(c: &mut Criterion) {
    let x = Var::from_tensor(&randn(SHAPE, 0)).unwrap();
    let r = randn(SHAPE, 1);
    let leaky = 0.3;
    let mut g = c.benchmark_group("nn_layers_b4_c128_32x64");
    g.sample_size(20).measurement_time(Duration::from_secs(5));
    g.bench_function("leaky_relu/fused", |b| b.iter(|| fwd_bwd(&[&x], &r, &|t| leaky_relu(t[0], leaky).unwrap())));
    g.bench_function("leaky_relu/composed", |b| {
        b.iter(|| fwd_bwd(&[&x], &r, &|t| leaky_relu_composed(t[0], leaky).unwrap()))
    });
    let w = Var::ones(SHAPE.1, DType::F32, &Device::Cpu).unwrap();
    let bias = Var::zeros(SHAPE.1, DType::F32, &Device::Cpu).unwrap();
    let act = Activation::LeakyRelu { negative_slope: leaky };
    g.bench_function("batch_norm_train/fused", |b| {
        b.iter(|| {
            fwd_bwd(&[&x, &w, &bias], &r, &|t| batch_norm_train(t[0], Some(t[1]), Some(t[2]), 1e-5, act).unwrap().0)
        })
    });
    g.bench_function("batch_norm_train/composed", |b| {
        b.iter(|| {
            fwd_bwd(&[&x, &w, &bias], &r, &|t| {
                batch_norm_train_composed(t[0], Some(t[1]), Some(t[2]), 1e-5, act).unwrap().0
            })
        })
    });
    let wc = Var::from_tensor(&(randn((128, 128, 3, 3), 2) * 0.03).unwrap()).unwrap();
    let bc = Var::zeros(128, DType::F32, &Device::Cpu).unwrap();
    let p = Conv2dParams {
        padding_mode: [PaddingMode::Zeros, PaddingMode::Circular],
        ..Conv2dParams::default().padding(1)
    };
    let conv = |t: &[&Tensor]| conv_act(t[0], t[1], Some(t[2]), &p, act).unwrap();
    g.bench_function("conv3x3_bias_leaky_relu/fused", |b| b.iter(|| fwd_bwd(&[&x, &wc, &bc], &r, &conv)));
    g.bench_function("conv3x3_bias_leaky_relu/composed", |b| {
        b.iter(|| pbdl_core::nn::with_composed(|| fwd_bwd(&[&x, &wc, &bc], &r, &conv)))
    });
    g.bench_function("rfft2_irfft2", |b| {
        b.iter(|| {
            fwd_bwd(&[&x], &r, &|t| {
                let z = pbdl_core::fft::rfft2(t[0]).unwrap();
                pbdl_core::fft::irfft2(&z, SHAPE.3).unwrap()
            })
        })
    });
    g.finish();
}

fn bench_small(c: &mut Criterion) {
    let mut g = c.benchmark_group("nn_small");
    g.sample_size(20).measurement_time(Duration::from_secs(5));
    let dev = Device::Cpu;
    let rnd = |shape: &[usize], seed| pbdl_core::seed::randn(shape, 0.0, 0.1, DType::F32, &dev, seed).unwrap();
    let (x, w, b) = (
        Var::from_tensor(&rnd(&[96, 1024], 3)).unwrap(),
        Var::from_tensor(&rnd(&[4096, 1024], 4)).unwrap(),
        Var::from_tensor(&rnd(&[4096], 5)).unwrap(),
    );
    let r = rnd(&[96, 4096], 6);
    let lin = |t: &[&Tensor]| pbdl_core::nn::linear(t[0], t[1], Some(t[2])).unwrap();
    g.bench_function("linear/fused", |bch| bch.iter(|| fwd_bwd(&[&x, &w, &b], &r, &lin)));
    g.bench_function("linear/composed", |bch| {
        bch.iter(|| pbdl_core::nn::with_composed(|| fwd_bwd(&[&x, &w, &b], &r, &lin)))
    });

    let vars: Vec<Var> = (0..40)
        .flat_map(|i| {
            [
                Var::from_tensor(&rnd(&[128, 128, 3, 3], 10 + i)).unwrap(),
                Var::from_tensor(&rnd(&[128], 100 + i)).unwrap(),
            ]
        })
        .collect();
    let loss = vars.iter().map(|v| v.as_tensor().sqr().unwrap().sum_all().unwrap()).reduce(|a, b| (a + b).unwrap());
    let grads = loss.unwrap().backward().unwrap();
    let config = pbdl_core::train::OptimizerConfig::Adam(Default::default());
    for composed in [false, true] {
        let mut opt = config.build(vars.clone()).unwrap();
        let name = if composed { "adamw_step/composed" } else { "adamw_step/in_place" };
        g.bench_function(name, |bch| {
            bch.iter(|| {
                let mut step = || candle_nn::Optimizer::step(&mut opt, &grads).unwrap();
                if composed {
                    pbdl_core::nn::with_composed(step)
                } else {
                    step()
                }
            })
        });
    }

    let xs: Vec<f32> = (0..1_000_000).map(|i| (i as f32 - 5e5) * 1e-5).collect();
    g.bench_function("tanh_1m/vmath", |bch| {
        bch.iter(|| {
            let mut v = xs.clone();
            pbdl_core::vmath::tanh_in_place(&mut v);
            black_box(v);
        })
    });
    g.bench_function("tanh_1m/libm", |bch| {
        bch.iter(|| {
            let mut v = xs.clone();
            v.iter_mut().for_each(|t| *t = t.tanh());
            black_box(v);
        })
    });
    g.finish();
}

criterion_group!(benches, bench, bench_small);
fn main() {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers");
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
