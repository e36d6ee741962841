//! Tests of the direct depthwise convolution kernels (`groups == in_channels == out_channels`):
//! they are the ones that run, they agree with the im2col path (values and all gradients) over
//! strides, paddings, dilations, odd sizes and 1D/2D/3D, and they pass finite-difference
//! gradient checks of first and second derivatives in f64.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{
    conv, conv2d, conv_im2col, conv_transpose2d, uses_direct_kernel, Conv1dParams, Conv2dParams, Conv3dParams,
    ConvParams,
};
use pbdl_core::{check_grad, GradCheckOptions};

mod common;
use common::{randn, rel_diff, value_and_grads, F32_TOL, F64_TOL, GRAD_TOL};

/// Asserts that `conv` runs the direct kernel for the case and agrees with the im2col path in
/// the output and the three gradients.
fn assert_paths_agree<const N: usize>(x_shape: &[usize], k: [usize; N], p: ConvParams<N>, dtype: DType, tol: f64) {
    let c = x_shape[1];
    let mut w_shape = vec![c, 1];
    w_shape.extend_from_slice(&k);
    assert!(uses_direct_kernel(x_shape, &w_shape, &p).unwrap(), "not dispatched to the direct kernel: {p:?}");
    let x = randn(x_shape, dtype, 1);
    let w = randn(&w_shape, dtype, 2);
    let b = randn(&[c], dtype, 3);
    let direct = value_and_grads(conv, &x, &w, &b, &p);
    let im2col = value_and_grads(conv_im2col, &x, &w, &b, &p);
    for (i, name) in ["output", "input gradient", "weight gradient", "bias gradient"].iter().enumerate() {
        let e = rel_diff(&direct[i], &im2col[i]);
        assert!(e <= tol, "{name}: relative difference {e:e} > {tol:e} for x {x_shape:?}, kernel {k:?}, {p:?}");
    }
}

#[test]
fn dispatch_takes_only_depthwise_geometries() {
    let p = Conv2dParams::default().padding(3).groups(4);
    assert!(uses_direct_kernel(&[2, 4, 9, 9], &[4, 1, 7, 7], &p).unwrap());
    // Two filters per channel, and ordinary grouped or dense convolutions, stay on im2col.
    assert!(!uses_direct_kernel(&[2, 4, 9, 9], &[8, 1, 7, 7], &p).unwrap());
    assert!(!uses_direct_kernel(&[2, 4, 9, 9], &[4, 2, 7, 7], &p.groups(2)).unwrap());
    assert!(!uses_direct_kernel(&[2, 4, 9, 9], &[4, 4, 7, 7], &p.groups(1)).unwrap());
    // A single channel is depthwise too.
    assert!(uses_direct_kernel(&[2, 1, 9, 9], &[1, 1, 3, 3], &Conv2dParams::default()).unwrap());
}

#[test]
fn direct_2d_equals_im2col_f64() {
    let p = Conv2dParams::default();
    let cases: Vec<(Vec<usize>, [usize; 2], Conv2dParams)> = vec![
        // The ConvNeXt block's 7x7 conv, odd sizes, batch > 1.
        (vec![2, 3, 9, 7], [7, 7], p.padding(3).groups(3)),
        (vec![3, 2, 13, 70], [7, 7], p.padding(3).groups(2)), // full and partial register blocks
        (vec![2, 3, 9, 7], [7, 7], p.padding(3).groups(3).circular()),
        (vec![2, 2, 5, 29], [3, 3], p.padding(1).groups(2)), // blocks of 16, 8, 4 and 1
        (vec![2, 2, 11, 6], [3, 5], Conv2dParams { stride: [2, 2], padding: [1, 2], groups: 2, ..p }),
        (
            vec![2, 2, 10, 37],
            [3, 3],
            Conv2dParams { stride: [1, 2], padding: [2, 0], dilation: [2, 1], groups: 2, ..p },
        ),
        (vec![1, 3, 8, 9], [3, 3], p.stride(2).padding(2).dilation(2).groups(3).circular()),
        (vec![2, 2, 7, 5], [3, 3], Conv2dParams { dilation: [1, 3], padding: [1, 3], groups: 2, ..p }.circular()),
        (vec![2, 2, 6, 7], [3, 2], p.groups(2)), // no padding, even kernel
        (vec![1, 2, 3, 4], [3, 3], p.padding(4).groups(2)), // padding larger than the input
        (vec![1, 2, 3, 4], [7, 7], p.padding(5).groups(2).circular()), // wraps more than once
    ];
    for (x, k, p) in cases {
        assert_paths_agree(&x, k, p, DType::F64, F64_TOL);
    }
}

#[test]
fn direct_1d_and_3d_equal_im2col_f64() {
    let p1 = Conv1dParams::default();
    assert_paths_agree(&[3, 2, 41], [7], p1.padding(3).groups(2), DType::F64, F64_TOL);
    assert_paths_agree(&[2, 3, 17], [3], p1.stride(2).padding(1).dilation(2).groups(3).circular(), DType::F64, F64_TOL);
    let p3 = Conv3dParams::default();
    assert_paths_agree(&[2, 2, 5, 6, 7], [3, 3, 3], p3.padding(1).groups(2), DType::F64, F64_TOL);
    let p = Conv3dParams { stride: [1, 2, 2], padding: [1, 1, 2], dilation: [2, 1, 1], groups: 3, ..p3 };
    assert_paths_agree(&[2, 3, 5, 6, 7], [2, 3, 3], p, DType::F64, F64_TOL);
    assert_paths_agree(&[1, 2, 4, 5, 6], [3, 2, 3], p3.padding(2).stride(2).groups(2).circular(), DType::F64, F64_TOL);
}

#[test]
fn direct_equals_im2col_f32_at_unet_sizes() {
    // The ACDM U-Net's ConvNeXt 7x7 convs at its four resolutions (batch reduced).
    for (c, h, w) in [(16, 64, 32), (32, 32, 16), (64, 16, 8), (128, 8, 4)] {
        assert_paths_agree(&[2, c, h, w], [7, 7], Conv2dParams::default().padding(3).groups(c), DType::F32, F32_TOL);
    }
}

#[test]
fn depthwise_transposed_conv_is_the_input_gradient_of_the_conv() {
    // conv_transpose2d with groups = channels runs the direct strided input-gradient kernel; it
    // must equal d/dz <conv_im2col(z, w), x> for the same geometry.
    let p = Conv2dParams::default().stride(2).padding(1).groups(3);
    let x = randn(&[2, 3, 5, 4], DType::F64, 4);
    let w = randn(&[3, 1, 4, 4], DType::F64, 5);
    let t = conv_transpose2d(&x, &w, None, &p, [0, 0]).unwrap();
    assert_eq!(t.dims(), &[2, 3, 10, 8]);
    let z = Var::from_tensor(&Tensor::zeros(t.dims(), DType::F64, &Device::Cpu).unwrap()).unwrap();
    let y = conv_im2col(z.as_tensor(), &w, None, &p).unwrap();
    let gz = (&y * &x).unwrap().sum_all().unwrap().backward().unwrap().get(z.as_tensor()).unwrap().clone();
    let e = rel_diff(&t, &gz);
    assert!(e <= F64_TOL, "relative difference {e:e}");
}

fn grad_check(f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>, inputs: &[Tensor], what: &str) {
    let r = check_grad(f, inputs, &GradCheckOptions { max_probes: 40, ..Default::default() }).unwrap();
    assert!(r.max_rel_error <= GRAD_TOL, "{what}: {r:?}");
}

#[test]
fn direct_kernels_pass_gradient_check() {
    let x = randn(&[2, 3, 9, 7], DType::F64, 6);
    let w = randn(&[3, 1, 7, 7], DType::F64, 7);
    let b = randn(&[3], DType::F64, 8);
    let p = Conv2dParams::default().groups(3);
    for p in [
        p.padding(3),
        p.padding(3).circular(),
        Conv2dParams { stride: [2, 1], padding: [3, 5], dilation: [1, 2], ..p },
        p.stride(2).padding(2).circular(),
    ] {
        assert!(uses_direct_kernel(x.dims(), w.dims(), &p).unwrap());
        grad_check(
            |t| Ok(conv2d(&t[0], &t[1], Some(&t[2]), &p)?),
            &[x.clone(), w.clone(), b.clone()],
            &format!("{p:?}"),
        );
    }
    // 3D, strided and periodic.
    let x3 = randn(&[2, 2, 4, 5, 6], DType::F64, 9);
    let w3 = randn(&[2, 1, 3, 3, 3], DType::F64, 10);
    let p3 = Conv3dParams::default().padding(1).stride(2).groups(2).circular();
    grad_check(
        |t| Ok(pbdl_core::conv::conv3d(&t[0], &t[1], Some(&t[2]), &p3)?),
        &[x3, w3, b.narrow(0, 0, 2).unwrap()],
        "3d",
    );
}

#[test]
fn direct_second_derivatives_pass_gradient_check() {
    // The input and weight gradients run the direct kernels too: check d(grad_x)/dw and d(grad_w)/dx.
    let x0 = randn(&[2, 2, 8, 7], DType::F64, 11);
    let w0 = randn(&[2, 1, 5, 5], DType::F64, 12);
    for p in [
        Conv2dParams::default().padding(2).groups(2),
        Conv2dParams::default().padding(2).stride(2).groups(2).circular(),
    ] {
        let out = pbdl_core::conv::output_size([8, 7], [5, 5], &p).unwrap();
        let r = randn(&[2, 2, out[0], out[1]], DType::F64, 13);
        let grads_of = |x: &Tensor, w: &Tensor, of_x: bool| -> candle_core::Result<Tensor> {
            let target = Var::from_tensor(if of_x { x } else { w })?;
            let (x, w) = if of_x { (target.as_tensor(), w) } else { (x, target.as_tensor()) };
            let g = conv2d(x, w, None, &p)?.mul(&r)?.sum_all()?.backward()?;
            Ok(g.get(target.as_tensor()).expect("gradient").clone())
        };
        grad_check(|t| grads_of(&x0, &t[0], true), std::slice::from_ref(&w0), &format!("d grad_x / d w, {p:?}"));
        grad_check(|t| grads_of(&t[0], &w0, false), std::slice::from_ref(&x0), &format!("d grad_w / d x, {p:?}"));
    }
}
