//! Tests of the fused CPU kernels behind `nn::group_norm` and `nn::activation::gelu_erf`:
//! values and gradients equal the composed references (`nn::group_norm_composed`,
//! `activation::gelu_erf_composed`) to round-off in `f32` and `f64`, on small shapes and on
//! shapes large enough for the rayon path; and finite-difference gradient checks in `f64`.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::nn::{self, activation};
use pbdl_core::{check_grad, seed, GradCheckOptions};

fn randn(shape: &[usize], mean: f64, std: f64, dtype: DType, s: u64) -> Tensor {
    seed::randn(shape, mean, std, dtype, &Device::Cpu, s).unwrap()
}

fn vec(t: &Tensor) -> Vec<f64> {
    t.flatten_all().unwrap().to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
}

/// `max |a - b| / max(max |b|, 1e-300)`: the difference relative to the reference's scale.
fn rel_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.dims(), b.dims());
    let (a, b) = (vec(a), vec(b));
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max) / scale
}

/// `max_i |a_i - b_i| / max(|b_i|, floor)`: elementwise relative difference.
fn elem_rel_diff(a: &Tensor, b: &Tensor, floor: f64) -> f64 {
    assert_eq!(a.dims(), b.dims());
    vec(a).iter().zip(vec(b)).map(|(x, y)| (x - y).abs() / y.abs().max(floor)).fold(0.0, f64::max)
}

/// How two tensors are compared.
type Metric<'a> = dyn Fn(&Tensor, &Tensor) -> f64 + 'a;

/// Output and the gradients of `sum(f(inputs) * r)` for a seeded cotangent `r`.
fn value_and_grads(f: &dyn Fn(&[Tensor]) -> Tensor, inputs: &[Tensor], r_seed: u64) -> (Tensor, Vec<Tensor>) {
    let vars: Vec<Var> = inputs.iter().map(|t| Var::from_tensor(t).unwrap()).collect();
    let ts: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
    let y = f(&ts);
    let r = randn(y.dims(), 0.0, 1.0, y.dtype(), r_seed);
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let gs = ts.iter().map(|t| grads.get(t).expect("every input gets a gradient").clone()).collect();
    (y, gs)
}

/// Asserts fused == composed for values and every gradient; returns the largest relative
/// difference.
fn compare(
    name: &str,
    fused: &dyn Fn(&[Tensor]) -> Tensor,
    composed: &dyn Fn(&[Tensor]) -> Tensor,
    inputs: &[Tensor],
    tol: f64,
    metric: &Metric<'_>,
) -> f64 {
    let (yf, gf) = value_and_grads(fused, inputs, 99);
    let (yc, gc) = value_and_grads(composed, inputs, 99);
    let mut worst = metric(&yf, &yc);
    assert!(worst <= tol, "{name}: values differ by {worst:e} (relative)");
    for (i, (a, b)) in gf.iter().zip(&gc).enumerate() {
        let d = metric(a, b);
        assert!(d <= tol, "{name}: gradient of input {i} differs by {d:e} (relative)");
        worst = worst.max(d);
    }
    worst
}

/// (shape, groups) cases: tiny, odd sizes, instance norm, and U-Net-like sizes above the
/// rayon threshold (32768 elements).
const GN_CASES: [(&[usize], usize); 7] = [
    (&[2, 6, 3, 2], 1),
    (&[2, 6, 3, 2], 3),
    (&[2, 6, 3, 2], 6),
    (&[3, 4, 5], 2),
    (&[1, 5, 7, 3], 5),
    (&[4, 16, 32, 16], 1),
    (&[3, 32, 16, 8], 4),
];

/// Runs `f` in a private two-thread rayon pool, so that the kernels take their parallel path
/// on the large cases whatever `RAYON_NUM_THREADS` says (they run serially on one thread).
fn with_two_threads(f: impl FnOnce() + Send) {
    rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(f)
}

#[test]
fn fused_group_norm_equals_composed_values_and_gradients() {
    with_two_threads(group_norm_equivalence);
    // And serially (the large cases too).
    rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(group_norm_equivalence);
}

fn group_norm_equivalence() {
    for dtype in [DType::F64, DType::F32] {
        // Relative to the scale of each output; f32 sums differ by the accumulation order.
        let tol = if dtype == DType::F64 { 1e-12 } else { 2e-5 };
        let mut worst = 0.0f64;
        for (k, &(shape, groups)) in GN_CASES.iter().enumerate() {
            let s = 10 * k as u64;
            let x = randn(shape, 0.7, 2.0, dtype, s);
            let w = randn(&[shape[1]], 1.0, 0.5, dtype, s + 1);
            let b = randn(&[shape[1]], 0.0, 0.5, dtype, s + 2);
            let fused = |xs: &[Tensor]| nn::group_norm(&xs[0], groups, Some(&xs[1]), Some(&xs[2]), 1e-5).unwrap();
            let composed =
                |xs: &[Tensor]| nn::group_norm_composed(&xs[0], groups, Some(&xs[1]), Some(&xs[2]), 1e-5).unwrap();
            let name = format!("{dtype:?} {shape:?} groups {groups}");
            worst = worst.max(compare(&name, &fused, &composed, &[x.clone(), w.clone(), b.clone()], tol, &rel_diff));
            // Without affine parameters, and with only one of them.
            let plain = |xs: &[Tensor]| nn::group_norm(&xs[0], groups, None, None, 1e-5).unwrap();
            let plain_c = |xs: &[Tensor]| nn::group_norm_composed(&xs[0], groups, None, None, 1e-5).unwrap();
            worst = worst.max(compare(
                &format!("{name} plain"),
                &plain,
                &plain_c,
                std::slice::from_ref(&x),
                tol,
                &rel_diff,
            ));
            let wonly = |xs: &[Tensor]| nn::group_norm(&xs[0], groups, Some(&xs[1]), None, 1e-5).unwrap();
            let wonly_c = |xs: &[Tensor]| nn::group_norm_composed(&xs[0], groups, Some(&xs[1]), None, 1e-5).unwrap();
            worst =
                worst.max(compare(&format!("{name} weight only"), &wonly, &wonly_c, &[x.clone(), w], tol, &rel_diff));
            let bonly = |xs: &[Tensor]| nn::group_norm(&xs[0], groups, None, Some(&xs[1]), 1e-5).unwrap();
            let bonly_c = |xs: &[Tensor]| nn::group_norm_composed(&xs[0], groups, None, Some(&xs[1]), 1e-5).unwrap();
            worst = worst.max(compare(&format!("{name} bias only"), &bonly, &bonly_c, &[x, b], tol, &rel_diff));
        }
        println!("group_norm {dtype:?}: max relative difference fused vs composed {worst:.2e}");
    }
}

#[test]
fn fused_group_norm_handles_offset_mean_and_strided_input() {
    // A large mean relative to the spread: the kernel centres before it scales.
    for dtype in [DType::F64, DType::F32] {
        let tol = if dtype == DType::F64 { 1e-11 } else { 1e-3 };
        let x = randn(&[2, 4, 6, 5], 300.0, 0.5, dtype, 70);
        let f = |xs: &[Tensor]| nn::group_norm(&xs[0], 2, None, None, 1e-5).unwrap();
        let c = |xs: &[Tensor]| nn::group_norm_composed(&xs[0], 2, None, None, 1e-5).unwrap();
        compare(&format!("{dtype:?} offset mean"), &f, &c, &[x], tol, &rel_diff);
    }
    // A transposed (non-contiguous) view: the spatial axes swapped.
    let base = randn(&[2, 6, 5, 4], 0.0, 1.0, DType::F64, 71);
    let view = base.transpose(2, 3).unwrap();
    assert!(!view.is_contiguous());
    let w = randn(&[6], 1.0, 0.5, DType::F64, 72);
    let b = randn(&[6], 0.0, 0.5, DType::F64, 73);
    let fused = nn::group_norm(&view, 3, Some(&w), Some(&b), 1e-5).unwrap();
    let composed = nn::group_norm_composed(&view.contiguous().unwrap(), 3, Some(&w), Some(&b), 1e-5).unwrap();
    assert!(rel_diff(&fused, &composed) < 1e-13);
}

#[test]
fn fused_group_norm_gradient_check_in_x_weight_and_bias() {
    with_two_threads(group_norm_gradient_checks);
}

fn group_norm_gradient_checks() {
    for (k, &(shape, groups)) in GN_CASES.iter().enumerate() {
        // Round-off in the loss (a sum over all outputs) grows with the size: a wider step
        // for the large cases keeps the finite differences meaningful.
        let big = shape.iter().product::<usize>() > 4096;
        let opts = GradCheckOptions { eps: if big { 1e-4 } else { 1e-6 }, ..Default::default() };
        let s = 100 + 10 * k as u64;
        let x = randn(shape, 0.3, 1.5, DType::F64, s);
        let w = randn(&[shape[1]], 1.0, 0.4, DType::F64, s + 1);
        let b = randn(&[shape[1]], 0.0, 0.4, DType::F64, s + 2);
        let r = check_grad(
            |xs| Ok(nn::group_norm(&xs[0], groups, Some(&xs[1]), Some(&xs[2]), 1e-5)?),
            &[x.clone(), w, b],
            &opts,
        )
        .unwrap();
        assert!(r.max_rel_error < 1e-6, "{shape:?} groups {groups}: {r:?}");
        let r = check_grad(|xs| Ok(nn::group_norm(&xs[0], groups, None, None, 0.0)?), &[x], &opts).unwrap();
        assert!(r.max_rel_error < 1e-6, "{shape:?} groups {groups}, no affine, eps 0: {r:?}");
    }
}

/// The fused group norm's statistics: each (sample, group) has mean `bias`-free 0 and
/// variance `var / (var + eps)` (checked directly, not against the composed version).
#[test]
fn fused_group_norm_standardises_each_group() {
    let (n, c, h, w, g) = (3, 8, 9, 7, 2);
    let x = randn(&[n, c, h, w], -2.0, 3.0, DType::F64, 80);
    let y = vec(&nn::group_norm(&x, g, None, None, 1e-5).unwrap());
    let xv = vec(&x);
    let per = c / g * h * w;
    for k in 0..n * g {
        let chunk = &xv[k * per..(k + 1) * per];
        let mean = chunk.iter().sum::<f64>() / per as f64;
        let var = chunk.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / per as f64;
        let ys = &y[k * per..(k + 1) * per];
        let ym = ys.iter().sum::<f64>() / per as f64;
        let yv = ys.iter().map(|v| (v - ym).powi(2)).sum::<f64>() / per as f64;
        assert!(ym.abs() < 1e-13, "group {k}: mean {ym:e}");
        assert!((yv - var / (var + 1e-5)).abs() < 1e-12, "group {k}: variance {yv}");
    }
}

#[test]
fn half_precision_group_norm_and_gelu_still_work() {
    let x = randn(&[2, 4, 3, 3], 0.5, 1.0, DType::F32, 90);
    let h = x.to_dtype(DType::F16).unwrap();
    let y = nn::group_norm(&h, 2, None, None, 1e-5).unwrap();
    assert_eq!(y.dtype(), DType::F16);
    assert!(rel_diff(&y, &nn::group_norm(&x, 2, None, None, 1e-5).unwrap()) < 5e-3);
    let g = activation::gelu_erf(&h).unwrap();
    assert_eq!(g.dtype(), DType::F16);
    assert!(rel_diff(&g, &activation::gelu_erf(&x).unwrap()) < 5e-3);
}

/// Inputs for GELU: normals of width 3 plus the far tails and zero.
fn gelu_input(shape: &[usize], dtype: DType, s: u64) -> Tensor {
    let mut v = vec(&randn(shape, 0.0, 3.0, DType::F64, s));
    let extremes = [0.0, -0.0, 1e-20, -1e-20, 8.0, -8.0, 40.0, -40.0, 1e4, -1e4];
    for (i, e) in extremes.iter().enumerate() {
        v[i] = *e;
    }
    Tensor::from_vec(v, shape, &Device::Cpu).unwrap().to_dtype(dtype).unwrap()
}

#[test]
fn fused_gelu_erf_equals_composed_values_and_gradients() {
    with_two_threads(gelu_equivalence);
    rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(gelu_equivalence);
}

fn gelu_equivalence() {
    for dtype in [DType::F64, DType::F32] {
        // Elementwise, relative to max(|reference|, floor): the gradient crosses zero near
        // x = -0.75 as the difference of two O(0.2) terms. The composed version scales by
        // 1 / SQRT_2 = 0.7071067811865475, one ulp below 1/sqrt(2); in the left tail the value
        // magnifies that by ~x^2 (1e-14 relative at x = -10).
        let (tol, floor) = if dtype == DType::F64 { (1e-12, 1e-3) } else { (1e-6, 1.0) };
        let mut worst = 0.0f64;
        // Small (serial) and above two rayon chunks (65536 elements).
        for (k, shape) in [&[4usize, 10][..], &[3, 5, 7], &[16, 16, 24, 16]].into_iter().enumerate() {
            let x = gelu_input(shape, dtype, 200 + k as u64);
            let f = |xs: &[Tensor]| activation::gelu_erf(&xs[0]).unwrap();
            let c = |xs: &[Tensor]| activation::gelu_erf_composed(&xs[0]).unwrap();
            let m = |a: &Tensor, b: &Tensor| elem_rel_diff(a, b, floor);
            worst = worst.max(compare(&format!("gelu_erf {dtype:?} {shape:?}"), &f, &c, &[x], tol, &m));
        }
        println!("gelu_erf {dtype:?}: max relative difference fused vs composed {worst:.2e}");
    }
    // Element by element in f64: the gradient to 1e-13 relative, also in the tails.
    let x = gelu_input(&[400], DType::F64, 210);
    let (_, gf) = value_and_grads(&|xs| activation::gelu_erf(&xs[0]).unwrap(), std::slice::from_ref(&x), 5);
    let (_, gc) = value_and_grads(&|xs| activation::gelu_erf_composed(&xs[0]).unwrap(), std::slice::from_ref(&x), 5);
    let xs = vec(&x);
    for ((a, b), x) in vec(&gf[0]).iter().zip(vec(&gc[0])).zip(xs) {
        // Away from the zero of the derivative (x = -0.7518), relative; near it, absolute.
        let tol = if (x + 0.7518).abs() > 0.05 { 1e-13 * b.abs() } else { 1e-16 };
        assert!((a - b).abs() <= tol + 1e-300, "x = {x}: {a} vs {b}");
    }
}

#[test]
fn fused_gelu_erf_gradient_check_and_exact_values() {
    let x = gelu_input(&[6, 8], DType::F64, 220);
    // Skip the 1e4 entries: central differences there cancel nothing but test nothing either.
    let x = x.clamp(-9.0, 9.0).unwrap();
    let r = check_grad(|xs| Ok(activation::gelu_erf(&xs[0])?), &[x], &GradCheckOptions::default()).unwrap();
    assert!(r.max_rel_error < 1e-8, "{r:?}");
    // Values at points with known normal CDF: Phi(1) = 0.8413447460685429,
    // Phi(-2) = 0.022750131948179195; and the derivative Phi(x) + x phi(x) at x = 1.
    let x = Var::new(&[1.0f64, -2.0], &Device::Cpu).unwrap();
    let y = activation::gelu_erf(x.as_tensor()).unwrap();
    let yv = y.to_vec1::<f64>().unwrap();
    assert!((yv[0] - 0.8413447460685429).abs() < 1e-15, "{}", yv[0]);
    assert!((yv[1] + 2.0 * 0.022750131948179195).abs() < 1e-16, "{}", yv[1]);
    let g = y.sum_all().unwrap().backward().unwrap();
    let gv = g.get(x.as_tensor()).unwrap().to_vec1::<f64>().unwrap();
    let phi1 = (-0.5f64).exp() / (2.0 * std::f64::consts::PI).sqrt();
    assert!((gv[0] - (0.8413447460685429 + phi1)).abs() < 1e-15, "{}", gv[0]);
}

/// The fused leaky ReLU gives the composed version's values (up to the sign of zero) and
/// gradients exactly (f32 and f64, with exact zeros in the input where the gradient is the mean slope, small and above two
/// rayon chunks), and passes a finite-difference check away from the kink.
#[test]
fn fused_leaky_relu_equals_composed_and_passes_fd() {
    for dtype in [DType::F64, DType::F32] {
        for (k, shape) in [&[4usize, 10][..], &[16, 16, 24, 16]].into_iter().enumerate() {
            let x = randn(shape, 0.0, 1.0, dtype, 300 + k as u64);
            // Every 7th element exactly 0 (the kink).
            let n = x.elem_count();
            let mask: Vec<f64> = (0..n).map(|i| if i % 7 == 0 { 0.0 } else { 1.0 }).collect();
            let mask = Tensor::from_vec(mask, shape, &Device::Cpu).unwrap().to_dtype(dtype).unwrap();
            let x = (x * mask).unwrap();
            for slope in [0.3, 0.01] {
                let (yf, gf) =
                    value_and_grads(&|xs| activation::leaky_relu(&xs[0], slope).unwrap(), std::slice::from_ref(&x), 7);
                let (yc, gc) = nn::with_composed(|| {
                    value_and_grads(
                        &|xs| activation::leaky_relu_composed(&xs[0], slope).unwrap(),
                        std::slice::from_ref(&x),
                        7,
                    )
                });
                let xs = vec(&x);
                for (name, a, b) in [("value", vec(&yf), vec(&yc)), ("gradient", vec(&gf[0]), vec(&gc[0]))] {
                    let bad = a.iter().zip(&b).position(|(p, q)| p != q);
                    if let Some(i) = bad {
                        panic!(
                            "{name} {dtype:?} {shape:?} slope {slope}: x = {} fused {} composed {}",
                            xs[i], a[i], b[i]
                        );
                    }
                }
            }
        }
    }
    // Finite differences in f64, inputs kept away from 0.
    let x = randn(&[5, 6], 0.0, 1.0, DType::F64, 320);
    let x = (x.sign().unwrap() * (x.abs().unwrap() + 0.1).unwrap()).unwrap();
    let leaky = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        activation::leaky_relu(&xs[0], 0.3).map_err(|e| candle_core::Error::Msg(e.to_string()))
    };
    let report = check_grad(leaky, &[x], &GradCheckOptions::default()).unwrap();
    assert!(report.max_rel_error < pbdl_core::tolerance::GRAD_CHECK_F64, "{report:?}");
}

/// The fused ReLU gives candle's `relu` values and gradients (gradient 1 at exactly 0), f32 and
/// f64, small and above two rayon chunks, and passes a finite-difference check.
#[test]
fn fused_relu_equals_candles() {
    for dtype in [DType::F64, DType::F32] {
        for (k, shape) in [&[4usize, 10][..], &[16, 16, 24, 16]].into_iter().enumerate() {
            let x = randn(shape, 0.0, 1.0, dtype, 330 + k as u64);
            let n = x.elem_count();
            let mask: Vec<f64> = (0..n).map(|i| if i % 5 == 0 { 0.0 } else { 1.0 }).collect();
            let x = (x * Tensor::from_vec(mask, shape, &Device::Cpu).unwrap().to_dtype(dtype).unwrap()).unwrap();
            let (yf, gf) = value_and_grads(&|xs| activation::relu(&xs[0]).unwrap(), std::slice::from_ref(&x), 8);
            let (yc, gc) = value_and_grads(&|xs| xs[0].relu().unwrap(), std::slice::from_ref(&x), 8);
            assert_eq!(vec(&yf), vec(&yc), "values {dtype:?} {shape:?}");
            assert_eq!(vec(&gf[0]), vec(&gc[0]), "gradients {dtype:?} {shape:?}");
        }
    }
    // Finite differences in f64, inputs kept away from 0.
    let x = randn(&[5, 6], 0.0, 1.0, DType::F64, 340);
    let x = (x.sign().unwrap() * (x.abs().unwrap() + 0.1).unwrap()).unwrap();
    let relu = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        activation::relu(&xs[0]).map_err(|e| candle_core::Error::Msg(e.to_string()))
    };
    let report = check_grad(relu, &[x], &GradCheckOptions::default()).unwrap();
    assert!(report.max_rel_error < pbdl_core::tolerance::GRAD_CHECK_F64, "{report:?}");
}

/// Group norm with a ReLU / LeakyReLU epilogue: the same values as the group norm followed by
/// the fused activation op (bit for bit in f32), gradients to round-off, and a
/// finite-difference check in f64, with and without the affine parameters.
#[test]
fn fused_group_norm_activation_equals_separate_ops_and_passes_fd() {
    use nn::Activation;
    let acts = [Activation::Relu, Activation::LeakyRelu { negative_slope: 0.2 }];
    for act in acts {
        for affine in [false, true] {
            let x = randn(&[3, 6, 5, 7], 0.3, 1.5, DType::F32, 40);
            let w = randn(&[6], 1.0, 0.3, DType::F32, 41);
            let b = randn(&[6], 0.0, 0.3, DType::F32, 42);
            let f = |fused: bool| {
                move |t: &[Tensor]| {
                    let (w, b) = if affine { (Some(&t[1]), Some(&t[2])) } else { (None, None) };
                    if fused {
                        nn::group_norm_act(&t[0], 2, w, b, 1e-5, act).unwrap()
                    } else {
                        act.apply(&nn::group_norm(&t[0], 2, w, b, 1e-5).unwrap()).unwrap()
                    }
                }
            };
            let used = if affine { 3 } else { 1 };
            let inputs = [x, w, b];
            let (yf, gf) = value_and_grads(&f(true), &inputs[..used], 43);
            let (yu, gu) = value_and_grads(&f(false), &inputs[..used], 43);
            assert_eq!(vec(&yf), vec(&yu), "{act:?} affine {affine}: values");
            for (i, (a, b)) in gf.iter().zip(&gu).enumerate() {
                let e = rel_diff(a, b);
                assert!(e < 1e-5, "{act:?} affine {affine}: gradient {i} differs by {e:.2e}");
            }
            let inputs64: Vec<Tensor> = inputs[..used].iter().map(|t| t.to_dtype(DType::F64).unwrap()).collect();
            let g = move |t: &[Tensor]| {
                let (w, b) = if affine { (Some(&t[1]), Some(&t[2])) } else { (None, None) };
                Ok(nn::group_norm_act(&t[0], 2, w, b, 1e-5, act)?)
            };
            let r = check_grad(g, &inputs64, &GradCheckOptions { max_probes: 30, ..Default::default() }).unwrap();
            assert!(r.max_rel_error < 1e-6, "{act:?} affine {affine}: {r:?}");
        }
    }
}
