//! Tests of the implicit-GEMM convolution path (stride 1, one group; `conv/implicit.rs`): it
//! agrees with the im2col path (`conv_im2col`) in the output and all gradients over kernel
//! shapes, dilations, zero/periodic/mixed padding, odd sizes, several tiles per image, channel
//! and batch counts and 1D/2D/3D, with the fused bias + activation epilogue, and it passes
//! finite-difference checks of first and second derivatives in f64.
//!
//! The path is opt-in (`PBDL_CONV_IMPLICIT=1`, read once per process); every test here switches
//! it on through [`implicit_on`] before its first convolution.

use candle_core::{DType, Tensor, Var};
use pbdl_core::conv::PaddingMode::{Circular, Zeros};
use pbdl_core::conv::{conv, conv2d, conv_act, conv_im2col, Conv1dParams, Conv2dParams, Conv3dParams, ConvParams};
use pbdl_core::nn::Activation;
use pbdl_core::{check_grad, GradCheckOptions};
use std::sync::Once;

mod common;
use common::{randn, rel_diff, value_and_grads, F32_TOL, F64_TOL, GRAD_TOL};

/// Switches the implicit path on for this test process. Every test calls it first, so the
/// variable is set (once, under `Once`) before any convolution reads it.
fn implicit_on() {
    static ON: Once = Once::new();
    ON.call_once(|| std::env::set_var("PBDL_CONV_IMPLICIT", "1"));
    // Otherwise every comparison below would be im2col against im2col.
    assert!(pbdl_core::conv::implicit_path_enabled(), "the implicit path did not switch on");
}

/// Asserts that `conv` (implicit path for these shapes) and `conv_im2col` agree in the output
/// and the three gradients, for `c_out` output channels and kernel `k`.
fn assert_paths_agree<const N: usize>(x_shape: &[usize], c_out: usize, k: [usize; N], p: ConvParams<N>, dtype: DType) {
    implicit_on();
    let tol = if dtype == DType::F64 { F64_TOL } else { F32_TOL };
    let mut w_shape = vec![c_out, x_shape[1]];
    w_shape.extend_from_slice(&k);
    let x = randn(x_shape, dtype, 1);
    let w = randn(&w_shape, dtype, 2);
    let b = randn(&[c_out], dtype, 3);
    let implicit = value_and_grads(conv, &x, &w, &b, &p);
    let im2col = value_and_grads(conv_im2col, &x, &w, &b, &p);
    for (i, name) in ["output", "input gradient", "weight gradient", "bias gradient"].iter().enumerate() {
        let e = rel_diff(&implicit[i], &im2col[i]);
        assert!(e <= tol, "{name}: relative difference {e:e} > {tol:e} for x {x_shape:?}, kernel {k:?}, {p:?}");
    }
}

/// The 2D cases: `(input shape, output channels, kernel, params)`.
fn cases_2d() -> Vec<(Vec<usize>, usize, [usize; 2], Conv2dParams)> {
    let p = Conv2dParams::default();
    let per_x = |q: Conv2dParams| Conv2dParams { padding_mode: [Zeros, Circular], ..q };
    vec![
        (vec![2, 16, 9, 7], 8, [3, 3], p.padding(1)),
        (vec![3, 3, 9, 7], 8, [3, 3], p.padding(1)), // few channels (an RGB input layer)
        (vec![2, 2, 8, 11], 1, [3, 3], p.padding(1).circular()),
        (vec![2, 16, 9, 7], 8, [1, 1], p.padding(1)), // 1x1 with padding
        (vec![3, 17, 11, 13], 5, [5, 5], p.padding(2)),
        (vec![1, 16, 8, 10], 6, [1, 3], Conv2dParams { padding: [0, 1], ..p }),
        (vec![2, 16, 12, 9], 4, [7, 7], p.padding(3)),
        (vec![2, 16, 10, 11], 7, [3, 3], p.padding(2).dilation(2)),
        (vec![2, 18, 7, 9], 3, [3, 3], Conv2dParams { padding: [1, 3], dilation: [1, 2], ..p }),
        // Periodic in x only (a lat-lon grid), in both axes, and on one axis with zero padding 0.
        (vec![2, 16, 9, 12], 8, [3, 3], per_x(p.padding(1))),
        (vec![1, 16, 9, 12], 5, [3, 3], p.padding(1).circular()),
        (vec![3, 16, 7, 8], 4, [5, 5], p.padding(2).circular()),
        (vec![2, 16, 6, 9], 4, [3, 3], Conv2dParams { padding: [0, 1], padding_mode: [Zeros, Circular], ..p }),
        (vec![2, 16, 11, 10], 5, [3, 5], Conv2dParams { padding: [1, 4], dilation: [1, 2], ..p }.circular()),
        // No padding, per-axis padding, an even kernel, padding beyond the input size.
        (vec![2, 16, 9, 8], 6, [3, 3], p),
        (vec![2, 16, 9, 8], 6, [5, 3], Conv2dParams { padding: [2, 0], ..p }),
        (vec![1, 16, 6, 7], 3, [2, 4], Conv2dParams { padding: [1, 2], ..p }),
        (vec![1, 16, 3, 4], 3, [3, 3], p.padding(4)),
        (vec![2, 16, 3, 4], 3, [3, 3], p.padding(4).circular()),
        // Several tiles per image (tiles of about 256 KiB).
        (vec![2, 16, 90, 41], 8, [3, 3], per_x(p.padding(1))),
        (vec![1, 24, 70, 37], 24, [5, 5], p.padding(2).circular()),
    ]
}

#[test]
fn implicit_2d_equals_im2col_f64() {
    for (x, co, k, p) in cases_2d() {
        assert_paths_agree(&x, co, k, p, DType::F64);
    }
}

#[test]
fn implicit_2d_equals_im2col_f32() {
    for (x, co, k, p) in cases_2d() {
        assert_paths_agree(&x, co, k, p, DType::F32);
    }
}

#[test]
fn implicit_1d_and_3d_equal_im2col() {
    let p1 = Conv1dParams::default();
    for dtype in [DType::F64, DType::F32] {
        assert_paths_agree(&[2, 16, 37], 5, [5], p1.padding(2), dtype);
        assert_paths_agree(&[3, 16, 20], 4, [3], p1.padding(2).dilation(2).circular(), dtype);
        assert_paths_agree(&[1, 16, 9], 4, [4], p1, dtype);
    }
    let p3 = Conv3dParams::default();
    for dtype in [DType::F64, DType::F32] {
        assert_paths_agree(&[2, 16, 5, 6, 7], 4, [3, 3, 3], p3.padding(1), dtype);
        assert_paths_agree(&[1, 16, 5, 6, 7], 3, [3, 3, 3], p3.padding(1).circular(), dtype);
        let mixed =
            Conv3dParams { padding: [2, 1, 1], dilation: [2, 1, 1], padding_mode: [Circular, Zeros, Circular], ..p3 };
        assert_paths_agree(&[3, 16, 6, 5, 4], 5, [3, 2, 3], mixed, dtype);
        // Several tiles per output plane and several planes.
        assert_paths_agree(&[1, 16, 3, 60, 40], 8, [3, 3, 3], Conv3dParams { padding: [0, 1, 1], ..p3 }, dtype);
    }
}

#[test]
fn fused_epilogue_equals_im2col_then_activation() {
    implicit_on();
    let act = Activation::LeakyRelu { negative_slope: 0.2 };
    for dtype in [DType::F64, DType::F32] {
        let tol = if dtype == DType::F64 { F64_TOL } else { F32_TOL };
        let x = randn(&[3, 16, 13, 17], dtype, 4);
        let w = randn(&[8, 16, 3, 3], dtype, 5);
        let b = randn(&[8], dtype, 6);
        let p = Conv2dParams { padding_mode: [Zeros, Circular], ..Conv2dParams::default().padding(1) };
        let fused = conv_act(&x, &w, Some(&b), &p, act).unwrap();
        let reference = act.apply(&conv_im2col(&x, &w, Some(&b), &p).unwrap()).unwrap();
        let e = rel_diff(&fused, &reference);
        assert!(e <= tol, "{dtype:?}: relative difference {e:e}");
    }
}

fn grad_check(f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>, inputs: &[Tensor], what: &str) {
    let r = check_grad(f, inputs, &GradCheckOptions { max_probes: 30, ..Default::default() }).unwrap();
    assert!(r.max_rel_error <= GRAD_TOL, "{what}: {r:?}");
}

#[test]
fn implicit_passes_gradient_check() {
    implicit_on();
    let x = randn(&[2, 16, 6, 5], DType::F64, 7);
    let w = randn(&[3, 16, 3, 3], DType::F64, 8);
    let b = randn(&[3], DType::F64, 9);
    for p in [
        Conv2dParams::default().padding(1),
        Conv2dParams::default().padding(2).dilation(2).circular(),
        Conv2dParams { padding: [1, 2], padding_mode: [Zeros, Circular], ..Default::default() },
    ] {
        grad_check(
            |t| Ok(conv2d(&t[0], &t[1], Some(&t[2]), &p)?),
            &[x.clone(), w.clone(), b.clone()],
            &format!("{p:?}"),
        );
    }
}

#[test]
fn implicit_second_derivatives_pass_gradient_check() {
    implicit_on();
    // The adjoints run on the implicit path too: check d(grad_x)/dw and d(grad_w)/dx.
    let x0 = randn(&[2, 16, 5, 6], DType::F64, 11);
    let w0 = randn(&[3, 16, 3, 3], DType::F64, 12);
    let p = Conv2dParams { padding_mode: [Zeros, Circular], ..Conv2dParams::default().padding(1) };
    let r = randn(&[2, 3, 5, 6], DType::F64, 13);
    let grads_of = |x: &Tensor, w: &Tensor, of_x: bool| -> candle_core::Result<Tensor> {
        let target = Var::from_tensor(if of_x { x } else { w })?;
        let (x, w) = if of_x { (target.as_tensor(), w) } else { (x, target.as_tensor()) };
        let g = conv2d(x, w, None, &p)?.mul(&r)?.sum_all()?.backward()?;
        Ok(g.get(target.as_tensor()).expect("gradient").clone())
    };
    grad_check(|t| grads_of(&x0, &t[0], true), std::slice::from_ref(&w0), "d grad_x / d w");
    grad_check(|t| grads_of(&t[0], &w0, false), std::slice::from_ref(&x0), "d grad_w / d x");
}

#[test]
fn implicit_results_do_not_depend_on_scheduling() {
    implicit_on();
    // The weight gradient sums per-thread partials in a fixed order: bit-identical reruns.
    let x = randn(&[5, 16, 12, 10], DType::F32, 14);
    let w = randn(&[8, 16, 3, 3], DType::F32, 15);
    let b = randn(&[8], DType::F32, 16);
    let p = Conv2dParams::default().padding(1).circular();
    let first = value_and_grads(conv, &x, &w, &b, &p);
    for _ in 0..3 {
        let again = value_and_grads(conv, &x, &w, &b, &p);
        for (a, b) in first.iter().zip(&again) {
            let (a, b) = (
                a.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                b.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            );
            assert_eq!(a, b);
        }
    }
}
