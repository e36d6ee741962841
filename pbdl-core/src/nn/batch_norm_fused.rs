//! The fused CPU kernel behind [`super::batch_norm_train`] and [`super::batch_norm_eval`]:
//! batch normalisation, the per-channel affine map and an optional activation in one pass.
//!
//! The tensor is read as `[batch, channel, spatial]` (`spatial` the product of the trailing
//! dims, 1 for `[batch, channel]`); a channel's `n = batch * spatial` values lie in `batch`
//! contiguous slabs of `spatial` values. Per channel, with `xhat = (x - mean) * rstd`,
//! `rstd = 1 / sqrt(var + eps)`, `z = w xhat + b` and `y = act(z)`:
//!
//! * forward: the batch `mean` and biased `var` (two passes over `x`, accumulated in `f64`), or
//!   given statistics (eval mode); then one pass that writes `y`;
//! * backward, with `g = dy act'(z)` (the activation's derivative applied first):
//!   `db = sum(g)`, `dw = sum(g xhat)` and, with batch statistics,
//!   `dx = (w rstd / n) (n g - db - xhat dw)`; with given statistics (constants) `dx = w rstd g`.
//!
//! The activation's derivative is PyTorch's: `relu'(0) = 0`, `leaky_relu'(0) = slope` (the
//! kink is never hit by the finite-difference tests, and candle's composed `relu` uses 1 there).
//!
//! Work is split over rayon tasks by `(sample, channel)` slab (each slab a contiguous run of
//! `spatial` values, so every task writes its own slice of the output and no task needs
//! `unsafe` scattered writes); per-slab partial sums are added per channel in sample order, so
//! the result does not depend on the thread count. Small inputs run serially
//! ([`crate::threads::parallel`]).

use super::epilogue::Epilogue;
use super::fused::sum_f64;
use crate::op::{apply3, dense};
use crate::op::{Kernel3, Op3};
use crate::Real;
use candle_core::{DType, Shape, Storage, Tensor};
use rayon::prelude::*;
use std::borrow::Cow;
use std::sync::{Arc, OnceLock};

/// Slabs of one rayon task hold at least this many elements together.
const MIN_TASK: usize = 1 << 13;

/// Sizes of a batch norm problem read as `[batch, channel, spatial]`.
#[derive(Clone, Copy, Debug)]
struct Dims {
    channels: usize,
    spatial: usize,
    /// Number of slabs, `batch * channels`.
    slabs: usize,
    /// Values per channel, `batch * spatial`.
    count: usize,
}

fn dims(x: &Shape, channels_expected: Option<usize>) -> candle_core::Result<Dims> {
    let d = x.dims();
    if d.len() < 2 || channels_expected.is_some_and(|c| c != d[1]) {
        return Err(crate::Error::Shape {
            op: "batch_norm",
            arg: "x",
            expected: match channels_expected {
                Some(c) => format!("[batch, {c}, ..]"),
                None => "[batch, channel, ..]".into(),
            },
            got: d.to_vec(),
        }
        .into());
    }
    let spatial: usize = d[2..].iter().product();
    Ok(Dims { channels: d[1], spatial, slabs: d[0] * d[1], count: d[0] * spatial })
}

fn check_param(arg: &'static str, p: &Shape, channels: usize) -> candle_core::Result<()> {
    if p.dims() != [channels] {
        return Err(crate::Error::Shape {
            op: "batch_norm",
            arg,
            expected: format!("[{channels}]"),
            got: p.dims().to_vec(),
        }
        .into());
    }
    Ok(())
}

/// Per-channel statistics `[mean, biased variance]`, in `f64`.
pub(crate) type Stats = Vec<[f64; 2]>;

/// The fused op on `(x, weight, bias)`.
pub(crate) struct BatchNormOp {
    eps: f64,
    act: Epilogue,
    /// Eval mode: the statistics to normalise with (constants for the backward).
    given: Option<Stats>,
    /// Train mode: the batch statistics, set by the forward; shared with the caller, who
    /// updates the running statistics from them.
    batch: Arc<OnceLock<Stats>>,
}

/// Slabs per rayon task (at least [`MIN_TASK`] elements together).
fn min_len(d: Dims) -> usize {
    (MIN_TASK / d.spatial.max(1)).max(1)
}

/// One slab of the backward's first pass: its index, its `g` and slab sums, its `x` and `dy`.
type GradSlab<'a, T> = (usize, ((&'a mut [T], &'a mut [f64; 2]), (&'a [T], &'a [T])));

/// Runs `work(slab index, slab, out)` over the `(sample, channel)` slabs of `x` (each
/// `spatial` long), writing one value per slab into `out`; over rayon tasks when large.
fn per_slab<T: Real>(x: &[T], d: Dims, out: &mut [f64], work: impl Fn(usize, &[T]) -> f64 + Sync) {
    let f = |(k, (xs, o)): (usize, (&[T], &mut f64))| *o = work(k, xs);
    if d.slabs >= 2 && crate::threads::parallel(x.len()) {
        let min = min_len(d);
        x.par_chunks(d.spatial).zip(out.par_iter_mut()).enumerate().with_min_len(min).for_each(f);
    } else {
        x.chunks(d.spatial).zip(out.iter_mut()).enumerate().for_each(f);
    }
}

/// `sum_n part[n * channels + ch]` for every channel, in sample order.
fn per_channel(part: &[f64], channels: usize) -> Vec<f64> {
    let mut out = vec![0.0; channels];
    for row in part.chunks(channels) {
        for (o, p) in out.iter_mut().zip(row) {
            *o += p;
        }
    }
    out
}

/// The batch mean and biased variance of every channel (two-pass, in `f64`).
fn batch_stats<T: Real>(x: &[T], d: Dims) -> Stats {
    let mut part = vec![0.0; d.slabs];
    per_slab(x, d, &mut part, |_, xs| sum_f64(xs, |v| v.wide()));
    let inv_n = 1.0 / d.count as f64;
    let mean: Vec<f64> = per_channel(&part, d.channels).into_iter().map(|s| s * inv_n).collect();
    per_slab(x, d, &mut part, |k, xs| {
        let m = mean[k % d.channels];
        sum_f64(xs, |v| {
            let c = v.wide() - m;
            c * c
        })
    });
    let var = per_channel(&part, d.channels);
    mean.into_iter().zip(var).map(|(m, v)| [m, v * inv_n]).collect()
}

/// Writes `out[i] = f(k, i, x[i])` per slab `k`; over rayon tasks when large.
fn map_slabs<T: Real>(x: &[T], d: Dims, out: &mut [T], f: impl Fn(usize, &[T], &mut [T]) + Sync) {
    let run = |(k, (o, xs)): (usize, (&mut [T], &[T]))| f(k, xs, o);
    if d.slabs >= 2 && crate::threads::parallel(x.len()) {
        let min = min_len(d);
        out.par_chunks_mut(d.spatial).zip(x.par_chunks(d.spatial)).enumerate().with_min_len(min).for_each(run);
    } else {
        out.chunks_mut(d.spatial).zip(x.chunks(d.spatial)).enumerate().for_each(run);
    }
}

/// `y = act((x - m) scale + shift)` over one slab, the activation chosen outside the loop.
#[inline]
fn normalise<T: Real>(xs: &[T], ys: &mut [T], m: T, scale: T, shift: T, act: Epilogue) {
    let z = |x: T| (x - m) * scale + shift;
    match act {
        Epilogue::Identity => ys.iter_mut().zip(xs).for_each(|(y, &x)| *y = z(x)),
        Epilogue::Relu => ys.iter_mut().zip(xs).for_each(|(y, &x)| *y = z(x).fmax(T::zero())),
        Epilogue::LeakyRelu(a) => {
            let a = T::c(a);
            ys.iter_mut().zip(xs).for_each(|(y, &x)| {
                let z = z(x);
                *y = if z > T::zero() { z } else { z * a };
            })
        }
    }
}

/// `g = dy act'(z)` over one slab, written into `gs`; returns `[sum g, sum g (x - m)]`.
#[inline]
fn activation_grad<T: Real>(xs: &[T], gys: &[T], gs: &mut [T], m: T, scale: T, shift: T, act: Epilogue) -> [f64; 2] {
    let slope = match act {
        Epilogue::Identity => None,
        Epilogue::Relu => Some(T::zero()),
        Epilogue::LeakyRelu(a) => Some(T::c(a)),
    };
    let (mut s0, mut s1) = (0.0f64, 0.0f64);
    for ((g, &gy), &x) in gs.iter_mut().zip(gys).zip(xs) {
        let c = x - m;
        let v = match slope {
            None => gy,
            Some(a) => {
                if c * scale + shift > T::zero() {
                    gy
                } else {
                    gy * a
                }
            }
        };
        *g = v;
        s0 += v.wide();
        s1 += v.wide() * c.wide();
    }
    [s0, s1]
}

impl BatchNormOp {
    /// The op in train mode (batch statistics, returned through `batch`).
    pub(crate) fn train(eps: f64, act: Epilogue, batch: Arc<OnceLock<Stats>>) -> Self {
        Self { eps, act, given: None, batch }
    }

    /// The op in eval mode with the given `[mean, var]` per channel.
    pub(crate) fn eval(eps: f64, act: Epilogue, stats: Stats) -> Self {
        Self { eps, act, given: Some(stats), batch: Arc::new(OnceLock::new()) }
    }

    fn dims(&self, x: &Shape) -> candle_core::Result<Dims> {
        let d = dims(x, self.given.as_ref().map(Vec::len))?;
        if self.given.is_none() && d.count < 2 && d.slabs > 0 {
            return Err(crate::Error::invalid(
                "batch_norm",
                "x",
                format!(
                    "training mode needs more than one value per channel (batch x spatial), got shape {:?}; \
                     use a batch of 2 or more, or eval mode",
                    x.dims()
                ),
            )
            .into());
        }
        Ok(d)
    }

    /// Per channel `(mean, rstd, scale = w rstd, shift = b)`.
    fn coefficients<T: Real>(&self, stats: &[[f64; 2]], w: &[T], b: &[T]) -> Vec<[T; 4]> {
        stats
            .iter()
            .zip(w.iter().zip(b))
            .map(|(&[m, v], (&w, &b))| {
                let rstd = 1.0 / (v + self.eps).sqrt();
                [T::c(m), T::c(rstd), T::c(rstd * w.wide()), b]
            })
            .collect()
    }

    fn stats_for_backward<T: Real>(&self, x: &[T], d: Dims) -> Cow<'_, [[f64; 2]]> {
        match (&self.given, self.batch.get()) {
            (Some(s), _) | (None, Some(s)) => Cow::Borrowed(s.as_slice()),
            (None, None) => Cow::Owned(batch_stats(x, d)),
        }
    }

    fn backward_t<T: Real>(&self, x: &Tensor, w: &Tensor, b: &Tensor, gy: &Tensor) -> candle_core::Result<[Tensor; 3]> {
        let d = self.dims(x.shape())?;
        if gy.shape() != x.shape() {
            return Err(crate::Error::Shape {
                op: "batch_norm",
                arg: "grad",
                expected: format!("{:?}", x.dims()),
                got: gy.dims().to_vec(),
            }
            .into());
        }
        let (xs, xl) = x.storage_and_layout();
        let (gs, gl) = gy.storage_and_layout();
        let (ws, wl) = w.storage_and_layout();
        let (bs, bl) = b.storage_and_layout();
        let xd = dense::<T>(cpu(&xs)?, xl)?;
        let gd = dense::<T>(cpu(&gs)?, gl)?;
        let wd = dense::<T>(cpu(&ws)?, wl)?;
        let bd = dense::<T>(cpu(&bs)?, bl)?;
        let stats = self.stats_for_backward(&xd, d);
        let coef = self.coefficients(&stats, &wd, &bd);
        let mut gx = vec![T::zero(); xd.len()];
        let mut sums = vec![[0.0f64; 2]; d.slabs];
        if d.spatial > 0 {
            // Pass 1: g = dy act'(z) into gx, and the slab sums of g and g (x - mean).
            let act = self.act;
            let run = |(k, ((g, s), (xs, gys))): GradSlab<'_, T>| {
                let [m, _, scale, shift] = coef[k % d.channels];
                *s = activation_grad(xs, gys, g, m, scale, shift, act);
            };
            if d.slabs >= 2 && crate::threads::parallel(xd.len()) {
                let min = min_len(d);
                gx.par_chunks_mut(d.spatial)
                    .zip(sums.par_iter_mut())
                    .zip(xd.par_chunks(d.spatial).zip(gd.par_chunks(d.spatial)))
                    .enumerate()
                    .with_min_len(min)
                    .for_each(run);
            } else {
                gx.chunks_mut(d.spatial)
                    .zip(sums.iter_mut())
                    .zip(xd.chunks(d.spatial).zip(gd.chunks(d.spatial)))
                    .enumerate()
                    .for_each(run);
            }
        }
        let flat0: Vec<f64> = sums.iter().map(|s| s[0]).collect();
        let flat1: Vec<f64> = sums.iter().map(|s| s[1]).collect();
        let sum_g = per_channel(&flat0, d.channels);
        let sum_gc = per_channel(&flat1, d.channels);
        // dw = sum(g xhat) = rstd sum(g (x - mean)), db = sum(g).
        let gw: Vec<T> = sum_gc.iter().zip(stats.iter()).map(|(s, &[_, v])| T::c(s / (v + self.eps).sqrt())).collect();
        let gb: Vec<T> = sum_g.iter().map(|&s| T::c(s)).collect();
        if d.spatial > 0 {
            // Pass 2: dx = a g + c (x - mean) + off, with a = w rstd and, for batch statistics,
            // off = -a sum(g) / n, c = -a rstd dw / n (constants per channel).
            let inv_n = 1.0 / d.count as f64;
            let per_ch: Vec<[T; 4]> = (0..d.channels)
                .map(|ch| {
                    let [m, rstd, a, _] = coef[ch];
                    let (a64, r64) = (a.wide(), rstd.wide());
                    if self.given.is_some() {
                        [m, a, T::zero(), T::zero()]
                    } else {
                        let dw = sum_gc[ch] * r64;
                        [m, a, T::c(-a64 * r64 * dw * inv_n), T::c(-a64 * sum_g[ch] * inv_n)]
                    }
                })
                .collect();
            let given = self.given.is_some();
            let run = |(k, (g, xs)): (usize, (&mut [T], &[T]))| {
                let [m, a, c, off] = per_ch[k % d.channels];
                if given {
                    g.iter_mut().for_each(|g| *g *= a);
                } else {
                    for (g, &x) in g.iter_mut().zip(xs) {
                        *g = a * *g + c * (x - m) + off;
                    }
                }
            };
            if d.slabs >= 2 && crate::threads::parallel(xd.len()) {
                let min = min_len(d);
                gx.par_chunks_mut(d.spatial).zip(xd.par_chunks(d.spatial)).enumerate().with_min_len(min).for_each(run);
            } else {
                gx.chunks_mut(d.spatial).zip(xd.chunks(d.spatial)).enumerate().for_each(run);
            }
        }
        let dev = x.device();
        Ok([
            Tensor::from_vec(gx, x.shape(), dev)?,
            Tensor::from_vec(gw, d.channels, dev)?,
            Tensor::from_vec(gb, d.channels, dev)?,
        ])
    }
}

fn cpu(s: &Storage) -> candle_core::Result<&candle_core::CpuStorage> {
    match s {
        Storage::Cpu(s) => Ok(s),
        _ => Err(crate::Error::invalid("batch_norm", "x", "the fused batch norm runs on the CPU only").into()),
    }
}

impl Kernel3 for BatchNormOp {
    fn name(&self) -> &'static str {
        "batch_norm"
    }
    fn output_shape(&self, x: &Shape, w: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        let d = self.dims(x)?;
        check_param("weight", w, d.channels)?;
        check_param("bias", b, d.channels)?;
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
        let d = self.dims(shape)?;
        let stats = match &self.given {
            Some(s) => Cow::Borrowed(s.as_slice()),
            None if d.spatial == 0 || d.slabs == 0 => Cow::Owned(vec![[0.0, 1.0]; d.channels]),
            None => Cow::Owned(batch_stats(x, d)),
        };
        let coef = self.coefficients(&stats, w, b);
        if d.spatial > 0 {
            let act = self.act;
            map_slabs(x, d, y, |k, xs, ys| {
                let [m, _, scale, shift] = coef[k % d.channels];
                normalise(xs, ys, m, scale, shift, act);
            });
        }
        if self.given.is_none() {
            let _ = self.batch.set(stats.into_owned());
        }
        Ok(())
    }
}

impl Op3 for BatchNormOp {
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        b: &Tensor,
        _y: &Tensor,
        grad_y: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let [gx, gw, gb] = match x.dtype() {
            DType::F32 => self.backward_t::<f32>(x, w, b, grad_y)?,
            DType::F64 => self.backward_t::<f64>(x, w, b, grad_y)?,
            other => {
                return Err(
                    crate::Error::DType { op: "batch_norm", arg: "x", expected: "f32 or f64", got: other }.into()
                )
            }
        };
        Ok((gx, gw, gb))
    }
}

/// Applies the fused op to `x`, `weight`, `bias` (all given, one float dtype, CPU).
pub(crate) fn apply(x: &Tensor, weight: &Tensor, bias: &Tensor, op: BatchNormOp) -> candle_core::Result<Tensor> {
    apply3(x, weight, bias, op)
}
