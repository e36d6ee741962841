//! Tests of `pbdl_core::conv`: agreement with candle's conv1d/conv2d (values and gradients),
//! finite-difference gradient checks in f64, conv3d against a direct loop, circular padding
//! against explicitly periodic-padded input, and typed errors for bad input.

use candle_core::{DType, Device, Module, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::conv::PaddingMode::{Circular, Zeros};
use pbdl_core::conv::{
    conv, conv1d, conv2d, conv3d, output_size, Conv1dParams, Conv2dParams, Conv3dParams, ConvLayerConfig, ConvParams,
};
use pbdl_core::{assert_varmap_has_grads, check_grad, Error, GradCheckOptions};

mod common;
use common::{randn, rel_diff, F32_TOL, F64_TOL, GRAD_TOL};

/// Output and gradients (input, weight) of `f(x, w)` under the loss `sum(f(x, w) * r)`.
fn value_and_grads(
    f: impl Fn(&Tensor, &Tensor) -> candle_core::Result<Tensor>,
    x: &Tensor,
    w: &Tensor,
    seed: u64,
) -> (Tensor, Tensor, Tensor) {
    let xv = Var::from_tensor(x).unwrap();
    let wv = Var::from_tensor(w).unwrap();
    let y = f(xv.as_tensor(), wv.as_tensor()).unwrap();
    let r = randn(y.dims(), y.dtype(), seed);
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let gx = grads.get(xv.as_tensor()).expect("no input gradient").clone();
    let gw = grads.get(wv.as_tensor()).expect("no weight gradient").clone();
    (y, gx, gw)
}

/// (x shape, w shape, stride, padding, dilation, groups)
type Case = (Vec<usize>, Vec<usize>, usize, usize, usize, usize);

fn compare_with_candle(
    cases: &[Case],
    ours: impl Fn(&Tensor, &Tensor, &Case) -> candle_core::Result<Tensor>,
    theirs: impl Fn(&Tensor, &Tensor, &Case) -> candle_core::Result<Tensor>,
) {
    for (i, case) in cases.iter().enumerate() {
        let x = randn(&case.0, DType::F32, 10 + i as u64);
        let w = randn(&case.1, DType::F32, 100 + i as u64);
        let (y0, gx0, gw0) = value_and_grads(|x, w| ours(x, w, case), &x, &w, 7);
        let (y1, gx1, gw1) = value_and_grads(|x, w| theirs(x, w, case), &x, &w, 7);
        for (name, a, b) in [("output", &y0, &y1), ("input grad", &gx0, &gx1), ("weight grad", &gw0, &gw1)] {
            let e = rel_diff(a, b);
            assert!(e <= F32_TOL, "case {i} {case:?}: {name} differs from candle by {e:.2e}");
        }
    }
}

// candle 0.11.1's conv2d backward derives the output padding of a strided convolution from the
// y axis alone and fails with a shape error when x needs another one (e.g. 9x8 input, stride 2):
// the strided cases here have sizes where both axes agree.
#[test]
fn conv2d_matches_candle_values_and_gradients() {
    let cases: Vec<Case> = vec![
        (vec![2, 3, 9, 8], vec![4, 3, 3, 3], 1, 1, 1, 1),
        (vec![2, 3, 9, 11], vec![4, 3, 3, 3], 2, 1, 1, 1),
        (vec![1, 2, 11, 10], vec![3, 2, 3, 2], 1, 2, 2, 1),
        (vec![2, 2, 12, 9], vec![5, 2, 3, 3], 3, 2, 2, 1),
        (vec![2, 4, 7, 7], vec![6, 2, 3, 3], 1, 1, 1, 2),
        (vec![3, 4, 8, 6], vec![8, 1, 3, 3], 1, 1, 1, 4),
        (vec![2, 5, 6, 7], vec![3, 5, 1, 1], 1, 0, 1, 1),
        (vec![1, 3, 5, 40], vec![2, 3, 5, 5], 1, 2, 1, 1),
        (vec![9, 32, 10, 12], vec![16, 32, 3, 3], 1, 1, 1, 1),
    ];
    compare_with_candle(
        &cases,
        |x, w, c| {
            let p = Conv2dParams::default().stride(c.2).padding(c.3).dilation(c.4).groups(c.5);
            Ok(conv2d(x, w, None, &p)?)
        },
        |x, w, c| x.conv2d(w, c.3, c.2, c.4, c.5),
    );
}

// candle 0.11.1's conv1d gradients are wrong for batch > 1 (check_grad in f64, [2, 3, 17] input,
// 3-tap kernel: relative error ~1 for the weight, and for the input too without padding), so
// gradients are compared with candle's conv2d on a singleton y axis (zero-padded by hand: candle
// pads both axes alike), values with candle's conv1d too.
#[test]
fn conv1d_matches_candle_values_and_gradients() {
    let cases: Vec<Case> = vec![
        (vec![2, 3, 17], vec![4, 3, 3], 1, 1, 1, 1),
        (vec![2, 3, 17], vec![4, 3, 5], 2, 2, 1, 1),
        (vec![1, 2, 20], vec![3, 2, 3], 1, 3, 3, 1),
        (vec![2, 4, 15], vec![4, 1, 3], 1, 1, 1, 4),
        (vec![3, 6, 15], vec![4, 3, 2], 3, 0, 2, 2),
    ];
    let ours = |x: &Tensor, w: &Tensor, c: &Case| -> candle_core::Result<Tensor> {
        let p = Conv1dParams::default().stride(c.2).padding(c.3).dilation(c.4).groups(c.5);
        Ok(conv1d(x, w, None, &p)?)
    };
    compare_with_candle(&cases, ours, |x, w, c| {
        x.pad_with_zeros(2, c.3, c.3)?.unsqueeze(2)?.conv2d(&w.unsqueeze(2)?, 0, c.2, c.4, c.5)?.squeeze(2)
    });
    for (i, c) in cases.iter().enumerate() {
        let x = randn(&c.0, DType::F32, i as u64);
        let w = randn(&c.1, DType::F32, 50 + i as u64);
        let e = rel_diff(&ours(&x, &w, c).unwrap(), &x.conv1d(&w, c.3, c.2, c.4, c.5).unwrap());
        assert!(e <= F32_TOL, "case {i}: conv1d value differs from candle's by {e:.2e}");
    }
}

#[test]
fn bias_is_added_per_channel_and_gets_its_gradient() {
    let x = randn(&[2, 3, 6, 5], DType::F32, 1);
    let w = randn(&[4, 3, 3, 3], DType::F32, 2);
    let b = Var::from_tensor(&randn(&[4], DType::F32, 3)).unwrap();
    let p = Conv2dParams::default().padding(1);
    let y = conv2d(&x, &w, Some(b.as_tensor()), &p).unwrap();
    let expect =
        x.conv2d(&w, 1, 1, 1, 1).unwrap().broadcast_add(&b.as_tensor().reshape((1, 4, 1, 1)).unwrap()).unwrap();
    assert!(rel_diff(&y, &expect) <= F32_TOL);
    let gb = y.sum_all().unwrap().backward().unwrap().get(b.as_tensor()).unwrap().to_vec1::<f32>().unwrap();
    // d sum(y) / d b_o = number of outputs per channel.
    assert!(gb.iter().all(|&g| (g - 2.0 * 30.0).abs() < 1e-3), "{gb:?}");
}

fn grad_check(f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>, inputs: &[Tensor], what: &str) {
    let r = check_grad(f, inputs, &GradCheckOptions { max_probes: 30, ..Default::default() }).unwrap();
    assert!(r.max_rel_error <= GRAD_TOL, "{what}: {r:?}");
}

#[test]
fn conv1d_passes_gradient_check() {
    let x = randn(&[2, 4, 13], DType::F64, 1);
    let w = randn(&[6, 2, 3], DType::F64, 2);
    let b = randn(&[6], DType::F64, 3);
    for p in [
        Conv1dParams::default().stride(2).padding(2).dilation(2).groups(2),
        Conv1dParams::default().padding(3).circular().groups(2),
        Conv1dParams::default().stride(3).padding(1).dilation(2).circular().groups(2),
    ] {
        grad_check(
            |t| Ok(conv1d(&t[0], &t[1], Some(&t[2]), &p)?),
            &[x.clone(), w.clone(), b.clone()],
            &format!("{p:?}"),
        );
    }
}

#[test]
fn conv2d_passes_gradient_check() {
    let x = randn(&[2, 3, 8, 7], DType::F64, 4);
    let w = randn(&[5, 3, 3, 2], DType::F64, 5);
    for p in [
        Conv2dParams { stride: [2, 1], padding: [1, 2], dilation: [1, 2], ..Default::default() },
        Conv2dParams::default().padding(2).dilation(2).stride(2).circular(),
        Conv2dParams::default().padding(1).circular(),
        // Periodic in x only (a lat-lon grid), also strided.
        Conv2dParams { padding_mode: [Zeros, Circular], ..Conv2dParams::default().padding(1) },
        Conv2dParams { padding_mode: [Circular, Zeros], ..Conv2dParams::default().padding(2).stride(2) },
    ] {
        grad_check(|t| Ok(conv2d(&t[0], &t[1], None, &p)?), &[x.clone(), w.clone()], &format!("{p:?}"));
    }
    // Depthwise: groups == in_channels, two filters per channel.
    let wd = randn(&[6, 1, 3, 3], DType::F64, 6);
    let p = Conv2dParams::default().padding(1).groups(3).circular();
    grad_check(|t| Ok(conv2d(&t[0], &t[1], None, &p)?), &[x.clone(), wd.clone()], "depthwise circular");
    let p = Conv2dParams { padding_mode: [Zeros, Circular], ..p };
    grad_check(|t| Ok(conv2d(&t[0], &t[1], None, &p)?), &[x.clone(), wd], "depthwise periodic in x");
}

#[test]
fn conv3d_passes_gradient_check() {
    let x = randn(&[2, 4, 5, 6, 7], DType::F64, 7);
    let w = randn(&[4, 2, 3, 2, 3], DType::F64, 8);
    let b = randn(&[4], DType::F64, 9);
    for p in [
        Conv3dParams { stride: [1, 2, 2], padding: [1, 1, 2], dilation: [2, 1, 1], groups: 2, ..Default::default() },
        Conv3dParams::default().padding(1).circular().groups(2),
        Conv3dParams::default().padding(1).stride(2).dilation(2).circular().groups(4),
    ] {
        let w = if p.groups == 4 { randn(&[4, 1, 3, 2, 3], DType::F64, 10) } else { w.clone() };
        grad_check(|t| Ok(conv3d(&t[0], &t[1], Some(&t[2]), &p)?), &[x.clone(), w, b.clone()], &format!("{p:?}"));
    }
}

#[test]
fn second_derivatives_pass_gradient_check() {
    // The input and weight gradients are differentiable ops too: check d(grad_x)/dw and d(grad_w)/dx.
    let x0 = randn(&[2, 4, 6, 5], DType::F64, 11);
    let w0 = randn(&[4, 2, 3, 3], DType::F64, 12);
    let p = Conv2dParams::default().padding(1).stride(2).groups(2).circular();
    let r = randn(&[2, 4, 3, 3], DType::F64, 13);
    let grads_of = |x: &Tensor, w: &Tensor, of_x: bool| -> candle_core::Result<Tensor> {
        let target = Var::from_tensor(if of_x { x } else { w })?;
        let (x, w) = if of_x { (target.as_tensor(), w) } else { (x, target.as_tensor()) };
        let g = conv2d(x, w, None, &p)?.mul(&r)?.sum_all()?.backward()?;
        Ok(g.get(target.as_tensor()).expect("gradient").clone())
    };
    grad_check(|t| grads_of(&x0, &t[0], true), std::slice::from_ref(&w0), "d grad_x / d w");
    grad_check(|t| grads_of(&t[0], &w0, false), std::slice::from_ref(&x0), "d grad_w / d x");
}

/// Direct-loop 3D convolution in f64: [b, c, z, y, x] * [o, c/g, kz, ky, kx].
fn naive_conv3d(x: &Tensor, w: &Tensor, p: &Conv3dParams) -> Tensor {
    let (b, c, d, h, wd) = x.dims5().unwrap();
    let (o, cg, kd, kh, kw) = w.dims5().unwrap();
    let xs = x.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let ws = w.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let n = [d, h, wd];
    let k = [kd, kh, kw];
    let out: Vec<usize> =
        (0..3).map(|a| (n[a] + 2 * p.padding[a] - p.dilation[a] * (k[a] - 1) - 1) / p.stride[a] + 1).collect();
    let og = o / p.groups;
    let idx = |a: usize, o: usize, t: usize| -> Option<usize> {
        let i = (o * p.stride[a] + t * p.dilation[a]) as isize - p.padding[a] as isize;
        if p.is_circular(a) {
            Some(i.rem_euclid(n[a] as isize) as usize)
        } else {
            (0..n[a] as isize).contains(&i).then_some(i as usize)
        }
    };
    let mut y = vec![0.0; b * o * out.iter().product::<usize>()];
    let mut at = 0;
    for bi in 0..b {
        for oc in 0..o {
            let grp = oc / og;
            for oz in 0..out[0] {
                for oy in 0..out[1] {
                    for ox in 0..out[2] {
                        let mut s = 0.0;
                        for ci in 0..cg {
                            let c_abs = grp * cg + ci;
                            for tz in 0..kd {
                                for ty in 0..kh {
                                    for tx in 0..kw {
                                        if let (Some(iz), Some(iy), Some(ix)) =
                                            (idx(0, oz, tz), idx(1, oy, ty), idx(2, ox, tx))
                                        {
                                            let xv = xs[(((bi * c + c_abs) * d + iz) * h + iy) * wd + ix];
                                            let wv = ws[(((oc * cg + ci) * kd + tz) * kh + ty) * kw + tx];
                                            s += xv * wv;
                                        }
                                    }
                                }
                            }
                        }
                        y[at] = s;
                        at += 1;
                    }
                }
            }
        }
    }
    Tensor::from_vec(y, (b, o, out[0], out[1], out[2]), &Device::Cpu).unwrap()
}

#[test]
fn conv3d_matches_a_direct_loop() {
    let cases = [
        ([2, 3, 5, 6, 7], [4, 3, 3, 3, 3], Conv3dParams::default().padding(1)),
        (
            [1, 4, 6, 5, 8],
            [6, 2, 2, 3, 3],
            Conv3dParams {
                stride: [2, 1, 3],
                padding: [0, 2, 1],
                dilation: [1, 2, 2],
                groups: 2,
                ..Default::default()
            },
        ),
        ([2, 2, 4, 4, 4], [2, 1, 3, 3, 3], Conv3dParams::default().padding(2).groups(2).circular()),
        ([1, 2, 7, 3, 5], [3, 2, 2, 2, 2], Conv3dParams::default().padding(1).stride(2).circular()),
        ([2, 3, 3, 4, 5], [5, 3, 1, 1, 1], Conv3dParams::default()),
        // Periodic along some axes only (im2col and direct depthwise paths).
        (
            [2, 3, 4, 5, 6],
            [4, 3, 3, 3, 3],
            Conv3dParams { padding_mode: [Zeros, Circular, Circular], ..Conv3dParams::default().padding(1) },
        ),
        (
            [1, 4, 5, 4, 7],
            [4, 1, 3, 3, 3],
            Conv3dParams { padding_mode: [Circular, Zeros, Circular], ..Conv3dParams::default().padding(1).groups(4) },
        ),
        (
            [1, 2, 5, 6, 7],
            [2, 2, 2, 3, 3],
            Conv3dParams { padding_mode: [Zeros, Zeros, Circular], ..Conv3dParams::default().padding(2).stride(2) },
        ),
    ];
    for (i, (xs, ws, p)) in cases.iter().enumerate() {
        let x = randn(xs, DType::F64, 20 + i as u64);
        let w = randn(ws, DType::F64, 40 + i as u64);
        let ours = conv3d(&x, &w, None, p).unwrap();
        let reference = naive_conv3d(&x, &w, p);
        let e = rel_diff(&ours, &reference);
        assert!(e <= F64_TOL, "case {i}: conv3d differs from the direct loop by {e:.2e}");
    }
}

#[test]
fn large_volume_is_tiled_and_parallel_and_still_exact() {
    // Large enough for several im2col tiles per image and several images per thread.
    let x = randn(&[3, 4, 12, 40, 40], DType::F64, 50);
    let w = randn(&[4, 4, 3, 3, 3], DType::F64, 51);
    let p = Conv3dParams::default().padding(1).circular();
    let e = rel_diff(&conv3d(&x, &w, None, &p).unwrap(), &naive_conv3d(&x, &w, &p));
    assert!(e <= F64_TOL, "{e:.2e}");
}

/// Pads `x` periodically by `p` on both sides of `axis`.
fn periodic_pad(x: &Tensor, axis: usize, p: usize) -> Tensor {
    let n = x.dim(axis).unwrap();
    Tensor::cat(&[&x.narrow(axis, n - p, p).unwrap(), x, &x.narrow(axis, 0, p).unwrap()], axis).unwrap()
}

#[test]
fn circular_padding_equals_explicitly_periodic_input() {
    // 2D with different paddings per axis, strided and dilated; values and both gradients.
    let x = randn(&[2, 3, 9, 8], DType::F64, 60);
    let w = randn(&[4, 3, 3, 3], DType::F64, 61);
    let p = Conv2dParams { padding: [2, 1], stride: [2, 1], dilation: [2, 1], ..Default::default() };
    let circular = |x: &Tensor, w: &Tensor| -> candle_core::Result<Tensor> { Ok(conv2d(x, w, None, &p.circular())?) };
    let explicit = |x: &Tensor, w: &Tensor| -> candle_core::Result<Tensor> {
        let padded = periodic_pad(&periodic_pad(x, 2, 2), 3, 1);
        Ok(conv2d(&padded, w, None, &Conv2dParams { padding: [0, 0], ..p })?)
    };
    let (y0, gx0, gw0) = value_and_grads(circular, &x, &w, 3);
    let (y1, gx1, gw1) = value_and_grads(explicit, &x, &w, 3);
    for (name, a, b) in [("output", &y0, &y1), ("input grad", &gx0, &gx1), ("weight grad", &gw0, &gw1)] {
        let e = rel_diff(a, b);
        assert!(e <= F64_TOL, "{name}: {e:.2e}");
    }

    // 1D and 3D values.
    let x1 = randn(&[2, 2, 10], DType::F64, 62);
    let w1 = randn(&[3, 2, 5], DType::F64, 63);
    let a = conv1d(&x1, &w1, None, &Conv1dParams::default().padding(2).circular()).unwrap();
    let b = conv1d(&periodic_pad(&x1, 2, 2), &w1, None, &Conv1dParams::default()).unwrap();
    assert!(rel_diff(&a, &b) <= F64_TOL);
    let x3 = randn(&[1, 2, 4, 5, 6], DType::F64, 64);
    let w3 = randn(&[2, 2, 3, 3, 3], DType::F64, 65);
    let a = conv3d(&x3, &w3, None, &Conv3dParams::default().padding(1).circular()).unwrap();
    let padded = periodic_pad(&periodic_pad(&periodic_pad(&x3, 2, 1), 3, 1), 4, 1);
    let b = conv3d(&padded, &w3, None, &Conv3dParams::default()).unwrap();
    assert!(rel_diff(&a, &b) <= F64_TOL);
}

#[test]
fn non_contiguous_input_is_read_correctly() {
    let base = randn(&[2, 3, 8, 9], DType::F32, 70);
    let x = base.transpose(2, 3).unwrap(); // [2, 3, 9, 8], strided
    assert!(!x.is_contiguous());
    let w = randn(&[4, 3, 3, 3], DType::F32, 71);
    let ours = conv2d(&x, &w, None, &Conv2dParams::default().padding(1)).unwrap();
    let theirs = x.contiguous().unwrap().conv2d(&w, 1, 1, 1, 1).unwrap();
    assert!(rel_diff(&ours, &theirs) <= F32_TOL);
}

#[test]
fn bad_input_gives_typed_errors() {
    let x = randn(&[2, 4, 8, 8], DType::F32, 80);
    let w = randn(&[6, 4, 3, 3], DType::F32, 81);
    let p = Conv2dParams::default();
    let shape_err = |r: pbdl_core::Result<Tensor>, arg: &str| match r {
        Err(Error::Shape { arg: a, .. }) if a == arg => {}
        other => panic!("expected a Shape error for `{arg}`, got {other:?}"),
    };
    let invalid = |r: pbdl_core::Result<Tensor>, arg: &str| match r {
        Err(Error::InvalidArgument { arg: a, ref reason, .. }) if a == arg => assert!(!reason.is_empty()),
        other => panic!("expected InvalidArgument for `{arg}`, got {other:?}"),
    };
    // Channels of input and weight disagree.
    shape_err(conv2d(&x, &randn(&[6, 3, 3, 3], DType::F32, 1), None, &p), "weight");
    // Wrong ranks.
    shape_err(conv2d(&x.flatten_from(2).unwrap(), &w, None, &p), "input");
    shape_err(conv2d(&x, &w.flatten_from(2).unwrap(), None, &p), "weight");
    // Groups not dividing the channels, or zero.
    invalid(conv2d(&x, &randn(&[6, 1, 3, 3], DType::F32, 2), None, &p.groups(3)), "groups");
    invalid(conv2d(&x, &w, None, &p.groups(0)), "groups");
    // Kernel larger than the padded input; padding makes it fit.
    let big = randn(&[6, 4, 11, 3], DType::F32, 3);
    invalid(conv2d(&x, &big, None, &p), "weight");
    assert!(conv2d(&x, &big, None, &p.padding(2)).is_ok());
    // Zero stride or dilation.
    invalid(conv2d(&x, &w, None, &p.stride(0)), "stride");
    invalid(conv2d(&x, &w, None, &p.dilation(0)), "dilation");
    // Bias of the wrong length.
    shape_err(conv2d(&x, &w, Some(&randn(&[5], DType::F32, 4)), &p), "bias");
    // Mixed or unsupported dtypes.
    assert!(matches!(conv2d(&x, &w.to_dtype(DType::F64).unwrap(), None, &p), Err(Error::DType { arg: "weight", .. })));
    let xi = x.to_dtype(DType::U32).unwrap();
    assert!(matches!(conv2d(&xi, &w, None, &p), Err(Error::DType { arg: "input", .. })));
    // Messages say what to change.
    let msg = conv2d(&x, &big, None, &p).unwrap_err().to_string();
    assert!(msg.contains("more padding"), "{msg}");
    let msg = conv2d(&x, &randn(&[6, 3, 3, 3], DType::F32, 1), None, &p).unwrap_err().to_string();
    assert!(msg.contains("in_channels / groups"), "{msg}");
}

#[test]
fn output_size_helper_matches_the_op() {
    let p = Conv2dParams { stride: [2, 3], padding: [1, 0], dilation: [1, 2], ..Default::default() };
    let size = output_size([17, 20], [3, 4], &p).unwrap();
    let y = conv2d(&randn(&[1, 1, 17, 20], DType::F32, 1), &randn(&[1, 1, 3, 4], DType::F32, 2), None, &p).unwrap();
    assert_eq!(&y.dims()[2..], &size);
    assert!(output_size([2], [5], &Conv1dParams::default()).is_err());
}

#[test]
fn layers_are_modules_and_train_every_parameter() {
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let c1 = ConvLayerConfig::new(2, 4, [5])
        .with_params(Conv1dParams::default().padding(2).circular())
        .init(vb.pp("c1"))
        .unwrap();
    let c2 = ConvLayerConfig::new(3, 6, [3, 3])
        .with_params(Conv2dParams::default().padding(1).groups(3))
        .init(vb.pp("c2"))
        .unwrap();
    let c3 = ConvLayerConfig::new(2, 2, [3, 3, 3])
        .with_params(Conv3dParams::default().padding(1))
        .without_bias()
        .init(vb.pp("c3"))
        .unwrap();
    assert!(c3.bias().is_none());

    let x2 = randn(&[2, 3, 6, 6], DType::F32, 90);
    let y2 = c2.forward(&x2).unwrap();
    let expect = x2
        .conv2d(c2.weight(), 1, 1, 1, 3)
        .unwrap()
        .broadcast_add(&c2.bias().unwrap().reshape((1, 6, 1, 1)).unwrap())
        .unwrap();
    assert!(rel_diff(&y2, &expect) <= F32_TOL);

    let l1 = c1.forward(&randn(&[2, 2, 8], DType::F32, 91)).unwrap().sqr().unwrap().sum_all().unwrap();
    let l3 = c3.forward(&randn(&[1, 2, 4, 4, 4], DType::F32, 92)).unwrap().sqr().unwrap().sum_all().unwrap();
    let loss = (l1 + y2.sqr().unwrap().sum_all().unwrap() + l3).unwrap();
    let grads = loss.backward().unwrap();
    assert_varmap_has_grads(&varmap, &grads).unwrap();
    assert_eq!(varmap.all_vars().len(), 5);

    // The generic function serves all ranks.
    let _: Tensor = conv(&x2, c2.weight(), None, &ConvParams::<2>::default().padding(1).groups(3)).unwrap();
}
