//! Stride-1 dense convolutions: the implicit-GEMM path (no im2col matrix; opt-in with
//! `PBDL_CONV_IMPLICIT=1`, which this bench sets) that `conv2d` then takes against the im2col
//! path (`conv_im2col`), f32, 2 threads, through candle's autograd (so with the graph overhead;
//! the kernels alone: the ignored test `conv::implicit::tests::probe_timing`).
//!
//! Cases: batch 4, 3x3 kernel, padding 1: 64 channels at 32x32 (TecoGAN's generator), 64 at
//! 64x64, 128 at 32x64 periodic in x (the WeatherBench ResNet), and 16 and 32 channels at 64x64
//! (few channels, where one im2col product has the shortest inner dimension).
//!
//! For each path it times the forward alone, the forward with the input gradient, with the
//! weight gradient, and with both (loss `sum(y * r)`, `r` dense); the two gradients' own times
//! are the differences to the forward. Rounds alternate between the paths; the printed times
//! are medians of each round's per-iteration medians.
//!
//! Run with `cargo bench -p pbdl-core --bench conv_implicit` (`-- QUICK` for one round).
#![allow(missing_docs)]

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{conv2d, conv_im2col, Conv2dParams, PaddingMode};
use pbdl_core::threads::{self, ThreadPolicy};
use std::hint::black_box;
use std::time::Instant;

/// A convolution under test.
type ConvFn = fn(&Tensor, &Tensor, Option<&Tensor>, &Conv2dParams) -> pbdl_core::Result<Tensor>;

/// One benchmark case.
struct Case {
    name: &'static str,
    c: usize,
    h: usize,
    w: usize,
    periodic_x: bool,
}

/// Median wall time in ms of `iters` calls of `f`, after two warm-up calls.
fn median_ms(iters: usize, mut f: impl FnMut()) -> f64 {
    f();
    f();
    let mut t: Vec<f64> = (0..iters)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// `[fwd, fwd + gx, fwd + gw, fwd + gx + gw]` in ms.
fn time_path(f: ConvFn, case: &Case, iters: usize) -> [f64; 4] {
    let dev = Device::Cpu;
    let randn =
        |shape: &[usize], std: f64, seed: u64| pbdl_core::seed::randn(shape, 0.0, std, DType::F32, &dev, seed).unwrap();
    let x = randn(&[4, case.c, case.h, case.w], 1.0, 1);
    let w = randn(&[case.c, case.c, 3, 3], 0.05, 2);
    let r = randn(&[4, case.c, case.h, case.w], 1.0, 3);
    let mut p = Conv2dParams::default().padding(1);
    if case.periodic_x {
        p.padding_mode = [PaddingMode::Zeros, PaddingMode::Circular];
    }
    let (xv, wv) = (Var::from_tensor(&x).unwrap(), Var::from_tensor(&w).unwrap());
    let fwd = median_ms(iters, || {
        black_box(f(&x, &w, None, &p).unwrap());
    });
    let grads = |xa: &Tensor, wa: &Tensor| {
        median_ms(iters, || {
            let y = f(xa, wa, None, &p).unwrap();
            black_box((&y * &r).unwrap().sum_all().unwrap().backward().unwrap());
        })
    };
    let gx = grads(xv.as_tensor(), &w);
    let gw = grads(&x, wv.as_tensor());
    let both = grads(xv.as_tensor(), wv.as_tensor());
    [fwd, gx, gw, both]
}

fn main() {
    // The implicit path is opt-in; set before anything reads the environment.
    std::env::set_var("PBDL_CONV_IMPLICIT", "1");
    threads::init_with(ThreadPolicy { threads: 2, serial_below: threads::DEFAULT_SERIAL_BELOW }).unwrap();
    let quick = std::env::args().any(|a| a == "QUICK");
    let rounds = if quick { 1 } else { 3 };
    let cases = [
        Case { name: "64ch 32x32", c: 64, h: 32, w: 32, periodic_x: false },
        Case { name: "64ch 64x64", c: 64, h: 64, w: 64, periodic_x: false },
        Case { name: "128ch 32x64 per-x", c: 128, h: 32, w: 64, periodic_x: true },
        Case { name: "32ch 64x64", c: 32, h: 64, w: 64, periodic_x: false },
        Case { name: "16ch 64x64", c: 16, h: 64, w: 64, periodic_x: false },
    ];
    let paths: [(&str, ConvFn); 2] = [("im2col", conv_im2col), ("implicit", conv2d)];
    println!("times in ms (median over {rounds} rounds); gx, gw = (fwd+grad) - fwd");
    for case in &cases {
        let iters = (20 * 64 * 64 * 64 / (case.c * case.h * case.w)).clamp(5, 60);
        // rows[path][round] = [fwd, fwd+gx, fwd+gw, fwd+both]
        let mut rows = vec![Vec::new(); paths.len()];
        for _ in 0..rounds {
            for (i, (_, f)) in paths.iter().enumerate() {
                rows[i].push(time_path(*f, case, iters));
            }
        }
        let mut totals = Vec::new();
        for (i, (name, _)) in paths.iter().enumerate() {
            let med = |k: usize| median(rows[i].iter().map(|r| r[k]).collect());
            let (fwd, fgx, fgw, both) = (med(0), med(1), med(2), med(3));
            let total = fwd + (fgx - fwd) + (fgw - fwd);
            totals.push(total);
            let per_round: Vec<String> = rows[i].iter().map(|r| format!("{:.2}", r[3])).collect();
            println!(
                "{:<18} {name:<8} fwd {fwd:7.2}  gx {:7.2}  gw {:7.2}  fwd+gx+gw {total:7.2}  measured fwd+bwd {both:7.2} (rounds {})",
                case.name,
                fgx - fwd,
                fgw - fwd,
                per_round.join(" / ")
            );
        }
        println!("{:<18} implicit / im2col (fwd+gx+gw): {:.3}", case.name, totals[1] / totals[0]);
    }
}
