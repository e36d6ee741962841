//! Property tests (proptest) of pbdl-core's linear operators, on random shapes and parameters:
//!
//! * convolution (1D/2D/3D; stride, padding, dilation, groups, zero and periodic padding per
//!   axis): `<conv(x, W), y> = <x, conv_transpose(y, W)>` between the two forward ops, and
//!   `<x, J_x^T y>`, `<W, J_W^T y>` from the hand-written backward;
//! * sampling: `grid_sample` and `warp` (2D/3D, clamped/periodic) are linear in the field, and
//!   their backward (the splat) is the transpose; the splat preserves total mass (weights sum
//!   to 1); `resize2d`/`resize3d` (every mode) and `spline_zoom` backward are transposes;
//! * FFT: `rfft2`, `irfft2`, `rfft3`, `irfft3` backward are transposes, and
//!   `irfft(rfft(x)) = x`.
//!
//! Everything runs in f64. Tolerance 1e-10 relative to `|A x| |y| + |x| |A^T y|`: each inner
//! product sums at most a few thousand products, so round-off is ~1e-13, while a wrong tap,
//! border term or output padding moves the identity by ~1/sqrt(size) >= 1e-2.
//! The proptest seed is fixed (deterministic CI) unless `PROPTEST_RNG_SEED` is set;
//! `PROPTEST_CASES` overrides the case counts.

use candle_core::{DType, Device, Tensor};
use pbdl_core::conv::{conv, conv_transpose, ConvParams, PaddingMode};
use pbdl_core::fft::{irfft2, irfft3, rfft2, rfft3};
use pbdl_core::sample::{grid_sample, resize2d, resize3d, spline_zoom, warp, Boundary, Resize};
use pbdl_core::seed;
use pbdl_core::testing::{adjoint_gap, adjoint_gap_by_backward, norm, vjp};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// `cases` random cases (or `PROPTEST_CASES`), a fixed seed (or `PROPTEST_RNG_SEED`), and no
/// regression files written into the source tree (a failure prints its minimal input).
fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_none() {
        c.cases = cases;
    }
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_0025);
    }
    c.failure_persistence = None;
    c
}

const TOL: f64 = 1e-10;

fn randn(shape: &[usize], s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

/// Largest `|sum(splat) - sum(y)|` over batch and channels: a splat `[b, c, spatial...]` of
/// point values `y` `[b, c, points]`.
fn splat_mass_error(splat: &Tensor, y: &Tensor) -> f64 {
    let d = (splat.flatten_from(2).unwrap().sum(2).unwrap() - y.sum(2).unwrap()).unwrap();
    d.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
}

/// One axis of a random convolution: kernel, stride, dilation, padding, extra input length
/// beyond the smallest valid one, and whether the axis is periodic.
#[derive(Clone, Copy, Debug)]
struct Axis {
    k: usize,
    s: usize,
    d: usize,
    p: usize,
    extra: usize,
    circular: bool,
}

fn axis() -> impl Strategy<Value = Axis> {
    (1usize..4, 1usize..4, 1usize..3, 0usize..3, 0usize..5, any::<bool>())
        .prop_map(|(k, s, d, p, extra, circular)| Axis { k, s, d, p, extra, circular })
}

/// Checks the conv adjoint identities for `N` random axes; returns the worst violation.
fn conv_case<const N: usize>(
    axes: [Axis; N],
    groups: usize,
    cin_g: usize,
    cout_g: usize,
    batch: usize,
    s: u64,
) -> (f64, String) {
    let mut p = ConvParams::<N> { groups, ..Default::default() };
    let mut xs = vec![batch, groups * cin_g];
    let mut ws = vec![groups * cout_g, cin_g];
    for (i, a) in axes.iter().enumerate() {
        p.stride[i] = a.s;
        p.dilation[i] = a.d;
        p.padding[i] = a.p;
        p.padding_mode[i] = if a.circular { PaddingMode::Circular } else { PaddingMode::Zeros };
        // Smallest input whose padded length covers the dilated kernel.
        let span = a.d * (a.k - 1) + 1;
        xs.push(span.saturating_sub(2 * a.p).max(1) + a.extra);
        ws.push(a.k);
    }
    let x = randn(&xs, s);
    let w = randn(&ws, s ^ 1);
    let yx = conv(&x, &w, None, &p).unwrap();
    let y = randn(yx.dims(), s ^ 2);
    let what = format!("x {xs:?} w {ws:?} {p:?}");
    // Backward for the input and for the weight (conv is bilinear).
    let ex = adjoint_gap_by_backward(|t| conv(t, &w, None, &p).unwrap(), &x, &y);
    let ew = adjoint_gap_by_backward(|t| conv(&x, t, None, &p).unwrap(), &w, &y);
    let mut worst = ex.max(ew);
    // Zero padding: the transposed convolution (PyTorch layout: the same weight tensor read as
    // [in, out / groups, k...]) with the output padding that restores the input size.
    if p.is_zero_padded() {
        let mut op = [0usize; N];
        for (i, a) in axes.iter().enumerate() {
            let m = yx.dims()[2 + i];
            op[i] = xs[2 + i] + 2 * a.p - ((m - 1) * a.s + a.d * (a.k - 1) + 1);
        }
        let aty = conv_transpose(&y, &w, None, &p, op).unwrap();
        worst = worst.max(adjoint_gap(&yx, &y, &x, &aty));
    }
    (worst, what)
}

proptest! {
    #![proptest_config(config(48))]

    /// conv1d/2d/3d: backward for input and weight, and conv_transpose, are transposes.
    #[test]
    fn convolution_adjoints(
        a in prop::array::uniform3(axis()), groups in 1usize..3, cin_g in 1usize..3, cout_g in 1usize..3,
        batch in 1usize..3, dims in 1usize..4, s in any::<u64>(),
    ) {
        let (e, what) = match dims {
            1 => conv_case::<1>([a[0]], groups, cin_g, cout_g, batch, s),
            2 => conv_case::<2>([a[0], a[1]], groups, cin_g, cout_g, batch, s),
            _ => conv_case::<3>(a, groups, cin_g, cout_g, batch, s),
        };
        prop_assert!(e < TOL, "{what}: {e:e}");
    }

    /// Depthwise convolutions (one input and one output channel per group) take the direct
    /// kernels instead of im2col; the same identities.
    #[test]
    fn depthwise_convolution_adjoints(
        a in prop::array::uniform2(axis()), channels in 1usize..5, batch in 1usize..3, s in any::<u64>(),
    ) {
        let (e, what) = conv_case::<2>(a, channels, 1, 1, batch, s);
        prop_assert!(e < TOL, "{what}: {e:e}");
    }

    /// `grid_sample` and `warp` are linear in the field for fixed points/displacements; the
    /// backward for the field is the transpose (a splat), and the splat keeps the total mass:
    /// interpolation weights sum to 1, so `sum(A^T y) = sum(y)` per channel.
    #[test]
    fn sampling_is_transposed_by_its_splat(
        n in prop::array::uniform3(1usize..7), dims in 2usize..4, npts in 1usize..20,
        bx in any::<bool>(), by in any::<bool>(), bz in any::<bool>(), s in any::<u64>(),
    ) {
        let b = |p: bool| if p { Boundary::Periodic } else { Boundary::Clamp };
        let spatial: Vec<usize> = n[..dims].to_vec();
        let mut fs = vec![2usize, 3];
        fs.extend(&spatial);
        let field = randn(&fs, s);
        // Points spread over [-2, n + 2] along each axis (outside too).
        let u = seed::rand_uniform((2, npts, dims), 0.0, 1.0, DType::F64, &Device::Cpu, s ^ 1).unwrap();
        let ext: Vec<f64> = spatial.iter().rev().map(|&m| m as f64 + 4.0).collect();
        let ext = Tensor::from_vec(ext, (1, 1, dims), &Device::Cpu).unwrap();
        let pts = (u.broadcast_mul(&ext).unwrap() - 2.0).unwrap();
        let y = randn(&[2, 3, npts], s ^ 2);
        let e = if dims == 2 {
            let bc = [b(bx), b(by)];
            let f = |t: &Tensor| grid_sample(t, &pts, bc).unwrap();
            let m = splat_mass_error(&vjp(f, &field, &y), &y);
            prop_assert!(m < 1e-12 * npts as f64, "2D splat changes the mass by {m:e}");
            adjoint_gap_by_backward(f, &field, &y)
        } else {
            let bc = [b(bx), b(by), b(bz)];
            let f = |t: &Tensor| grid_sample(t, &pts, bc).unwrap();
            let m = splat_mass_error(&vjp(f, &field, &y), &y);
            prop_assert!(m < 1e-12 * npts as f64, "3D splat changes the mass by {m:e}");
            adjoint_gap_by_backward(f, &field, &y)
        };
        prop_assert!(e < TOL, "grid_sample {dims}D {spatial:?}: {e:e}");

        // warp: displacements up to +-3 cells.
        let mut ds = vec![2usize, dims];
        ds.extend(&spatial);
        let disp = (randn(&ds, s ^ 3) * 1.5).unwrap();
        let yw = randn(&fs, s ^ 4);
        let e = if dims == 2 {
            adjoint_gap_by_backward(|t| warp(t, &disp, [b(bx), b(by)]).unwrap(), &field, &yw)
        } else {
            adjoint_gap_by_backward(|t| warp(t, &disp, [b(bx), b(by), b(bz)]).unwrap(), &field, &yw)
        };
        prop_assert!(e < TOL, "warp {dims}D {spatial:?}: {e:e}");
    }

    /// Resizing (nearest, bilinear/trilinear, bicubic; both corner conventions; up and down) and
    /// the cubic B-spline zoom: the backward is the transpose.
    #[test]
    fn resize_backward_is_the_transpose(
        n_in in prop::array::uniform3(1usize..9), n_out in prop::array::uniform3(1usize..9),
        mode in 0usize..5, s in any::<u64>(),
    ) {
        let mode = match mode {
            0 => Resize::Nearest,
            1 => Resize::Bilinear { align_corners: false },
            2 => Resize::Bilinear { align_corners: true },
            3 => Resize::Bicubic { align_corners: false },
            _ => Resize::Bicubic { align_corners: true },
        };
        let x = randn(&[2, 2, n_in[1], n_in[2]], s);
        let y = randn(&[2, 2, n_out[1], n_out[2]], s ^ 1);
        let e = adjoint_gap_by_backward(|t| resize2d(t, (n_out[1], n_out[2]), mode).unwrap(), &x, &y);
        prop_assert!(e < TOL, "resize2d {mode:?} {n_in:?} -> {n_out:?}: {e:e}");
        let x3 = randn(&[1, 2, n_in[0], n_in[1], n_in[2]], s ^ 2);
        let y3 = randn(&[1, 2, n_out[0], n_out[1], n_out[2]], s ^ 3);
        let e = adjoint_gap_by_backward(|t| resize3d(t, (n_out[0], n_out[1], n_out[2]), mode).unwrap(), &x3, &y3);
        prop_assert!(e < TOL, "resize3d {mode:?} {n_in:?} -> {n_out:?}: {e:e}");
        let e = adjoint_gap_by_backward(|t| spline_zoom(t, &n_out).unwrap(), &x3, &y3);
        prop_assert!(e < TOL, "spline_zoom {n_in:?} -> {n_out:?}: {e:e}");
    }

    /// Real FFTs: the backward of `rfft2`/`irfft2`/`rfft3`/`irfft3` is the transpose (even and
    /// odd sizes, so both the Nyquist and the no-Nyquist column layouts), and the inverse
    /// inverts. Round trip: 1e-12 relative, a few FFT passes of round-off.
    #[test]
    fn fft_backward_is_the_transpose(
        n in prop::array::uniform3(1usize..10), batch in 1usize..3, s in any::<u64>(),
    ) {
        let [nz, ny, nx] = n;
        let w = nx / 2 + 1;
        let x = randn(&[batch, ny, nx], s);
        let z = randn(&[batch, ny, w, 2], s ^ 1);
        let e = adjoint_gap_by_backward(|t| rfft2(t).unwrap(), &x, &z);
        prop_assert!(e < TOL, "rfft2 {n:?}: {e:e}");
        let e = adjoint_gap_by_backward(|t| irfft2(t, nx).unwrap(), &z, &x);
        prop_assert!(e < TOL, "irfft2 {n:?}: {e:e}");
        let back = irfft2(&rfft2(&x).unwrap(), nx).unwrap();
        let r = norm(&(back - &x).unwrap()) / norm(&x);
        prop_assert!(r < 1e-12, "irfft2(rfft2(x)) {n:?}: {r:e}");

        let x3 = randn(&[batch, nz, ny, nx], s ^ 2);
        let z3 = randn(&[batch, nz, ny, w, 2], s ^ 3);
        let e = adjoint_gap_by_backward(|t| rfft3(t).unwrap(), &x3, &z3);
        prop_assert!(e < TOL, "rfft3 {n:?}: {e:e}");
        let e = adjoint_gap_by_backward(|t| irfft3(t, nx).unwrap(), &z3, &x3);
        prop_assert!(e < TOL, "irfft3 {n:?}: {e:e}");
        let back = irfft3(&rfft3(&x3).unwrap(), nx).unwrap();
        let r = norm(&(back - &x3).unwrap()) / norm(&x3);
        prop_assert!(r < 1e-12, "irfft3(rfft3(x)) {n:?}: {r:e}");
    }
}
