//! conv2d forward and forward+backward: pbdl's im2col + gemm convolution against candle's.
//!
//! Case: batch 8, 32 -> 32 channels, 64x64, 3x3 kernel, padding 1, f32, on the CPU. The backward
//! computes the gradients with respect to both the input and the weight.
//!
//! Depthwise cases (the 7x7 conv of the ACDM U-Net's ConvNeXt blocks): batch 16, 16 or 32
//! channels, 64x32, 7x7 kernel, padding 3, groups = channels, f32; the direct kernel that
//! `conv2d` runs against the im2col path it replaced (`conv_im2col`), forward and
//! forward+backward (gradients of input, weight and bias under a dense output gradient).
//!
//! Run with `cargo bench -p pbdl-core --bench conv` (`-- depthwise` for the depthwise cases
//! only).
// criterion's macros generate undocumented functions.
#![allow(missing_docs)]

use candle_core::{DType, Device, Tensor, Var};
use criterion::{criterion_group, Criterion};
use pbdl_core::conv::{conv2d, conv_im2col, Conv2dParams};
use std::hint::black_box;
use std::time::Duration;

const B: usize = 8;
const C: usize = 32;
const N: usize = 64;
const K: usize = 3;

fn inputs() -> (Var, Var) {
    let dev = Device::Cpu;
    let x = pbdl_core::seed::randn((B, C, N, N), 0.0, 1.0, DType::F32, &dev, 0).unwrap();
    let w = pbdl_core::seed::randn((C, C, K, K), 0.0, 0.1, DType::F32, &dev, 1).unwrap();
    (Var::from_tensor(&x).unwrap(), Var::from_tensor(&w).unwrap())
}

/// A convolution under test: input and weight to output.
type ConvFn = fn(&Tensor, &Tensor) -> Tensor;

fn ours(x: &Tensor, w: &Tensor) -> Tensor {
    conv2d(x, w, None, &Conv2dParams::default().padding(1)).unwrap()
}

fn candle(x: &Tensor, w: &Tensor) -> Tensor {
    x.conv2d(w, 1, 1, 1, 1).unwrap()
}

/// Forward, then the gradients of `sum(y)` with respect to input and weight.
fn fwd_bwd(f: ConvFn, x: &Var, w: &Var) -> (Tensor, Tensor) {
    let grads = f(x.as_tensor(), w.as_tensor()).sum_all().unwrap().backward().unwrap();
    (grads.get(x.as_tensor()).unwrap().clone(), grads.get(w.as_tensor()).unwrap().clone())
}

fn bench(c: &mut Criterion) {
    let (x, w) = inputs();
    let cases: [(&str, ConvFn); 2] = [("ours", ours), ("candle", candle)];

    let mut g = c.benchmark_group("conv2d_f32_fwd");
    g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    for (name, f) in cases {
        g.bench_function(name, |b| b.iter(|| black_box(f(x.as_tensor(), w.as_tensor()))));
    }
    g.finish();

    let mut g = c.benchmark_group("conv2d_f32_fwd_bwd");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(6));
    for (name, f) in cases {
        g.bench_function(name, |b| b.iter(|| black_box(fwd_bwd(f, &x, &w))));
    }
    g.finish();
    depthwise(c);
}

const DW_B: usize = 16;
const DW_K: usize = 7;
const DW_SIZE: (usize, usize) = (64, 32);

/// A depthwise convolution under test: input, weight and bias to output.
type DwFn = fn(&Tensor, &Tensor, &Tensor) -> Tensor;

fn dw_params(c: usize) -> Conv2dParams {
    Conv2dParams::default().padding(DW_K / 2).groups(c)
}

fn dw_direct(x: &Tensor, w: &Tensor, b: &Tensor) -> Tensor {
    conv2d(x, w, Some(b), &dw_params(x.dim(1).unwrap())).unwrap()
}

fn dw_im2col(x: &Tensor, w: &Tensor, b: &Tensor) -> Tensor {
    conv_im2col(x, w, Some(b), &dw_params(x.dim(1).unwrap())).unwrap()
}

fn depthwise(c: &mut Criterion) {
    let cases: [(&str, DwFn); 2] = [("direct", dw_direct), ("im2col", dw_im2col)];
    for ch in [16, 32] {
        let dev = Device::Cpu;
        let (h, wd) = DW_SIZE;
        let randn = |shape: &[usize], std: f64, seed: u64| {
            Var::from_tensor(&pbdl_core::seed::randn(shape, 0.0, std, DType::F32, &dev, seed).unwrap()).unwrap()
        };
        let (x, w, b) = (randn(&[DW_B, ch, h, wd], 1.0, 2), randn(&[ch, 1, DW_K, DW_K], 0.1, 3), randn(&[ch], 0.1, 4));
        // A dense output gradient, as in a network.
        let r = randn(&[DW_B, ch, h, wd], 1.0, 5).as_tensor().clone();

        let mut g = c.benchmark_group(format!("depthwise7x7_c{ch}_f32_fwd"));
        g.sample_size(30).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(3));
        for (name, f) in cases {
            g.bench_function(name, |bch| bch.iter(|| black_box(f(x.as_tensor(), w.as_tensor(), b.as_tensor()))));
        }
        g.finish();

        let mut g = c.benchmark_group(format!("depthwise7x7_c{ch}_f32_fwd_bwd"));
        g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
        for (name, f) in cases {
            g.bench_function(name, |bch| {
                bch.iter(|| {
                    let y = f(x.as_tensor(), w.as_tensor(), b.as_tensor());
                    let grads = y.mul(&r).unwrap().sum_all().unwrap().backward().unwrap();
                    black_box([&x, &w, &b].map(|v| grads.get(v.as_tensor()).unwrap().clone()))
                })
            });
        }
        g.finish();
    }
}

criterion_group!(benches, bench);
fn main() {
    // candle re-counts the cores on every CPU matmul unless the thread count is in the environment.
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
