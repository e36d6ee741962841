//! Direct kernels for depthwise convolutions: one input and one output channel per group
//! (`groups == in_channels == out_channels`, e.g. the 7x7 convolution that opens a ConvNeXt
//! block).
//!
//! The im2col path would build a `[taps x positions]` matrix per (image, channel) and multiply
//! it by a single row of weights, which is almost all data movement. Here each (image, channel)
//! unit is copied once into a padded scratch plane (zero or periodic border), after which every
//! kernel tap reads a plain shifted window with no boundary tests. Output lines are computed in
//! blocks of `L` values that stay in registers while all taps are added, so the inner loop is a
//! fixed-length multiply-add that the compiler vectorises.
//!
//! * forward: `y[o] = sum_t w[t] xp[o s + t d]` (`xp` the padded input);
//! * input gradient, stride 1: the same correlation of the zero-padded output gradient with the
//!   flipped kernel, then the padded plane is folded back onto the input (cropped for zero
//!   padding, wrapped and summed for periodic padding); other strides scatter into the plane;
//! * weight gradient: per channel, `gw[t] = sum_{b, o} gy[b, o] xp_b[o s + t d]`, accumulated in
//!   [`LANES`] register lanes per tap and summed at the end (the order is fixed, so results do
//!   not depend on scheduling);
//! * bias: with a bias, [`conv_bias_tensor`] starts every output sum at it, and its gradient is
//!   one pass over the output gradient ([`channel_sum`]), instead of candle's broadcast add and
//!   reduction.
//!
//! Every stride, padding (zero or periodic) and dilation is handled; the dispatch in
//! `forward.rs`/`backward.rs`/`mod.rs` sends all depthwise geometries here unless
//! `Geometry::direct` is off (environment `PBDL_CONV_DIRECT=0`, or the hidden
//! `conv::conv_im2col` that tests and benches compare with). Units of work are (image,
//! channel) pairs for the forward and input gradient, channels for the weight and bias
//! gradients, all in parallel with rayon. The kernels are compiled twice: for baseline x86-64
//! and, chosen at run time, for AVX2 with fused multiply-adds.

use super::backward::{grad_input_tensor, grad_weight_tensor};
use super::geometry::{expect_shape, Geometry};
use crate::op::{apply1, apply3, grad_if_tracked, Kernel1, Kernel3, Op1, Op3};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;
use std::sync::OnceLock;

/// Marks a padded position with no source (zero padding).
const OUTSIDE: usize = usize::MAX;

/// Whether new geometries use the direct kernels: yes unless the environment variable
/// `PBDL_CONV_DIRECT` is `0` (read once; a switch for before/after timings).
pub(crate) fn direct_by_default() -> bool {
    static DIRECT: OnceLock<bool> = OnceLock::new();
    *DIRECT.get_or_init(|| std::env::var("PBDL_CONV_DIRECT").map_or(true, |v| v.trim() != "0"))
}

/// Whether the direct kernels handle `g`: one input and one output channel per group.
pub(crate) fn handles(g: &Geometry) -> bool {
    g.direct && g.cin_g() == 1 && g.cout_g() == 1
}

/// The padded plane of one channel: sizes and, per axis, the source index of each padded
/// position ([`OUTSIDE`] where zero padding applies).
pub(super) struct Padding {
    input: [usize; 3],
    pad: [usize; 3],
    /// Padded spatial size `[Dp, Hp, Wp]`.
    pub(super) dims: [usize; 3],
    /// `maps[a][i]`: input index of padded position `i` along axis `a`, or [`OUTSIDE`].
    maps: [Vec<usize>; 3],
}

impl Padding {
    pub(super) fn new(g: &Geometry) -> Self {
        let map = |a: usize| -> Vec<usize> {
            let (n, p) = (g.input[a] as isize, g.padding[a] as isize);
            (0..n + 2 * p)
                .map(|i| {
                    let s = i - p;
                    if (0..n).contains(&s) {
                        s as usize
                    } else if g.circular[a] {
                        s.rem_euclid(n) as usize
                    } else {
                        OUTSIDE
                    }
                })
                .collect()
        };
        let dims = [0, 1, 2].map(|a| g.input[a] + 2 * g.padding[a]);
        Padding { input: g.input, pad: g.padding, dims, maps: [map(0), map(1), map(2)] }
    }

    /// Elements of one padded channel.
    pub(super) fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// Fills the padded plane `xp` from the channel `x`.
    pub(super) fn fill<T: Real>(&self, x: &[T], xp: &mut [T]) {
        let [_, h, w] = self.input;
        let [_, ph, pw] = self.dims;
        let px = self.pad[2];
        for (r, dst) in xp[..self.len()].chunks_exact_mut(pw).enumerate() {
            let (sz, sy) = (self.maps[0][r / ph], self.maps[1][r % ph]);
            if sz == OUTSIDE || sy == OUTSIDE {
                dst.fill(T::zero());
                continue;
            }
            let src = &x[(sz * h + sy) * w..][..w];
            dst[px..px + w].copy_from_slice(src);
            for j in (0..px).chain(px + w..pw) {
                let s = self.maps[2][j];
                dst[j] = if s == OUTSIDE { T::zero() } else { src[s] };
            }
        }
    }

    /// The adjoint of [`Padding::fill`]: adds every padded value to the input position it was
    /// read from.
    pub(super) fn fold<T: Real>(&self, xp: &[T], gx: &mut [T]) {
        let [_, h, w] = self.input;
        let [_, ph, pw] = self.dims;
        let px = self.pad[2];
        for (r, src) in xp[..self.len()].chunks_exact(pw).enumerate() {
            let (sz, sy) = (self.maps[0][r / ph], self.maps[1][r % ph]);
            if sz == OUTSIDE || sy == OUTSIDE {
                continue;
            }
            let dst = &mut gx[(sz * h + sy) * w..][..w];
            for (d, &v) in dst.iter_mut().zip(&src[px..px + w]) {
                *d += v;
            }
            for j in (0..px).chain(px + w..pw) {
                let s = self.maps[2][j];
                if s != OUTSIDE {
                    dst[s] += src[j];
                }
            }
        }
    }
}

/// A valid correlation on a dense 3D plane `src` of size `src_dims`:
/// `out[o] = bias + sum_t w[t] src[origin + o * stride + t * dilation]` for `o < out_dims`.
#[derive(Clone, Copy)]
struct Window {
    src_dims: [usize; 3],
    out_dims: [usize; 3],
    origin: [usize; 3],
    kernel: [usize; 3],
    stride: [usize; 3],
    dilation: [usize; 3],
}

impl Window {
    /// Index in `src` of tap `(tz, ty)`, first x position of output line `(oz, oy)` at `ox`.
    #[inline(always)]
    fn base(&self, oz: usize, oy: usize, ox: usize, tz: usize, ty: usize) -> usize {
        let [o, s, d] = [self.origin, self.stride, self.dilation];
        let z = o[0] + oz * s[0] + tz * d[0];
        let y = o[1] + oy * s[1] + ty * d[1];
        (z * self.src_dims[1] + y) * self.src_dims[2] + o[2] + ox * s[2]
    }

    /// Panics unless every index the window reads lies in `src` (so the loops below cannot
    /// go out of bounds on their own).
    fn check<T>(&self, src: &[T]) {
        let [od, oh, ow] = self.out_dims;
        let [kd, kh, kw] = self.kernel;
        let last = self.base(od - 1, oh - 1, ow - 1, kd - 1, kh - 1) + (kw - 1) * self.dilation[2];
        assert!(last < src.len(), "depthwise window reads past its plane");
    }

    /// `B` outputs of line `(oz, oy)` from `ox` on, stride 1 along x, kept in registers while
    /// all taps are added.
    #[inline(always)]
    fn block<T: Real, const B: usize, const FMA: bool>(
        &self,
        src: &[T],
        w: &[T],
        init: T,
        at: [usize; 3],
        out: &mut [T],
    ) {
        let [kd, kh, kw] = self.kernel;
        let dx = self.dilation[2];
        let mut acc = [init; B];
        for tz in 0..kd {
            for ty in 0..kh {
                let base = self.base(at[0], at[1], at[2], tz, ty);
                for (tx, &wv) in w[(tz * kh + ty) * kw..][..kw].iter().enumerate() {
                    let seg: &[T; B] = src[base + tx * dx..][..B].try_into().expect("B values");
                    for i in 0..B {
                        acc[i] = madd::<T, FMA>(wv, seg[i], acc[i]);
                    }
                }
            }
        }
        out[..B].copy_from_slice(&acc);
    }

    /// Writes the correlation of `src` with `w` to `out`: along each output line, blocks of
    /// `L`, 16, 8 and 4 outputs held in registers (stride 1), the rest one by one; with `FMA`,
    /// as fused multiply-adds.
    #[inline(always)]
    fn correlate<T: Real, const L: usize, const FMA: bool>(&self, src: &[T], w: &[T], init: T, out: &mut [T]) {
        let [od, oh, ow] = self.out_dims;
        let [kd, kh, kw] = self.kernel;
        let (sx, dx) = (self.stride[2], self.dilation[2]);
        self.check(src);
        assert!(out.len() >= od * oh * ow && w.len() >= kd * kh * kw);
        for (line, yrow) in out.chunks_exact_mut(ow).take(od * oh).enumerate() {
            let (oz, oy) = (line / oh, line % oh);
            let mut ox = 0;
            if sx == 1 {
                while ow - ox >= L {
                    self.block::<T, L, FMA>(src, w, init, [oz, oy, ox], &mut yrow[ox..]);
                    ox += L;
                }
                if L > 16 && ow - ox >= 16 {
                    self.block::<T, 16, FMA>(src, w, init, [oz, oy, ox], &mut yrow[ox..]);
                    ox += 16;
                }
                if ow - ox >= 8 {
                    self.block::<T, 8, FMA>(src, w, init, [oz, oy, ox], &mut yrow[ox..]);
                    ox += 8;
                }
                if ow - ox >= 4 {
                    self.block::<T, 4, FMA>(src, w, init, [oz, oy, ox], &mut yrow[ox..]);
                    ox += 4;
                }
            }
            for (i, y) in yrow.iter_mut().enumerate().skip(ox) {
                let mut acc = init;
                for tz in 0..kd {
                    for ty in 0..kh {
                        let base = self.base(oz, oy, i, tz, ty);
                        for (tx, &wv) in w[(tz * kh + ty) * kw..][..kw].iter().enumerate() {
                            acc = madd::<T, FMA>(wv, src[base + tx * dx], acc);
                        }
                    }
                }
                *y = acc;
            }
        }
    }

    /// Adds `sum_o gy[o] src[origin + o * stride + t * dilation]` to `lanes[t]` for every tap
    /// `t`, spread over `L` lanes (summed by the caller). Each tap's lanes stay in registers
    /// over the whole plane; output `ox` of a line goes to lane `ox % L`.
    #[inline(always)]
    fn accumulate_taps<T: Real, const L: usize, const FMA: bool>(&self, src: &[T], gy: &[T], lanes: &mut [[T; L]]) {
        let [od, oh, ow] = self.out_dims;
        let [kd, kh, kw] = self.kernel;
        let (sx, dx) = (self.stride[2], self.dilation[2]);
        self.check(src);
        assert!(gy.len() >= od * oh * ow && lanes.len() >= kd * kh * kw);
        // Outputs per line covered by blocks of L, 16, 8 and 4 (stride 1 only).
        let (full, mut vec_end) = if sx == 1 { (ow / L, ow / L * L) } else { (0, 0) };
        let (b16, b8, b4);
        (b16, vec_end) =
            if sx == 1 && L > 16 && ow - vec_end >= 16 { (Some(vec_end), vec_end + 16) } else { (None, vec_end) };
        (b8, vec_end) = if sx == 1 && ow - vec_end >= 8 { (Some(vec_end), vec_end + 8) } else { (None, vec_end) };
        (b4, vec_end) = if sx == 1 && ow - vec_end >= 4 { (Some(vec_end), vec_end + 4) } else { (None, vec_end) };
        for tz in 0..kd {
            for ty in 0..kh {
                for tx in 0..kw {
                    let lane = &mut lanes[(tz * kh + ty) * kw + tx];
                    let mut acc = *lane;
                    // Nested line loops: no division per line in this innermost part.
                    for oz in 0..od {
                        for oy in 0..oh {
                            let g = &gy[(oz * oh + oy) * ow..][..ow];
                            let x = &src[self.base(oz, oy, 0, tz, ty) + tx * dx..];
                            for blk in 0..full {
                                fma_lanes::<T, L, L, FMA>(&mut acc, &g[blk * L..], &x[blk * L..]);
                            }
                            if let Some(o) = b16 {
                                fma_lanes::<T, L, 16, FMA>(&mut acc, &g[o..], &x[o..]);
                            }
                            if let Some(o) = b8 {
                                fma_lanes::<T, L, 8, FMA>(&mut acc, &g[o..], &x[o..]);
                            }
                            if let Some(o) = b4 {
                                fma_lanes::<T, L, 4, FMA>(&mut acc, &g[o..], &x[o..]);
                            }
                            for o in vec_end..ow {
                                acc[o % L] = madd::<T, FMA>(g[o], x[o * sx], acc[o % L]);
                            }
                        }
                    }
                    *lane = acc;
                }
            }
        }
    }
}

/// `acc[i] += a[i] * b[i]` for the first `B` of `L` lanes.
#[inline(always)]
fn fma_lanes<T: Real, const L: usize, const B: usize, const FMA: bool>(acc: &mut [T; L], a: &[T], b: &[T]) {
    let (a, b): (&[T; B], &[T; B]) = (a[..B].try_into().expect("B values"), b[..B].try_into().expect("B values"));
    for i in 0..B {
        acc[i] = madd::<T, FMA>(a[i], b[i], acc[i]);
    }
}

/// `a * b + c`, fused when `FMA` (a libm call unless the CPU feature is enabled, so only
/// instantiated inside `#[target_feature(enable = "fma")]` functions).
#[inline(always)]
fn madd<T: Real, const FMA: bool>(a: T, b: T, c: T) -> T {
    if FMA {
        num_traits::Float::mul_add(a, b, c)
    } else {
        a * b + c
    }
}

/// Outputs per register block: 32 `f32` or 16 `f64`.
fn block_len<T>() -> usize {
    if std::mem::size_of::<T>() <= 4 {
        32
    } else {
        16
    }
}

/// [`Window::correlate`] and [`Window::accumulate_taps`] with the block length of `T`.
#[inline(always)]
fn kernels<T: Real, const FMA: bool>(job: Job<'_, T>) {
    match (job, block_len::<T>() == 32) {
        (Job::Correlate(win, src, w, init, out), true) => win.correlate::<T, 32, FMA>(src, w, init, out),
        (Job::Correlate(win, src, w, init, out), false) => win.correlate::<T, 16, FMA>(src, w, init, out),
        (Job::Taps(win, src, gy, lanes), _) => win.accumulate_taps::<T, LANES, FMA>(src, gy, lanes),
    }
}

/// Lanes of the weight-gradient accumulators.
const LANES: usize = 32;

/// One call of a kernel, with its arguments.
enum Job<'a, T> {
    Correlate(&'a Window, &'a [T], &'a [T], T, &'a mut [T]),
    Taps(&'a Window, &'a [T], &'a [T], &'a mut [[T; LANES]]),
}

/// Runs `job` with AVX2 and FMA where the CPU has them (checked at run time; the build targets
/// baseline x86-64), portable code otherwise.
fn run<T: Real>(job: Job<'_, T>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA, the only requirement of `kernels_avx2`.
        unsafe { kernels_avx2(job) };
        return;
    }
    kernels::<T, false>(job)
}

/// [`kernels`] compiled for AVX2 with fused multiply-adds.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn kernels_avx2<T: Real>(job: Job<'_, T>) {
    kernels::<T, true>(job)
}

/// `out = init + correlation of src with w` (see [`Window`]).
fn correlate<T: Real>(win: &Window, src: &[T], w: &[T], init: T, out: &mut [T]) {
    run(Job::Correlate(win, src, w, init, out))
}

/// The forward window: the padded input read at `o * stride + t * dilation`.
fn forward_window(g: &Geometry, pad: &Padding) -> Window {
    Window {
        src_dims: pad.dims,
        out_dims: g.output,
        origin: [0; 3],
        kernel: g.kernel,
        stride: g.stride,
        dilation: g.dilation,
    }
}

/// `y = conv(x, w) (+ bias)` for a depthwise geometry (see [`handles`]); `y` is overwritten.
pub(crate) fn forward<T: Real>(g: &Geometry, x: &[T], w: &[T], bias: Option<&[T]>, y: &mut [T]) {
    debug_assert!(handles(g));
    let (in_len, out_len, taps) = (g.in_len(), g.out_len(), g.k_len());
    let pad = Padding::new(g);
    let win = forward_window(g, &pad);
    let scratch = || vec![T::zero(); pad.len()];
    y[..g.batch * g.c_out * out_len].par_chunks_mut(out_len).enumerate().for_each_init(scratch, |xp, (u, yu)| {
        let c = u % g.c_in;
        pad.fill(&x[u * in_len..][..in_len], xp);
        correlate(&win, xp, &w[c * taps..][..taps], bias.map_or(T::zero(), |b| b[c]), yu);
    });
}

/// `gx = grad_input(gy, w)` for a depthwise geometry; `gx` must be zero on entry.
pub(crate) fn grad_input<T: Real>(g: &Geometry, gy: &[T], w: &[T], gx: &mut [T]) {
    debug_assert!(handles(g));
    let (in_len, out_len, taps) = (g.in_len(), g.out_len(), g.k_len());
    let pad = Padding::new(g);
    let units = &mut gx[..g.batch * g.c_in * in_len];
    if g.stride == [1; 3] {
        // The output gradient, zero-padded by the kernel extent - 1 on each side, correlated
        // with the flipped kernel gives the gradient on the padded plane. With zero padding only
        // the input part of that plane is computed (`origin` = padding).
        let ext = [0, 1, 2].map(|a| g.dilation[a] * (g.kernel[a] - 1));
        // With any periodic axis the gradient is computed on the whole padded plane and folded
        // back (periodic axes wrap, zero-padded ones drop their border).
        let periodic = g.circular.contains(&true);
        let gpad = Geometry { input: g.output, padding: ext, circular: [false; 3], ..*g };
        let gpad = Padding::new(&gpad);
        let win = Window {
            src_dims: gpad.dims,
            out_dims: if periodic { pad.dims } else { g.input },
            origin: if periodic { [0; 3] } else { g.padding },
            kernel: g.kernel,
            stride: [1; 3],
            dilation: g.dilation,
        };
        let plane = if periodic { pad.len() } else { 0 };
        let flipped: Vec<T> = w[..g.c_out * taps].chunks_exact(taps).flat_map(|wc| wc.iter().rev()).copied().collect();
        let scratch = || (vec![T::zero(); gpad.len()], vec![T::zero(); plane]);
        units.par_chunks_mut(in_len).enumerate().for_each_init(scratch, |(gyp, gxp), (u, gxu)| {
            let wf = &flipped[(u % g.c_in) * taps..][..taps];
            gpad.fill(&gy[u * out_len..][..out_len], gyp);
            if periodic {
                correlate(&win, gyp, wf, T::zero(), gxp);
                pad.fold(gxp, gxu);
            } else {
                correlate(&win, gyp, wf, T::zero(), gxu);
            }
        });
    } else {
        // Strided: scatter every output gradient to the padded positions its taps read.
        let [_, oh, ow] = g.output;
        let [kd, kh, kw] = g.kernel;
        let ([sz, sy, sx], [dz, dy, dx]) = (g.stride, g.dilation);
        let [_, ph, pw] = pad.dims;
        let scratch = || vec![T::zero(); pad.len()];
        units.par_chunks_mut(in_len).enumerate().for_each_init(scratch, |gxp, (u, gxu)| {
            let c = u % g.c_in;
            let wc = &w[c * taps..][..taps];
            gxp.fill(T::zero());
            for (line, grow) in gy[u * out_len..][..out_len].chunks_exact(ow).enumerate() {
                let (oz, oy) = (line / oh, line % oh);
                for tz in 0..kd {
                    for ty in 0..kh {
                        let row = ((oz * sz + tz * dz) * ph + oy * sy + ty * dy) * pw;
                        let dst = &mut gxp[row..row + pw];
                        for (tx, &wv) in wc[(tz * kh + ty) * kw..][..kw].iter().enumerate() {
                            for (ox, &v) in grow.iter().enumerate() {
                                dst[ox * sx + tx * dx] += wv * v;
                            }
                        }
                    }
                }
            }
            pad.fold(gxp, gxu);
        });
    }
}

/// `gw = grad_weight(x, gy)` for a depthwise geometry; `gw` is overwritten.
pub(crate) fn grad_weight<T: Real>(g: &Geometry, x: &[T], gy: &[T], gw: &mut [T]) {
    debug_assert!(handles(g));
    let (in_len, out_len, taps) = (g.in_len(), g.out_len(), g.k_len());
    let pad = Padding::new(g);
    let win = forward_window(g, &pad);
    gw[..g.c_out * taps].par_chunks_mut(taps).enumerate().for_each(|(c, gwc)| {
        let mut xp = vec![T::zero(); pad.len()];
        let mut lanes = vec![[T::zero(); LANES]; taps];
        for b in 0..g.batch {
            let u = b * g.c_in + c;
            pad.fill(&x[u * in_len..][..in_len], &mut xp);
            run(Job::Taps(&win, &xp, &gy[u * out_len..][..out_len], &mut lanes));
        }
        gwc.iter_mut().zip(&lanes).for_each(|(d, l)| *d = l.iter().fold(T::zero(), |s, &v| s + v));
    });
}

/// `gb[c] = sum_{b, o} gy[b, c, o]`: the bias gradient; `gb` is overwritten.
pub(crate) fn channel_sum<T: Real>(g: &Geometry, gy: &[T], gb: &mut [T]) {
    let out_len = g.out_len();
    gb[..g.c_out].par_iter_mut().enumerate().for_each(|(c, gbc)| {
        let mut lanes = [T::zero(); LANES];
        let mut rest = T::zero();
        for b in 0..g.batch {
            let plane = &gy[(b * g.c_out + c) * out_len..][..out_len];
            let mut chunks = plane.chunks_exact(LANES);
            for chunk in &mut chunks {
                let chunk: &[T; LANES] = chunk.try_into().expect("LANES values");
                for i in 0..LANES {
                    lanes[i] += chunk[i];
                }
            }
            rest = chunks.remainder().iter().fold(rest, |s, &v| s + v);
        }
        *gbc = lanes.iter().fold(rest, |s, &v| s + v);
    });
}

/// The differentiable op `y = conv(x, w) + bias` of a depthwise geometry: the bias is the
/// initial value of every output sum, and its gradient a single pass over the output gradient.
struct ConvBias(Geometry);

impl Kernel3 for ConvBias {
    fn name(&self) -> &'static str {
        "conv"
    }

    fn output_shape(&self, x: &Shape, w: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        expect_shape("conv", "input", x.dims(), &self.0.x_shape())?;
        expect_shape("conv", "weight", w.dims(), &self.0.w_shape())?;
        expect_shape("conv", "bias", b.dims(), &[self.0.c_out])?;
        Ok(Shape::from(self.0.y_shape()))
    }

    fn forward<T: Real>(
        &self,
        x: &[T],
        _: &Shape,
        w: &[T],
        _: &Shape,
        b: &[T],
        _: &Shape,
        y: &mut [T],
    ) -> candle_core::Result<()> {
        forward(&self.0, x, w, Some(b), y);
        Ok(())
    }
}

impl Op3 for ConvBias {
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        b: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let gx = grad_if_tracked(x, || grad_input_tensor(&self.0, gy, w))?;
        let gw = grad_if_tracked(w, || grad_weight_tensor(&self.0, x, gy))?;
        let gb = grad_if_tracked(b, || apply1(gy, ChannelSum(self.0)))?;
        Ok((gx, gw, gb))
    }
}

/// The differentiable op `gb = channel_sum(gy)` (a bias gradient); its own gradient broadcasts
/// back over batch and positions.
struct ChannelSum(Geometry);

impl Kernel1 for ChannelSum {
    fn name(&self) -> &'static str {
        "conv_grad_bias"
    }

    fn output_shape(&self, gy: &Shape) -> candle_core::Result<Shape> {
        expect_shape("conv_grad_bias", "grad_output", gy.dims(), &self.0.y_shape())?;
        Ok(Shape::from(self.0.c_out))
    }

    fn forward<T: Real>(&self, gy: &[T], _: &Shape, gb: &mut [T]) -> candle_core::Result<()> {
        channel_sum(&self.0, gy, gb);
        Ok(())
    }
}

impl Op1 for ChannelSum {
    fn backward(&self, gy: &Tensor, _gb: &Tensor, ggb: &Tensor) -> candle_core::Result<Tensor> {
        let mut shape = vec![1; gy.rank()];
        shape[1] = self.0.c_out;
        ggb.reshape(shape)?.broadcast_as(gy.shape())
    }
}

/// `conv(x, w) + bias` on tensors of a depthwise geometry (see [`handles`]), differentiable to
/// any order.
pub(crate) fn conv_bias_tensor(g: &Geometry, x: &Tensor, w: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    debug_assert!(handles(g));
    apply3(x, w, b, ConvBias(*g))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::Conv2dParams;

    /// The forward correlation and the weight-gradient lanes by a plain loop over taps.
    fn naive(g: &Geometry, xp: &[f64], pdims: [usize; 3], w: &[f64], gy: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let ([_, oh, ow], [_, kh, kw]) = (g.output, g.kernel);
        let (mut y, mut gw) = (vec![0.0; oh * ow], vec![0.0; kh * kw]);
        for oy in 0..oh {
            for ox in 0..ow {
                for ty in 0..kh {
                    for tx in 0..kw {
                        let iy = oy * g.stride[1] + ty * g.dilation[1];
                        let ix = ox * g.stride[2] + tx * g.dilation[2];
                        let v = xp[iy * pdims[2] + ix];
                        y[oy * ow + ox] += w[ty * kw + tx] * v;
                        gw[ty * kw + tx] += gy[oy * ow + ox] * v;
                    }
                }
            }
        }
        (y, gw)
    }

    #[test]
    fn portable_and_fused_kernels_match_a_loop() {
        // Widths that exercise every block size (32, 16, 8, 4, single) and a strided case.
        for (w_in, stride) in [(75, 1), (29, 1), (7, 1), (40, 2)] {
            let p = Conv2dParams { padding: [1, 2], stride: [1, stride], ..Default::default() };
            let g = Geometry::new("t", &[1, 1, 5, w_in], &[1, 1, 3, 5], &p).unwrap();
            let pad = Padding::new(&g);
            let x: Vec<f64> = (0..g.in_len()).map(|i| ((i * 37 % 17) as f64) - 8.0).collect();
            let w: Vec<f64> = (0..15).map(|i| ((i * 7 % 5) as f64) - 2.0).collect();
            let gy: Vec<f64> = (0..g.out_len()).map(|i| ((i * 13 % 11) as f64) - 5.0).collect();
            let mut xp = vec![0.0; pad.len()];
            pad.fill(&x, &mut xp);
            let (y_ref, gw_ref) = naive(&g, &xp, pad.dims, &w, &gy);
            let win = forward_window(&g, &pad);
            let mut fused = vec![false];
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                fused.push(true);
            }
            for fma in fused {
                let mut y = vec![f64::NAN; g.out_len()];
                let mut lanes = vec![[0.0; LANES]; 15];
                let jobs = [Job::Correlate(&win, &xp, &w, 0.0, &mut y), Job::Taps(&win, &xp, &gy, &mut lanes)];
                for job in jobs {
                    if fma {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: AVX2 and FMA were detected above.
                        unsafe {
                            kernels_avx2(job)
                        };
                    } else {
                        kernels::<f64, false>(job);
                    }
                }
                // Small integers: every sum is exact in any order.
                assert_eq!(y, y_ref, "width {w_in}, stride {stride}, fma {fma}");
                let gw: Vec<f64> = lanes.iter().map(|l| l.iter().sum()).collect();
                assert_eq!(gw, gw_ref, "width {w_in}, stride {stride}, fma {fma}");
            }
        }
    }

    #[test]
    fn bias_gradient_op_sums_channels_and_passes_gradient_check() {
        let p = Conv2dParams::default().padding(1).groups(3);
        let g = Geometry::new("t", &[2, 3, 4, 37], &[3, 1, 3, 3], &p).unwrap();
        let dev = candle_core::Device::Cpu;
        let gy = crate::seed::randn(g.y_shape(), 0.0, 1.0, candle_core::DType::F64, &dev, 0).unwrap();
        let gb = apply1(&gy, ChannelSum(g)).unwrap().to_vec1::<f64>().unwrap();
        let expect = gy.sum((0, 2, 3)).unwrap().to_vec1::<f64>().unwrap();
        for (a, e) in gb.iter().zip(&expect) {
            assert!((a - e).abs() <= 1e-12 * e.abs().max(1.0), "{gb:?} vs {expect:?}");
        }
        let r = crate::check_grad(|t| apply1(&t[0], ChannelSum(g)), &[gy], &Default::default()).unwrap();
        assert!(r.max_rel_error <= 1e-8, "{r:?}");
    }
}
