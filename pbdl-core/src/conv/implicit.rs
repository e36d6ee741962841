//! Implicit-GEMM convolution for stride 1 and one group: no im2col matrix is built.
//!
//! Each image is copied once into a padded buffer `xp` of shape `[c_in, Dp, Hp, Wp]` (zero or
//! periodic border). With stride 1, the input value that kernel tap `t` reads for output
//! position `(z, y, x)` sits at `xp[c, z + tz dz, y + ty dy, x + tx dx]`, i.e. at the flat
//! index `c P + off_t + p` with `P = Dp Hp Wp`, `off_t` the tap's offset and
//! `p = (z Hp + y) Wp + x` the output position laid out with the padded row length ("wide"
//! positions; the columns `x >= ow` are garbage). So for every tap the im2col rows of that tap
//! are a plain strided view of `xp` (row stride `P`, column stride 1), and
//!
//! * forward: `y_wide = sum_t W_t xp[off_t..]`, one accumulating matrix product per tap
//!   (`W_t[o, c] = w[o, c, t]`), then the valid columns are copied out;
//! * input gradient: `gxp[off_t..] += W_t^T gy_wide` with the garbage columns of `gy_wide` set
//!   to zero, then `gxp` is folded back onto the input (cropped for zero padding, wrapped and
//!   summed for periodic padding);
//! * weight gradient: `gw_t += gy_wide xp[off_t..]^T`, a product whose inner dimension is the
//!   output positions.
//!
//! Output positions are tiled by lines within one output plane, so the wide tile and the part
//! of `xp` it reads stay in cache. Work is split over images like the im2col path (each image
//! writes its own block; weight-gradient partials per thread are summed in a fixed order).
//!
//! The path is off unless `PBDL_CONV_IMPLICIT=1` (see [`enabled`] for why).

use super::depthwise::{self, Padding};
use super::epilogue::Epilogue;
use super::geometry::Geometry;
use crate::matmul::{matmul, split, Mat};
use crate::Real;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Target bytes of one tile's working set (input window and wide output, all channels).
const TILE_BYTES: usize = 256 << 10;

/// Whether the implicit path is switched on: only with the environment variable
/// `PBDL_CONV_IMPLICIT=1` (read once). Off by default: on 2 threads it measured only 2-8%
/// faster than im2col in forward + both gradients at 64-128 channels (the bar for switching
/// was 10%), though 3-47% at 2-32 channels (bench `conv_implicit`, probe test below).
pub(crate) fn enabled() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var("PBDL_CONV_IMPLICIT").is_ok_and(|v| v.trim() == "1"))
}

/// Whether the implicit path computes `g`: switched on ([`enabled`]) and [`eligible`].
pub(crate) fn handles(g: &Geometry) -> bool {
    enabled() && eligible(g)
}

/// Whether the implicit path can compute `g`: stride 1, one group, not pointwise (im2col is the
/// input itself there), not depthwise, and direct kernels allowed (`conv_im2col` turns them
/// off to compare paths), at least one input channel (the shifted views need a buffer). No
/// channel threshold: it was faster from 2 channels on.
fn eligible(g: &Geometry) -> bool {
    g.direct && g.groups == 1 && g.stride == [1; 3] && g.c_in > 0 && !g.pointwise() && !depthwise::handles(g)
}

/// One tile of output lines `y0..y0 + rows` in output plane `z`.
#[derive(Clone, Copy, Debug)]
struct Tile {
    /// Wide index of the tile's first position (also its offset in `xp` for tap 0).
    base: usize,
    /// Wide columns of the tile: `(rows - 1) Wp + ow` (the last row's garbage is left out).
    n: usize,
    /// Output lines in the tile.
    rows: usize,
    /// Index of the tile's first output within an output channel.
    out: usize,
}

/// The padded layout of one convolution: the padding (shared with the depthwise kernels), tap
/// offsets and tiles.
struct Layout {
    padding: Padding,
    /// Padded spatial size `[Dp, Hp, Wp]`.
    dims: [usize; 3],
    input: [usize; 3],
    /// Offset in a padded channel of each kernel tap, in weight order `(tz, ty, tx)`.
    offsets: Vec<usize>,
    output: [usize; 3],
    /// Output lines per tile.
    tile_rows: usize,
}

impl Layout {
    fn new<T>(g: &Geometry) -> Self {
        let padding = Padding::new(g);
        let dims = padding.dims;
        let [kd, kh, kw] = g.kernel;
        let [dd, dh, dw] = g.dilation;
        let mut offsets = Vec::with_capacity(kd * kh * kw);
        for tz in 0..kd {
            for ty in 0..kh {
                for tx in 0..kw {
                    offsets.push((tz * dd * dims[1] + ty * dh) * dims[2] + tx * dw);
                }
            }
        }
        let row_bytes = (g.c_in + g.c_out) * dims[2] * std::mem::size_of::<T>();
        let tile_rows = (TILE_BYTES / row_bytes.max(1)).clamp(1, g.output[1].max(1));
        Layout { padding, dims, input: g.input, offsets, output: g.output, tile_rows }
    }

    /// Elements of one padded channel.
    fn plane(&self) -> usize {
        self.dims.iter().product()
    }

    /// Columns of the widest tile.
    fn max_n(&self) -> usize {
        (self.tile_rows - 1) * self.dims[2] + self.output[2]
    }

    /// The tiles, plane by plane (a tile never spans two output planes: the rows between them
    /// are not output positions).
    fn tiles(&self) -> impl Iterator<Item = Tile> + '_ {
        let [od, oh, ow] = self.output;
        let [_, hp, wp] = self.dims;
        (0..od).flat_map(move |z| {
            (0..oh).step_by(self.tile_rows).map(move |y0| {
                let rows = self.tile_rows.min(oh - y0);
                Tile { base: (z * hp + y0) * wp, n: (rows - 1) * wp + ow, rows, out: (z * oh + y0) * ow }
            })
        })
    }

    /// Fills the padded channels `xp` from the input channels `x` (`channels` of each).
    fn fill<T: Real>(&self, x: &[T], channels: usize, xp: &mut [T]) {
        let (in_len, plane) = (self.input.iter().product::<usize>(), self.plane());
        for c in 0..channels {
            self.padding.fill(&x[c * in_len..][..in_len], &mut xp[c * plane..][..plane]);
        }
    }

    /// The adjoint of [`Layout::fill`]: adds every padded value to the input position it was
    /// read from (`gx` must hold the running sum, zero at first).
    fn fold<T: Real>(&self, xp: &[T], channels: usize, gx: &mut [T]) {
        let (in_len, plane) = (self.input.iter().product::<usize>(), self.plane());
        for c in 0..channels {
            self.padding.fold(&xp[c * plane..][..plane], &mut gx[c * in_len..][..in_len]);
        }
    }

    /// Writes the output channels `src` (`channels` rows of `src_rs` elements) into the wide
    /// tile `dst` (`channels` rows of `tile.n`), zeroing the garbage columns.
    fn widen<T: Real>(&self, src: &[T], src_rs: usize, channels: usize, tile: Tile, dst: &mut [T]) {
        let (ow, wp) = (self.output[2], self.dims[2]);
        for c in 0..channels {
            let s = &src[c * src_rs + tile.out..][..tile.rows * ow];
            let d = &mut dst[c * tile.n..][..tile.n];
            for (r, line) in s.chunks_exact(ow).enumerate() {
                d[r * wp..r * wp + ow].copy_from_slice(line);
                if r + 1 < tile.rows {
                    d[r * wp + ow..(r + 1) * wp].fill(T::zero());
                }
            }
        }
    }
}

/// The weight in tap-major order `[taps, c_out, c_in]`, so each tap's matrix is contiguous.
fn taps_first<T: Real>(g: &Geometry, w: &[T]) -> Vec<T> {
    let taps = g.kernel.iter().product::<usize>();
    let (cout, cin) = (g.c_out, g.c_in);
    let mut out = vec![T::zero(); w.len()];
    for o in 0..cout {
        for c in 0..cin {
            for t in 0..taps {
                out[(t * cout + o) * cin + c] = w[(o * cin + c) * taps + t];
            }
        }
    }
    out
}

/// `y = conv(x, w)`, then `epilogue` (bias per output channel and activation) per tile; `y` is
/// overwritten. Requires [`handles`].
pub(crate) fn forward<T: Real>(g: &Geometry, x: &[T], w: &[T], epilogue: Option<(&[T], Epilogue)>, y: &mut [T]) {
    let (cin, cout) = (g.c_in, g.c_out);
    let (in_len, out_len, ow) = (g.in_len(), g.out_len(), g.output[2]);
    if g.batch == 0 || cout * out_len == 0 {
        return;
    }
    let lay = Layout::new::<T>(g);
    let (plane, wp) = (lay.plane(), lay.dims[2]);
    let wt = taps_first(g, w);
    let (_, par) = split(g.batch);
    let scratch = || (vec![T::zero(); cin * plane], vec![T::zero(); cout * lay.max_n()]);
    y.par_chunks_mut(cout * out_len).enumerate().for_each_init(scratch, |(xp, yw), (b, yb)| {
        lay.fill(&x[b * cin * in_len..][..cin * in_len], cin, xp);
        for tile in lay.tiles() {
            let n = tile.n;
            for (t, &off) in lay.offsets.iter().enumerate() {
                let wm = Mat { data: &wt[t * cout * cin..][..cout * cin], rs: cin, cs: 1 };
                let xm = Mat { data: &xp[tile.base + off..], rs: plane, cs: 1 };
                matmul(yw, n, t > 0, wm, xm, (cout, n, cin), T::one(), par);
            }
            for (o, yo) in yb.chunks_exact_mut(out_len).enumerate() {
                let dst = &mut yo[tile.out..][..tile.rows * ow];
                for (r, line) in dst.chunks_exact_mut(ow).enumerate() {
                    line.copy_from_slice(&yw[o * n + r * wp..][..ow]);
                }
                if let Some((bias, e)) = epilogue {
                    e.apply(dst, bias[o]);
                }
            }
        }
    });
}

/// `gx = grad_input(gy, w)`; `gx` must be zero on entry. Requires [`handles`].
pub(crate) fn grad_input<T: Real>(g: &Geometry, gy: &[T], w: &[T], gx: &mut [T]) {
    let (cin, cout) = (g.c_in, g.c_out);
    let (in_len, out_len) = (g.in_len(), g.out_len());
    if g.batch == 0 || cin * in_len == 0 {
        return;
    }
    let lay = Layout::new::<T>(g);
    let plane = lay.plane();
    let wt = taps_first(g, w);
    let (_, par) = split(g.batch);
    let scratch = || (vec![T::zero(); cin * plane], vec![T::zero(); cout * lay.max_n()]);
    gx.par_chunks_mut(cin * in_len).enumerate().for_each_init(scratch, |(gxp, gyw), (b, gxb)| {
        gxp.fill(T::zero());
        let gyb = &gy[b * cout * out_len..][..cout * out_len];
        for tile in lay.tiles() {
            let n = tile.n;
            lay.widen(gyb, out_len, cout, tile, gyw);
            let gm = Mat { data: &gyw[..cout * n], rs: n, cs: 1 };
            for (t, &off) in lay.offsets.iter().enumerate() {
                // W_t^T: element (c, o) of the tap's [c_out, c_in] block.
                let wm = Mat { data: &wt[t * cout * cin..][..cout * cin], rs: 1, cs: cin };
                matmul(&mut gxp[tile.base + off..], plane, true, wm, gm, (cin, n, cout), T::one(), par);
            }
        }
        lay.fold(gxp, cin, gxb);
    });
}

/// `gw = grad_weight(x, gy)`; `gw` is overwritten. Requires [`handles`].
///
/// Images are split into one contiguous range per thread; each range sums into its own
/// accumulator and the accumulators are added in order, so the result does not depend on
/// scheduling.
pub(crate) fn grad_weight<T: Real>(g: &Geometry, x: &[T], gy: &[T], gw: &mut [T]) {
    let (cin, cout) = (g.c_in, g.c_out);
    let (in_len, out_len) = (g.in_len(), g.out_len());
    gw.fill(T::zero());
    if g.batch == 0 || gw.is_empty() || out_len == 0 {
        return;
    }
    let lay = Layout::new::<T>(g);
    let plane = lay.plane();
    let taps = lay.offsets.len();
    let (chunks, par) = split(g.batch);
    let per = g.batch.div_ceil(chunks);
    let partials: Vec<Vec<T>> = (0..chunks)
        .into_par_iter()
        .map(|ci| {
            // Tap-major [taps, c_out, c_in], so each tap's block has unit column stride.
            let mut acc = vec![T::zero(); gw.len()];
            let mut xp = vec![T::zero(); cin * plane];
            let mut gyw = vec![T::zero(); cout * lay.max_n()];
            for b in ci * per..((ci + 1) * per).min(g.batch) {
                lay.fill(&x[b * cin * in_len..][..cin * in_len], cin, &mut xp);
                let gyb = &gy[b * cout * out_len..][..cout * out_len];
                for tile in lay.tiles() {
                    let n = tile.n;
                    lay.widen(gyb, out_len, cout, tile, &mut gyw);
                    let gm = Mat { data: &gyw[..cout * n], rs: n, cs: 1 };
                    for (t, &off) in lay.offsets.iter().enumerate() {
                        // xp window^T: element (position, c).
                        let xm = Mat { data: &xp[tile.base + off..], rs: 1, cs: plane };
                        let dst = &mut acc[t * cout * cin..][..cout * cin];
                        matmul(dst, cin, true, gm, xm, (cout, cin, n), T::one(), par);
                    }
                }
            }
            acc
        })
        .collect();
    let mut sum = vec![T::zero(); gw.len()];
    for p in partials {
        sum.iter_mut().zip(&p).for_each(|(a, &b)| *a += b);
    }
    for o in 0..cout {
        for c in 0..cin {
            for t in 0..taps {
                gw[(o * cin + c) * taps + t] = sum[(t * cout + o) * cin + c];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::{Conv2dParams, PaddingMode};

    #[test]
    fn eligible_geometries() {
        let p = Conv2dParams::default().padding(1);
        let geo = |x: &[usize], w: &[usize], p: Conv2dParams| Geometry::new("t", x, w, &p).unwrap();
        assert!(eligible(&geo(&[2, 16, 8, 8], &[4, 16, 3, 3], p)));
        assert!(eligible(&geo(&[2, 2, 8, 8], &[4, 2, 3, 3], p)));
        assert!(eligible(&geo(&[2, 16, 8, 8], &[4, 16, 1, 1], p)), "1x1 with padding is not pointwise");
        assert!(!eligible(&geo(&[2, 16, 8, 8], &[4, 16, 1, 1], Conv2dParams::default())), "pointwise");
        assert!(!eligible(&geo(&[2, 16, 8, 8], &[4, 16, 3, 3], p.stride(2))), "strided");
        assert!(!eligible(&geo(&[2, 16, 8, 8], &[4, 8, 3, 3], p.groups(2))), "grouped");
        assert!(!eligible(&geo(&[2, 1, 8, 8], &[1, 1, 3, 3], p)), "depthwise");
        assert!(!eligible(&geo(&[2, 0, 8, 8], &[4, 0, 3, 3], p)), "no input channels");
        let mut g = geo(&[2, 16, 8, 8], &[4, 16, 3, 3], p);
        g.direct = false;
        assert!(!eligible(&g), "conv_im2col");
    }

    /// Kernel-level timing of both paths, whatever [`enabled`] says (the issue-17 probe; run
    /// with `cargo test -p pbdl-core --release --lib conv::implicit -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn probe_timing() {
        use std::time::Instant;
        crate::threads::init_with(crate::threads::ThreadPolicy { threads: 2, serial_below: 192 * 192 }).unwrap();
        let per_x = |q: Conv2dParams| Conv2dParams { padding_mode: [PaddingMode::Zeros, PaddingMode::Circular], ..q };
        let p = Conv2dParams::default().padding(1);
        let cases = [
            ("64ch 32x32", [4, 64, 32, 32], p),
            ("64ch 64x64", [4, 64, 64, 64], p),
            ("128ch 32x64 per-x", [4, 128, 32, 64], per_x(p)),
            ("32ch 64x64", [4, 32, 64, 64], p),
            ("16ch 64x64", [4, 16, 64, 64], p),
            ("8ch 64x64", [4, 8, 64, 64], p),
            ("4ch 64x64", [4, 4, 64, 64], p),
            ("2ch 64x64", [4, 2, 64, 64], p),
        ];
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        for (name, xs, p) in cases {
            let ws = [xs[1], xs[1], 3, 3];
            let g = Geometry::new("probe", &xs, &ws, &p).unwrap();
            let mut gi = g;
            gi.direct = false;
            let x: Vec<f32> =
                (0..g.batch * g.c_in * g.in_len()).map(|i| ((i * 7919 % 101) as f32) / 50.0 - 1.0).collect();
            let w: Vec<f32> = (0..g.c_out * g.k_len()).map(|i| ((i * 31 % 17) as f32) / 80.0 - 0.1).collect();
            let gy: Vec<f32> =
                (0..g.batch * g.c_out * g.out_len()).map(|i| ((i * 13 % 23) as f32) / 11.0 - 1.0).collect();
            let mut y = vec![0f32; gy.len()];
            let mut gx = vec![0f32; x.len()];
            let mut gw = vec![0f32; w.len()];
            let iters = (40 * 64 * 64 * 64 / (xs[1] * xs[2] * xs[3])).clamp(10, 100);
            let time = |f: &mut dyn FnMut()| {
                f();
                let v: Vec<f64> = (0..iters)
                    .map(|_| {
                        let s = Instant::now();
                        f();
                        s.elapsed().as_secs_f64() * 1e3
                    })
                    .collect();
                median(v)
            };
            // [path][round] -> [fwd, gx, gw]
            let mut res = [Vec::new(), Vec::new()];
            for _ in 0..3 {
                for (k, geo) in [gi, g].iter().enumerate() {
                    let fwd = time(&mut || {
                        if k == 0 {
                            super::super::forward::conv_forward(geo, &x, &w, &mut y)
                        } else {
                            forward(geo, &x, &w, None, &mut y)
                        }
                    });
                    let gxt = time(&mut || {
                        gx.fill(0.0);
                        if k == 0 {
                            super::super::backward::conv_grad_input(geo, &gy, &w, &mut gx)
                        } else {
                            grad_input(geo, &gy, &w, &mut gx)
                        }
                    });
                    let gwt = time(&mut || {
                        if k == 0 {
                            super::super::backward::conv_grad_weight(geo, &x, &gy, &mut gw)
                        } else {
                            grad_weight(geo, &x, &gy, &mut gw)
                        }
                    });
                    res[k].push([fwd, gxt, gwt]);
                }
            }
            // Lower bound of any im2col-free forward on this gemm: one K = k_len product per
            // image from a ready im2col matrix.
            let col: Vec<f32> = (0..g.k_len() * g.out_len()).map(|i| ((i * 7 % 19) as f32) / 9.0 - 1.0).collect();
            let gemm_only = time(&mut || {
                y.par_chunks_mut(g.c_out * g.out_len()).for_each(|yb| {
                    let wm = Mat { data: &w, rs: g.k_len(), cs: 1 };
                    let cm = Mat { data: &col, rs: g.out_len(), cs: 1 };
                    matmul(
                        yb,
                        g.out_len(),
                        false,
                        wm,
                        cm,
                        (g.c_out, g.out_len(), g.k_len()),
                        1.0,
                        crate::matmul::Threads::Serial,
                    );
                })
            });
            println!("{name:<18} gemm only (fwd, ready im2col matrix) {gemm_only:6.2} ms");
            let mut tot = [0.0; 2];
            for (k, path) in ["im2col", "implicit"].iter().enumerate() {
                let m = |j: usize| median(res[k].iter().map(|r| r[j]).collect());
                tot[k] = m(0) + m(1) + m(2);
                let rounds: Vec<String> = res[k].iter().map(|r| format!("{:.2}", r[0] + r[1] + r[2])).collect();
                println!(
                    "{name:<18} {path:<8} fwd {:6.2} gx {:6.2} gw {:6.2} total {:6.2} ms (rounds {})",
                    m(0),
                    m(1),
                    m(2),
                    tot[k],
                    rounds.join(" / ")
                );
            }
            println!("{name:<18} implicit / im2col = {:.3}", tot[1] / tot[0]);
        }
    }
}
