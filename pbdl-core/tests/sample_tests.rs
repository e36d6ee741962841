//! Tests of `pbdl_core::sample`: accuracy of interpolation against analytic fields, boundaries,
//! gradients against finite differences, resize against scipy/PyTorch reference numbers, and
//! typed errors on bad input.

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::sample::{grid_sample, index_grid, resize2d, resize3d, warp, Boundary, Resize};
use pbdl_core::{check_grad, Error, GradCheckOptions};
use std::f64::consts::PI;

// Tolerance of the finite-difference checks (f64, central differences, eps = 1e-6).
use pbdl_core::tolerance::GRAD_CHECK_F64 as GRAD_TOL;

fn cpu() -> Device {
    Device::Cpu
}

fn tensor(data: Vec<f64>, shape: &[usize]) -> Tensor {
    Tensor::from_vec(data, shape, &cpu()).unwrap()
}

fn values(t: &Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap()
}

/// `[1.234e-3, ...]`, for messages.
fn sci(v: &[f64]) -> String {
    format!("[{}]", v.iter().map(|x| format!("{x:.3e}")).collect::<Vec<_>>().join(", "))
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// A deterministic pseudo-random number in [0, 1) (a hash of `i`), so tests need no RNG state.
fn unit(i: usize) -> f64 {
    let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// A field [batch, channel, spatial...] with `f(b, c, coords)` at each sample; `spatial` is in
/// the tensor's axis order and `f` receives coordinates x first.
fn field(batch: usize, channels: usize, spatial: &[usize], f: impl Fn(usize, usize, &[f64]) -> f64) -> Tensor {
    let vol: usize = spatial.iter().product();
    let mut data = Vec::with_capacity(batch * channels * vol);
    for b in 0..batch {
        for c in 0..channels {
            for flat in 0..vol {
                let mut rest = flat;
                let mut coords = vec![0.0; spatial.len()];
                for (d, &n) in spatial.iter().rev().enumerate() {
                    coords[d] = (rest % n) as f64;
                    rest /= n;
                }
                data.push(f(b, c, &coords));
            }
        }
    }
    let mut shape = vec![batch, channels];
    shape.extend_from_slice(spatial);
    tensor(data, &shape)
}

/// Points [batch, count, D] from `p(b, i) -> coordinates`.
fn points(batch: usize, count: usize, dims: usize, p: impl Fn(usize, usize) -> Vec<f64>) -> Tensor {
    let mut data = Vec::new();
    for b in 0..batch {
        for i in 0..count {
            let q = p(b, i);
            assert_eq!(q.len(), dims);
            data.extend(q);
        }
    }
    tensor(data, &[batch, count, dims])
}

/// A coordinate with integer part in `lo..hi` and fractional part in [0.15, 0.85]: at least 0.15
/// from every integer, where the interpolant has kinks (finite differences must not straddle one).
fn off_grid(i: usize, lo: i64, hi: i64) -> f64 {
    let whole = lo + ((unit(i) * (hi - lo) as f64) as i64).min(hi - lo - 1);
    whole as f64 + 0.15 + 0.7 * unit(i + 7919)
}

// ---------------------------------------------------------------------------------------------
// Forward accuracy

#[test]
fn bilinear_sampling_of_a_linear_function_is_exact() {
    let (ny, nx) = (7, 9);
    let lin = |b: usize, c: usize, x: f64, y: f64| 0.5 + b as f64 - c as f64 + 2.0 * x - 3.0 * y;
    let f = field(2, 3, &[ny, nx], |b, c, q| lin(b, c, q[0], q[1]));
    let p =
        points(2, 40, 2, |b, i| vec![unit(i + 100 * b) * (nx - 1) as f64, unit(i + 100 * b + 50) * (ny - 1) as f64]);
    for boundary in [Boundary::Clamp, Boundary::Periodic] {
        let y = values(&grid_sample(&f, &p, boundary).unwrap());
        let pv = values(&p);
        let mut expect = Vec::new();
        for b in 0..2 {
            for c in 0..3 {
                for i in 0..40 {
                    expect.push(lin(b, c, pv[(b * 40 + i) * 2], pv[(b * 40 + i) * 2 + 1]));
                }
            }
        }
        let err = max_abs_diff(&y, &expect);
        assert!(err < 1e-12, "{boundary:?}: max error {err:e}");
    }
}

#[test]
fn trilinear_sampling_of_a_linear_function_is_exact() {
    let (nz, ny, nx) = (4, 5, 6);
    let lin = |c: usize, q: &[f64]| 1.0 + c as f64 + 0.5 * q[0] - 2.0 * q[1] + 3.0 * q[2];
    let f = field(1, 2, &[nz, ny, nx], |_, c, q| lin(c, q));
    let p = points(1, 30, 3, |_, i| vec![unit(i) * 5.0, unit(i + 31) * 4.0, unit(i + 62) * 3.0]);
    let y = values(&grid_sample(&f, &p, Boundary::Clamp).unwrap());
    let pv = values(&p);
    let expect: Vec<f64> =
        (0..2).flat_map(|c| (0..30).map(move |i| (c, i))).map(|(c, i)| lin(c, &pv[i * 3..i * 3 + 3])).collect();
    let err = max_abs_diff(&y, &expect);
    assert!(err < 1e-12, "max error {err:e}");
}

#[test]
fn clamp_replicates_the_border_value_outside() {
    // f(x, y) = x + 10 y on a 3x4 grid.
    let f = field(1, 1, &[3, 4], |_, _, q| q[0] + 10.0 * q[1]);
    let p = tensor(vec![-2.0, 1.5, 9.0, 0.25, 2.5, -7.0, 50.0, 50.0, -1.0, -1.0], &[1, 5, 2]);
    let y = values(&grid_sample(&f, &p, Boundary::Clamp).unwrap());
    assert_eq!(y, [15.0, 5.5, 2.5, 23.0, 0.0]);
}

#[test]
fn periodic_boundary_wraps_in_every_direction() {
    let (ny, nx) = (3, 4);
    let f = field(1, 1, &[ny, nx], |_, _, q| q[0] * q[0] + 10.0 * q[1]);
    let at = |x: usize, y: usize| (x * x) as f64 + 10.0 * y as f64;
    let p = tensor(
        vec![
            -0.5,
            1.0, // halfway between the last and the first column
            3.5,
            1.0, // the same point one period on
            1.25 + 4.0,
            2.0 - 6.0, // one period in x, two in y back
            1.25,
            2.0, // its image inside
            0.0,
            -0.5, // halfway between the last and the first row
        ],
        &[1, 5, 2],
    );
    let y = values(&grid_sample(&f, &p, Boundary::Periodic).unwrap());
    let expect = [
        0.5 * (at(3, 1) + at(0, 1)),
        0.5 * (at(3, 1) + at(0, 1)),
        0.75 * at(1, 2) + 0.25 * at(2, 2),
        0.75 * at(1, 2) + 0.25 * at(2, 2),
        0.5 * (at(0, 2) + at(0, 0)),
    ];
    let err = max_abs_diff(&y, &expect);
    assert!(err < 1e-12, "{y:?} vs {expect:?}");
}

#[test]
fn per_axis_boundary_is_periodic_in_x_and_clamped_in_y() {
    let f = field(1, 1, &[3, 4], |_, _, q| q[0] + 10.0 * q[1]);
    let p = tensor(vec![-0.5, -3.0, 4.25, 7.0], &[1, 2, 2]);
    let y = values(&grid_sample(&f, &p, [Boundary::Periodic, Boundary::Clamp]).unwrap());
    assert_eq!(y, [1.5, 20.25]);
    // And the other way round: clamped in x, periodic in y.
    let y = values(&grid_sample(&f, &p, [Boundary::Clamp, Boundary::Periodic]).unwrap());
    assert_eq!(y, [0.0, 13.0]);
}

/// Max error of warping `sin(2 pi x) cos(2 pi y)` (periodic on the unit square, `n^2` samples at
/// `i / n`) by a constant displacement of `(0.3, 0.6)` cells against the exact shifted field.
fn warp_error_2d(n: usize) -> f64 {
    let h = 1.0 / n as f64;
    let exact = |x: f64, y: f64| (2.0 * PI * x).sin() * (2.0 * PI * y).cos();
    let f = field(1, 1, &[n, n], |_, _, q| exact(q[0] * h, q[1] * h));
    let mut disp = vec![0.3; n * n];
    disp.extend(vec![0.6; n * n]);
    let y = values(&warp(&f, &tensor(disp, &[1, 2, n, n]), Boundary::Periodic).unwrap());
    let expect = values(&field(1, 1, &[n, n], |_, _, q| exact((q[0] + 0.3) * h, (q[1] + 0.6) * h)));
    max_abs_diff(&y, &expect)
}

#[test]
fn smooth_field_is_sampled_with_second_order_error_2d() {
    let errors: Vec<f64> = [16, 32, 64, 128].into_iter().map(warp_error_2d).collect();
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    println!("2D warp errors {}, observed orders {orders:.3?}", sci(&errors));
    assert!(orders.iter().all(|&o| o >= 1.8), "errors {errors:?}, orders {orders:?}");
}

#[test]
fn smooth_field_is_sampled_with_second_order_error_3d() {
    let run = |n: usize| {
        let h = 1.0 / n as f64;
        let exact = |q: &[f64]| (2.0 * PI * q[0]).sin() * (2.0 * PI * q[1]).cos() * (2.0 * PI * q[2]).sin();
        let f = field(1, 1, &[n, n, n], |_, _, q| exact(&[q[0] * h, q[1] * h, q[2] * h]));
        let shift = [0.3, -0.45, 0.7];
        let disp: Vec<f64> = shift.iter().flat_map(|&s| vec![s; n * n * n]).collect();
        let y = values(&warp(&f, &tensor(disp, &[1, 3, n, n, n]), Boundary::Periodic).unwrap());
        let expect =
            values(&field(1, 1, &[n, n, n], |_, _, q| exact(&[(q[0] + 0.3) * h, (q[1] - 0.45) * h, (q[2] + 0.7) * h])));
        max_abs_diff(&y, &expect)
    };
    let errors: Vec<f64> = [16, 32, 64].into_iter().map(run).collect();
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    println!("3D warp errors {}, observed orders {orders:.3?}", sci(&errors));
    assert!(orders.iter().all(|&o| o >= 1.8), "errors {errors:?}, orders {orders:?}");
}

#[test]
fn clamped_sampling_at_scattered_points_converges_at_second_order() {
    // Non-periodic f = exp(x) sin(3 y) on [0, 1]^2 with n samples per axis (spacing 1/(n-1)),
    // sampled at the same 500 scattered physical points at every resolution.
    let exact = |x: f64, y: f64| x.exp() * (3.0 * y).sin();
    let run = |n: usize| {
        let h = 1.0 / (n - 1) as f64;
        let f = field(1, 1, &[n, n], |_, _, q| exact(q[0] * h, q[1] * h));
        let phys: Vec<(f64, f64)> = (0..500).map(|i| (unit(i), unit(i + 1000))).collect();
        let p = points(1, 500, 2, |_, i| vec![phys[i].0 / h, phys[i].1 / h]);
        let y = values(&grid_sample(&f, &p, Boundary::Clamp).unwrap());
        let expect: Vec<f64> = phys.iter().map(|&(x, y)| exact(x, y)).collect();
        max_abs_diff(&y, &expect)
    };
    let errors: Vec<f64> = [17, 33, 65, 129].into_iter().map(run).collect();
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    println!("scattered clamped errors {}, observed orders {orders:.3?}", sci(&errors));
    assert!(orders.iter().all(|&o| o >= 1.8), "errors {errors:?}, orders {orders:?}");
}

#[test]
fn output_has_the_points_middle_axes() {
    let f = Tensor::ones((2, 3, 5, 6), DType::F32, &cpu()).unwrap();
    let p = Tensor::zeros((2, 4, 7, 2), DType::F32, &cpu()).unwrap();
    assert_eq!(grid_sample(&f, &p, Boundary::Clamp).unwrap().dims(), &[2, 3, 4, 7]);
    let p = Tensor::zeros((2, 2), DType::F32, &cpu()).unwrap();
    assert_eq!(grid_sample(&f, &p, Boundary::Clamp).unwrap().dims(), &[2, 3]);
}

#[test]
fn f32_agrees_with_f64_forward_and_backward() {
    let f64_field = field(2, 2, &[9, 11], |b, c, q| (0.3 * q[0] + b as f64).sin() * (0.2 * q[1] - c as f64).cos());
    let f64_points = points(2, 64, 2, |b, i| vec![off_grid(i + b * 64, -2, 12), off_grid(i + b * 64 + 500, -2, 10)]);
    let run = |dtype: DType| {
        let fv = Var::from_tensor(&f64_field.to_dtype(dtype).unwrap()).unwrap();
        let pv = Var::from_tensor(&f64_points.to_dtype(dtype).unwrap()).unwrap();
        let y = grid_sample(fv.as_tensor(), pv.as_tensor(), Boundary::Clamp).unwrap();
        let grads = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        (values(&y), values(grads.get(fv.as_tensor()).unwrap()), values(grads.get(pv.as_tensor()).unwrap()))
    };
    let (a, b) = (run(DType::F32), run(DType::F64));
    assert!(max_abs_diff(&a.0, &b.0) < 1e-5);
    assert!(max_abs_diff(&a.1, &b.1) < 1e-5);
    assert!(max_abs_diff(&a.2, &b.2) < 1e-5);
}

// ---------------------------------------------------------------------------------------------
// Gradients

fn check(f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>, inputs: &[Tensor]) -> f64 {
    let opts = GradCheckOptions { max_probes: 64, ..Default::default() };
    let r = check_grad(f, inputs, &opts).unwrap();
    r.ensure(GRAD_TOL).unwrap_or_else(|e| panic!("{e}"));
    r.max_rel_error
}

fn sample_fn(boundary: Boundary) -> impl Fn(&[Tensor]) -> candle_core::Result<Tensor> {
    move |xs| grid_sample(&xs[0], &xs[1], boundary).map_err(candle_core::Error::wrap)
}

#[test]
fn gradients_2d_match_finite_differences() {
    let f = field(2, 2, &[5, 6], |b, c, q| (0.7 * q[0] - 0.4 * q[1] + b as f64 + 2.0 * c as f64).sin());
    // Clamp: points also outside the grid (zero coordinate gradient there); periodic: far out.
    let clamp_pts = tensor(
        (0..2 * 12 * 2).map(|i| if i % 2 == 0 { off_grid(i, -2, 7) } else { off_grid(i, -2, 6) }).collect(),
        &[2, 3, 4, 2],
    );
    let per_pts = tensor((0..2 * 12 * 2).map(|i| off_grid(i, -9, 14)).collect(), &[2, 3, 4, 2]);
    let e1 = check(sample_fn(Boundary::Clamp), &[f.clone(), clamp_pts]);
    let e2 = check(sample_fn(Boundary::Periodic), &[f, per_pts]);
    println!("2D grad check: clamp {e1:.2e}, periodic {e2:.2e}");
}

#[test]
fn gradients_3d_match_finite_differences() {
    let f = field(2, 2, &[3, 4, 5], |b, c, q| (0.7 * q[0] - 0.4 * q[1] + 0.9 * q[2] + b as f64 + c as f64).cos());
    let clamp_pts = tensor((0..2 * 10 * 3).map(|i| off_grid(i, -2, 6)).collect(), &[2, 10, 3]);
    let per_pts = tensor((0..2 * 10 * 3).map(|i| off_grid(i, -7, 12)).collect(), &[2, 10, 3]);
    let e1 = check(sample_fn(Boundary::Clamp), &[f.clone(), clamp_pts]);
    let e2 = check(sample_fn(Boundary::Periodic), &[f, per_pts]);
    println!("3D grad check: clamp {e1:.2e}, periodic {e2:.2e}");
}

#[test]
fn gradients_with_mixed_boundaries_match_finite_differences() {
    let f = field(1, 3, &[4, 5], |_, c, q| (q[0] * q[1] * 0.3 + c as f64).sin());
    let pts = tensor((0..2 * 20).map(|i| off_grid(i, -3, 8)).collect(), &[1, 20, 2]);
    let e = check(
        |xs| grid_sample(&xs[0], &xs[1], [Boundary::Periodic, Boundary::Clamp]).map_err(candle_core::Error::wrap),
        &[f, pts],
    );
    println!("mixed-boundary grad check {e:.2e}");
}

#[test]
fn coordinate_gradient_is_zero_outside_a_clamped_grid() {
    let f = field(1, 1, &[4, 4], |_, _, q| q[0] * q[0] + q[1]);
    let p = Var::new(&[[[-1.5f64, 1.5], [1.5, 5.2], [1.5, 1.5]]], &cpu()).unwrap();
    let y = grid_sample(&f, p.as_tensor(), Boundary::Clamp).unwrap();
    let grads = y.sum_all().unwrap().backward().unwrap();
    let g = values(grads.get(p.as_tensor()).unwrap());
    // Point 0: x outside (dx = 0), y inside (df/dy = 1). Point 1: x inside, y outside. Point 2:
    // inside, df/dx = f(2, .) - f(1, .) = 3 in the cell [1, 2].
    assert_eq!(g, [0.0, 1.0, 3.0, 0.0, 3.0, 1.0]);
    // The constant field tracks no gradient: it gets zeros (and no backward kernel runs for it).
    if let Some(gf) = grads.get(&f) {
        assert!(values(gf).iter().all(|&v| v == 0.0));
    }
}

#[test]
fn warp_gradients_match_finite_differences() {
    let f = field(2, 2, &[5, 6], |b, c, q| (0.5 * q[0] + 0.8 * q[1] + b as f64 - c as f64).sin());
    // Displacements whose targets stay 0.15 away from integers: the grid is integer.
    let disp = tensor((0..2 * 2 * 30).map(|i| off_grid(i, -2, 2)).collect(), &[2, 2, 5, 6]);
    let warp_fn = |b: Boundary| move |xs: &[Tensor]| warp(&xs[0], &xs[1], b).map_err(candle_core::Error::wrap);
    let e1 = check(warp_fn(Boundary::Periodic), &[f.clone(), disp.clone()]);
    let e2 = check(warp_fn(Boundary::Clamp), &[f, disp]);
    let f3 = field(1, 1, &[3, 4, 4], |_, _, q| (q[0] - q[1] + 0.5 * q[2]).cos());
    let d3 = tensor((0..3 * 48).map(|i| off_grid(i, -2, 2)).collect(), &[1, 3, 3, 4, 4]);
    let e3 = check(warp_fn(Boundary::Periodic), &[f3, d3]);
    println!("warp grad check: 2D periodic {e1:.2e}, 2D clamp {e2:.2e}, 3D periodic {e3:.2e}");
}

#[test]
fn warp_equals_grid_sample_at_grid_plus_displacement_with_gradients() {
    // Large enough for many parallel chunks, and (2D, one row) for the split scatter.
    for (spatial, batch, channels) in [(vec![128usize, 96], 1usize, 1usize), (vec![20, 24, 28], 2, 3)] {
        let dims = spatial.len();
        let f = field(batch, channels, &spatial, |b, c, q| (0.3 * q[0] - 0.2 * q[1] + b as f64 + c as f64).sin());
        let vol: usize = spatial.iter().product();
        let mut dshape = vec![batch, dims];
        dshape.extend_from_slice(&spatial);
        let disp = tensor((0..batch * dims * vol).map(|i| 6.0 * unit(i) - 3.0).collect(), &dshape);
        let weights = tensor((0..f.elem_count()).map(|i| unit(i + 99) - 0.5).collect(), f.dims());
        let run = |fused: bool, boundary: Boundary| {
            let (fv, dv) = (Var::from_tensor(&f).unwrap(), Var::from_tensor(&disp).unwrap());
            let y = if fused {
                warp(fv.as_tensor(), dv.as_tensor(), boundary).unwrap()
            } else {
                let grid = index_grid(&spatial, DType::F64, &cpu()).unwrap();
                let mut order: Vec<usize> = vec![0];
                order.extend(2..dims + 2);
                order.push(1);
                let pts = dv.as_tensor().broadcast_add(&grid).unwrap().permute(order).unwrap();
                grid_sample(fv.as_tensor(), &pts, boundary).unwrap()
            };
            let grads = (&y * &weights).unwrap().sum_all().unwrap().backward().unwrap();
            let (gf, gd) = (grads.get(fv.as_tensor()).unwrap(), grads.get(dv.as_tensor()).unwrap());
            (values(&y), values(gf), values(gd))
        };
        for boundary in [Boundary::Clamp, Boundary::Periodic] {
            let (a, b) = (run(true, boundary), run(false, boundary));
            assert!(max_abs_diff(&a.0, &b.0) < 1e-12, "{spatial:?} {boundary:?} values");
            assert!(max_abs_diff(&a.1, &b.1) < 1e-12, "{spatial:?} {boundary:?} field gradient");
            assert!(max_abs_diff(&a.2, &b.2) < 1e-12, "{spatial:?} {boundary:?} displacement gradient");
        }
    }
}

#[test]
fn index_grid_plus_zero_displacement_is_the_identity() {
    let f = field(1, 2, &[3, 4, 5], |_, c, q| q[0] + 7.0 * q[1] - 3.0 * q[2] + c as f64);
    let zero = Tensor::zeros((1, 3, 3, 4, 5), DType::F64, &cpu()).unwrap();
    for b in [Boundary::Clamp, Boundary::Periodic] {
        assert_eq!(values(&warp(&f, &zero, b).unwrap()), values(&f));
    }
    let grid = index_grid(&[3, 4, 5], DType::F64, &cpu()).unwrap();
    let pts = grid.permute((0, 2, 3, 4, 1)).unwrap();
    assert_eq!(values(&grid_sample(&f, &pts, Boundary::Clamp).unwrap()), values(&f));
}

// ---------------------------------------------------------------------------------------------
// Resize

#[test]
fn bilinear_align_corners_resize_of_a_ramp_is_exact() {
    let ramp2 = |q: &[f64]| 1.0 + 2.0 * q[0] - 3.0 * q[1];
    let x = field(1, 2, &[5, 7], |_, c, q| ramp2(q) + c as f64);
    let y = values(&resize2d(&x, (9, 4), Resize::Bilinear { align_corners: true }).unwrap());
    let expect = values(&field(1, 2, &[9, 4], |_, c, q| ramp2(&[q[0] * 6.0 / 3.0, q[1] * 4.0 / 8.0]) + c as f64));
    assert!(max_abs_diff(&y, &expect) < 1e-12);

    let ramp3 = |q: &[f64]| 1.0 + 2.0 * q[0] - 3.0 * q[1] + 0.5 * q[2];
    let x = field(2, 1, &[3, 4, 5], |_, _, q| ramp3(q));
    let y = values(&resize3d(&x, (6, 2, 9), Resize::Bilinear { align_corners: true }).unwrap());
    let expect = values(&field(2, 1, &[6, 2, 9], |_, _, q| ramp3(&[q[0] * 4.0 / 8.0, q[1] * 3.0, q[2] * 2.0 / 5.0])));
    assert!(max_abs_diff(&y, &expect) < 1e-12);
}

#[test]
fn bilinear_half_pixel_resize_matches_pytorch() {
    // torch.nn.functional.interpolate(torch.arange(4.).view(1, 1, 1, 4), size=(1, 8),
    // mode="bilinear", align_corners=False): the source coordinate (o + 0.5) / 2 - 0.5 is clamped
    // at 0 and the last sample repeats.
    let x = tensor(vec![0.0, 1.0, 2.0, 3.0], &[1, 1, 1, 4]);
    let y = values(&resize2d(&x, (1, 8), Resize::Bilinear { align_corners: false }).unwrap());
    assert!(max_abs_diff(&y, &[0.0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.0]) < 1e-12, "{y:?}");
    // Downsampling arange(8) to 3: source coordinates 5/6, 7/2, 37/6.
    let x = tensor((0..8).map(f64::from).collect(), &[1, 1, 1, 8]);
    let y = values(&resize2d(&x, (1, 3), Resize::Bilinear { align_corners: false }).unwrap());
    assert!(max_abs_diff(&y, &[5.0 / 6.0, 3.5, 37.0 / 6.0]) < 1e-12, "{y:?}");
}

#[test]
fn bicubic_resize_matches_pytorch_reference_values() {
    // Expected values from a literal Python port of PyTorch's CPU upsample_bicubic2d (index
    // guard, clamped taps, A = -0.75):
    //   A = -0.75; cc1 = lambda x: ((A+2)*x - (A+3))*x*x + 1
    //   cc2 = lambda x: ((A*x - 5*A)*x + 8*A)*x - 4*A
    //   src = scale*(o+0.5) - 0.5 (align_corners=False, scale = in/out) or o*(in-1)/(out-1)
    //   i = min(floor(src), in-1); t = clamp(src - i, 0, 1)
    //   weights [cc2(t+1), cc1(t), cc1(1-t), cc2(2-t)] on samples clamp(i-1..=i+2, 0, in-1)
    let x = tensor(vec![0.0, 1.0, 2.0, 3.0], &[1, 1, 1, 4]);
    let y = values(&resize2d(&x, (1, 8), Resize::Bicubic { align_corners: false }).unwrap());
    let expect = [-0.10546875, 0.19140625, 0.66796875, 1.296875, 1.703125, 2.33203125, 2.80859375, 3.10546875];
    assert!(max_abs_diff(&y, &expect) < 1e-12, "{y:?}");

    let img = tensor(vec![1., 2., 4., 0., 3., -1., 2., 5., 1.], &[1, 1, 3, 3]);
    let y = values(&resize2d(&img, (4, 5), Resize::Bicubic { align_corners: false }).unwrap());
    #[rustfmt::skip]
    let expect = [
        0.9895585937500003, 1.2290703124999995, 1.92822265625, 3.4774531250000003, 4.592230468749999,
        -0.07818750000000008, 1.1573203124999993, 2.419921875, 1.4592421875, 0.4055937499999997,
        0.30174609375, 2.1955546875, 3.83056640625, 1.2109687499999993, -1.2758945312500003,
        1.8555546875000004, 3.5955546875, 5.1435546875, 2.9115546875, 0.7595546874999991,
    ];
    assert!(max_abs_diff(&y, &expect) < 1e-12, "{y:?}");

    let y = values(&resize2d(&img, (4, 5), Resize::Bicubic { align_corners: true }).unwrap());
    #[rustfmt::skip]
    let expect = [
        1.0, 1.3125, 2.0, 3.09375, 4.0,
        0.0925925925925919, 1.4756944444444435, 2.4629629629629615, 1.6296296296296278, 0.3518518518518494,
        0.5185185185185188, 2.5671296296296306, 3.7407407407407423, 1.709490740740741, -0.9259259259259259,
        2.0, 3.875, 5.0, 3.28125, 1.0,
    ];
    assert!(max_abs_diff(&y, &expect) < 1e-12, "{y:?}");

    let y = values(&resize2d(&img, (2, 2), Resize::Bicubic { align_corners: false }).unwrap());
    assert!(
        max_abs_diff(&y, &[1.00982666015625, 2.70281982421875, 2.355377197265625, 1.433074951171875]) < 1e-12,
        "{y:?}"
    );
}

#[test]
fn nearest_resize_matches_scipy_zoom_order_0() {
    // scipy.ndimage.zoom(np.arange(35.).reshape(5, 7), (4/5, 9/7), order=0) (scipy 1.17).
    let x = tensor((0..35).map(f64::from).collect(), &[1, 1, 5, 7]);
    let y = values(&resize2d(&x, (4, 9), Resize::Nearest).unwrap());
    #[rustfmt::skip]
    let expect = [
        0., 1., 2., 2., 3., 4., 5., 5., 6.,
        7., 8., 9., 9., 10., 11., 12., 12., 13.,
        21., 22., 23., 23., 24., 25., 26., 26., 27.,
        28., 29., 30., 30., 31., 32., 33., 33., 34.,
    ];
    assert_eq!(y, expect);
    // 3 -> 5 samples: coordinates 0, 0.5, 1, 1.5, 2 round half up to 0, 1, 1, 2, 2.
    let x = tensor(vec![10.0, 11.0, 12.0], &[1, 1, 1, 3]);
    assert_eq!(values(&resize2d(&x, (1, 5), Resize::Nearest).unwrap()), [10., 11., 11., 12., 12.]);
    // scipy.ndimage.zoom(np.arange(60.).reshape(3, 4, 5), (5/3, 3/4, 7/5), order=0).
    let x = tensor((0..60).map(f64::from).collect(), &[1, 1, 3, 4, 5]);
    let y = values(&resize3d(&x, (5, 3, 7), Resize::Nearest).unwrap());
    let plane = |p: f64| -> Vec<f64> {
        [0., 1., 1., 2., 3., 3., 4., 10., 11., 11., 12., 13., 13., 14., 15., 16., 16., 17., 18., 18., 19.]
            .iter()
            .map(|v| v + p)
            .collect()
    };
    let expect: Vec<f64> = [0.0, 20.0, 20.0, 40.0, 40.0].into_iter().flat_map(plane).collect();
    assert_eq!(y, expect);
    // Where scipy's last coordinate rounds past the input (8 -> 26: 25 * (7/25) = 7.000000000000001)
    // its mode="constant" writes 0; we read the last sample.
    let x = tensor((1..=8).map(f64::from).collect(), &[1, 1, 1, 8]);
    assert_eq!(values(&resize2d(&x, (1, 26), Resize::Nearest).unwrap())[25], 8.0);
}

#[test]
fn resize_to_the_same_size_is_the_identity() {
    let x = field(2, 3, &[4, 6], |b, c, q| (q[0] * 1.3 + q[1] * 0.7 + b as f64 + c as f64).sin());
    for mode in [Resize::Nearest, Resize::Bilinear { align_corners: false }, Resize::Bicubic { align_corners: false }] {
        assert_eq!(values(&resize2d(&x, (4, 6), mode).unwrap()), values(&x), "{mode:?}");
    }
}

#[test]
fn resize_backward_matches_finite_differences() {
    let x2 = field(2, 2, &[4, 5], |b, c, q| (q[0] * 1.1 - q[1] * 0.6 + b as f64 + 3.0 * c as f64).sin());
    let x3 = field(1, 2, &[3, 4, 3], |_, c, q| (q[0] * 1.1 - q[1] * 0.6 + q[2] + c as f64).cos());
    let modes = [
        Resize::Nearest,
        Resize::Bilinear { align_corners: true },
        Resize::Bilinear { align_corners: false },
        Resize::Bicubic { align_corners: true },
        Resize::Bicubic { align_corners: false },
    ];
    let mut worst = 0.0f64;
    for mode in modes {
        for size in [(7, 3), (2, 9)] {
            worst = worst.max(check(
                |xs| resize2d(&xs[0], size, mode).map_err(candle_core::Error::wrap),
                std::slice::from_ref(&x2),
            ));
        }
        for size in [(5, 2, 4), (2, 7, 3)] {
            worst = worst.max(check(
                |xs| resize3d(&xs[0], size, mode).map_err(candle_core::Error::wrap),
                std::slice::from_ref(&x3),
            ));
        }
    }
    println!("resize grad check: worst relative error {worst:.2e}");
}

#[test]
fn nearest_backward_scatters_onto_the_selected_samples() {
    let x = Var::new(&[[[[1.0f64, 2.0, 3.0]]]], &cpu()).unwrap();
    let y = resize2d(x.as_tensor(), (1, 5), Resize::Nearest).unwrap();
    let g = values(y.sum_all().unwrap().backward().unwrap().get(x.as_tensor()).unwrap());
    assert_eq!(g, [1.0, 2.0, 2.0]);
}

#[test]
fn resize_runs_in_f32() {
    let x = field(1, 1, &[6, 6], |_, _, q| q[0] + q[1]).to_dtype(DType::F32).unwrap();
    let y = resize2d(&x, (11, 11), Resize::Bilinear { align_corners: true }).unwrap();
    assert_eq!(y.dtype(), DType::F32);
    let expect = values(&field(1, 1, &[11, 11], |_, _, q| 0.5 * (q[0] + q[1])));
    assert!(max_abs_diff(&values(&y), &expect) < 1e-5);
}

// ---------------------------------------------------------------------------------------------
// Bad input

#[test]
fn bad_input_gives_typed_errors() {
    let f2 = Tensor::zeros((2, 1, 4, 4), DType::F32, &cpu()).unwrap();
    let f3 = Tensor::zeros((2, 1, 3, 4, 4), DType::F32, &cpu()).unwrap();
    let pts = |shape: &[usize]| Tensor::zeros(shape, DType::F32, &cpu()).unwrap();
    let shape_err = |r: pbdl_core::Result<Tensor>, which: &str| match r {
        Err(Error::Shape { arg, .. }) => assert_eq!(arg, which),
        other => panic!("expected a shape error on `{which}`, got {other:?}"),
    };
    // Wrong number of coordinates for the field's dimension.
    shape_err(grid_sample(&f2, &pts(&[2, 5, 3]), Boundary::Clamp), "points");
    shape_err(grid_sample(&f3, &pts(&[2, 5, 2]), Boundary::Clamp), "points");
    // Batch mismatch, points without a batch axis.
    shape_err(grid_sample(&f2, &pts(&[3, 5, 2]), Boundary::Clamp), "points");
    shape_err(grid_sample(&f2, &pts(&[2]), Boundary::Clamp), "points");
    // Field of the wrong rank, or with an empty spatial axis.
    shape_err(grid_sample(&pts(&[2, 4, 4]), &pts(&[2, 5, 2]), Boundary::Clamp), "field");
    shape_err(grid_sample(&pts(&[2, 1, 0, 4]), &pts(&[2, 5, 2]), Boundary::Clamp), "field");
    // Mixed or integer dtypes.
    let p64 = Tensor::zeros((2, 5, 2), DType::F64, &cpu()).unwrap();
    assert!(matches!(grid_sample(&f2, &p64, Boundary::Clamp), Err(Error::DType { arg: "points", .. })));
    let fu = Tensor::zeros((2, 1, 4, 4), DType::U32, &cpu()).unwrap();
    assert!(matches!(grid_sample(&fu, &pts(&[2, 5, 2]), Boundary::Clamp), Err(Error::DType { arg: "field", .. })));
    // A per-axis boundary list of the wrong length.
    let r = grid_sample(&f2, &pts(&[2, 5, 2]), [Boundary::Clamp; 3]);
    assert!(matches!(r, Err(Error::InvalidArgument { arg: "boundary", .. })), "{r:?}");
    // warp: displacement shape and dtype.
    shape_err(warp(&f2, &pts(&[2, 3, 4, 4]), Boundary::Clamp), "displacement");
    shape_err(warp(&f2, &pts(&[2, 2, 4, 5]), Boundary::Clamp), "displacement");
    shape_err(warp(&f3, &pts(&[2, 2, 4, 4]), Boundary::Clamp), "displacement");
    shape_err(warp(&pts(&[2, 4, 4]), &pts(&[2, 2, 4, 4]), Boundary::Clamp), "field");
    let d64 = Tensor::zeros((2, 2, 4, 4), DType::F64, &cpu()).unwrap();
    assert!(matches!(warp(&f2, &d64, Boundary::Clamp), Err(Error::DType { arg: "displacement", .. })));
    // resize: rank, sizes, dtype.
    shape_err(resize2d(&f3, (2, 2), Resize::Nearest), "x");
    shape_err(resize3d(&f2, (2, 2, 2), Resize::Nearest), "x");
    assert!(matches!(resize2d(&f2, (0, 3), Resize::Nearest), Err(Error::InvalidArgument { arg: "size", .. })));
    assert!(matches!(resize2d(&fu, (3, 3), Resize::Nearest), Err(Error::DType { .. })));
    // The message names the op, the argument and both shapes.
    let msg = grid_sample(&f2, &pts(&[2, 5, 3]), Boundary::Clamp).unwrap_err().to_string();
    assert!(
        msg.contains("grid_sample")
            && msg.contains("points")
            && msg.contains("[2, 5, 3]")
            && msg.contains("[2, ..., 2]"),
        "{msg}"
    );
}
