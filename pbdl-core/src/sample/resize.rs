//! Resizing of images and volumes: nearest (scipy's convention), bilinear/trilinear and bicubic
//! (PyTorch's conventions), with backward.
//!
//! Every mode is separable and linear in the input: along each axis, output sample `o` is a
//! weighted sum of a few input samples ("taps"). The op applies the taps axis by axis; its
//! backward applies the transposed taps, i.e. it is exact, and is itself differentiable.

use crate::op::{apply1, Kernel1, Op1};
use crate::{Error, Real, Result};
use candle_core::{Shape, Tensor};
use rayon::prelude::*;
use std::sync::Arc;

/// Output elements per parallel task.
const CHUNK: usize = 4096;

/// The interpolation of [`resize2d`] and [`resize3d`]. In the formulas, `o` is an output index,
/// `n_in`/`n_out` the sizes of the axis, and `src` the input coordinate that `o` maps to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Resize {
    /// Nearest neighbour as `scipy.ndimage.zoom(order=0)` (its default `grid_mode=False`):
    /// `src = o * (n_in - 1) / (n_out - 1)` (`src = 0` when `n_out == 1`), rounded half up,
    /// i.e. to `floor(src + 0.5)` (scipy's C code; the coordinates are >= 0, so this is also
    /// half away from zero). Example: 3 -> 5 samples reads inputs `[0, 1, 1, 2, 2]`. Checked
    /// against scipy 1.17 for every size pair up to 69 -> 259. One deliberate difference: where
    /// `(n_out - 1) * zoom` rounds to slightly above `n_in - 1` (e.g. 32 -> 224, 512 -> 224,
    /// 8 -> 26), scipy's default `mode="constant"` writes `cval = 0` into the last output row;
    /// here that row is the last input row. The backward scatters each output gradient onto the
    /// input sample it was read from (the transpose of the selection): the op is piecewise
    /// constant in the coordinates but linear in the values.
    Nearest,
    /// Bilinear in 2D, trilinear in 3D, as PyTorch's `interpolate(mode="bilinear" /
    /// "trilinear")` without antialiasing. `align_corners = true`:
    /// `src = o * (n_in - 1) / (n_out - 1)` (the corner samples coincide; used by LSiM for its
    /// normalisation maps); `false`: `src = (o + 0.5) * n_in / n_out - 0.5`, clamped to `>= 0`
    /// (half-pixel centres). Samples beyond the last input repeat it.
    Bilinear {
        /// Map the corner samples of input and output onto each other.
        align_corners: bool,
    },
    /// Bicubic as PyTorch's `interpolate(mode="bicubic")`: Keys' cubic convolution with
    /// `a = -0.75` over the 4 samples `floor(src) - 1 ..= floor(src) + 2` (indices clamped to
    /// the border), `src` as for [`Resize::Bilinear`] but not clamped. With `a = -0.75` the
    /// kernel reproduces constants but not linear functions (only `a = -0.5` does), and it
    /// overshoots at edges, like PyTorch's. In 3D it is the tensor-product (tricubic) extension,
    /// which PyTorch does not have.
    Bicubic {
        /// Map the corner samples of input and output onto each other.
        align_corners: bool,
    },
}

/// Resizes `x` (`[batch, channel, y, x]`) to `[batch, channel, h, w]` with `size = (h, w)`.
///
/// See [`Resize`] for the modes and their coordinate conventions. Differentiable with respect to
/// `x` in every mode (all are linear in `x`; the backward is the exact transpose). `f32` or
/// `f64`; a wrong rank or a zero size is a typed [`Error`].
pub fn resize2d(x: &Tensor, size: (usize, usize), mode: Resize) -> Result<Tensor> {
    resize("resize2d", x, &[size.0, size.1], mode)
}

/// Resizes `x` (`[batch, channel, z, y, x]`) to `[batch, channel, d, h, w]` with
/// `size = (d, h, w)`; [`Resize::Bilinear`] is trilinear here. Otherwise as [`resize2d`].
pub fn resize3d(x: &Tensor, size: (usize, usize, usize), mode: Resize) -> Result<Tensor> {
    resize("resize3d", x, &[size.0, size.1, size.2], mode)
}

/// `size` is in the order of the tensor's axes (`[.., y, x]`).
fn resize(op: &'static str, x: &Tensor, size: &[usize], mode: Resize) -> Result<Tensor> {
    let s = size.len();
    let layout = if s == 2 { "[batch, channel, y, x]" } else { "[batch, channel, z, y, x]" };
    crate::error::check_float(op, "x", x)?;
    crate::error::check_rank(op, "x", x, s + 2, layout)?;
    if size.contains(&0) {
        return Err(Error::invalid(op, "size", format!("every output size must be at least 1, got {size:?}")));
    }
    let dims = x.dims();
    if dims[2..].contains(&0) {
        return Err(Error::Shape {
            op,
            arg: "x",
            expected: format!("{layout} with every spatial size >= 1"),
            got: dims.to_vec(),
        });
    }
    // Taps per axis, x first.
    let fwd: Vec<Taps> = (0..s).map(|d| Taps::new(dims[s + 1 - d], size[s - 1 - d], mode)).collect();
    if fwd.iter().all(Taps::is_identity) {
        return Ok(x.clone());
    }
    let bwd = fwd.iter().map(Taps::transpose).collect();
    Ok(apply1(x, ResizeOp { fwd: Arc::new(fwd), bwd: Arc::new(bwd), transposed: false })?)
}

/// The taps of one axis in compressed rows: output `o` reads inputs `idx[k]` with weights `w[k]`
/// for `k` in `start[o]..start[o + 1]`.
#[derive(Clone, Debug, PartialEq)]
struct Taps {
    n_src: usize,
    n_dst: usize,
    start: Vec<usize>,
    idx: Vec<usize>,
    w: Vec<f64>,
}

impl Taps {
    fn new(n_src: usize, n_dst: usize, mode: Resize) -> Taps {
        match mode {
            Resize::Nearest => {
                let zoom = if n_dst > 1 { (n_src - 1) as f64 / (n_dst - 1) as f64 } else { 1.0 };
                Taps::from_rows(n_src, n_dst, |o, row| {
                    let i = ((o as f64 * zoom + 0.5).floor() as usize).min(n_src - 1);
                    row.push((i, 1.0));
                })
            }
            Resize::Bilinear { align_corners } => Taps::from_rows(n_src, n_dst, |o, row| {
                let src = source_coordinate(o, n_src, n_dst, align_corners).max(0.0);
                let i0 = (src.floor() as usize).min(n_src - 1);
                let i1 = (i0 + 1).min(n_src - 1);
                let t = (src - i0 as f64).clamp(0.0, 1.0);
                row.extend([(i0, 1.0 - t), (i1, t)]);
            }),
            Resize::Bicubic { align_corners } => Taps::from_rows(n_src, n_dst, |o, row| {
                let src = source_coordinate(o, n_src, n_dst, align_corners);
                let i = (src.floor() as isize).min(n_src as isize - 1);
                let t = (src - i as f64).clamp(0.0, 1.0);
                let w = cubic_weights(t, -0.75);
                for (j, w) in (-1..=2).zip(w) {
                    row.push(((i + j).clamp(0, n_src as isize - 1) as usize, w));
                }
            }),
        }
    }

    /// Builds the taps from `row(o, taps)`, merging taps on the same input (clamped border taps)
    /// and dropping zero weights.
    fn from_rows(n_src: usize, n_dst: usize, mut row: impl FnMut(usize, &mut Vec<(usize, f64)>)) -> Taps {
        let mut taps = Taps { n_src, n_dst, start: vec![0], idx: Vec::new(), w: Vec::new() };
        let mut buf = Vec::new();
        for o in 0..n_dst {
            buf.clear();
            row(o, &mut buf);
            buf.sort_by_key(|&(i, _)| i);
            let first = taps.idx.len();
            for &(i, w) in &buf {
                if taps.idx.len() > first && taps.idx.last() == Some(&i) {
                    *taps.w.last_mut().expect("non-empty") += w;
                } else {
                    taps.idx.push(i);
                    taps.w.push(w);
                }
            }
            // Drop zero weights of this row (e.g. the second tap of a bilinear row at t = 0).
            let mut keep = first;
            for k in first..taps.idx.len() {
                if taps.w[k] != 0.0 {
                    taps.idx[keep] = taps.idx[k];
                    taps.w[keep] = taps.w[k];
                    keep += 1;
                }
            }
            taps.idx.truncate(keep);
            taps.w.truncate(keep);
            taps.start.push(keep);
        }
        taps
    }

    /// The transposed map, from `n_dst` back to `n_src` samples.
    fn transpose(&self) -> Taps {
        let mut rows = vec![Vec::new(); self.n_src];
        for o in 0..self.n_dst {
            for k in self.start[o]..self.start[o + 1] {
                rows[self.idx[k]].push((o, self.w[k]));
            }
        }
        Taps::from_rows(self.n_dst, self.n_src, |i, row| row.extend_from_slice(&rows[i]))
    }

    fn is_identity(&self) -> bool {
        self.n_src == self.n_dst
            && (0..self.n_dst).all(|o| self.start[o + 1] == o + 1 && self.idx[o] == o && self.w[o] == 1.0)
    }
}

/// PyTorch's `area_pixel_compute_source_index` (before the clamp that only linear modes apply).
fn source_coordinate(o: usize, n_src: usize, n_dst: usize, align_corners: bool) -> f64 {
    if align_corners {
        let scale = if n_dst > 1 { (n_src - 1) as f64 / (n_dst - 1) as f64 } else { 0.0 };
        scale * o as f64
    } else {
        let scale = n_src as f64 / n_dst as f64;
        (o as f64 + 0.5) * scale - 0.5
    }
}

/// Weights of the samples at offsets -1, 0, 1, 2 for a point at fraction `t` past sample 0:
/// Keys' cubic convolution kernel with parameter `a` (PyTorch's `get_cubic_upsample_coefficients`).
fn cubic_weights(t: f64, a: f64) -> [f64; 4] {
    // |s| <= 1 and 1 < |s| < 2 branches of the kernel.
    let near = |s: f64| ((a + 2.0) * s - (a + 3.0)) * s * s + 1.0;
    let far = |s: f64| ((a * s - 5.0 * a) * s + 8.0 * a) * s - 4.0 * a;
    [far(t + 1.0), near(t), near(1.0 - t), far(2.0 - t)]
}

/// The resize op: applies `fwd` (x first); its backward applies `bwd`, the transposed taps.
struct ResizeOp {
    fwd: Arc<Vec<Taps>>,
    bwd: Arc<Vec<Taps>>,
    transposed: bool,
}

impl Kernel1 for ResizeOp {
    fn name(&self) -> &'static str {
        if self.transposed {
            "resize_transpose"
        } else {
            "resize"
        }
    }

    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        let dims = input.dims();
        let s = self.fwd.len();
        let fits = dims.len() == s + 2 && self.fwd.iter().enumerate().all(|(d, t)| dims[s + 1 - d] == t.n_src);
        if !fits {
            let expected: Vec<usize> = self.fwd.iter().rev().map(|t| t.n_src).collect();
            return Err(Error::Shape {
                op: self.name(),
                arg: "x",
                expected: format!("[batch, channel, {expected:?}]"),
                got: dims.to_vec(),
            }
            .into());
        }
        let mut out = dims.to_vec();
        for (d, t) in self.fwd.iter().enumerate() {
            out[s + 1 - d] = t.n_dst;
        }
        Ok(Shape::from(out))
    }

    fn forward<T: Real>(&self, x: &[T], x_shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let s = self.fwd.len();
        // Current extents, x first, and the flat number of (batch, channel) rows.
        let mut ext: Vec<usize> = (0..s).map(|d| x_shape.dims()[s + 1 - d]).collect();
        let rows: usize = x_shape.dims()[..2].iter().product();
        let mut cur: Vec<T> = Vec::new();
        for (d, taps) in self.fwd.iter().enumerate() {
            let inner: usize = ext[..d].iter().product();
            ext[d] = taps.n_dst;
            let src: &[T] = if d == 0 { x } else { &cur };
            if d + 1 == s {
                apply_axis(src, out, taps, inner);
            } else {
                let mut next = vec![T::zero(); rows * ext.iter().product::<usize>()];
                apply_axis(src, &mut next, taps, inner);
                cur = next;
            }
        }
        Ok(())
    }
}

impl Op1 for ResizeOp {
    fn backward(&self, _x: &Tensor, _y: &Tensor, grad: &Tensor) -> candle_core::Result<Tensor> {
        apply1(grad, ResizeOp { fwd: self.bwd.clone(), bwd: self.fwd.clone(), transposed: !self.transposed })
    }
}

/// `dst[a, o, i] = sum_k w[o, k] * src[a, idx[o, k], i]` for `src` laid out `[outer, n_src,
/// inner]` and a zeroed `dst` laid out `[outer, n_dst, inner]`.
fn apply_axis<T: Real>(src: &[T], dst: &mut [T], taps: &Taps, inner: usize) {
    let w: Vec<T> = taps.w.iter().map(|&v| T::c(v)).collect();
    let (n_src, n_dst) = (taps.n_src, taps.n_dst);
    if inner == 1 {
        // Along x: one contiguous row in, one out.
        dst.par_chunks_mut(n_dst).with_min_len((CHUNK / n_dst).max(1)).zip(src.par_chunks(n_src)).for_each(|(d, s)| {
            for (o, y) in d.iter_mut().enumerate() {
                let mut acc = T::zero();
                for k in taps.start[o]..taps.start[o + 1] {
                    acc += w[k] * s[taps.idx[k]];
                }
                *y = acc;
            }
        });
    } else {
        // Along y or z: whole contiguous lines of length `inner` are combined.
        dst.par_chunks_mut(inner).with_min_len((CHUNK / inner).max(1)).enumerate().for_each(|(r, d)| {
            let (a, o) = (r / n_dst, r % n_dst);
            for k in taps.start[o]..taps.start[o + 1] {
                let wk = w[k];
                let s = &src[(a * n_src + taps.idx[k]) * inner..][..inner];
                for (y, &v) in d.iter_mut().zip(s) {
                    *y += wk * v;
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dense(t: &Taps) -> Vec<Vec<f64>> {
        let mut m = vec![vec![0.0; t.n_src]; t.n_dst];
        for o in 0..t.n_dst {
            for k in t.start[o]..t.start[o + 1] {
                m[o][t.idx[k]] += t.w[k];
            }
        }
        m
    }

    #[test]
    fn every_row_of_every_mode_sums_to_one() {
        let modes = [
            Resize::Nearest,
            Resize::Bilinear { align_corners: true },
            Resize::Bilinear { align_corners: false },
            Resize::Bicubic { align_corners: true },
            Resize::Bicubic { align_corners: false },
        ];
        for mode in modes {
            for (a, b) in [(1, 4), (4, 1), (3, 7), (7, 3), (5, 5), (2, 9)] {
                let t = Taps::new(a, b, mode);
                for row in dense(&t) {
                    assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{mode:?} {a}->{b}: {row:?}");
                }
            }
        }
    }

    #[test]
    fn transpose_is_the_matrix_transpose() {
        let t = Taps::new(5, 8, Resize::Bicubic { align_corners: false });
        let (m, mt) = (dense(&t), dense(&t.transpose()));
        for i in 0..5 {
            for o in 0..8 {
                assert!((m[o][i] - mt[i][o]).abs() < 1e-15);
            }
        }
    }

    #[test]
    fn cubic_with_a_half_reproduces_quadratics_and_pytorch_a_does_not_reproduce_lines() {
        // Keys' kernel is third-order accurate only for a = -1/2; this pins the formula.
        for t in [0.0, 0.1, 0.25, 0.5, 0.8] {
            let w = cubic_weights(t, -0.5);
            let q = |x: f64| 1.0 - 2.0 * x + 3.0 * x * x;
            let v: f64 = (-1..=2).zip(w).map(|(j, w)| w * q(j as f64)).sum();
            assert!((v - q(t)).abs() < 1e-12, "t = {t}: {v} vs {}", q(t));
        }
        let w = cubic_weights(0.25, -0.75);
        let first_moment: f64 = (-1..=2).zip(w).map(|(j, w)| w * j as f64).sum();
        assert!((first_moment - 0.296875).abs() < 1e-12, "{first_moment}");
    }

    #[test]
    fn same_size_is_the_identity_for_every_mode() {
        for mode in
            [Resize::Nearest, Resize::Bilinear { align_corners: false }, Resize::Bicubic { align_corners: true }]
        {
            assert!(Taps::new(6, 6, mode).is_identity(), "{mode:?}");
        }
        assert!(!Taps::new(6, 7, Resize::Nearest).is_identity());
    }
}
