//! Tests of `pbdl_core::nn`: finite-difference gradient checks in f64, values against
//! hand-computed references, and the gradient gaps of candle's fused kernels.

use candle_core::{DType, Device, Module, Tensor, D};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::nn::{
    self, activation, Activation, GroupNorm, GroupNormConfig, LayerNorm, LayerNormConfig, RmsNorm, RmsNormConfig,
};
use pbdl_core::{assert_varmap_has_grads, check_grad, seed, Error, GradCheckOptions};

// Tolerance on the relative (max-norm) error of analytic vs finite-difference gradients.
use pbdl_core::tolerance::GRAD_CHECK_F64 as GRAD_TOL;

fn randn(shape: &[usize], mean: f64, std: f64, s: u64) -> Tensor {
    seed::randn(shape, mean, std, DType::F64, &Device::Cpu, s).unwrap()
}

fn vec(t: &Tensor) -> Vec<f64> {
    t.flatten_all().unwrap().to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    vec(a).iter().zip(vec(b)).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Runs `check_grad` and asserts the tolerance, printing the report on failure.
fn grad_ok<F>(name: &str, f: F, inputs: &[Tensor])
where
    F: Fn(&[Tensor]) -> candle_core::Result<Tensor>,
{
    let r = check_grad(f, inputs, &GradCheckOptions::default()).unwrap();
    assert!(r.max_rel_error <= GRAD_TOL, "{name}: {r:?}");
}

// ---------------------------------------------------------------- gradient checks

#[test]
fn layer_norm_gradient_in_x_weight_and_bias() {
    let x = randn(&[3, 5], 0.5, 2.0, 1);
    let w = randn(&[5], 1.0, 0.3, 2);
    let b = randn(&[5], 0.0, 0.3, 3);
    grad_ok("layer_norm", |xs| Ok(nn::layer_norm(&xs[0], &[5], Some(&xs[1]), Some(&xs[2]), 1e-5)?), &[x, w, b]);
}

#[test]
fn layer_norm_over_two_trailing_dims_gradient() {
    let x = randn(&[2, 3, 4], 0.0, 1.0, 4);
    let w = randn(&[3, 4], 1.0, 0.3, 5);
    let b = randn(&[3, 4], 0.0, 0.3, 6);
    grad_ok("layer_norm 2d", |xs| Ok(nn::layer_norm(&xs[0], &[3, 4], Some(&xs[1]), Some(&xs[2]), 1e-5)?), &[x, w, b]);
}

#[test]
fn rms_norm_gradient_in_x_and_weight() {
    let x = randn(&[4, 6], 0.3, 1.5, 7);
    let w = randn(&[6], 1.0, 0.3, 8);
    grad_ok("rms_norm", |xs| Ok(nn::rms_norm(&xs[0], &[6], Some(&xs[1]), 1e-5)?), &[x, w]);
}

#[test]
fn group_norm_gradient_in_x_weight_and_bias() {
    let x = randn(&[2, 6, 3, 2], 0.2, 1.3, 9);
    let w = randn(&[6], 1.0, 0.3, 10);
    let b = randn(&[6], 0.0, 0.3, 11);
    grad_ok("group_norm", |xs| Ok(nn::group_norm(&xs[0], 3, Some(&xs[1]), Some(&xs[2]), 1e-5)?), &[x, w, b]);
}

#[test]
fn group_norm_without_affine_and_instance_norm_gradients() {
    let x = randn(&[2, 4, 5], 0.0, 1.0, 12);
    grad_ok("group_norm no affine", |xs| Ok(nn::group_norm(&xs[0], 2, None, None, 1e-5)?), std::slice::from_ref(&x));
    grad_ok("instance norm", |xs| Ok(nn::group_norm(&xs[0], 4, None, None, 1e-5)?), &[x]);
}

#[test]
fn softmax_and_log_softmax_gradients_over_each_dim() {
    let x = randn(&[3, 4, 5], 0.0, 2.0, 13);
    for dim in 0..3 {
        grad_ok("softmax", |xs| Ok(nn::softmax(&xs[0], dim)?), std::slice::from_ref(&x));
        grad_ok("log_softmax", |xs| Ok(nn::log_softmax(&xs[0], dim)?), std::slice::from_ref(&x));
    }
    grad_ok("softmax D::Minus1", |xs| Ok(nn::softmax(&xs[0], D::Minus1)?), &[x]);
}

/// A VarBuilder serving the given tensors, so check_grad can vary a module's parameters.
fn vb_from(params: &[(&str, &Tensor)]) -> VarBuilder<'static> {
    let map = params.iter().map(|(k, t)| (k.to_string(), (*t).clone())).collect();
    VarBuilder::from_tensors(map, DType::F64, &Device::Cpu)
}

#[test]
fn modules_pass_gradient_checks_through_their_parameters() {
    let x = randn(&[2, 4, 3], 0.0, 1.0, 14);
    let w = randn(&[4], 1.0, 0.3, 15);
    let b = randn(&[4], 0.0, 0.3, 16);
    let gn = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        let m = GroupNorm::new(2, 4, GroupNormConfig::default(), vb_from(&[("weight", &xs[1]), ("bias", &xs[2])]))?;
        m.forward(&xs[0])
    };
    grad_ok("GroupNorm", gn, &[x.clone(), w.clone(), b.clone()]);
    let w3 = randn(&[3], 1.0, 0.3, 18);
    let b3 = randn(&[3], 0.0, 0.3, 19);
    let ln = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        let m = LayerNorm::new(&[3], LayerNormConfig::default(), vb_from(&[("weight", &xs[1]), ("bias", &xs[2])]))?;
        m.forward(&xs[0])
    };
    grad_ok("LayerNorm", ln, &[x.clone(), w3.clone(), b3]);
    let rms = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        let m = RmsNorm::new(&[3], RmsNormConfig::default(), vb_from(&[("weight", &xs[1])]))?;
        m.forward(&xs[0])
    };
    grad_ok("RmsNorm", rms, &[x, w3]);
}

/// Inputs for activations: seeded normals kept at least 1e-3 away from the kinks at 0.
fn activation_input() -> Tensor {
    let v: Vec<f64> =
        vec(&randn(&[40], 0.0, 2.0, 17)).into_iter().map(|x| if x.abs() < 1e-3 { x + 0.1 } else { x }).collect();
    Tensor::from_vec(v, (4, 10), &Device::Cpu).unwrap()
}

#[test]
fn every_activation_passes_gradient_check() {
    let x = activation_input();
    let acts = [
        Activation::Identity,
        Activation::Relu,
        Activation::Gelu,
        Activation::GeluErf,
        Activation::Silu,
        Activation::Tanh,
        Activation::Sigmoid,
        Activation::Softplus,
        Activation::Mish,
        Activation::Elu { alpha: 0.7 },
        Activation::LeakyRelu { negative_slope: 0.05 },
    ];
    for act in acts {
        grad_ok(&format!("{act:?}"), |xs| Ok(act.apply(&xs[0])?), std::slice::from_ref(&x));
    }
}

#[test]
fn activations_gradients_are_finite_for_large_inputs() {
    // exp(100) overflows f32: candle_nn::ops::mish's gradient is NaN there, ours is not.
    let x = candle_core::Var::new(&[-100.0f32, -30.0, 30.0, 100.0], &Device::Cpu).unwrap();
    for f in [activation::softplus, activation::mish, activation::sigmoid, activation::silu, activation::gelu] {
        let g = f(x.as_tensor()).unwrap().sum_all().unwrap().backward().unwrap();
        let g = vec(g.get(x.as_tensor()).unwrap());
        assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
    }
    let g = candle_nn::ops::mish(x.as_tensor()).unwrap().sum_all().unwrap().backward().unwrap();
    let g = vec(g.get(x.as_tensor()).unwrap());
    assert!(g[3].is_nan(), "candle_nn::ops::mish at x = 100 (f32) is expected to have a NaN gradient, got {g:?}");
}

/// candle's fused `gelu` / `gelu_erf` backward use 6-digit constants: measurable gradient error,
/// which is why `nn::activation::gelu` is composed and `nn::activation::gelu_erf` is our own
/// fused op with full-precision constants. Their forward is exact and equal to ours.
#[test]
fn candle_fused_gelu_backward_is_only_approximate() {
    let x = activation_input();
    let opts = GradCheckOptions::default();
    let fused = check_grad(|xs| xs[0].gelu(), std::slice::from_ref(&x), &opts).unwrap().max_rel_error;
    let fused_erf = check_grad(|xs| xs[0].gelu_erf(), std::slice::from_ref(&x), &opts).unwrap().max_rel_error;
    let ours = check_grad(|xs| Ok(activation::gelu(&xs[0])?), std::slice::from_ref(&x), &opts).unwrap().max_rel_error;
    let ours_erf =
        check_grad(|xs| Ok(activation::gelu_erf(&xs[0])?), std::slice::from_ref(&x), &opts).unwrap().max_rel_error;
    println!("gelu: candle {fused:.2e} ours {ours:.2e}; gelu_erf: candle {fused_erf:.2e} ours {ours_erf:.2e}");
    assert!(ours < 1e-8 && ours_erf < 1e-8, "{ours:e} {ours_erf:e}");
    assert!(fused > 1e-7 && fused_erf > 1e-7, "candle's fused gelu backward got exact? {fused:e} {fused_erf:e}");
    assert!(max_abs_diff(&activation::gelu(&x).unwrap(), &x.gelu().unwrap()) < 1e-14);
    assert!(max_abs_diff(&activation::gelu_erf(&x).unwrap(), &x.gelu_erf().unwrap()) < 1e-14);
}

// ---------------------------------------------------------------- values

#[test]
fn softmax_rows_sum_to_one_and_match_hand_computation() {
    let rows = [[1.0f64, 2.0, 3.0], [-1.0, 0.0, 0.5], [700.0, 701.0, 702.0]];
    let x = Tensor::new(&rows, &Device::Cpu).unwrap();
    let p = nn::softmax(&x, 1).unwrap().to_vec2::<f64>().unwrap();
    let lp = nn::log_softmax(&x, 1).unwrap().to_vec2::<f64>().unwrap();
    for (r, row) in rows.iter().enumerate() {
        // Reference in plain f64, shifted by the row max by hand.
        let m = row.iter().cloned().fold(f64::MIN, f64::max);
        let z: f64 = row.iter().map(|v| (v - m).exp()).sum();
        for c in 0..3 {
            let expect = (row[c] - m).exp() / z;
            assert!((p[r][c] - expect).abs() < 1e-15, "{r},{c}");
            assert!((lp[r][c] - (row[c] - m - z.ln())).abs() < 1e-13, "{r},{c}");
        }
        assert!((p[r].iter().sum::<f64>() - 1.0).abs() < 1e-15);
    }
    // Over dim 0 the columns sum to one.
    let p0 = nn::softmax(&x, 0).unwrap().sum(0).unwrap();
    assert!(vec(&p0).iter().all(|s| (s - 1.0).abs() < 1e-15));
}

#[test]
fn layer_norm_output_has_mean_zero_variance_one_and_matches_loops() {
    let x = randn(&[4, 16], 3.0, 5.0, 20);
    let eps = 1e-5;
    let y = nn::layer_norm(&x, &[16], None, None, eps).unwrap().to_vec2::<f64>().unwrap();
    for (r, row) in x.to_vec2::<f64>().unwrap().iter().enumerate() {
        let mean = row.iter().sum::<f64>() / 16.0;
        let var = row.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 16.0;
        for c in 0..16 {
            assert!((y[r][c] - (row[c] - mean) / (var + eps).sqrt()).abs() < 1e-13);
        }
        let ym = y[r].iter().sum::<f64>() / 16.0;
        let yv = y[r].iter().map(|v| (v - ym).powi(2)).sum::<f64>() / 16.0;
        assert!(ym.abs() < 1e-14, "mean {ym}");
        // Variance is var / (var + eps): 1 up to eps / var.
        assert!((yv - var / (var + eps)).abs() < 1e-13 && (yv - 1.0).abs() < 1e-5, "var {yv}");
    }
    // Weight and bias: y * w + b elementwise.
    let w = randn(&[16], 1.0, 0.5, 21);
    let b = randn(&[16], 0.0, 0.5, 22);
    let plain = nn::layer_norm(&x, &[16], None, None, eps).unwrap();
    let affine = nn::layer_norm(&x, &[16], Some(&w), Some(&b), eps).unwrap();
    let expect = plain.broadcast_mul(&w).unwrap().broadcast_add(&b).unwrap();
    assert!(max_abs_diff(&affine, &expect) < 1e-14);
}

#[test]
fn layer_norm_and_rms_norm_match_candle_fused_values() {
    // candle's fused kernels give the right values (only their backward is missing). They have
    // no f64 kernel (both fail with "unsupported dtype for rmsnorm F64"), so compare in f32.
    let f32 = |t: Tensor| t.to_dtype(DType::F32).unwrap();
    let x = f32(randn(&[3, 8], 1.0, 2.0, 23));
    let w = f32(randn(&[8], 1.0, 0.5, 24));
    let b = f32(randn(&[8], 0.0, 0.5, 25));
    let ours = nn::layer_norm(&x, &[8], Some(&w), Some(&b), 1e-5).unwrap();
    let theirs = candle_nn::ops::layer_norm(&x, &w, &b, 1e-5).unwrap();
    assert!(max_abs_diff(&ours, &theirs) < 1e-5);
    let ours = nn::rms_norm(&x, &[8], Some(&w), 1e-5).unwrap();
    let theirs = candle_nn::ops::rms_norm(&x, &w, 1e-5).unwrap();
    assert!(max_abs_diff(&ours, &theirs) < 1e-5);
    assert!(candle_nn::ops::layer_norm(&x.to_dtype(DType::F64).unwrap(), &w, &b, 1e-5).is_err());
}

#[test]
fn group_norm_with_one_group_is_layer_norm_over_chw() {
    let x = randn(&[2, 3, 4, 5], -1.0, 2.0, 26);
    let w = randn(&[3], 1.0, 0.5, 27);
    let b = randn(&[3], 0.0, 0.5, 28);
    let gn = nn::group_norm(&x, 1, None, None, 1e-5).unwrap();
    let ln = nn::layer_norm(&x, &[3, 4, 5], None, None, 1e-5).unwrap();
    assert!(max_abs_diff(&gn, &ln) < 1e-14);
    // With per-channel parameters: layer norm with those broadcast over (H, W).
    let gn = nn::group_norm(&x, 1, Some(&w), Some(&b), 1e-5).unwrap();
    let w3 = w.reshape((3, 1, 1)).unwrap().broadcast_as((3, 4, 5)).unwrap().contiguous().unwrap();
    let b3 = b.reshape((3, 1, 1)).unwrap().broadcast_as((3, 4, 5)).unwrap().contiguous().unwrap();
    let ln = nn::layer_norm(&x, &[3, 4, 5], Some(&w3), Some(&b3), 1e-5).unwrap();
    assert!(max_abs_diff(&gn, &ln) < 1e-14);
}

#[test]
fn group_norm_matches_loops_and_candle_nn() {
    let (n, c, l, g) = (2, 6, 7, 3);
    let x = randn(&[n, c, l], 0.5, 1.5, 29);
    let y = vec(&nn::group_norm(&x, g, None, None, 0.0).unwrap());
    let xv = vec(&x);
    let per = c / g * l;
    for s in 0..n * g {
        let chunk = &xv[s * per..(s + 1) * per];
        let mean = chunk.iter().sum::<f64>() / per as f64;
        let var = chunk.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / per as f64;
        for i in 0..per {
            assert!((y[s * per + i] - (chunk[i] - mean) / var.sqrt()).abs() < 1e-13);
        }
    }
    // candle-nn's GroupNorm is composed (it trains); values agree with ours.
    let w = randn(&[c], 1.0, 0.5, 30);
    let b = randn(&[c], 0.0, 0.5, 31);
    let theirs = candle_nn::GroupNorm::new(w.clone(), b.clone(), c, g, 1e-5).unwrap().forward(&x).unwrap();
    let ours = nn::group_norm(&x, g, Some(&w), Some(&b), 1e-5).unwrap();
    assert!(max_abs_diff(&ours, &theirs) < 1e-13);
}

#[test]
fn rms_norm_matches_loops() {
    let x = randn(&[3, 5], 0.0, 2.0, 32);
    let y = nn::rms_norm(&x, &[5], None, 1e-6).unwrap().to_vec2::<f64>().unwrap();
    for (r, row) in x.to_vec2::<f64>().unwrap().iter().enumerate() {
        let rms = (row.iter().map(|v| v * v).sum::<f64>() / 5.0 + 1e-6).sqrt();
        for c in 0..5 {
            assert!((y[r][c] - row[c] / rms).abs() < 1e-14);
        }
    }
}

#[test]
fn activation_values_match_formulas() {
    let xs = [-3.0f64, -0.5, 0.0, 0.7, 4.0];
    let x = Tensor::new(&xs, &Device::Cpu).unwrap();
    let check = |act: Activation, f: &dyn Fn(f64) -> f64| {
        let y = act.apply(&x).unwrap().to_vec1::<f64>().unwrap();
        for (v, &xi) in y.iter().zip(&xs) {
            assert!((v - f(xi)).abs() < 1e-14, "{act:?}({xi}) = {v}, expected {}", f(xi));
        }
    };
    let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
    let softplus = |x: f64| (1.0 + x.exp()).ln();
    check(Activation::Relu, &|x| x.max(0.0));
    check(Activation::Sigmoid, &sig);
    check(Activation::Silu, &|x| x * sig(x));
    check(Activation::Tanh, &f64::tanh);
    check(Activation::Softplus, &softplus);
    check(Activation::Mish, &|x| x * softplus(x).tanh());
    check(Activation::Elu { alpha: 0.7 }, &|x| if x > 0.0 { x } else { 0.7 * (x.exp() - 1.0) });
    check(Activation::LeakyRelu { negative_slope: 0.05 }, &|x| if x > 0.0 { x } else { 0.05 * x });
    check(Activation::Gelu, &|x| {
        0.5 * x * (1.0 + ((2.0 / std::f64::consts::PI).sqrt() * (x + 0.044715 * x.powi(3))).tanh())
    });
}

#[test]
fn activation_serde_round_trip() {
    for act in [Activation::Gelu, Activation::Elu { alpha: 1.0 }, Activation::LeakyRelu { negative_slope: 0.2 }] {
        let s = serde_json::to_string(&act).unwrap();
        assert_eq!(serde_json::from_str::<Activation>(&s).unwrap(), act, "{s}");
    }
    assert_eq!(serde_json::from_str::<Activation>(r#""gelu_erf""#).unwrap(), Activation::GeluErf);
    assert_eq!(Activation::default(), Activation::Gelu);
}

// ---------------------------------------------------------------- errors

#[test]
fn shape_errors_name_op_and_expected_dims() {
    let x = randn(&[2, 6, 4], 0.0, 1.0, 33);
    let e = nn::group_norm(&x, 4, None, None, 1e-5).unwrap_err();
    assert!(matches!(e, Error::InvalidArgument { op: "group_norm", arg: "num_groups", .. }), "{e}");
    assert!(e.to_string().contains("divisor"), "{e}");
    let e = nn::layer_norm(&x, &[6], None, None, 1e-5).unwrap_err();
    assert!(matches!(e, Error::Shape { op: "layer_norm", .. }), "{e}");
    assert!(e.to_string().contains("[2, 6, 4]"), "{e}");
    let w = randn(&[5], 1.0, 0.1, 34);
    let e = nn::layer_norm(&x, &[4], Some(&w), None, 1e-5).unwrap_err();
    assert!(matches!(e, Error::Shape { arg: "weight", .. }), "{e}");
    let e = nn::layer_norm(&x, &[4], None, None, -1.0).unwrap_err();
    assert!(e.to_string().contains("eps"), "{e}");
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let gn = GroupNorm::new(2, 4, GroupNormConfig::default(), vb.pp("gn")).unwrap();
    let e = gn.apply(&x.to_dtype(DType::F32).unwrap()).unwrap_err();
    assert!(e.to_string().contains("[batch, 4, ..]"), "{e}");
    assert!(GroupNorm::new(3, 4, GroupNormConfig::default(), vb.pp("bad")).is_err());
}

// ---------------------------------------------------------------- training

/// One training step through each of our norm modules gives every VarMap variable a
/// gradient, in f32 as used in training.
#[test]
fn one_training_step_reaches_every_parameter() {
    let dev = Device::Cpu;
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let lin = candle_nn::linear(8, 8, vb.pp("lin")).unwrap();
    let ln = LayerNorm::new(&[8], LayerNormConfig::default(), vb.pp("ln")).unwrap();
    let rms = RmsNorm::new(&[8], RmsNormConfig::default(), vb.pp("rms")).unwrap();
    let gn = GroupNorm::new(2, 4, GroupNormConfig::default(), vb.pp("gn")).unwrap();
    // candle_nn::linear's random init is not seedable: overwrite it with seeded values.
    let mut varmap = varmap;
    varmap.set_one("lin.weight", seed::randn((8, 8), 0.0, 0.3, DType::F32, &dev, 43).unwrap()).unwrap();
    varmap.set_one("lin.bias", seed::randn(8, 0.0, 0.3, DType::F32, &dev, 44).unwrap()).unwrap();
    let x = seed::randn((4, 8), 0.0, 1.0, DType::F32, &dev, 40).unwrap();
    assert!(x.is_contiguous(), "the case where candle_nn::LayerNorm loses its gradient");
    let h = ln.forward(&lin.forward(&x).unwrap()).unwrap();
    let h = rms.forward(&Activation::Gelu.forward(&h).unwrap()).unwrap();
    let h = gn.forward(&h.reshape((4, 4, 2)).unwrap()).unwrap();
    let logp = nn::log_softmax(&h.flatten_from(1).unwrap(), 1).unwrap();
    let loss = logp.narrow(1, 0, 1).unwrap().mean_all().unwrap().neg().unwrap();
    let grads = loss.backward().unwrap();
    assert_varmap_has_grads(&varmap, &grads).unwrap();
    assert_eq!(varmap.all_vars().len(), 7, "lin.weight, lin.bias, ln.weight, ln.bias, rms.weight, gn.weight, gn.bias");

    // The step itself moves the parameters.
    let before = vec(ln.weight().unwrap());
    let mut opt = <candle_nn::SGD as candle_nn::Optimizer>::new(varmap.all_vars(), 0.1).unwrap();
    candle_nn::Optimizer::step(&mut opt, &grads).unwrap();
    assert_ne!(before, vec(ln.weight().unwrap()));
}

/// Documents candle 0.11's silent gap: its fused LayerNorm / RmsNorm / softmax_last_dim on
/// contiguous input return no gradient at all, and `backward()` does not complain.
/// If this test starts failing, candle has fixed it.
#[test]
fn candle_fused_norms_silently_drop_gradients() {
    let dev = Device::Cpu;
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let ln = candle_nn::layer_norm(8, candle_nn::LayerNormConfig::default(), vb.pp("candle_ln")).unwrap();
    let x = candle_core::Var::from_tensor(&seed::randn((4, 8), 0.0, 1.0, DType::F32, &dev, 41).unwrap()).unwrap();
    let grads = ln.forward(x.as_tensor()).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap();
    match assert_varmap_has_grads(&varmap, &grads) {
        Err(Error::MissingGradient { names }) => assert_eq!(names, ["candle_ln.bias", "candle_ln.weight"]),
        other => panic!("expected candle_nn::LayerNorm to lose its gradients, got {other:?}"),
    }
    assert!(grads.get(x.as_tensor()).is_none());

    let r = candle_nn::rms_norm(8, 1e-5, vb.pp("candle_rms")).unwrap();
    let grads = r.forward(x.as_tensor()).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap();
    assert!(grads.get(x.as_tensor()).is_none());

    let w = seed::randn((4, 8), 0.0, 1.0, DType::F32, &dev, 42).unwrap();
    let grads = candle_nn::ops::softmax_last_dim(x.as_tensor())
        .unwrap()
        .mul(&w)
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    assert!(grads.get(x.as_tensor()).is_none());
    // Ours, same input: gradients present.
    let grads = nn::softmax(x.as_tensor(), D::Minus1).unwrap().mul(&w).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(grads.get(x.as_tensor()).is_some());
}

// ---------------------------------------------------------------- max pooling

#[test]
fn max_pool_gradient_at_kernel_equal_stride_and_overlapping_windows() {
    let x = randn(&[2, 3, 8, 8], 0.0, 1.0, 31);
    grad_ok("max_pool2d(2, 2)", |xs| Ok(nn::max_pool2d(&xs[0], 2, 2)?), std::slice::from_ref(&x));
    grad_ok("max_pool2d(4, 2)", |xs| Ok(nn::max_pool2d(&xs[0], 4, 2)?), &[x]);
}

/// candle 0.11's `max_pool2d(2)` backward returns a quarter of the true input gradient
/// (docs/candle-traps.md). This test pins the gap: if a candle upgrade fixes it, it fails, and
/// `nn::max_pool2d` may be dropped in favour of candle's.
#[test]
fn candle_max_pool2d_backward_is_four_times_too_small() {
    let x = candle_core::Var::from_tensor(&randn(&[1, 2, 6, 6], 0.0, 1.0, 32)).unwrap();
    let ours = nn::max_pool2d(x.as_tensor(), 2, 2).unwrap();
    let theirs = x.as_tensor().max_pool2d(2).unwrap();
    assert_eq!(vec(&ours), vec(&theirs), "forward values agree");
    let g_ours = ours.sum_all().unwrap().backward().unwrap().get(&x).unwrap().clone();
    let g_theirs = theirs.sum_all().unwrap().backward().unwrap().get(&x).unwrap().clone();
    // Sum of the input gradient = number of windows (one 1 per window) for the true gradient.
    let (s_ours, s_theirs) = (vec(&g_ours).iter().sum::<f64>(), vec(&g_theirs).iter().sum::<f64>());
    assert_eq!(s_ours, 18.0, "one unit of gradient per window (2 channels x 3 x 3)");
    assert!(
        (s_theirs - s_ours / 4.0).abs() < 1e-12,
        "candle's gradient sum {s_theirs} (ours {s_ours}): the gap changed"
    );
}
