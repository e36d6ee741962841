//! im2col and its adjoint col2im: the gather that turns a convolution into a matrix product.
//!
//! For one image and one channel group, the im2col matrix has a row per kernel tap
//! `(c, kz, ky, kx)` and a column per output position `(oz, oy, ox)`; its entry is the input
//! value that tap reads for that output (zero, or the periodic image, outside the input).
//! Output positions are handled in tiles of whole output lines (fixed `oz, oy`, all `ox`) so the
//! matrix stays cache-sized however large the volume is. Index arithmetic is precomputed once
//! per call in a [`Plan`]; the inner loops only copy slices.

use super::geometry::Geometry;
use crate::Real;
use std::ops::Range;

/// Marks a tap that reads outside the (zero-padded) input.
const OUTSIDE: usize = usize::MAX;

/// Target size of one im2col tile: large enough for efficient matrix products, small enough to
/// stay in a core's L2 cache next to the packed panels of the matrix product.
const TILE_BYTES: usize = 256 << 10;

/// A run of consecutive outputs along x whose taps read `src, src + stride, ...`, or zeros.
#[derive(Clone, Copy, Debug)]
struct Run {
    out: usize,
    len: usize,
    src: usize,
}

/// Precomputed index maps of one convolution.
pub(crate) struct Plan {
    geo: Geometry,
    /// `z[kz * od + oz]`: input plane read by tap `kz` for output `oz`, or [`OUTSIDE`].
    z: Vec<usize>,
    /// `y[ky * oh + oy]`: input row read by tap `ky` for output `oy`, or [`OUTSIDE`].
    y: Vec<usize>,
    /// Runs along x of tap `kx`: `x_runs[x_start[kx]..x_start[kx + 1]]`.
    x_runs: Vec<Run>,
    x_start: Vec<usize>,
    /// Output lines per tile.
    tile_lines: usize,
}

/// Input index read by tap `t` for output `o` along one axis, or [`OUTSIDE`].
fn tap_index(geo: &Geometry, axis: usize, t: usize, o: usize) -> usize {
    let n = geo.input[axis] as isize;
    let i = (o * geo.stride[axis] + t * geo.dilation[axis]) as isize - geo.padding[axis] as isize;
    if (0..n).contains(&i) {
        i as usize
    } else if geo.circular[axis] {
        i.rem_euclid(n) as usize
    } else {
        OUTSIDE
    }
}

fn axis_map(geo: &Geometry, axis: usize) -> Vec<usize> {
    let (k, m) = (geo.kernel[axis], geo.output[axis]);
    (0..k).flat_map(|t| (0..m).map(move |o| tap_index(geo, axis, t, o))).collect()
}

impl Plan {
    /// Builds the index maps for `geo`, with tiles sized for elements of type `T`.
    pub fn new<T>(geo: &Geometry) -> Self {
        Self::with_tile_elems(geo, TILE_BYTES / std::mem::size_of::<T>())
    }

    /// [`Plan::new`] with im2col tiles of about `tile_elems` elements (at least one line).
    pub fn with_tile_elems(geo: &Geometry, tile_elems: usize) -> Self {
        let (kw, ow, sx) = (geo.kernel[2], geo.output[2], geo.stride[2]);
        let mut x_runs = Vec::new();
        let mut x_start = Vec::with_capacity(kw + 1);
        for t in 0..kw {
            x_start.push(x_runs.len());
            let mut o = 0;
            while o < ow {
                let src = tap_index(geo, 2, t, o);
                let mut len = 1;
                // Extend while the source keeps advancing by the stride (or stays outside).
                while o + len < ow {
                    let next = tap_index(geo, 2, t, o + len);
                    let continues = if src == OUTSIDE { next == OUTSIDE } else { next == src + len * sx };
                    if !continues {
                        break;
                    }
                    len += 1;
                }
                x_runs.push(Run { out: o, len, src });
                o += len;
            }
        }
        x_start.push(x_runs.len());
        let lines = geo.output[0] * geo.output[1];
        let line_elems = (geo.k_len() * ow).max(1);
        let tiles = (lines * line_elems).div_ceil(tile_elems.max(1)).clamp(1, lines.max(1));
        Plan {
            geo: *geo,
            z: axis_map(geo, 0),
            y: axis_map(geo, 1),
            x_runs,
            x_start,
            tile_lines: lines.div_ceil(tiles).max(1),
        }
    }

    /// The tiles: ranges of output lines (a line is one `(oz, oy)` with all `ox`).
    pub fn tiles(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        let lines = self.geo.output[0] * self.geo.output[1];
        (0..lines).step_by(self.tile_lines).map(move |s| s..(s + self.tile_lines).min(lines))
    }

    /// Elements of the largest im2col tile.
    pub fn tile_len(&self) -> usize {
        self.geo.k_len() * self.tile_lines * self.geo.output[2]
    }

    /// Calls `f(row, j, tap)` for every im2col row and output line `j` of `lines`, where `tap`
    /// is `Some((offset of the input row within a channel, kx))`, or `None` when the tap's row
    /// lies outside the zero-padded input.
    #[inline(always)]
    fn for_each_line(&self, lines: &Range<usize>, mut f: impl FnMut(usize, usize, Option<(usize, usize)>)) {
        let g = &self.geo;
        let [kd, kh, kw] = g.kernel;
        let [od, oh, _] = g.output;
        let [_, h, w] = g.input;
        for c in 0..g.cin_g() {
            for tz in 0..kd {
                for ty in 0..kh {
                    for tx in 0..kw {
                        let row = ((c * kd + tz) * kh + ty) * kw + tx;
                        for (j, line) in lines.clone().enumerate() {
                            let iz = self.z[tz * od + line / oh];
                            let iy = self.y[ty * oh + line % oh];
                            let tap =
                                (iz != OUTSIDE && iy != OUTSIDE).then(|| (c * g.in_len() + (iz * h + iy) * w, tx));
                            f(row, j, tap);
                        }
                    }
                }
            }
        }
    }

    /// Fills `col` (`k_len` rows of `lines.len() * ow` columns) from the input channels `x` of
    /// one group.
    pub fn im2col<T: Real>(&self, x: &[T], lines: &Range<usize>, col: &mut [T]) {
        let g = &self.geo;
        let (ow, w, sx) = (g.output[2], g.input[2], g.stride[2]);
        let ncol = lines.len() * ow;
        debug_assert!(col.len() >= g.k_len() * ncol && x.len() >= g.cin_g() * g.in_len());
        let (runs, starts) = (&self.x_runs, &self.x_start);
        self.for_each_line(lines, |row, j, tap| {
            let dst = &mut col[row * ncol + j * ow..][..ow];
            let Some((src_row, tx)) = tap else {
                dst.fill(T::zero());
                return;
            };
            let src = &x[src_row..src_row + w];
            for r in &runs[starts[tx]..starts[tx + 1]] {
                let d = &mut dst[r.out..r.out + r.len];
                if r.src == OUTSIDE {
                    d.fill(T::zero());
                } else if sx == 1 {
                    d.copy_from_slice(&src[r.src..r.src + r.len]);
                } else {
                    for (i, v) in d.iter_mut().enumerate() {
                        *v = src[r.src + i * sx];
                    }
                }
            }
        });
    }

    /// The adjoint of [`Plan::im2col`]: adds every entry of `col` to the input position it was
    /// read from, in the channels `dx` of one group.
    pub fn col2im<T: Real>(&self, col: &[T], lines: &Range<usize>, dx: &mut [T]) {
        let g = &self.geo;
        let (ow, w, sx) = (g.output[2], g.input[2], g.stride[2]);
        let ncol = lines.len() * ow;
        debug_assert!(col.len() >= g.k_len() * ncol && dx.len() >= g.cin_g() * g.in_len());
        let runs = &self.x_runs;
        let starts = &self.x_start;
        self.for_each_line(lines, |row, j, tap| {
            let Some((dst_row, tx)) = tap else { return };
            let src = &col[row * ncol + j * ow..][..ow];
            let dst = &mut dx[dst_row..dst_row + w];
            for r in &runs[starts[tx]..starts[tx + 1]] {
                if r.src == OUTSIDE {
                    continue;
                }
                let s = &src[r.out..r.out + r.len];
                if sx == 1 {
                    for (d, &v) in dst[r.src..r.src + r.len].iter_mut().zip(s) {
                        *d += v;
                    }
                } else {
                    for (i, &v) in s.iter().enumerate() {
                        dst[r.src + i * sx] += v;
                    }
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::Conv2dParams;

    fn geo(x: &[usize], w: &[usize], p: Conv2dParams) -> Geometry {
        Geometry::new("t", x, w, &p).unwrap()
    }

    #[test]
    fn im2col_of_a_small_image() {
        // 1 channel, 2x3 input, 2x2 kernel, zero padding 1 on x only.
        let p = Conv2dParams { padding: [0, 1], ..Default::default() };
        let g = geo(&[1, 1, 2, 3], &[1, 1, 2, 2], p);
        assert_eq!(g.output, [1, 1, 4]);
        let plan = Plan::new::<f64>(&g);
        let x = [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0];
        let mut col = vec![f64::NAN; plan.tile_len()];
        plan.im2col(&x, &(0..1), &mut col);
        #[rustfmt::skip]
        let expect = [
            0.0, 1.0, 2.0, 3.0, // tap (0, 0)
            1.0, 2.0, 3.0, 0.0, // tap (0, 1)
            0.0, 4.0, 5.0, 6.0, // tap (1, 0)
            4.0, 5.0, 6.0, 0.0, // tap (1, 1)
        ];
        assert_eq!(col, expect);
    }

    #[test]
    fn circular_strided_taps_wrap() {
        let p = Conv2dParams { padding: [0, 2], stride: [1, 2], ..Default::default() }.circular();
        let g = geo(&[1, 1, 1, 5], &[1, 1, 1, 3], p);
        // (5 + 4 - 3) / 2 + 1 = 4 outputs reading x[-2..1], x[0..3], x[2..5], x[4..7] (periodic).
        assert_eq!(g.output, [1, 1, 4]);
        let plan = Plan::new::<f64>(&g);
        let x = [10.0f64, 11.0, 12.0, 13.0, 14.0];
        let mut col = vec![f64::NAN; plan.tile_len()];
        plan.im2col(&x, &(0..1), &mut col);
        assert_eq!(&col[..4], &[13.0, 10.0, 12.0, 14.0]);
        assert_eq!(&col[4..8], &[14.0, 11.0, 13.0, 10.0]);
        assert_eq!(&col[8..], &[10.0, 12.0, 14.0, 11.0]);
    }

    #[test]
    fn col2im_is_the_adjoint_of_im2col() {
        // <im2col(x), c> == <x, col2im(c)> for a strided, dilated, padded, periodic case, tile by tile.
        for circular in [false, true] {
            let mut p = Conv2dParams { stride: [2, 1], padding: [2, 1], dilation: [1, 2], ..Default::default() };
            if circular {
                p = p.circular();
            }
            let g = geo(&[1, 2, 7, 6], &[1, 2, 3, 2], p);
            // Tiles of one output line each, so tile boundaries are exercised too.
            let plan = Plan::with_tile_elems(&g, 1);
            assert_eq!(plan.tiles().count(), g.output[1]);
            let x: Vec<f64> = (0..2 * 42).map(|i| ((i * 37 % 11) as f64) - 5.0).collect();
            let mut lhs = 0.0;
            let mut dx = vec![0.0f64; x.len()];
            for lines in plan.tiles() {
                let n = g.k_len() * lines.len() * g.output[2];
                let c: Vec<f64> = (0..n).map(|i| ((i * 13 % 7) as f64) - 3.0).collect();
                let mut col = vec![0.0; n];
                plan.im2col(&x, &lines, &mut col);
                lhs += col.iter().zip(&c).map(|(a, b)| a * b).sum::<f64>();
                plan.col2im(&c, &lines, &mut dx);
            }
            let rhs: f64 = x.iter().zip(&dx).map(|(a, b)| a * b).sum();
            assert_eq!(lhs, rhs, "circular = {circular}");
        }
    }
}
