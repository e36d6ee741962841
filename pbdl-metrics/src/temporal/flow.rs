//! Dense optical flow: coarse-to-fine Horn–Schunck with warping.
//!
//! **Convention.** `x` is the column index (fastest axis), `y` the row index; whether row 0 is
//! the top or the bottom of the picture does not matter (the flow is in index units). The flow
//! `(u, v)` at pixel `(y, x)` of `frame0` is the displacement, in pixels, to where that content
//! sits in `frame1`:
//!
//! ```text
//! frame0(y, x) ≈ frame1(y + v(y, x), x + u(y, x))
//! ```
//!
//! the convention of OpenCV's Farnebäck (`prev(y, x) ≈ next(y + flow_y, x + flow_x)`) that
//! TecoGAN's tOF uses. Content moving right by 0.3 px between the frames gives `u = +0.3`.
//!
//! **Method.** The energy
//!
//! ```text
//! E(u, v) = sum_p (I1(p + w(p)) - I0(p))^2 + alpha^2 sum_(p,q neighbours) |w(p) - w(q)|^2
//! ```
//!
//! is minimised coarse to fine (Horn & Schunck 1981 with the warping scheme of Brox et al. 2004,
//! quadratic penalties). Both frames are first mapped jointly to [0, 1] (min/max of the pair; the
//! flow is then invariant to a common affine change of intensity, and `alpha` is in units of that
//! range per pixel) and smoothed with a Gaussian of `presmooth` pixels. A Gaussian pyramid
//! (Gaussian blur of sigma [`PYRAMID_SIGMA`], then 2x2 block means) is built down to
//! [`FlowOptions::min_side`]; on each level, from the coarsest, the flow upsampled from the
//! coarser level (bilinear, times 2) is refined by [`FlowOptions::warps`] outer iterations:
//!
//! 1. `frame1` is warped with the current flow (bicubic Keys interpolation, `a = -1/2`, edges
//!    replicated);
//! 2. the brightness constancy is linearised around the current flow, with gradients by
//!    fourth-order central differences (second-order next to the edges) of the mean of `frame0`
//!    and the warped `frame1`;
//! 3. the resulting linear Horn–Schunck system (4-neighbour smoothness, Neumann boundaries) is
//!    relaxed by [`FlowOptions::iterations`] red-black successive over-relaxation sweeps
//!    (coupled 2x2 per-pixel solves, factor [`FlowOptions::omega`]).
//!
//! Pixels whose warped position falls outside `frame1` carry no data term; the smoothness fills
//! them in. Work: about `(4/3) warps iterations` sweeps of ~40 flops per pixel; rows run on
//! rayon above [`pbdl_core::threads::parallel`]'s size threshold.
//!
//! The fixed point of the warping iterations is where the warped `frame1` equals `frame0`, so
//! the accuracy on smooth content is set by the bicubic warp, not by the finite-difference
//! gradients: an analytic sub-pixel shift and a 2 degree rotation are recovered to a few
//! thousandths of a pixel away from the border (see `tests/temporal_tests.rs`). Linear flow
//! fields (translation, rotation, shear) cost nothing in the smoothness term's Euler–Lagrange
//! equation, so the regulariser does not bias them except within a few pixels of the border.
//! Fields where the frames have no gradient (constant regions) get the flow interpolated from
//! their surroundings; two constant frames give zero flow.
//!
//! The estimator is not OpenCV's Farnebäck: tOF values computed with it are comparable with each
//! other (a temporal GAN against a per-frame baseline, on one data set), not with published
//! Farnebäck-based numbers.

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use rayon::prelude::*;

const OP: &str = "optical_flow";

/// Standard deviation in pixels of the Gaussian blur before each 2x downsampling of the pyramid.
/// Deliberately strong: content near a level's Nyquist frequency makes the finite-difference
/// gradients too small, and the warping iterations then overshoot. Measured on the test pattern
/// of `tests/temporal_tests.rs` (64x64): with 1.0 a (1.6, 0.9) px shift and with 1.2 a
/// (-5.5, 4.0) px shift were not recovered; with 1.5 both are, to 0.004 px.
pub const PYRAMID_SIGMA: f64 = 1.5;

/// The smallest side a frame may have for [`optical_flow`].
pub const MIN_FLOW_SIDE: usize = 8;

/// Parameters of [`optical_flow`]; `Default` is the tested setting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowOptions {
    /// The most pyramid levels, the full resolution included (>= 1). Default 5. Fewer levels are
    /// used where the coarsest would have a side below [`FlowOptions::min_side`]. Each level
    /// halves the resolution; motions up to about `2^(levels - 1)` pixels are found.
    pub levels: usize,
    /// The smallest side of the coarsest pyramid level (>= [`MIN_FLOW_SIDE`]). Default 16.
    pub min_side: usize,
    /// Outer warping iterations per level (>= 1). Default 5.
    pub warps: usize,
    /// Red-black SOR sweeps per warp (>= 1). Default 20.
    pub iterations: usize,
    /// Smoothness weight `alpha` (> 0), in units of the pair's [0, 1]-normalised intensity per
    /// pixel. Larger values give smoother flows; where the frames have little texture the flow
    /// is interpolated over a distance of about `alpha / |grad I|` pixels. Default 0.02.
    pub alpha: f64,
    /// SOR over-relaxation factor, in (0, 2). Default 1.8.
    pub omega: f64,
    /// Standard deviation in pixels of the Gaussian applied to both frames before the pyramid
    /// (>= 0; 0 turns it off). Default 1.0.
    pub presmooth: f64,
}

impl Default for FlowOptions {
    fn default() -> Self {
        Self { levels: 5, min_side: 16, warps: 5, iterations: 20, alpha: 0.02, omega: 1.8, presmooth: 1.0 }
    }
}

impl FlowOptions {
    fn validate(&self) -> Result<()> {
        let positive = |arg: &'static str, v: usize, min: usize| -> Result<()> {
            if v < min {
                return Err(Error::invalid(OP, arg, format!("must be at least {min}, got {v}")));
            }
            Ok(())
        };
        positive("levels", self.levels, 1)?;
        positive("min_side", self.min_side, MIN_FLOW_SIDE)?;
        positive("warps", self.warps, 1)?;
        positive("iterations", self.iterations, 1)?;
        if !(self.alpha > 0.0 && self.alpha.is_finite()) {
            return Err(Error::invalid(OP, "alpha", format!("must be positive and finite, got {}", self.alpha)));
        }
        if !(self.omega > 0.0 && self.omega < 2.0) {
            return Err(Error::invalid(OP, "omega", format!("must lie in (0, 2), got {}", self.omega)));
        }
        if !(self.presmooth >= 0.0 && self.presmooth.is_finite()) {
            return Err(Error::invalid(OP, "presmooth", format!("must be >= 0 and finite, got {}", self.presmooth)));
        }
        Ok(())
    }
}

/// A dense flow field on a `ny x nx` grid, row-major (x fastest); see the module docs for the
/// convention.
#[derive(Clone, Debug, PartialEq)]
pub struct Flow {
    /// Rows.
    pub ny: usize,
    /// Columns.
    pub nx: usize,
    /// x (column) component per pixel, `ny * nx` values.
    pub u: Vec<f32>,
    /// y (row) component per pixel, `ny * nx` values.
    pub v: Vec<f32>,
}

impl Flow {
    /// The flow `(u, v)` at row `y`, column `x`.
    ///
    /// Panics if `(y, x)` is outside the grid.
    pub fn at(&self, y: usize, x: usize) -> (f32, f32) {
        assert!(y < self.ny && x < self.nx, "Flow::at: ({y}, {x}) outside {}x{}", self.ny, self.nx);
        let i = y * self.nx + x;
        (self.u[i], self.v[i])
    }

    /// The flow as a tensor `[2, ny, nx]` (`f32`): channel 0 is `u` (x), channel 1 is `v` (y).
    pub fn to_tensor(&self, device: &Device) -> Result<Tensor> {
        let mut data = Vec::with_capacity(2 * self.u.len());
        data.extend_from_slice(&self.u);
        data.extend_from_slice(&self.v);
        Ok(Tensor::from_vec(data, (2, self.ny, self.nx), device)?)
    }

    /// Mean endpoint distance `|w_self - w_other|_2` over the pixels at least `border` pixels from
    /// every edge (the rows `border..ny - border`, the columns `border..nx - border`).
    ///
    /// Errors: different grids, or a border that leaves no pixel.
    pub fn mean_endpoint_error(&self, other: &Flow, border: usize) -> Result<f64> {
        const OP: &str = "Flow::mean_endpoint_error";
        if (self.ny, self.nx) != (other.ny, other.nx) {
            return Err(Error::ShapeMismatch { op: OP, a: vec![self.ny, self.nx], b: vec![other.ny, other.nx] });
        }
        if 2 * border >= self.ny || 2 * border >= self.nx {
            return Err(Error::invalid(
                OP,
                "border",
                format!("{border} leaves no pixel of a {}x{} grid", self.ny, self.nx),
            ));
        }
        let (mut sum, mut n) = (0.0f64, 0usize);
        for y in border..self.ny - border {
            for x in border..self.nx - border {
                let i = y * self.nx + x;
                let du = f64::from(self.u[i]) - f64::from(other.u[i]);
                let dv = f64::from(self.v[i]) - f64::from(other.v[i]);
                sum += (du * du + dv * dv).sqrt();
                n += 1;
            }
        }
        Ok(sum / n as f64)
    }
}

/// Dense optical flow from `frame0` to `frame1`, grey frames of `ny` rows and `nx` columns stored
/// row-major (x fastest). See the module docs for the convention and the method.
///
/// Errors (typed, naming the argument): a slice whose length is not `ny * nx`, a side below
/// [`MIN_FLOW_SIDE`], a NaN or infinity in a frame, options out of range.
pub fn optical_flow(frame0: &[f32], frame1: &[f32], ny: usize, nx: usize, opts: &FlowOptions) -> Result<Flow> {
    opts.validate()?;
    if ny < MIN_FLOW_SIDE || nx < MIN_FLOW_SIDE {
        return Err(Error::Shape {
            op: OP,
            arg: "frame0",
            expected: format!("a frame of at least {MIN_FLOW_SIDE}x{MIN_FLOW_SIDE} pixels"),
            got: vec![ny, nx],
        });
    }
    for (arg, f) in [("frame0", frame0), ("frame1", frame1)] {
        if f.len() != ny * nx {
            return Err(Error::Shape {
                op: OP,
                arg,
                expected: format!("{} values (ny = {ny} rows times nx = {nx} columns)", ny * nx),
                got: vec![f.len()],
            });
        }
        if let Some((index, &value)) = f.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(Error::NonFinite { op: OP, arg, index, value: f64::from(value) });
        }
    }
    Ok(estimate(frame0, frame1, ny, nx, opts))
}

/// [`optical_flow`] on tensors: each frame `[y, x]`, `[1, y, x]` or `[1, 1, y, x]`, `f32` or `f64`
/// (computed in `f32` input precision, `f64` arithmetic). Returns the flow `[2, y, x]` (`f32`,
/// channel 0 = x component `u`, channel 1 = y component `v`) on the frames' device.
///
/// Errors: other ranks or leading sizes, different shapes, non-float dtypes; otherwise as
/// [`optical_flow`].
pub fn optical_flow_tensor(frame0: &Tensor, frame1: &Tensor, opts: &FlowOptions) -> Result<Tensor> {
    let mut sizes = [(0, 0); 2];
    for (k, (arg, t)) in [("frame0", frame0), ("frame1", frame1)].into_iter().enumerate() {
        let d = t.dims();
        let r = d.len();
        let ok = (2..=4).contains(&r) && d[..r - 2].iter().all(|&s| s == 1);
        if !ok {
            return Err(Error::Shape {
                op: OP,
                arg,
                expected: "one grey frame [y, x], [1, y, x] or [1, 1, y, x]".into(),
                got: d.to_vec(),
            });
        }
        crate::check::float(OP, arg, t)?;
        sizes[k] = (d[r - 2], d[r - 1]);
    }
    if sizes[0] != sizes[1] {
        return Err(Error::ShapeMismatch { op: OP, a: frame0.dims().to_vec(), b: frame1.dims().to_vec() });
    }
    let (ny, nx) = sizes[0];
    let read = |t: &Tensor| -> Result<Vec<f32>> { Ok(t.flatten_all()?.to_dtype(DType::F32)?.to_vec1::<f32>()?) };
    let flow = optical_flow(&read(frame0)?, &read(frame1)?, ny, nx, opts)?;
    flow.to_tensor(frame0.device())
}

// ---------------------------------------------------------------------------------------------
// Implementation. Images are `Img` (row-major f64); everything below assumes validated input.

#[derive(Clone)]
struct Img {
    ny: usize,
    nx: usize,
    d: Vec<f64>,
}

impl Img {
    fn at(&self, y: usize, x: usize) -> f64 {
        self.d[y * self.nx + x]
    }
}

/// Runs `f(row_index, row)` over the rows of `out` (length `rows * row_len`), in parallel when
/// the thread policy says the work is large enough.
fn for_rows<F>(out: &mut [f64], row_len: usize, work: usize, f: F)
where
    F: Fn(usize, &mut [f64]) + Sync + Send,
{
    if pbdl_core::threads::parallel(work) {
        out.par_chunks_mut(row_len).enumerate().for_each(|(y, row)| f(y, row));
    } else {
        out.chunks_mut(row_len).enumerate().for_each(|(y, row)| f(y, row));
    }
}

fn gaussian_kernel(sigma: f64) -> Vec<f64> {
    let r = (3.0 * sigma).ceil().max(1.0) as i64;
    let k: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let s: f64 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Separable Gaussian blur with replicated edges.
fn blur(img: &Img, sigma: f64) -> Img {
    if sigma <= 0.0 {
        return img.clone();
    }
    let k = gaussian_kernel(sigma);
    let r = (k.len() / 2) as i64;
    let (ny, nx) = (img.ny, img.nx);
    let work = ny * nx * k.len() / 8;
    let mut tmp = vec![0.0; ny * nx];
    for_rows(&mut tmp, nx, work, |y, row| {
        let src = &img.d[y * nx..(y + 1) * nx];
        for (x, out) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for (j, w) in k.iter().enumerate() {
                let xx = (x as i64 + j as i64 - r).clamp(0, nx as i64 - 1) as usize;
                s += w * src[xx];
            }
            *out = s;
        }
    });
    let mut out = vec![0.0; ny * nx];
    for_rows(&mut out, nx, work, |y, row| {
        for (j, w) in k.iter().enumerate() {
            let yy = (y as i64 + j as i64 - r).clamp(0, ny as i64 - 1) as usize;
            let src = &tmp[yy * nx..(yy + 1) * nx];
            for (o, s) in row.iter_mut().zip(src) {
                *o += w * s;
            }
        }
    });
    Img { ny, nx, d: out }
}

/// Anti-aliased 2x downsampling: blur, then 2x2 block means (coarse pixel `i` covers fine
/// pixels `2i, 2i + 1`; a last odd row or column is dropped).
fn downsample(img: &Img) -> Img {
    let b = blur(img, PYRAMID_SIGMA);
    let (ny, nx) = (img.ny / 2, img.nx / 2);
    let mut d = vec![0.0; ny * nx];
    for y in 0..ny {
        for x in 0..nx {
            d[y * nx + x] = 0.25
                * (b.at(2 * y, 2 * x) + b.at(2 * y, 2 * x + 1) + b.at(2 * y + 1, 2 * x) + b.at(2 * y + 1, 2 * x + 1));
        }
    }
    Img { ny, nx, d }
}

/// Bilinear sample with clamped coordinates.
fn bilinear(img: &Img, y: f64, x: f64) -> f64 {
    let y = y.clamp(0.0, (img.ny - 1) as f64);
    let x = x.clamp(0.0, (img.nx - 1) as f64);
    let (y0, x0) = (y.floor() as usize, x.floor() as usize);
    let (y1, x1) = ((y0 + 1).min(img.ny - 1), (x0 + 1).min(img.nx - 1));
    let (ty, tx) = (y - y0 as f64, x - x0 as f64);
    let top = img.at(y0, x0) * (1.0 - tx) + img.at(y0, x1) * tx;
    let bot = img.at(y1, x0) * (1.0 - tx) + img.at(y1, x1) * tx;
    top * (1.0 - ty) + bot * ty
}

/// Flow of a coarse level upsampled to a fine grid of `ny x nx`: fine pixel `x` sits at coarse
/// coordinate `(x - 0.5) / 2`; values are doubled.
fn upsample_flow(c: &Img, ny: usize, nx: usize) -> Img {
    let mut d = vec![0.0; ny * nx];
    for y in 0..ny {
        for x in 0..nx {
            d[y * nx + x] = 2.0 * bilinear(c, (y as f64 - 0.5) / 2.0, (x as f64 - 0.5) / 2.0);
        }
    }
    Img { ny, nx, d }
}

/// Keys cubic convolution weights (a = -1/2) for the fractional offset `t` in [0, 1).
fn cubic_weights(t: f64) -> [f64; 4] {
    let a = -0.5;
    let w = |s: f64| {
        let s = s.abs();
        if s <= 1.0 {
            ((a + 2.0) * s - (a + 3.0)) * s * s + 1.0
        } else if s < 2.0 {
            ((a * s - 5.0 * a) * s + 8.0 * a) * s - 4.0 * a
        } else {
            0.0
        }
    };
    [w(1.0 + t), w(t), w(1.0 - t), w(2.0 - t)]
}

/// Bicubic (Keys) sample with replicated edges; `None` outside `[0, n - 1]` on either axis.
fn bicubic(img: &Img, y: f64, x: f64) -> Option<f64> {
    if !(0.0..=(img.ny - 1) as f64).contains(&y) || !(0.0..=(img.nx - 1) as f64).contains(&x) {
        return None;
    }
    let (fy, fx) = (y.floor(), x.floor());
    let (wy, wx) = (cubic_weights(y - fy), cubic_weights(x - fx));
    let (iy, ix) = (fy as i64, fx as i64);
    let mut s = 0.0;
    for (j, wyj) in wy.iter().enumerate() {
        let yy = (iy + j as i64 - 1).clamp(0, img.ny as i64 - 1) as usize;
        let row = &img.d[yy * img.nx..(yy + 1) * img.nx];
        let mut r = 0.0;
        for (i, wxi) in wx.iter().enumerate() {
            let xx = (ix + i as i64 - 1).clamp(0, img.nx as i64 - 1) as usize;
            r += wxi * row[xx];
        }
        s += wyj * r;
    }
    Some(s)
}

/// The whole estimator on validated input.
fn estimate(frame0: &[f32], frame1: &[f32], ny: usize, nx: usize, opts: &FlowOptions) -> Flow {
    // Joint [0, 1] normalisation of the pair.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &v in frame0.iter().chain(frame1) {
        lo = lo.min(f64::from(v));
        hi = hi.max(f64::from(v));
    }
    let scale = if hi > lo { 1.0 / (hi - lo) } else { 0.0 };
    let norm = |f: &[f32]| Img { ny, nx, d: f.iter().map(|&v| (f64::from(v) - lo) * scale).collect() };
    let mut p0 = vec![blur(&norm(frame0), opts.presmooth)];
    let mut p1 = vec![blur(&norm(frame1), opts.presmooth)];
    while p0.len() < opts.levels {
        let last = p0.last().expect("pyramid has a level");
        if last.ny / 2 < opts.min_side || last.nx / 2 < opts.min_side {
            break;
        }
        let (a, b) = (downsample(last), downsample(p1.last().expect("pyramid has a level")));
        p0.push(a);
        p1.push(b);
    }
    let coarsest = p0.last().expect("pyramid has a level");
    let zero = |img: &Img| Img { ny: img.ny, nx: img.nx, d: vec![0.0; img.ny * img.nx] };
    let (mut u, mut v) = (zero(coarsest), zero(coarsest));
    for level in (0..p0.len()).rev() {
        let (i0, i1) = (&p0[level], &p1[level]);
        if u.ny != i0.ny || u.nx != i0.nx {
            u = upsample_flow(&u, i0.ny, i0.nx);
            v = upsample_flow(&v, i0.ny, i0.nx);
        }
        for _ in 0..opts.warps {
            let sys = linearise(i0, i1, &u, &v);
            relax(&sys, &mut u, &mut v, opts);
        }
    }
    Flow { ny, nx, u: u.d.iter().map(|&x| x as f32).collect(), v: v.d.iter().map(|&x| x as f32).collect() }
}

/// Per-pixel coefficients of the linearised data term `(ix u + iy v + b)^2`, stored as
/// `[ix^2, ix iy, iy^2, ix b, iy b]` per pixel.
struct System {
    ny: usize,
    nx: usize,
    c: Vec<[f64; 5]>,
}

fn linearise(i0: &Img, i1: &Img, u: &Img, v: &Img) -> System {
    let (ny, nx) = (i0.ny, i0.nx);
    // Warped frame1 and its validity.
    let mut warped = vec![0.0; ny * nx];
    let mut valid = vec![false; ny * nx];
    for y in 0..ny {
        for x in 0..nx {
            let i = y * nx + x;
            match bicubic(i1, y as f64 + v.d[i], x as f64 + u.d[i]) {
                Some(s) => {
                    warped[i] = s;
                    valid[i] = true;
                }
                None => warped[i] = i0.d[i],
            }
        }
    }
    let mean: Vec<f64> = warped.iter().zip(&i0.d).map(|(a, b)| 0.5 * (a + b)).collect();
    let mut c = vec![[0.0; 5]; ny * nx];
    for y in 0..ny {
        for x in 0..nx {
            let i = y * nx + x;
            if !valid[i] {
                continue;
            }
            let ix = derivative(&mean[y * nx..(y + 1) * nx], 1, x, nx);
            let iy = derivative(&mean[x..], nx, y, ny);
            let it = warped[i] - i0.d[i];
            let b = it - ix * u.d[i] - iy * v.d[i];
            c[i] = [ix * ix, ix * iy, iy * iy, ix * b, iy * b];
        }
    }
    System { ny, nx, c }
}

/// Derivative along an axis of `n` samples `f[k * stride]` at index `i`: the fourth-order
/// central stencil `(f[i-2] - 8 f[i-1] + 8 f[i+1] - f[i+2]) / 12` in the interior, second-order
/// central differences next to the edges, one-sided at the edges.
fn derivative(f: &[f64], stride: usize, i: usize, n: usize) -> f64 {
    let at = |k: usize| f[k * stride];
    if i >= 2 && i + 2 < n {
        (at(i - 2) - 8.0 * at(i - 1) + 8.0 * at(i + 1) - at(i + 2)) / 12.0
    } else {
        let (l, r) = (i.saturating_sub(1), (i + 1).min(n - 1));
        (at(r) - at(l)) / (r - l) as f64
    }
}

/// Red-black SOR on the linear Horn–Schunck system; `u`, `v` hold the start and the result.
fn relax(sys: &System, u: &mut Img, v: &mut Img, opts: &FlowOptions) {
    let (ny, nx) = (sys.ny, sys.nx);
    let a2 = opts.alpha * opts.alpha;
    let omega = opts.omega;
    // Per pixel: the inverse of the 2x2 matrix [[ix^2 + a2 n, ix iy], [ix iy, iy^2 + a2 n]]
    // (n = neighbour count) as [i11, i12, i22], and the data right-hand side [ix b, iy b].
    let inv: Vec<[f64; 5]> = sys
        .c
        .iter()
        .enumerate()
        .map(|(i, &[a11, a12, a22, b1, b2])| {
            let (y, x) = (i / nx, i % nx);
            let n = [x > 0, x + 1 < nx, y > 0, y + 1 < ny].iter().filter(|&&b| b).count() as f64;
            let (m11, m22) = (a11 + a2 * n, a22 + a2 * n);
            let det = m11 * m22 - a12 * a12;
            [m22 / det, -a12 / det, m11 / det, b1, b2]
        })
        .collect();
    // Interleaved (u, v) per pixel; two buffers, one colour updated per half sweep.
    let mut cur: Vec<f64> = u.d.iter().zip(&v.d).flat_map(|(&a, &b)| [a, b]).collect();
    let mut next = cur.clone();
    let work = ny * nx * 4;
    for _ in 0..opts.iterations {
        for colour in 0..2 {
            let src = &cur;
            for_rows(&mut next, 2 * nx, work, |y, row| {
                row.copy_from_slice(&src[2 * y * nx..2 * (y + 1) * nx]);
                for x in ((y + colour) % 2..nx).step_by(2) {
                    let (mut su, mut sv) = (0.0, 0.0);
                    let mut add = |j: usize| {
                        su += src[2 * j];
                        sv += src[2 * j + 1];
                    };
                    if x > 0 {
                        add(y * nx + x - 1);
                    }
                    if x + 1 < nx {
                        add(y * nx + x + 1);
                    }
                    if y > 0 {
                        add((y - 1) * nx + x);
                    }
                    if y + 1 < ny {
                        add((y + 1) * nx + x);
                    }
                    let [i11, i12, i22, b1, b2] = inv[y * nx + x];
                    let (r1, r2) = (a2 * su - b1, a2 * sv - b2);
                    let (gu, gv) = (i11 * r1 + i12 * r2, i12 * r1 + i22 * r2);
                    let (pu, pv) = (row[2 * x], row[2 * x + 1]);
                    row[2 * x] = pu + omega * (gu - pu);
                    row[2 * x + 1] = pv + omega * (gv - pv);
                }
            });
            std::mem::swap(&mut cur, &mut next);
        }
    }
    for (i, pair) in cur.chunks_exact(2).enumerate() {
        u.d[i] = pair[0];
        v.d[i] = pair[1];
    }
}
