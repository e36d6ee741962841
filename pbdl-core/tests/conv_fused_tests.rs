//! The fused convolution + bias + activation (`conv_act`): equal to the unfused ops (values
//! bit for bit, gradients to f32 round-off) on the im2col path (periodic axes, strides, groups,
//! pointwise) and the direct depthwise path, finite-difference gradient
//! checks in f64, second derivatives, transposed convolutions.

mod common;

use candle_core::{DType, Tensor, Var};
use pbdl_core::conv::{
    conv2d, conv_act, conv_transpose2d, conv_transpose_act, uses_direct_kernel, Conv2dParams, PaddingMode,
};
use pbdl_core::nn::Activation;
use pbdl_core::{check_grad, GradCheckOptions};

use common::{randn, rel_diff, F32_TOL, F64_TOL, GRAD_TOL};

const ACTS: [Activation; 3] = [Activation::Identity, Activation::Relu, Activation::LeakyRelu { negative_slope: 0.3 }];

/// `(input shape, weight shape, params)` covering the kernel paths.
fn cases() -> Vec<([usize; 4], [usize; 4], Conv2dParams)> {
    let periodic_x = Conv2dParams {
        padding_mode: [PaddingMode::Zeros, PaddingMode::Circular],
        ..Conv2dParams::default().padding(1)
    };
    vec![
        ([2, 5, 9, 12], [6, 5, 3, 3], Conv2dParams::default().padding(1)),
        ([2, 5, 9, 12], [6, 5, 3, 3], periodic_x),
        ([3, 4, 11, 10], [6, 2, 3, 2], Conv2dParams { stride: [2, 1], ..Conv2dParams::default().padding(2).groups(2) }),
        ([2, 4, 8, 8], [4, 1, 3, 3], Conv2dParams::default().padding(1).groups(4)), // depthwise, direct
        ([2, 3, 6, 7], [5, 3, 1, 1], Conv2dParams::default()),                      // pointwise
    ]
}

/// The reference: convolution, then candle's broadcast add, then the activation, as 3 ops.
fn unfused(x: &Tensor, w: &Tensor, b: &Tensor, p: &Conv2dParams, act: Activation) -> Tensor {
    let y = conv2d(x, w, None, p).unwrap();
    let y = y.broadcast_add(&b.reshape((1, b.dim(0).unwrap(), 1, 1)).unwrap()).unwrap();
    act.apply(&y).unwrap()
}

#[test]
fn fused_equals_unfused_values_and_gradients_in_f32() {
    for (i, (xs, ws, p)) in cases().into_iter().enumerate() {
        let x = Var::from_tensor(&randn(&xs, DType::F32, 100 + i as u64)).unwrap();
        let w = Var::from_tensor(&randn(&ws, DType::F32, 200 + i as u64)).unwrap();
        let b = Var::from_tensor(&randn(&[ws[0]], DType::F32, 300 + i as u64)).unwrap();
        for act in ACTS {
            let what = format!("case {i}, {act:?}");
            let fused = conv_act(&x, &w, Some(&b), &p, act).unwrap();
            let reference = unfused(&x, &w, &b, &p, act);
            if uses_direct_kernel(&xs, &ws, &p).unwrap() && act == Activation::Identity {
                // Without an activation the direct depthwise kernel starts its sums at the
                // bias (the epilogue adds it after them): the same terms, another rounding.
                let e = rel_diff(&fused, &reference);
                assert!(e < 1e-6, "{what}: values differ by {e:.2e}");
            } else {
                let (f, r) = (fused.flatten_all().unwrap(), reference.flatten_all().unwrap());
                assert_eq!(f.to_vec1::<f32>().unwrap(), r.to_vec1::<f32>().unwrap(), "{what}: values");
            }
            // A fixed random projection as the loss, so every output gradient differs.
            let proj = randn(fused.dims(), DType::F32, 400 + i as u64);
            let gf = fused.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
            let gr = reference.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
            for (name, v) in [("x", &x), ("w", &w), ("b", &b)] {
                let e = rel_diff(gf.get(v).unwrap(), gr.get(v).unwrap());
                assert!(e < F32_TOL, "{what}: gradient of {name} differs by {e:.2e}");
            }
        }
    }
}

#[test]
fn fused_conv_passes_gradient_check_in_f64() {
    for (i, (xs, ws, p)) in cases().into_iter().enumerate() {
        let x = randn(&xs, DType::F64, 500 + i as u64);
        let w = randn(&ws, DType::F64, 600 + i as u64);
        let b = randn(&[ws[0]], DType::F64, 700 + i as u64);
        for act in ACTS {
            let r = check_grad(
                |t| Ok(conv_act(&t[0], &t[1], Some(&t[2]), &p, act)?),
                &[x.clone(), w.clone(), b.clone()],
                &GradCheckOptions { max_probes: 30, ..Default::default() },
            )
            .unwrap();
            assert!(r.max_rel_error <= GRAD_TOL, "case {i}, {act:?}: {r:?}");
        }
    }
}

#[test]
fn fused_conv_without_bias_and_with_other_activations() {
    let x = randn(&[2, 3, 7, 6], DType::F64, 800);
    let w = randn(&[4, 3, 3, 3], DType::F64, 801);
    let p = Conv2dParams::default().padding(1);
    // No bias: a constant zero bias inside, no gradient needed for it.
    let act = Activation::Relu;
    let r = check_grad(|t| Ok(conv_act(&t[0], &t[1], None, &p, act)?), &[x.clone(), w.clone()], &Default::default());
    assert!(r.unwrap().max_rel_error <= GRAD_TOL);
    // An activation that cannot be fused runs after the convolution, with the same result.
    let b = randn(&[4], DType::F64, 802);
    let gelu = conv_act(&x, &w, Some(&b), &p, Activation::Gelu).unwrap();
    let e = rel_diff(&gelu, &Activation::Gelu.apply(&conv2d(&x, &w, Some(&b), &p).unwrap()).unwrap());
    assert!(e <= F64_TOL, "{e:.2e}");
}

/// The direct depthwise kernel with the epilogue and no bias: values bit for bit, gradients to
/// round-off, FD in f64 (with a bias: the first test).
#[test]
fn fused_depthwise_activation_without_bias() {
    let p = Conv2dParams::default().padding(1).groups(4);
    assert!(uses_direct_kernel(&[2, 4, 8, 8], &[4, 1, 3, 3], &p).unwrap());
    for act in [Activation::Relu, Activation::LeakyRelu { negative_slope: 0.3 }] {
        let x = Var::from_tensor(&randn(&[2, 4, 8, 8], DType::F32, 1100)).unwrap();
        let w = Var::from_tensor(&randn(&[4, 1, 3, 3], DType::F32, 1101)).unwrap();
        let fused = conv_act(&x, &w, None, &p, act).unwrap();
        let reference = act.apply(&conv2d(&x, &w, None, &p).unwrap()).unwrap();
        let (f, r) = (fused.flatten_all().unwrap(), reference.flatten_all().unwrap());
        assert_eq!(f.to_vec1::<f32>().unwrap(), r.to_vec1::<f32>().unwrap(), "{act:?}: values");
        let proj = randn(fused.dims(), DType::F32, 1102);
        let gf = fused.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
        let gr = reference.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in [("x", &x), ("w", &w)] {
            let e = rel_diff(gf.get(v).unwrap(), gr.get(v).unwrap());
            assert!(e < F32_TOL, "{act:?}: gradient of {name} differs by {e:.2e}");
        }
        let inputs = [randn(&[2, 4, 8, 8], DType::F64, 1103), randn(&[4, 1, 3, 3], DType::F64, 1104)];
        let r = check_grad(|t| Ok(conv_act(&t[0], &t[1], None, &p, act)?), &inputs, &Default::default()).unwrap();
        assert!(r.max_rel_error <= GRAD_TOL, "{act:?}: {r:?}");
    }
}

#[test]
fn second_derivatives_through_the_fused_activation() {
    // d(grad_w)/dx and d(grad_x)/dw of a LeakyReLU conv layer; the activation's derivative is
    // piecewise constant, so only the convolution's adjoints carry second-order terms.
    let x0 = randn(&[2, 3, 6, 5], DType::F64, 900);
    let w0 = randn(&[4, 3, 3, 3], DType::F64, 901);
    let b = randn(&[4], DType::F64, 902);
    let r = randn(&[2, 4, 6, 5], DType::F64, 903);
    let p = Conv2dParams::default().padding(1);
    let act = Activation::LeakyRelu { negative_slope: 0.2 };
    let grads_of = |x: &Tensor, w: &Tensor, of_x: bool| -> candle_core::Result<Tensor> {
        let target = Var::from_tensor(if of_x { x } else { w })?;
        let (x, w) = if of_x { (target.as_tensor(), w) } else { (x, target.as_tensor()) };
        let g = conv_act(x, w, Some(&b), &p, act)?.mul(&r)?.sum_all()?.backward()?;
        Ok(g.get(target.as_tensor()).expect("gradient").clone())
    };
    let opts = GradCheckOptions { max_probes: 30, ..Default::default() };
    let rep = check_grad(|t| grads_of(&x0, &t[0], true), std::slice::from_ref(&w0), &opts).unwrap();
    assert!(rep.max_rel_error <= GRAD_TOL, "d grad_x / d w: {rep:?}");
    let rep = check_grad(|t| grads_of(&t[0], &w0, false), std::slice::from_ref(&x0), &opts).unwrap();
    assert!(rep.max_rel_error <= GRAD_TOL, "d grad_w / d x: {rep:?}");
}

#[test]
fn fused_transposed_conv_equals_unfused_and_passes_gradient_check() {
    let p = Conv2dParams::default().stride(2).padding(1);
    for act in ACTS {
        // f32: values bit for bit, gradients to round-off.
        let x = Var::from_tensor(&randn(&[2, 4, 5, 6], DType::F32, 1000)).unwrap();
        let w = Var::from_tensor(&randn(&[4, 3, 3, 3], DType::F32, 1001)).unwrap();
        let b = Var::from_tensor(&randn(&[3], DType::F32, 1002)).unwrap();
        let fused = conv_transpose_act(&x, &w, Some(&b), &p, [1, 1], act).unwrap();
        let y = conv_transpose2d(&x, &w, None, &p, [1, 1]).unwrap();
        let reference = act.apply(&y.broadcast_add(&b.reshape((1, 3, 1, 1)).unwrap()).unwrap()).unwrap();
        let (f, r) = (fused.flatten_all().unwrap(), reference.flatten_all().unwrap());
        assert_eq!(f.to_vec1::<f32>().unwrap(), r.to_vec1::<f32>().unwrap(), "{act:?}: values");
        let proj = randn(fused.dims(), DType::F32, 1003);
        let gf = fused.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
        let gr = reference.mul(&proj).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in [("x", &x), ("w", &w), ("b", &b)] {
            let e = rel_diff(gf.get(v).unwrap(), gr.get(v).unwrap());
            assert!(e < F32_TOL, "{act:?}: gradient of {name} differs by {e:.2e}");
        }
        // f64 finite differences.
        let inputs = [
            randn(&[2, 4, 5, 6], DType::F64, 1004),
            randn(&[4, 3, 3, 3], DType::F64, 1005),
            randn(&[3], DType::F64, 1006),
        ];
        let r = check_grad(
            |t| Ok(conv_transpose_act(&t[0], &t[1], Some(&t[2]), &p, [1, 1], act)?),
            &inputs,
            &GradCheckOptions { max_probes: 30, ..Default::default() },
        )
        .unwrap();
        assert!(r.max_rel_error <= GRAD_TOL, "{act:?}: {r:?}");
        // Without a bias (the epilogue with a zero bias).
        let r = check_grad(
            |t| Ok(conv_transpose_act(&t[0], &t[1], None, &p, [1, 1], act)?),
            &inputs[..2],
            &GradCheckOptions { max_probes: 30, ..Default::default() },
        )
        .unwrap();
        assert!(r.max_rel_error <= GRAD_TOL, "{act:?} without bias: {r:?}");
    }
}
