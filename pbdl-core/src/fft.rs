//! Differentiable real FFTs over the last two or three axes, for spectral losses and spectral
//! solvers: [`rfft2`], [`irfft2`], [`rfft3`], [`irfft3`] and [`power_spectrum_2d`].
//!
//! # Conventions (numpy / PyTorch, `norm = "backward"`)
//!
//! A complex number is a trailing axis of size 2 holding `(re, im)`, the layout of
//! `torch.view_as_real`. Leading axes are a batch: every `[ny, nx]` (or `[nz, ny, nx]`) slice is
//! transformed on its own.
//!
//! * [`rfft2`]`(x)`: `[..., ny, nx]` real -> `[..., ny, nx/2+1, 2]`,
//!   `Z[ky, kx] = sum_{y,x} x[y, x] exp(-2 pi i (ky y / ny + kx x / nx))`, unnormalised, as
//!   `torch.view_as_real(torch.fft.rfft2(x))` and `numpy.fft.rfft2`. Row `ky` is frequency `ky`
//!   for `ky <= ny/2` and `ky - ny` above (numpy's `fftfreq` order); column `kx` is frequency `kx`.
//! * [`irfft2`]`(z, nx)`: the inverse with the factor `1 / (ny nx)`, as
//!   `numpy.fft.irfft2(z, s=(ny, nx))`: a complex inverse DFT along `y`, then the
//!   half-complex-to-real one along `x`. That last step reads only the real part of the DC column
//!   (`kx = 0`) and, for even `nx`, of the Nyquist column (`kx = nx/2`); their imaginary parts are
//!   ignored *after* the transform along `y`, as numpy (pocketfft) and PyTorch do. So `Im z[ky, 0]`
//!   with `ky != 0` still counts: what is dropped is the part of the column that is not Hermitian
//!   in `ky`. `nx` must be given because `nx = 2w - 2` and `nx = 2w - 1` share the width `w`.
//! * [`rfft3`] / [`irfft3`]: the same over `[..., nz, ny, nx]` (`numpy.fft.rfftn` / `irfftn` over
//!   the last three axes), `1 / (nz ny nx)` on the inverse.
//!
//! `f32` and `f64` tensors on the CPU (the transform runs in the tensor's precision; realfft and
//! rustfft, each size planned once per thread and cached; the slices of a batch run in parallel).
//! What differs from PyTorch: no complex dtype (the `(re, im)` axis instead), no
//! `s`/`dim`/`norm` arguments (only the last 2 or 3 axes, no padding or cropping, `"backward"`
//! normalisation).
//!
//! # Backward (the adjoints, written out)
//!
//! Let `N` be the number of transformed samples (`ny nx` or `nz ny nx`), `theta = 2 pi k.r / n`
//! the phase of frequency `k` at sample `r`, and `c_kx` the number of full-spectrum columns that
//! half-spectrum column `kx` stands for: `c = 1` for the DC column and (even `nx`) the Nyquist
//! column, `c = 2` for every other column (it stands for `kx` and `-kx`). Then the inverse is
//!
//! ```text
//! x_r = (1/N) sum_k c_kx Re(Z_k e^{+i theta})          (sum over the half spectrum)
//! ```
//!
//! which is exactly numpy's `irfft2`, dropping of the DC/Nyquist imaginary parts included (there
//! `e^{+i theta}` is real along `x`). Writing `Z = a + i b`,
//! `dx_r/da_k = (c_kx/N) cos theta` and `dx_r/db_k = -(c_kx/N) sin theta`, so an output gradient
//! `g` pulls back to
//!
//! ```text
//! grad_a + i grad_b = (c_kx / N) sum_r g_r e^{-i theta} = (c_kx / N) rfft(g)_k      (adjoint of irfft)
//! ```
//!
//! and for `Z_k = sum_r x_r e^{-i theta}` (`a = sum x cos`, `b = -sum x sin`) an output gradient
//! `G = Ga + i Gb` pulls back to
//!
//! ```text
//! grad_x_r = sum_k (Ga_k cos theta - Gb_k sin theta) = Re sum_k G_k e^{+i theta}
//!          = irfft(G * N / c_kx)_r                                                  (adjoint of rfft)
//! ```
//!
//! i.e. the interior columns count twice in the adjoint of `irfft` and half in the adjoint of
//! `rfft`. Each backward is the other op times a per-column weight, so the backward pass is itself
//! a differentiable op.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_core::fft::{irfft2, rfft2};
//!
//! // cos(2 pi (2x/8 + y/4)) on a 4 x 8 grid: one half-spectrum entry, N/2 = 16 at (ky=1, kx=2).
//! let (ny, nx) = (4usize, 8usize);
//! let v: Vec<f64> = (0..ny * nx)
//!     .map(|i| (2.0 * std::f64::consts::PI * (2.0 * (i % nx) as f64 / 8.0 + (i / nx) as f64 / 4.0)).cos())
//!     .collect();
//! let x = Tensor::from_vec(v, (ny, nx), &Device::Cpu)?;
//! let z = rfft2(&x)?; // [4, 5, 2]
//! assert_eq!(z.dims(), &[4, 5, 2]);
//! let re = z.get(1)?.get(2)?.get(0)?.to_scalar::<f64>()?;
//! assert!((re - 16.0).abs() < 1e-12);
//! let back = irfft2(&z, nx)?;
//! assert!((back - &x)?.abs()?.max_all()?.to_scalar::<f64>()? < 1e-12);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::error::check_float;
use crate::op::{apply1, Kernel1, Op1};
use crate::{Error, Real, Result};
use candle_core::{DType, Shape, Tensor, D};
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{FftNum, RealFftPlanner};
use rustfft::{Fft, FftPlanner};
use std::cell::RefCell;
use std::sync::Arc;

/// Real 2D FFT over the last two axes: `[..., ny, nx]` -> `[..., ny, nx/2+1, 2]` (`(re, im)`),
/// unnormalised, as `torch.view_as_real(torch.fft.rfft2(x))`; see the [module docs](self).
///
/// Differentiable (the backward is the adjoint in the module docs). `f32` or `f64`; rank < 2, a
/// zero-sized `ny` or `nx`, or another dtype is a typed [`Error`].
pub fn rfft2(x: &Tensor) -> Result<Tensor> {
    rfft("rfft2", x, 2)
}

/// Inverse of [`rfft2`]: `[..., ny, nx/2+1, 2]` -> `[..., ny, nx]` with the factor `1/(ny nx)`,
/// as `numpy.fft.irfft2(z, s=(ny, nx))`; the imaginary parts of the DC and (even `nx`) Nyquist
/// columns are ignored after the transform along `y`, as numpy does (module docs).
///
/// `nx` is the length of the real signal: the width `nx/2+1` of `z` does not tell an even from
/// an odd `nx`. A last axis other than 2, a width other than `nx/2+1`, rank < 3 or a non-float
/// dtype is a typed [`Error`].
pub fn irfft2(z: &Tensor, nx: usize) -> Result<Tensor> {
    irfft("irfft2", z, nx, 2)
}

/// Real 3D FFT over the last three axes: `[..., nz, ny, nx]` -> `[..., nz, ny, nx/2+1, 2]`,
/// unnormalised, as `numpy.fft.rfftn(x, axes=(-3, -2, -1))`. Otherwise as [`rfft2`].
pub fn rfft3(x: &Tensor) -> Result<Tensor> {
    rfft("rfft3", x, 3)
}

/// Inverse of [`rfft3`]: `[..., nz, ny, nx/2+1, 2]` -> `[..., nz, ny, nx]` with the factor
/// `1/(nz ny nx)`, as `numpy.fft.irfftn(z, s=(nz, ny, nx))`. Otherwise as [`irfft2`].
pub fn irfft3(z: &Tensor, nx: usize) -> Result<Tensor> {
    irfft("irfft3", z, nx, 3)
}

/// The power spectrum `|rfft2(x)|^2 = re^2 + im^2`: `[..., ny, nx]` -> `[..., ny, nx/2+1]`,
/// unnormalised (divide by `(ny nx)^2` for the squared mean amplitudes). Differentiable: composed
/// of [`rfft2`] and candle ops.
///
/// Each interior column `0 < kx < nx/2` stands for the two frequencies `kx` and `-kx`; weigh it
/// twice when summing energy over the half spectrum (Parseval:
/// `sum x^2 = (1/N) sum c_kx |Z|^2`, `c` as in the module docs).
pub fn power_spectrum_2d(x: &Tensor) -> Result<Tensor> {
    let z = rfft2(x)?;
    // Two narrows rather than `sqr().sum(D::Minus1)`: candle's sum over an axis of size 2 took
    // ~7x the time of the FFT itself (8x256x256 f32: 16 ms against 2.3 ms).
    let (re, im) = (z.narrow(D::Minus1, 0, 1)?, z.narrow(D::Minus1, 1, 1)?);
    Ok((re.sqr()? + im.sqr()?)?.squeeze(D::Minus1)?)
}

/// Checks `x` for [`rfft`]: a float of rank `>= ndim` with non-zero transformed sizes.
fn check_real_input(op: &'static str, x: &Tensor, ndim: usize) -> Result<()> {
    check_float(op, "x", x)?;
    let dims = x.dims();
    if dims.len() < ndim || dims[dims.len() - ndim..].contains(&0) {
        return Err(Error::Shape {
            op,
            arg: "x",
            expected: format!("rank >= {ndim}, {} with every transformed size >= 1", layout(ndim, false)),
            got: dims.to_vec(),
        });
    }
    Ok(())
}

/// `[..., ny, nx]`-style description of an op's real (`spectrum = false`) or spectral layout.
fn layout(ndim: usize, spectrum: bool) -> &'static str {
    match (ndim, spectrum) {
        (2, false) => "[..., ny, nx]",
        (2, true) => "[..., ny, nx/2+1, 2]",
        (_, false) => "[..., nz, ny, nx]",
        (_, true) => "[..., nz, ny, nx/2+1, 2]",
    }
}

fn rfft(op: &'static str, x: &Tensor, ndim: usize) -> Result<Tensor> {
    check_real_input(op, x, ndim)?;
    Ok(apply1(x, Rfft { ndim, weights: None })?)
}

fn irfft(op: &'static str, z: &Tensor, nx: usize, ndim: usize) -> Result<Tensor> {
    check_float(op, "z", z)?;
    let dims = z.dims();
    let r = dims.len();
    if r < ndim + 1 || dims[r - 1] != 2 || dims[r - ndim - 1..r - 1].contains(&0) {
        return Err(Error::Shape {
            op,
            arg: "z",
            expected: format!(
                "rank >= {}, {} (last axis (re, im), every other transformed size >= 1)",
                ndim + 1,
                layout(ndim, true)
            ),
            got: dims.to_vec(),
        });
    }
    let width = dims[r - 2];
    if nx == 0 || nx / 2 + 1 != width {
        let fits =
            if width == 1 { "nx = 1".to_string() } else { format!("nx = {} or {}", 2 * width - 2, 2 * width - 1) };
        return Err(Error::invalid(
            op,
            "nx",
            format!(
                "nx = {nx} needs a half spectrum of width nx/2+1 = {}, but `z` ({dims:?}) has width {width}, \
                 which fits {fits}",
                nx / 2 + 1
            ),
        ));
    }
    Ok(apply1(z, Irfft { ndim, nx, weights: None })?)
}

/// Per-column weights `w_kx` (length `nx/2+1`) that a kernel multiplies into the half spectrum,
/// broadcast over rows and batch; `None` is all ones. The backward passes are weighted
/// transforms (module docs), so the weights live in the kernels rather than in a separate
/// broadcast multiply.
type Weights = Option<Arc<[f64]>>;

/// `w_kx * f(c_kx)` for every column, `c_kx` as in the module docs.
fn reweight(w: &Weights, nx: usize, f: impl Fn(f64) -> f64) -> Weights {
    let col = |kx: usize| f(if kx == 0 || 2 * kx == nx { 1.0 } else { 2.0 });
    Some((0..nx / 2 + 1).map(|kx| w.as_ref().map_or(1.0, |w| w[kx]) * col(kx)).collect())
}

/// The forward real FFT over the last `ndim` axes, unnormalised, times `weights`:
/// `y = w_kx rfft(x)`.
struct Rfft {
    ndim: usize,
    weights: Weights,
}

impl Kernel1 for Rfft {
    fn name(&self) -> &'static str {
        if self.ndim == 2 {
            "rfft2"
        } else {
            "rfft3"
        }
    }

    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        let dims = input.dims();
        let r = dims.len();
        if r < self.ndim || dims[r - self.ndim..].contains(&0) {
            return Err(Error::Shape {
                op: self.name(),
                arg: "x",
                expected: format!("rank >= {}, {}", self.ndim, layout(self.ndim, false)),
                got: dims.to_vec(),
            }
            .into());
        }
        let mut out = dims[..r - 1].to_vec();
        out.extend([dims[r - 1] / 2 + 1, 2]);
        Ok(Shape::from(out))
    }

    fn forward<T: Real>(&self, x: &[T], x_shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let dims = x_shape.dims();
        let spatial = &dims[dims.len() - self.ndim..];
        match T::DTYPE {
            DType::F32 => rfft_batch::<T, f32>(x, spatial, self.weights.as_deref(), out),
            _ => rfft_batch::<T, f64>(x, spatial, self.weights.as_deref(), out),
        }
    }
}

impl Op1 for Rfft {
    /// `grad_x = irfft(G w_kx N / c_kx)` (module docs; `w` real, so it passes through).
    fn backward(&self, x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        let dims = x.dims();
        let nx = dims[dims.len() - 1];
        let n = dims[dims.len() - self.ndim..].iter().product::<usize>() as f64;
        apply1(grad_y, Irfft { ndim: self.ndim, nx, weights: reweight(&self.weights, nx, |c| n / c) })
    }
}

/// The inverse real FFT over the last `ndim` axes, with `1/N`, to `nx` samples along `x`, of
/// the spectrum times `weights`: `x = irfft(w_kx z)`.
struct Irfft {
    ndim: usize,
    nx: usize,
    weights: Weights,
}

impl Kernel1 for Irfft {
    fn name(&self) -> &'static str {
        if self.ndim == 2 {
            "irfft2"
        } else {
            "irfft3"
        }
    }

    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        let dims = input.dims();
        let r = dims.len();
        let fits = r > self.ndim
            && dims[r - 1] == 2
            && dims[r - 2] == self.nx / 2 + 1
            && !dims[r - self.ndim - 1..r - 1].contains(&0);
        if !fits {
            return Err(Error::Shape {
                op: self.name(),
                arg: "z",
                expected: format!("{} with nx = {}", layout(self.ndim, true), self.nx),
                got: dims.to_vec(),
            }
            .into());
        }
        let mut out = dims[..r - 2].to_vec();
        out.push(self.nx);
        Ok(Shape::from(out))
    }

    fn forward<T: Real>(&self, z: &[T], z_shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let dims = z_shape.dims();
        let r = dims.len();
        let mut spatial = dims[r - 1 - self.ndim..r - 2].to_vec();
        spatial.push(self.nx);
        match T::DTYPE {
            DType::F32 => irfft_batch::<T, f32>(z, &spatial, self.weights.as_deref(), out),
            _ => irfft_batch::<T, f64>(z, &spatial, self.weights.as_deref(), out),
        }
    }
}

impl Op1 for Irfft {
    /// `grad_z = w_kx rfft(g) c_kx / N` (module docs).
    fn backward(&self, _z: &Tensor, x: &Tensor, grad_x: &Tensor) -> candle_core::Result<Tensor> {
        let dims = x.dims();
        let n = dims[dims.len() - self.ndim..].iter().product::<usize>() as f64;
        apply1(grad_x, Rfft { ndim: self.ndim, weights: reweight(&self.weights, self.nx, |c| c / n) })
    }
}

/// The float types the transforms run in (`f32`, `f64`), with exact conversions from and to
/// `f64` and a per-thread cache of FFT plans.
trait FftFloat: FftNum + num_traits::Float {
    fn of(v: f64) -> Self;
    fn wide(self) -> f64;
    /// Runs `f` with this thread's planners: a size is planned once per thread, then shared.
    fn with_planners<R>(f: impl FnOnce(&mut Planners<Self>) -> R) -> R;
}

/// realfft's and rustfft's planners, which cache their plans by length.
struct Planners<F: FftNum> {
    real: RealFftPlanner<F>,
    complex: FftPlanner<F>,
}

impl<F: FftNum> Planners<F> {
    fn new() -> Self {
        Self { real: RealFftPlanner::new(), complex: FftPlanner::new() }
    }
}

thread_local! {
    static PLANNERS_F32: RefCell<Planners<f32>> = RefCell::new(Planners::new());
    static PLANNERS_F64: RefCell<Planners<f64>> = RefCell::new(Planners::new());
}

impl FftFloat for f32 {
    fn of(v: f64) -> Self {
        v as f32
    }
    fn wide(self) -> f64 {
        self as f64
    }
    fn with_planners<R>(f: impl FnOnce(&mut Planners<Self>) -> R) -> R {
        PLANNERS_F32.with(|p| f(&mut p.borrow_mut()))
    }
}

impl FftFloat for f64 {
    fn of(v: f64) -> Self {
        v
    }
    fn wide(self) -> f64 {
        self
    }
    fn with_planners<R>(f: impl FnOnce(&mut Planners<Self>) -> R) -> R {
        PLANNERS_F64.with(|p| f(&mut p.borrow_mut()))
    }
}

/// One worker's buffers: the half spectrum of a slice, a transposition buffer for the passes
/// along the slower axes, one real row and the FFT scratch.
struct Work<F> {
    spec: Vec<Complex<F>>,
    lines: Vec<Complex<F>>,
    row: Vec<F>,
    scratch: Vec<Complex<F>>,
}

impl<F: FftFloat> Work<F> {
    fn new(spec_len: usize, nx: usize, scratch_len: usize) -> Self {
        let zero = Complex::new(F::zero(), F::zero());
        Self {
            spec: vec![zero; spec_len],
            lines: vec![zero; spec_len],
            row: vec![F::zero(); nx],
            scratch: vec![zero; scratch_len],
        }
    }
}

/// The complex FFTs along the slower axes `lead` (`[ny]` or `[nz, ny]`) of a half spectrum
/// `spec` laid out `[lead..., h]`. Each block of lines along one axis is transposed so that the
/// lines are contiguous, transformed in one call, and transposed back.
fn complex_passes<F: FftFloat>(
    spec: &mut [Complex<F>],
    lines: &mut [Complex<F>],
    scratch: &mut [Complex<F>],
    lead: &[usize],
    h: usize,
    ffts: &[Arc<dyn Fft<F>>],
) {
    for (a, fft) in ffts.iter().enumerate() {
        let n = lead[a];
        if n == 1 {
            continue;
        }
        // The block [n][stride] of every `outer` index, with `stride` the size of the faster axes.
        let stride: usize = lead[a + 1..].iter().product::<usize>() * h;
        let block = n * stride;
        let scratch = &mut scratch[..fft.get_inplace_scratch_len()];
        for blk in spec.chunks_mut(block) {
            let lines = &mut lines[..block];
            for (k, row) in blk.chunks(stride).enumerate() {
                for (i, &v) in row.iter().enumerate() {
                    lines[i * n + k] = v;
                }
            }
            fft.process_with_scratch(lines, scratch);
            for (k, row) in blk.chunks_mut(stride).enumerate() {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = lines[i * n + k];
                }
            }
        }
    }
}

fn fft_error(op: &'static str, e: realfft::FftError) -> candle_core::Error {
    candle_core::Error::msg(format!("{op}: internal FFT size error: {e}"))
}

/// Runs `work` over the `batch` slices of `input` (`in_len` each) and `out` (`out_len` each), in
/// parallel when there is more than one, with one [`Work`] per worker.
fn for_each_slice<T: Real, F: FftFloat>(
    input: &[T],
    in_len: usize,
    out: &mut [T],
    out_len: usize,
    new_work: impl Fn() -> Work<F> + Sync + Send,
    work: impl Fn(&[T], &mut [T], &mut Work<F>) -> candle_core::Result<()> + Sync + Send,
) -> candle_core::Result<()> {
    let batch = input.len() / in_len;
    // Slices in parallel only when there are several and the whole is big enough for the
    // process's thread policy (each slice is independent, so the numbers do not change).
    if batch > 1 && crate::threads::parallel(input.len()) {
        input
            .par_chunks(in_len)
            .zip(out.par_chunks_mut(out_len))
            .try_for_each_init(&new_work, |w, (i, o)| work(i, o, w))
    } else {
        let mut w = new_work();
        input.chunks(in_len).zip(out.chunks_mut(out_len)).try_for_each(|(i, o)| work(i, o, &mut w))
    }
}

/// [`Rfft`] in precision `F` over slices of `spatial` (`[ny, nx]` or `[nz, ny, nx]`).
fn rfft_batch<T: Real, F: FftFloat>(
    x: &[T],
    spatial: &[usize],
    weights: Option<&[f64]>,
    out: &mut [T],
) -> candle_core::Result<()> {
    let (lead, nx) = (&spatial[..spatial.len() - 1], spatial[spatial.len() - 1]);
    let h = nx / 2 + 1;
    let rows: usize = lead.iter().product();
    let (r2c, ffts) = F::with_planners(|p| {
        let ffts: Vec<_> = lead.iter().map(|&n| p.complex.plan_fft_forward(n)).collect();
        (p.real.plan_fft_forward(nx), ffts)
    });
    let scratch_len = ffts.iter().map(|f| f.get_inplace_scratch_len()).fold(r2c.get_scratch_len(), usize::max);
    let new_work = || Work::<F>::new(rows * h, nx, scratch_len);
    let work = |xs: &[T], os: &mut [T], w: &mut Work<F>| {
        let Work { spec, lines, row, scratch } = w;
        for (xr, sr) in xs.chunks(nx).zip(spec.chunks_mut(h)) {
            for (r, &v) in row.iter_mut().zip(xr) {
                *r = F::of(v.wide());
            }
            r2c.process_with_scratch(row, sr, &mut scratch[..r2c.get_scratch_len()])
                .map_err(|e| fft_error("rfft", e))?;
        }
        complex_passes(spec, lines, scratch, lead, h, &ffts);
        match weights {
            None => {
                for (o, s) in os.chunks_mut(2).zip(spec.iter()) {
                    o[0] = T::c(s.re.wide());
                    o[1] = T::c(s.im.wide());
                }
            }
            Some(w) => {
                for (or, sr) in os.chunks_mut(2 * h).zip(spec.chunks(h)) {
                    for ((o, s), &w) in or.chunks_mut(2).zip(sr).zip(w) {
                        o[0] = T::c(s.re.wide() * w);
                        o[1] = T::c(s.im.wide() * w);
                    }
                }
            }
        }
        Ok(())
    };
    for_each_slice(x, rows * nx, out, rows * h * 2, new_work, work)
}

/// [`Irfft`] in precision `F` to slices of `spatial` (`[ny, nx]` or `[nz, ny, nx]`).
fn irfft_batch<T: Real, F: FftFloat>(
    z: &[T],
    spatial: &[usize],
    weights: Option<&[f64]>,
    out: &mut [T],
) -> candle_core::Result<()> {
    let (lead, nx) = (&spatial[..spatial.len() - 1], spatial[spatial.len() - 1]);
    let h = nx / 2 + 1;
    let rows: usize = lead.iter().product();
    let inv_n = 1.0 / (rows * nx) as f64;
    let (c2r, ffts) = F::with_planners(|p| {
        let ffts: Vec<_> = lead.iter().map(|&n| p.complex.plan_fft_inverse(n)).collect();
        (p.real.plan_fft_inverse(nx), ffts)
    });
    let scratch_len = ffts.iter().map(|f| f.get_inplace_scratch_len()).fold(c2r.get_scratch_len(), usize::max);
    let new_work = || Work::<F>::new(rows * h, nx, scratch_len);
    let work = |zs: &[T], os: &mut [T], w: &mut Work<F>| {
        let Work { spec, lines, row, scratch } = w;
        match weights {
            None => {
                for (s, zc) in spec.iter_mut().zip(zs.chunks(2)) {
                    *s = Complex::new(F::of(zc[0].wide()), F::of(zc[1].wide()));
                }
            }
            Some(w) => {
                for (sr, zr) in spec.chunks_mut(h).zip(zs.chunks(2 * h)) {
                    for ((s, zc), &w) in sr.iter_mut().zip(zr.chunks(2)).zip(w) {
                        *s = Complex::new(F::of(zc[0].wide() * w), F::of(zc[1].wide() * w));
                    }
                }
            }
        }
        complex_passes(spec, lines, scratch, lead, h, &ffts);
        for (sr, or) in spec.chunks_mut(h).zip(os.chunks_mut(nx)) {
            // numpy's half-complex-to-real transform reads only the real parts here.
            sr[0].im = F::zero();
            if nx % 2 == 0 {
                sr[h - 1].im = F::zero();
            }
            c2r.process_with_scratch(sr, row, &mut scratch[..c2r.get_scratch_len()])
                .map_err(|e| fft_error("irfft", e))?;
            for (o, &v) in or.iter_mut().zip(row.iter()) {
                *o = T::c(v.wide() * inv_n);
            }
        }
        Ok(())
    };
    for_each_slice(z, rows * h * 2, out, rows * nx, new_work, work)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::GRAD_CHECK_F64;
    use crate::{check_grad, seed};
    use candle_core::Device;

    fn randn(shape: &[usize], s: u64) -> Tensor {
        seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
    }

    /// The weighted kernels are what the backward passes run, so their own backward (used when
    /// differentiating a backward) gets a finite-difference check too.
    #[test]
    fn weighted_kernels_pass_gradient_checks() {
        for (spatial, ndim) in [(vec![5usize, 6], 2), (vec![4, 7], 2), (vec![3, 4, 5], 3)] {
            let nx = spatial[spatial.len() - 1];
            let w: Weights = Some((0..nx / 2 + 1).map(|k| 0.5 + k as f64).collect());
            let (wf, wi) = (w.clone(), w.clone());
            let x = randn(&spatial, 1);
            let r = check_grad(|xs| apply1(&xs[0], Rfft { ndim, weights: wf.clone() }), &[x], &Default::default());
            let r = r.unwrap();
            r.ensure(GRAD_CHECK_F64).unwrap();
            let mut zs = spatial[..ndim - 1].to_vec();
            zs.extend([nx / 2 + 1, 2]);
            let z = randn(&zs, 2);
            let r = check_grad(|xs| apply1(&xs[0], Irfft { ndim, nx, weights: wi.clone() }), &[z], &Default::default());
            r.unwrap().ensure(GRAD_CHECK_F64).unwrap();
        }
    }
}
