//! Tests of `pbdl_core::fft`: against a naive O(N^2) DFT, against numbers from numpy, round
//! trips, Parseval, finite-difference gradients of all ops, f32 against f64, typed errors.

mod common;

use candle_core::{DType, Device, Tensor, D};
use common::{randn, rel_diff, F32_TOL, F64_TOL, GRAD_TOL};
use pbdl_core::fft::{irfft2, irfft3, power_spectrum_2d, rfft2, rfft3};
use pbdl_core::{check_grad, Error, GradCheckOptions};
use std::f64::consts::PI;

/// Sizes `[ny, nx]`: odd and even, 1-wide, prime, power of two.
const SIZES_2D: [[usize; 2]; 8] = [[1, 1], [1, 5], [5, 6], [4, 7], [6, 1], [2, 2], [7, 9], [8, 16]];
/// Sizes `[nz, ny, nx]`.
const SIZES_3D: [[usize; 3]; 5] = [[1, 1, 1], [3, 4, 6], [2, 5, 5], [4, 1, 3], [3, 3, 8]];

fn to_vec(t: &Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap()
}

fn tensor(v: Vec<f64>, shape: &[usize]) -> Tensor {
    Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
}

/// Flat index -> multi-index over `dims`.
fn unravel(mut i: usize, dims: &[usize]) -> Vec<usize> {
    let mut idx = vec![0; dims.len()];
    for d in (0..dims.len()).rev() {
        idx[d] = i % dims[d];
        i /= dims[d];
    }
    idx
}

/// The phase `2 pi sum_d k_d r_d / n_d`.
fn phase(k: &[usize], r: &[usize], n: &[usize]) -> f64 {
    k.iter().zip(r).zip(n).map(|((&k, &r), &n)| 2.0 * PI * ((k * r) % n) as f64 / n as f64).sum()
}

/// Naive forward: `Z_k = sum_r x_r e^{-i theta}` over one slice of `spatial`, interleaved (re, im).
fn naive_rfft(x: &[f64], spatial: &[usize]) -> Vec<f64> {
    let nx = spatial[spatial.len() - 1];
    let mut half = spatial.to_vec();
    *half.last_mut().unwrap() = nx / 2 + 1;
    let m: usize = half.iter().product();
    let mut out = vec![0.0; 2 * m];
    for (ki, o) in out.chunks_mut(2).enumerate() {
        let k = unravel(ki, &half);
        for (ri, &v) in x.iter().enumerate() {
            let th = phase(&k, &unravel(ri, spatial), spatial);
            o[0] += v * th.cos();
            o[1] -= v * th.sin();
        }
    }
    out
}

/// Naive inverse: `x_r = (1/N) sum_k c_kx Re(Z_k e^{+i theta})` (numpy's irfftn; the formula is
/// checked against numpy's own numbers in `matches_numpy_reference_numbers`).
fn naive_irfft(z: &[f64], spatial: &[usize]) -> Vec<f64> {
    let nx = spatial[spatial.len() - 1];
    let mut half = spatial.to_vec();
    *half.last_mut().unwrap() = nx / 2 + 1;
    let n: usize = spatial.iter().product();
    let mut out = vec![0.0; n];
    for (ri, o) in out.iter_mut().enumerate() {
        let r = unravel(ri, spatial);
        for (ki, zc) in z.chunks(2).enumerate() {
            let k = unravel(ki, &half);
            let kx = k[k.len() - 1];
            let c = if kx == 0 || 2 * kx == nx { 1.0 } else { 2.0 };
            let th = phase(&k, &r, spatial);
            *o += c * (zc[0] * th.cos() - zc[1] * th.sin());
        }
        *o /= n as f64;
    }
    out
}

/// Applies a per-slice reference to every slice of a batched tensor.
fn per_slice(t: &Tensor, slice_len: usize, f: impl Fn(&[f64]) -> Vec<f64>) -> Vec<f64> {
    to_vec(t).chunks(slice_len).flat_map(f).collect()
}

fn spec_shape(batch: &[usize], spatial: &[usize]) -> Vec<usize> {
    let mut s = batch.to_vec();
    s.extend_from_slice(&spatial[..spatial.len() - 1]);
    s.extend([spatial[spatial.len() - 1] / 2 + 1, 2]);
    s
}

fn real_shape(batch: &[usize], spatial: &[usize]) -> Vec<usize> {
    let mut s = batch.to_vec();
    s.extend_from_slice(spatial);
    s
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
}

fn max_abs(a: &[f64]) -> f64 {
    a.iter().map(|v| v.abs()).fold(1e-300, f64::max)
}

type Forward = fn(&Tensor) -> pbdl_core::Result<Tensor>;
type Inverse = fn(&Tensor, usize) -> pbdl_core::Result<Tensor>;

/// Forward and inverse of `spatial` (2 or 3 axes) against the naive DFT, on a batch of 2 (the
/// parallel path) and unbatched (the serial path). The inverse gets a random half spectrum with
/// non-zero imaginary parts in the DC and Nyquist columns.
fn check_against_naive(spatial: &[usize], seed: u64) {
    let (fwd, inv): (Forward, Inverse) = if spatial.len() == 2 { (rfft2, irfft2) } else { (rfft3, irfft3) };
    let nx = spatial[spatial.len() - 1];
    let n: usize = spatial.iter().product();
    let m = n / nx * (nx / 2 + 1);
    for batch in [&[][..], &[2][..]] {
        let x = randn(&real_shape(batch, spatial), DType::F64, seed);
        let z = fwd(&x).unwrap();
        assert_eq!(z.dims(), spec_shape(batch, spatial).as_slice());
        let want = per_slice(&x, n, |s| naive_rfft(s, spatial));
        let err = max_abs_diff(&to_vec(&z), &want) / max_abs(&want);
        assert!(err < F64_TOL, "forward {spatial:?} batch {batch:?}: {err:e}");

        let zr = randn(&spec_shape(batch, spatial), DType::F64, seed + 100);
        let xr = inv(&zr, nx).unwrap();
        assert_eq!(xr.dims(), real_shape(batch, spatial).as_slice());
        let want = per_slice(&zr, 2 * m, |s| naive_irfft(s, spatial));
        let err = max_abs_diff(&to_vec(&xr), &want) / max_abs(&want);
        assert!(err < F64_TOL, "inverse {spatial:?} batch {batch:?}: {err:e}");
    }
}

#[test]
fn rfft2_and_irfft2_match_naive_dft() {
    for (i, s) in SIZES_2D.iter().enumerate() {
        check_against_naive(s, i as u64);
    }
}

#[test]
fn rfft3_and_irfft3_match_naive_dft() {
    for (i, s) in SIZES_3D.iter().enumerate() {
        check_against_naive(s, 10 + i as u64);
    }
}

/// Reference numbers from numpy 2.4.6:
///
/// ```python
/// import numpy as np
/// x = np.array([[1.0, 2.0, 0.0, -1.0], [3.0, -2.0, 1.0, 0.5], [0.0, 1.0, -1.0, 2.0]])
/// print(np.fft.rfft2(x).round(15).tolist())
/// z = np.array([[1+2j, 0.5-1j, -1+3j], [2-1j, 1+1j, 0.5+0.25j], [-1+0.5j, 2+0j, 1-2j]])
/// print(np.fft.irfft2(z, s=(3, 4)).tolist())
/// print(np.fft.irfft2(z, s=(3, 5)).tolist())
/// ```
///
/// `z` has non-zero imaginary parts in its DC column and (for nx = 4) its Nyquist column, and is
/// not Hermitian along y there: this pins which parts numpy ignores.
#[test]
fn matches_numpy_reference_numbers() {
    let x = tensor(vec![1.0, 2.0, 0.0, -1.0, 3.0, -2.0, 1.0, 0.5, 0.0, 1.0, -1.0, 2.0], &[3, 4]);
    #[rustfmt::skip]
    let want_z = [
        6.5, 0.0, 4.0, 0.5, 1.5, 0.0,
        -0.25, -0.433012701892219, 0.799038105676658, -5.616025403784438, -0.75, -8.227241335952167,
        -0.25, 0.433012701892219, -1.799038105676658, -3.883974596215562, -0.75, 8.227241335952167,
    ];
    assert!(max_abs_diff(&to_vec(&rfft2(&x).unwrap()), &want_z) < 1e-13);

    #[rustfmt::skip]
    let z = tensor(
        vec![1.0, 2.0, 0.5, -1.0, -1.0, 3.0, 2.0, -1.0, 1.0, 1.0, 0.5, 0.25, -1.0, 0.5, 2.0, 0.0, 1.0, -2.0],
        &[3, 3, 2],
    );
    #[rustfmt::skip]
    let want4 = [
        0.7916666666666665, 0.125, -0.37499999999999994, 0.125,
        -0.46929748836726715, 0.8524705059800435, 0.15271097956087898, 0.06379537138523067,
        -0.07236917829939951, 0.022529494019956506, -0.02771097956087904, -0.18879537138523061,
    ];
    assert!(max_abs_diff(&to_vec(&irfft2(&z, 4).unwrap()), &want4) < 1e-14);
    #[rustfmt::skip]
    let want5 = [
        0.6666666666666666, 0.1256425890345668, -0.06509737836745336, -0.38211621713250454, 0.32157100646539116,
        -0.6220084679281461, 0.47228741234967964, 0.7907316783401942, -0.4530654650636433, 0.4117342108608016,
        -0.04465819873852048, -0.3374395009921842, 0.5653374238734642, -0.626610434899994, 0.17702467553168197,
    ];
    assert!(max_abs_diff(&to_vec(&irfft2(&z, 5).unwrap()), &want5) < 1e-14);
    // The naive formula of these tests agrees with numpy on the same input.
    assert!(max_abs_diff(&naive_irfft(&to_vec(&z), &[3, 4]), &want4) < 1e-14);
    assert!(max_abs_diff(&naive_irfft(&to_vec(&z), &[3, 5]), &want5) < 1e-14);
}

/// `numpy.fft.rfftn(x3)` for `x3 = np.arange(24.0).reshape(2, 3, 4) ** 1.5 % 3.0` (numpy 2.4.6).
#[test]
fn rfft3_matches_numpy_reference_numbers() {
    let x3: Vec<f64> = (0..24).map(|i| (i as f64).powf(1.5) % 3.0).collect();
    let z = to_vec(&rfft3(&tensor(x3, &[2, 3, 4])).unwrap());
    #[rustfmt::skip]
    let want = [
        35.52401131058942, 0.0, -1.4486692026126442, 2.0378477525410794, 5.93074901309255, 0.0,
        1.653873021831549, -2.402180150126801, -4.758856855103918, 1.6206831827991148, -2.038703419969257, 2.086234321709869,
        1.653873021831549, 2.402180150126801, 1.2802925839316215, -2.402322830982128, -2.038703419969257, -2.086234321709869,
        -1.213644585258045, 0.0, -5.5927811677064145, -1.9999589394026493, 2.8611209859703717, 0.0,
        -0.7353177421387702, -3.9448701997949573, -3.9174035078799623, 3.163999897637133, -3.4604074734435293, -0.7508551677725471,
        -0.7353177421387702, 3.9448701997949573, -2.533144599105824, 4.756665473647242, -3.4604074734435293, 0.7508551677725471,
    ];
    assert!(max_abs_diff(&z, &want) < 1e-12);
}

/// A single Fourier mode, computed by hand: `cos(2 pi (kx x / nx + ky y / ny))` with
/// `0 < kx < nx/2` has exactly one half-spectrum entry, `N/2` at `(ky, kx)`; `sin` gives `-i N/2`.
#[test]
fn single_mode_lands_on_one_bin() {
    let (ny, nx, ky, kx) = (6usize, 10usize, 5usize, 3usize);
    for (f, want) in [(f64::cos as fn(f64) -> f64, (30.0, 0.0)), (f64::sin, (0.0, -30.0))] {
        let v: Vec<f64> = (0..ny * nx)
            .map(|i| f(2.0 * PI * ((kx * (i % nx)) as f64 / nx as f64 + (ky * (i / nx)) as f64 / ny as f64)))
            .collect();
        let z = to_vec(&rfft2(&tensor(v, &[ny, nx])).unwrap());
        for (i, c) in z.chunks(2).enumerate() {
            let expect = if i == ky * (nx / 2 + 1) + kx { want } else { (0.0, 0.0) };
            assert!((c[0] - expect.0).abs() < 1e-12 && (c[1] - expect.1).abs() < 1e-12, "bin {i}: {c:?}");
        }
    }
}

#[test]
fn inverse_undoes_forward() {
    for (shape, three) in [(vec![3, 5, 6], false), (vec![4, 7], false), (vec![2, 3, 4, 6], true), (vec![3, 5, 5], true)]
    {
        let x = randn(&shape, DType::F64, 7);
        let nx = shape[shape.len() - 1];
        let back = if three { irfft3(&rfft3(&x).unwrap(), nx) } else { irfft2(&rfft2(&x).unwrap(), nx) }.unwrap();
        let err = rel_diff(&back, &x);
        assert!(err < F64_TOL, "{shape:?}: {err:e}");
    }
}

/// Parseval over the half spectrum: `sum x^2 = (1/N) sum_k c_kx |Z_k|^2`, here through
/// `power_spectrum_2d`.
#[test]
fn parseval_holds_with_half_spectrum_weights() {
    for (ny, nx) in [(5usize, 6usize), (4, 7), (1, 1), (8, 2)] {
        let x = randn(&[ny, nx], DType::F64, 3);
        let energy: f64 = to_vec(&x).iter().map(|v| v * v).sum();
        let p = to_vec(&power_spectrum_2d(&x).unwrap());
        let h = nx / 2 + 1;
        let spectral: f64 =
            p.iter().enumerate().map(|(i, &v)| if i % h == 0 || 2 * (i % h) == nx { v } else { 2.0 * v }).sum::<f64>()
                / (ny * nx) as f64;
        assert!((energy - spectral).abs() < 1e-12 * energy, "{ny}x{nx}: {energy} vs {spectral}");
    }
}

fn grad_check(f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>, x: Tensor, what: &str) {
    let r = check_grad(f, &[x], &GradCheckOptions::default()).unwrap();
    eprintln!("{what}: max rel error {:.2e}", r.max_rel_error);
    r.ensure(GRAD_TOL).unwrap_or_else(|e| panic!("{what}: {e}"));
}

fn c(r: pbdl_core::Result<Tensor>) -> candle_core::Result<Tensor> {
    r.map_err(candle_core::Error::wrap)
}

/// Every output entry, real and imaginary, carries a random cotangent in `check_grad`; the
/// inverses get inputs with non-zero imaginary DC/Nyquist parts.
#[test]
fn rfft2_and_irfft2_pass_gradient_checks() {
    for shape in [vec![5usize, 6], vec![4, 7], vec![2, 3, 4], vec![1, 2]] {
        let nx = shape[shape.len() - 1];
        grad_check(|xs| c(rfft2(&xs[0])), randn(&shape, DType::F64, 1), &format!("rfft2 {shape:?}"));
        let zs = spec_shape(&[], &shape);
        grad_check(|xs| c(irfft2(&xs[0], nx)), randn(&zs, DType::F64, 2), &format!("irfft2 {shape:?}"));
    }
}

#[test]
fn rfft3_and_irfft3_pass_gradient_checks() {
    for shape in [vec![3usize, 4, 6], vec![3, 5, 5], vec![2, 2, 3, 4]] {
        let nx = shape[shape.len() - 1];
        grad_check(|xs| c(rfft3(&xs[0])), randn(&shape, DType::F64, 4), &format!("rfft3 {shape:?}"));
        let zs = spec_shape(&[], &shape);
        grad_check(|xs| c(irfft3(&xs[0], nx)), randn(&zs, DType::F64, 5), &format!("irfft3 {shape:?}"));
    }
}

/// Nonlinear spectral losses: the power spectrum, the squared imaginary parts alone, and an
/// irfft of a squared spectrum (both backwards chained).
#[test]
fn nonlinear_spectral_losses_pass_gradient_checks() {
    for shape in [vec![5usize, 6], vec![4, 7]] {
        let nx = shape[1];
        grad_check(|xs| c(power_spectrum_2d(&xs[0])), randn(&shape, DType::F64, 6), "power_spectrum_2d");
        grad_check(
            |xs| c(rfft2(&xs[0]))?.narrow(D::Minus1, 1, 1)?.sqr()?.sum_all(),
            randn(&shape, DType::F64, 7),
            "sum(im^2)",
        );
        grad_check(
            |xs| c(irfft2(&c(rfft2(&xs[0]))?.sqr()?, nx))?.sin(),
            randn(&shape, DType::F64, 8),
            "sin(irfft2(rfft2(x)^2))",
        );
    }
}

#[test]
fn f32_agrees_with_f64() {
    let check = |name: &str, a: Tensor, b: Tensor| {
        assert_eq!(a.dtype(), DType::F32);
        let err = rel_diff(&a.to_dtype(DType::F64).unwrap(), &b);
        assert!(err < F32_TOL, "{name}: {err:e}");
    };
    let x64 = randn(&[2, 24, 30], DType::F64, 9);
    let x32 = x64.to_dtype(DType::F32).unwrap();
    check("rfft2", rfft2(&x32).unwrap(), rfft2(&x64).unwrap());
    let z64 = randn(&[2, 24, 16, 2], DType::F64, 10);
    let z32 = z64.to_dtype(DType::F32).unwrap();
    check("irfft2", irfft2(&z32, 31).unwrap(), irfft2(&z64, 31).unwrap());
    let x64 = randn(&[6, 10, 12], DType::F64, 11);
    let x32 = x64.to_dtype(DType::F32).unwrap();
    check("rfft3", rfft3(&x32).unwrap(), rfft3(&x64).unwrap());
    let z64 = randn(&[6, 10, 7, 2], DType::F64, 12);
    let z32 = z64.to_dtype(DType::F32).unwrap();
    check("irfft3", irfft3(&z32, 12).unwrap(), irfft3(&z64, 12).unwrap());
}

#[test]
fn strided_input_is_read_correctly() {
    let x = randn(&[7, 5], DType::F64, 13);
    let view = x.t().unwrap();
    assert!(!view.is_contiguous());
    let a = rfft2(&view).unwrap();
    let b = rfft2(&view.contiguous().unwrap()).unwrap();
    assert_eq!(to_vec(&a), to_vec(&b));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let cpu = Device::Cpu;
    let shape_err = |r: pbdl_core::Result<Tensor>, op: &str| match r {
        Err(Error::Shape { op: o, .. }) => assert_eq!(o, op),
        other => panic!("{op}: expected a shape error, got {other:?}"),
    };
    shape_err(rfft2(&Tensor::zeros(5, DType::F32, &cpu).unwrap()), "rfft2");
    shape_err(rfft3(&Tensor::zeros((4, 5), DType::F32, &cpu).unwrap()), "rfft3");
    shape_err(rfft2(&Tensor::zeros((3, 0), DType::F32, &cpu).unwrap()), "rfft2");
    shape_err(irfft2(&Tensor::zeros((4, 3), DType::F32, &cpu).unwrap(), 4), "irfft2");
    shape_err(irfft2(&Tensor::zeros((4, 3, 3), DType::F32, &cpu).unwrap(), 4), "irfft2");
    shape_err(irfft3(&Tensor::zeros((4, 3, 2), DType::F32, &cpu).unwrap(), 4), "irfft3");

    for nx in [0, 3, 7] {
        match irfft2(&Tensor::zeros((4, 3, 2), DType::F32, &cpu).unwrap(), nx) {
            Err(e @ Error::InvalidArgument { arg: "nx", .. }) => {
                assert!(e.to_string().contains("fits nx = 4 or 5"), "{e}")
            }
            other => panic!("nx = {nx}: expected an nx error, got {other:?}"),
        }
    }

    let ints = Tensor::zeros((4, 6), DType::U32, &cpu).unwrap();
    assert!(matches!(rfft2(&ints), Err(Error::DType { op: "rfft2", .. })));
    let ints = Tensor::zeros((2, 4, 4, 2), DType::I64, &cpu).unwrap();
    assert!(matches!(irfft3(&ints, 6), Err(Error::DType { op: "irfft3", .. })));
}

/// An empty batch is not an error: it gives an empty spectrum of the right shape.
#[test]
fn empty_batch_gives_empty_output() {
    let x = Tensor::zeros((0, 4, 6), DType::F64, &Device::Cpu).unwrap();
    assert_eq!(rfft2(&x).unwrap().dims(), &[0, 4, 4, 2]);
    let z = Tensor::zeros((0, 4, 4, 2), DType::F64, &Device::Cpu).unwrap();
    assert_eq!(irfft2(&z, 7).unwrap().dims(), &[0, 4, 7]);
}

/// A batch large enough for the thread policy to split it (40 x 32 x 32 = 40,960 elements,
/// above the default 192^2) gives the same bits as transforming each slice on its own.
#[test]
fn a_large_batch_equals_its_slices_bit_for_bit() {
    let x = randn(&[40, 32, 32], DType::F64, 77);
    let whole = to_vec(&rfft2(&x).unwrap());
    let slices: Vec<f64> = (0..40).flat_map(|b| to_vec(&rfft2(&x.narrow(0, b, 1).unwrap()).unwrap())).collect();
    assert_eq!(whole, slices);
    let back = to_vec(&irfft2(&rfft2(&x).unwrap(), 32).unwrap());
    let back_slices: Vec<f64> =
        (0..40).flat_map(|b| to_vec(&irfft2(&rfft2(&x.narrow(0, b, 1).unwrap()).unwrap(), 32).unwrap())).collect();
    assert_eq!(back, back_slices);
}
