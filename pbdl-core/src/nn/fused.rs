//! Fused CPU kernels behind [`super::group_norm`], [`super::activation::gelu_erf`],
//! [`super::activation::leaky_relu`] and [`super::activation::relu`].
//!
//! The composed versions (kept as [`super::group_norm_composed`] and
//! [`super::activation::gelu_erf_composed`]) are exact but make one pass over memory and one
//! fresh buffer per candle op, forward and backward (about 8 ops forward and 20 backward for a
//! group norm). The kernels here do the forward in two passes (statistics, then normalise and
//! apply the affine map) and the backward in two passes, with hand-written vector-Jacobian
//! products:
//!
//! * group norm, per (sample, group) with `n` elements, `xhat = (x - mean) * rstd`,
//!   `rstd = 1 / sqrt(var + eps)` (biased variance, two-pass, accumulated in `f64`):
//!   `dx = rstd * (dy w - mean(dy w) - xhat mean(dy w xhat))`, `dw = sum(dy xhat)`,
//!   `db = sum(dy)` (the sums over batch and space);
//! * GELU: `y = x Phi(x)`, `dy/dx = Phi(x) + x exp(-x^2 / 2) / sqrt(2 pi)` with
//!   `Phi(x) = (1 + erf(x / sqrt 2)) / 2` and constants to full `f64` precision.
//!
//! Both run on the CPU in `f32` and `f64` (other dtypes and devices take the composed path).
//! Their gradients are first-order (like all of candle's backward passes, which build no graph
//! of their own). Large inputs are split over rayon tasks: (sample, group) pairs for the norm,
//! chunks of [`CHUNK`] elements for GELU.
//!
//! Setting the environment variable `PBDL_NN_COMPOSED=1` (read once per process) routes both
//! functions to the composed versions; it exists for A/B timings of whole networks.

use super::epilogue::Epilogue;
use crate::op::{apply1, apply3, apply_kernel2, dense, Kernel1, Kernel2, Kernel3, Op1, Op3};
use crate::Real;
use candle_core::cpu::erf::{erf_f32, erf_f64};
use candle_core::{DType, Shape, Storage, Tensor};
use rayon::prelude::*;
use std::borrow::Cow;
use std::f64::consts::{FRAC_1_SQRT_2, FRAC_2_SQRT_PI};
use std::sync::OnceLock;

/// Elements per rayon task of the elementwise kernels; inputs under two chunks run serially.
const CHUNK: usize = 1 << 15;
/// Group norm inputs with fewer elements run serially (a rayon region costs a wake-up).
const PAR_NORM: usize = 1 << 15;

/// Whether a loop over `len` elements should be split over rayon tasks: at least two chunks of
/// `threshold / 2`, more than one thread to run them (with one, the hand-off to the pool only
/// costs), and large enough for the process's [`crate::threads`] policy.
fn parallel(len: usize, threshold: usize) -> bool {
    len >= threshold && crate::threads::parallel(len)
}

std::thread_local! {
    /// Set inside [`with_composed`] on this thread.
    static COMPOSED_HERE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether `PBDL_NN_COMPOSED=1` (read once) or [`with_composed`] asks for the composed versions.
fn composed_forced() -> bool {
    static FORCED: OnceLock<bool> = OnceLock::new();
    COMPOSED_HERE.with(|c| c.get())
        || *FORCED.get_or_init(|| std::env::var_os("PBDL_NN_COMPOSED").is_some_and(|v| v == "1"))
}

/// Runs `f` with every fused kernel (group norm, GELU, batch norm) replaced by its composed
/// candle-op version on this thread: the A/B switch for comparing a whole network's training
/// fused and unfused in one process (`PBDL_NN_COMPOSED=1` does it for a whole process). The
/// choice is made when the forward pass builds the graph, so run the backward pass of that
/// graph as usual, inside or outside.
///
/// ```
/// use candle_core::{Device, Tensor};
/// let x = Tensor::new(&[[-1.0f64, 0.5, 2.0]], &Device::Cpu)?;
/// let fused = pbdl_core::nn::activation::gelu_erf(&x)?;
/// let composed = pbdl_core::nn::with_composed(|| pbdl_core::nn::activation::gelu_erf(&x))?;
/// let diff = (fused - composed)?.abs()?.max_all()?.to_scalar::<f64>()?;
/// assert!(diff < 1e-15);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn with_composed<R>(f: impl FnOnce() -> R) -> R {
    /// Restores the previous setting also when `f` unwinds.
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            COMPOSED_HERE.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(COMPOSED_HERE.with(|c| c.replace(true)));
    f()
}

/// Whether fused kernels may be used at all here (not inside [`with_composed`], not with
/// `PBDL_NN_COMPOSED=1`); crates with fused kernels of their own ask this too.
pub fn fusion_enabled() -> bool {
    !composed_forced()
}

/// Whether the fused kernels handle `x`: CPU, `f32` or `f64`, and not switched off.
pub(crate) fn fusable(x: &Tensor) -> bool {
    x.device().is_cpu() && matches!(x.dtype(), DType::F32 | DType::F64) && !composed_forced()
}

/// `erf` in the precision of `T` (libm's `erff` / `erf`, the ones candle's `Tensor::erf` uses).
#[inline(always)]
fn erf<T: Real>(x: T) -> T {
    if T::DTYPE == DType::F32 {
        T::c(erf_f32(x.wide() as f32) as f64)
    } else {
        T::c(erf_f64(x.wide()))
    }
}

/// `1 / sqrt(2)`.
const RSQRT2: f64 = FRAC_1_SQRT_2;
/// `1 / sqrt(2 pi) = (2 / sqrt(pi)) / (2 sqrt(2))`.
const RSQRT_2PI: f64 = FRAC_2_SQRT_PI * FRAC_1_SQRT_2 * 0.5;

/// `out[i] = f(a[i])`, over rayon chunks when large.
fn map1<T: Real>(a: &[T], out: &mut [T], f: impl Fn(T) -> T + Sync) {
    let run = |(o, a): (&mut [T], &[T])| {
        for (o, &a) in o.iter_mut().zip(a) {
            *o = f(a);
        }
    };
    if parallel(out.len(), 2 * CHUNK) {
        out.par_chunks_mut(CHUNK).zip(a.par_chunks(CHUNK)).for_each(run);
    } else {
        run((out, a));
    }
}

/// `out[i] = f(a[i], b[i])`, over rayon chunks when large.
fn map2<T: Real>(a: &[T], b: &[T], out: &mut [T], f: impl Fn(T, T) -> T + Sync) {
    let run = |((o, a), b): ((&mut [T], &[T]), &[T])| {
        for ((o, &a), &b) in o.iter_mut().zip(a).zip(b) {
            *o = f(a, b);
        }
    };
    if parallel(out.len(), 2 * CHUNK) {
        out.par_chunks_mut(CHUNK).zip(a.par_chunks(CHUNK)).zip(b.par_chunks(CHUNK)).for_each(run);
    } else {
        run(((out, a), b));
    }
}

fn same_shape(op: &'static str, a: &Shape, b: &Shape) -> candle_core::Result<()> {
    if a != b {
        return Err(crate::Error::Shape {
            op,
            arg: "grad",
            expected: format!("{:?}", a.dims()),
            got: b.dims().to_vec(),
        }
        .into());
    }
    Ok(())
}

// ---------------------------------------------------------------- GELU (erf)

/// `0.5 x (1 + erf(x / sqrt 2))`, elementwise. When the input is tracked for backprop, the
/// forward also stores the derivative (one `exp` per element more), so that the backward is a
/// single multiplication rather than another `erf` per element.
struct GeluErf {
    keep_derivative: bool,
    derivative: OnceLock<Tensor>,
}

impl Kernel1 for GeluErf {
    fn name(&self) -> &'static str {
        "gelu_erf"
    }
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        Ok(input.clone())
    }
    fn forward<T: Real>(&self, x: &[T], shape: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        let (r2, r2pi, half, one) = (T::c(RSQRT2), T::c(RSQRT_2PI), T::c(0.5), T::one());
        if !self.keep_derivative {
            map1(x, y, |x| (erf(x * r2) + one) * x * half);
            return Ok(());
        }
        let mut d = vec![T::zero(); x.len()];
        let run = |((y, d), x): ((&mut [T], &mut [T]), &[T])| {
            // The density factor first, in a loop that vectorises (vmath's exp, not libm's
            // scalar call); erf stays libm's, so the values equal candle's.
            crate::vmath::with_simd(
                #[inline(always)]
                || {
                    for (d, &x) in d.iter_mut().zip(x) {
                        *d = x * crate::vmath::exp(-(x * x) * half) * r2pi;
                    }
                },
            );
            for ((y, d), &x) in y.iter_mut().zip(d.iter_mut()).zip(x) {
                let cdf = (erf(x * r2) + one) * half;
                *y = cdf * x;
                *d += cdf;
            }
        };
        if parallel(y.len(), 2 * CHUNK) {
            y.par_chunks_mut(CHUNK).zip(d.par_chunks_mut(CHUNK)).zip(x.par_chunks(CHUNK)).for_each(run);
        } else {
            run(((y, &mut d), x));
        }
        let _ = self.derivative.set(Tensor::from_vec(d, shape.clone(), &candle_core::Device::Cpu)?);
        Ok(())
    }
}

impl Op1 for GeluErf {
    fn backward(&self, x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        match self.derivative.get() {
            Some(d) => grad_y.mul(d),
            None => apply_kernel2(x, grad_y, GeluErfGrad),
        }
    }
}

/// `grad_y * (Phi(x) + x phi(x))`, the vector-Jacobian product of [`GeluErf`].
struct GeluErfGrad;

impl Kernel2 for GeluErfGrad {
    fn name(&self) -> &'static str {
        "gelu_erf_grad"
    }
    fn output_shape(&self, x: &Shape, gy: &Shape) -> candle_core::Result<Shape> {
        same_shape("gelu_erf_grad", x, gy)?;
        Ok(x.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _: &Shape, gy: &[T], _: &Shape, gx: &mut [T]) -> candle_core::Result<()> {
        let (r2, r2pi, half, one) = (T::c(RSQRT2), T::c(RSQRT_2PI), T::c(0.5), T::one());
        map2(x, gy, gx, |x, gy| {
            let cdf = (erf(x * r2) + one) * half;
            let pdf = (-(x * x) * half).exp() * r2pi;
            gy * (cdf + x * pdf)
        });
        Ok(())
    }
}

/// Fused `gelu_erf` (caller checked [`fusable`]).
pub(crate) fn gelu_erf(x: &Tensor) -> candle_core::Result<Tensor> {
    apply1(x, GeluErf { keep_derivative: x.track_op(), derivative: OnceLock::new() })
}

// ---------------------------------------------------------------- leaky ReLU

/// `x` for `x > 0`, `slope x` otherwise, elementwise: one pass each way instead of the five
/// buffers forward (zeros, maximum, minimum, scale, add) and about ten backward of the composed
/// version. The gradient at exactly 0 is the mean of both slopes, as the composed version's.
struct LeakyRelu {
    slope: f64,
}

impl Kernel1 for LeakyRelu {
    fn name(&self) -> &'static str {
        "leaky_relu"
    }
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        Ok(input.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        let s = T::c(self.slope);
        map1(x, y, |x| if x > T::zero() { x } else { x * s });
        Ok(())
    }
}

impl Op1 for LeakyRelu {
    fn backward(&self, x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, grad_y, LeakyReluGrad { slope: self.slope })
    }
}

/// `grad_y * (1, slope or (1 + slope) / 2 at 0)`, the vector-Jacobian product of [`LeakyRelu`].
struct LeakyReluGrad {
    slope: f64,
}

impl Kernel2 for LeakyReluGrad {
    fn name(&self) -> &'static str {
        "leaky_relu_grad"
    }
    fn output_shape(&self, x: &Shape, gy: &Shape) -> candle_core::Result<Shape> {
        same_shape("leaky_relu_grad", x, gy)?;
        Ok(x.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _: &Shape, gy: &[T], _: &Shape, gx: &mut [T]) -> candle_core::Result<()> {
        let (s, half) = (T::c(self.slope), T::c(0.5));
        map2(x, gy, gx, |x, gy| {
            if x > T::zero() {
                gy
            } else if x < T::zero() {
                gy * s
            } else {
                // Half of each branch, summed in the composed version's order.
                gy * half + gy * s * half
            }
        });
        Ok(())
    }
}

/// Fused `leaky_relu` (caller checked [`fusable`]).
pub(crate) fn leaky_relu(x: &Tensor, slope: f64) -> candle_core::Result<Tensor> {
    apply1(x, LeakyRelu { slope })
}

// ---------------------------------------------------------------- ReLU

/// `max(x, 0)` elementwise with a one-pass backward `grad_y * [x >= 0]` (candle's own rule,
/// gradient 1 at 0), instead of candle's backward of a comparison, a cast and a product.
struct Relu;

impl Kernel1 for Relu {
    fn name(&self) -> &'static str {
        "relu"
    }
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        Ok(input.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        map1(x, y, |x| if x > T::zero() { x } else { T::zero() });
        Ok(())
    }
}

impl Op1 for Relu {
    fn backward(&self, x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, grad_y, ReluGrad)
    }
}

/// `grad_y * [x >= 0]`, the vector-Jacobian product of [`Relu`].
struct ReluGrad;

impl Kernel2 for ReluGrad {
    fn name(&self) -> &'static str {
        "relu_grad"
    }
    fn output_shape(&self, x: &Shape, gy: &Shape) -> candle_core::Result<Shape> {
        same_shape("relu_grad", x, gy)?;
        Ok(x.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _: &Shape, gy: &[T], _: &Shape, gx: &mut [T]) -> candle_core::Result<()> {
        // The product (not a select) keeps candle's NaN and signed-zero results.
        map2(x, gy, gx, |x, gy| gy * if x >= T::zero() { T::one() } else { T::zero() });
        Ok(())
    }
}

/// Fused `relu` (caller checked [`fusable`]).
pub(crate) fn relu(x: &Tensor) -> candle_core::Result<Tensor> {
    apply1(x, Relu)
}

// ---------------------------------------------------------------- group norm

/// Group norm of `[batch, channel, ..]`; the per-(sample, group) `[mean, rstd]` of the forward
/// are kept for the backward.
struct GroupNormOp {
    groups: usize,
    eps: f64,
    /// Activation applied to the normalised output (its derivative is read off the output).
    epilogue: Epilogue,
    stats: OnceLock<Vec<[f64; 2]>>,
}

/// One (sample, group) of the group norm backward: its index, its slice of `gx`, and its
/// channels' slices of the weight and bias gradient sums.
type GradTask<'a, T> = (usize, ((&'a mut [T], &'a mut [f64]), &'a mut [f64]));

/// Sizes of a group norm problem.
#[derive(Clone, Copy)]
struct Dims {
    channels: usize,
    /// Channels per group.
    cpg: usize,
    /// Elements per channel (product of the spatial dims).
    spatial: usize,
    /// Elements per (sample, group).
    group: usize,
    /// Number of (sample, group) pairs.
    tasks: usize,
}

impl GroupNormOp {
    fn new(groups: usize, eps: f64, epilogue: Epilogue) -> Self {
        Self { groups, eps, epilogue, stats: OnceLock::new() }
    }

    fn dims(&self, x: &Shape) -> candle_core::Result<Dims> {
        let d = x.dims();
        if d.len() < 2 || self.groups == 0 || d[1] % self.groups != 0 {
            return Err(crate::Error::Shape {
                op: "group_norm",
                arg: "x",
                expected: format!("[batch, channel, ..] with channel divisible by {}", self.groups),
                got: d.to_vec(),
            }
            .into());
        }
        let spatial: usize = d[2..].iter().product();
        let cpg = d[1] / self.groups;
        Ok(Dims { channels: d[1], cpg, spatial, group: cpg * spatial, tasks: d[0] * self.groups })
    }

    fn check_param(&self, arg: &'static str, p: &Shape, channels: usize) -> candle_core::Result<()> {
        if p.dims() != [channels] {
            return Err(crate::Error::Shape {
                op: "group_norm",
                arg,
                expected: format!("[{channels}]"),
                got: p.dims().to_vec(),
            }
            .into());
        }
        Ok(())
    }

    /// The forward pass; `params` are the per-channel weight and bias.
    fn run<T: Real>(&self, x: &[T], d: Dims, params: Option<(&[T], &[T])>, y: &mut [T]) {
        let mut stats = vec![[0.0f64; 2]; d.tasks];
        if d.group > 0 {
            let work = |(k, (y, st)): (usize, (&mut [T], &mut [f64; 2]))| {
                let xs = &x[k * d.group..(k + 1) * d.group];
                let inv_n = 1.0 / d.group as f64;
                let mean = sum_f64(xs, |v| v.wide()) * inv_n;
                let var = sum_f64(xs, |v| {
                    let c = v.wide() - mean;
                    c * c
                }) * inv_n;
                let rstd = 1.0 / (var + self.eps).sqrt();
                *st = [mean, rstd];
                let g = k % self.groups;
                let m = T::c(mean);
                for ci in 0..d.cpg {
                    let ch = g * d.cpg + ci;
                    let (w, b) = params.map_or((1.0, 0.0), |(w, b)| (w[ch].wide(), b[ch].wide()));
                    let (scale, shift) = (T::c(rstd * w), T::c(b));
                    let range = ci * d.spatial..(ci + 1) * d.spatial;
                    for (y, &x) in y[range.clone()].iter_mut().zip(&xs[range.clone()]) {
                        *y = (x - m) * scale + shift;
                    }
                    self.epilogue.activate(&mut y[range]);
                }
            };
            if d.tasks >= 2 && parallel(y.len(), PAR_NORM) {
                y.par_chunks_mut(d.group).zip(stats.par_iter_mut()).enumerate().for_each(work);
            } else {
                y.chunks_mut(d.group).zip(stats.iter_mut()).enumerate().for_each(work);
            }
        }
        let _ = self.stats.set(stats);
    }

    /// The backward pass: `gx`, and the per-sample channel sums `[sum dy xhat, sum dy]`
    /// (`[batch, channel]` each) that add up to the weight and bias gradients.
    fn grad<T: Real>(&self, x: &[T], gy: &[T], d: Dims, w: Option<&[T]>, gx: &mut [T]) -> (Vec<f64>, Vec<f64>) {
        let stats: Cow<[[f64; 2]]> = match self.stats.get() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(self.recompute_stats(x, d)),
        };
        let mut gw = vec![0.0f64; d.tasks * d.cpg];
        let mut gb = vec![0.0f64; d.tasks * d.cpg];
        if d.group == 0 {
            return (gw, gb);
        }
        let work = |(k, ((gx, gw), gb)): GradTask<'_, T>| {
            let range = k * d.group..(k + 1) * d.group;
            let (xs, gys) = (&x[range.clone()], &gy[range]);
            let [mean, rstd] = stats[k];
            let g = k % self.groups;
            // Pass 1: per-channel sums of dy and dy (x - mean).
            let (mut s1, mut s2) = (0.0, 0.0);
            for ci in 0..d.cpg {
                let ch = g * d.cpg + ci;
                let r = ci * d.spatial..(ci + 1) * d.spatial;
                let sum_gy = sum_f64(&gys[r.clone()], |v| v.wide());
                let sum_gyx = sum2_f64(&gys[r.clone()], &xs[r], |gy, x| gy.wide() * (x.wide() - mean));
                gb[ci] = sum_gy;
                gw[ci] = sum_gyx * rstd;
                let wc = w.map_or(1.0, |w| w[ch].wide());
                s1 += wc * sum_gy;
                s2 += wc * sum_gyx * rstd;
            }
            let inv_n = 1.0 / d.group as f64;
            let (mean1, mean2) = (s1 * inv_n, s2 * inv_n);
            // Pass 2: dx = rstd (dy w - mean1) - (x - mean) rstd^2 mean2.
            let c = T::c(-rstd * rstd * mean2);
            let off = T::c(-rstd * mean1);
            let m = T::c(mean);
            for ci in 0..d.cpg {
                let ch = g * d.cpg + ci;
                let a = T::c(rstd * w.map_or(1.0, |w| w[ch].wide()));
                let r = ci * d.spatial..(ci + 1) * d.spatial;
                for ((gx, &gy), &x) in gx[r.clone()].iter_mut().zip(&gys[r.clone()]).zip(&xs[r]) {
                    *gx = a * gy + c * (x - m) + off;
                }
            }
        };
        if d.tasks >= 2 && parallel(gx.len(), PAR_NORM) {
            gx.par_chunks_mut(d.group)
                .zip(gw.par_chunks_mut(d.cpg))
                .zip(gb.par_chunks_mut(d.cpg))
                .enumerate()
                .for_each(work);
        } else {
            gx.chunks_mut(d.group).zip(gw.chunks_mut(d.cpg)).zip(gb.chunks_mut(d.cpg)).enumerate().for_each(work);
        }
        (gw, gb)
    }

    /// The statistics of the forward pass, should they be missing.
    fn recompute_stats<T: Real>(&self, x: &[T], d: Dims) -> Vec<[f64; 2]> {
        (0..d.tasks)
            .map(|k| {
                let xs = &x[k * d.group..(k + 1) * d.group];
                let inv_n = 1.0 / d.group.max(1) as f64;
                let mean = sum_f64(xs, |v| v.wide()) * inv_n;
                let var = sum_f64(xs, |v| (v.wide() - mean).powi(2)) * inv_n;
                [mean, 1.0 / (var + self.eps).sqrt()]
            })
            .collect()
    }

    /// All gradients as tensors: `gx`, and `[gw, gb]` summed over the batch when `weight` is
    /// given (the affine form).
    fn backward_t<T: Real>(
        &self,
        x: &Tensor,
        weight: Option<&Tensor>,
        grad_y: &Tensor,
    ) -> candle_core::Result<(Tensor, Option<[Tensor; 2]>)> {
        let d = self.dims(x.shape())?;
        same_shape("group_norm", x.shape(), grad_y.shape())?;
        let (xs, xl) = x.storage_and_layout();
        let (gs, gl) = grad_y.storage_and_layout();
        let xd = dense::<T>(cpu(&xs)?, xl)?;
        let gd = dense::<T>(cpu(&gs)?, gl)?;
        let wguard = weight.map(|w| w.storage_and_layout());
        let wd = match &wguard {
            Some((ws, wl)) => Some(dense::<T>(cpu(ws)?, wl)?),
            None => None,
        };
        let mut gx = vec![T::zero(); xd.len()];
        let (gw, gb) = self.grad(&xd, &gd, d, wd.as_deref(), &mut gx);
        let gx = Tensor::from_vec(gx, x.shape(), x.device())?;
        if weight.is_none() {
            return Ok((gx, None));
        }
        // Sum the per-sample channel sums over the batch.
        let batch = d.tasks / self.groups;
        let reduce = |part: &[f64]| -> Vec<T> {
            (0..d.channels).map(|ch| T::c((0..batch).map(|n| part[n * d.channels + ch]).sum::<f64>())).collect()
        };
        let gw = Tensor::from_vec(reduce(&gw), d.channels, x.device())?;
        let gb = Tensor::from_vec(reduce(&gb), d.channels, x.device())?;
        Ok((gx, Some([gw, gb])))
    }

    fn backward_any(
        &self,
        x: &Tensor,
        weight: Option<&Tensor>,
        grad_y: &Tensor,
    ) -> candle_core::Result<(Tensor, Option<[Tensor; 2]>)> {
        match x.dtype() {
            DType::F32 => self.backward_t::<f32>(x, weight, grad_y),
            DType::F64 => self.backward_t::<f64>(x, weight, grad_y),
            other => Err(crate::Error::DType { op: "group_norm", arg: "x", expected: "f32 or f64", got: other }.into()),
        }
    }
}

fn cpu(s: &Storage) -> candle_core::Result<&candle_core::CpuStorage> {
    match s {
        Storage::Cpu(s) => Ok(s),
        _ => Err(crate::Error::invalid("group_norm", "x", "the fused group norm runs on the CPU only").into()),
    }
}

/// `sum f(x_i)` in `f64` over 4 lanes (so the loop vectorises). Shared with the batch norm
/// kernel.
#[inline]
pub(super) fn sum_f64<T: Real>(xs: &[T], f: impl Fn(T) -> f64) -> f64 {
    let mut acc = [0.0f64; 4];
    let chunks = xs.chunks_exact(4);
    let tail = chunks.remainder();
    for c in chunks {
        for k in 0..4 {
            acc[k] += f(c[k]);
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for &v in tail {
        s += f(v);
    }
    s
}

/// `sum f(a_i, b_i)` in `f64` over 4 lanes.
#[inline]
fn sum2_f64<T: Real>(a: &[T], b: &[T], f: impl Fn(T, T) -> f64) -> f64 {
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ta, tb) = (ca.remainder(), cb.remainder());
    for (ca, cb) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += f(ca[k], cb[k]);
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (&a, &b) in ta.iter().zip(tb) {
        s += f(a, b);
    }
    s
}

/// Group norm without affine parameters.
struct GroupNormPlain(GroupNormOp);

impl Kernel1 for GroupNormPlain {
    fn name(&self) -> &'static str {
        "group_norm"
    }
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        self.0.dims(input)?;
        Ok(input.clone())
    }
    fn forward<T: Real>(&self, x: &[T], shape: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        let d = self.0.dims(shape)?;
        self.0.run(x, d, None, y);
        Ok(())
    }
}

impl Op1 for GroupNormPlain {
    fn backward(&self, x: &Tensor, y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        Ok(self.0.backward_any(x, None, &self.0.epilogue.pre_activation_grad(y, grad_y)?)?.0)
    }
}

/// Group norm with per-channel weight and bias.
struct GroupNormAffine(GroupNormOp);

impl Kernel3 for GroupNormAffine {
    fn name(&self) -> &'static str {
        "group_norm"
    }
    fn output_shape(&self, x: &Shape, w: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        let d = self.0.dims(x)?;
        self.0.check_param("weight", w, d.channels)?;
        self.0.check_param("bias", b, d.channels)?;
        Ok(x.clone())
    }
    fn forward<T: Real>(
        &self,
        x: &[T],
        shape: &Shape,
        w: &[T],
        _: &Shape,
        b: &[T],
        _: &Shape,
        y: &mut [T],
    ) -> candle_core::Result<()> {
        let d = self.0.dims(shape)?;
        self.0.run(x, d, Some((w, b)), y);
        Ok(())
    }
}

impl Op3 for GroupNormAffine {
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        y: &Tensor,
        grad_y: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let (gx, params) = self.0.backward_any(x, Some(w), &self.0.epilogue.pre_activation_grad(y, grad_y)?)?;
        let [gw, gb] = params.expect("the affine backward returns parameter gradients");
        Ok((gx, gw, gb))
    }
}

/// Fused group norm followed by the activation `epilogue` (caller checked [`fusable`] and the
/// arguments). A missing weight is ones, a missing bias zeros, when the other one is given.
pub(crate) fn group_norm(
    x: &Tensor,
    groups: usize,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    epilogue: Epilogue,
) -> candle_core::Result<Tensor> {
    let op = GroupNormOp::new(groups, eps, epilogue);
    match (weight, bias) {
        (None, None) => apply1(x, GroupNormPlain(op)),
        (w, b) => {
            let c = x.dim(1)?;
            let w = match w {
                Some(w) => w.clone(),
                None => Tensor::ones(c, x.dtype(), x.device())?,
            };
            let b = match b {
                Some(b) => b.clone(),
                None => Tensor::zeros(c, x.dtype(), x.device())?,
            };
            apply3(x, &w, &b, GroupNormAffine(op))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference values of erf (Abramowitz & Stegun table 7.1 / high-precision evaluations).
    #[test]
    fn erf_matches_reference_values() {
        let cases = [
            (0.0, 0.0),
            (0.1, 0.1124629160182849),
            (0.5, 0.5204998778130465),
            (1.0, 0.8427007929497149),
            (1.5, 0.9661051464753108),
            (2.0, 0.9953222650189527),
            (3.0, 0.9999779095030014),
            (-0.7, -0.6778011938374184),
        ];
        for (x, e) in cases {
            let v = erf::<f64>(x);
            assert!((v - e).abs() <= 2e-16 * e.abs().max(1e-300) + 1e-300, "erf({x}) = {v}, expected {e}");
            let v32 = erf::<f32>(x as f32) as f64;
            assert!((v32 - e).abs() <= 2e-7, "erff({x}) = {v32}, expected {e}");
        }
        assert!((RSQRT_2PI - 0.398_942_280_401_432_7).abs() < 1e-17);
    }

    /// The backward without a stored derivative (the `erf` recomputed) gives the same gradient
    /// as the one with it, in both precisions.
    #[test]
    fn gelu_backward_with_and_without_stored_derivative_agree() {
        for dtype in [DType::F64, DType::F32] {
            let x = crate::seed::randn((5, 7), 0.0, 2.0, dtype, &candle_core::Device::Cpu, 3).unwrap();
            let x = candle_core::Var::from_tensor(&x).unwrap();
            let grad = |keep: bool| {
                let op = GeluErf { keep_derivative: keep, derivative: OnceLock::new() };
                let y = apply1(x.as_tensor(), op).unwrap();
                let g = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
                g.get(x.as_tensor()).unwrap().to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>()
            };
            let (a, b) = (grad(true).unwrap(), grad(false).unwrap());
            let tol = if dtype == DType::F64 { 1e-15 } else { 1e-6 };
            for (a, b) in a.iter().zip(&b) {
                assert!((a - b).abs() <= tol * b.abs().max(1.0), "{dtype:?}: {a} vs {b}");
            }
        }
    }
}
