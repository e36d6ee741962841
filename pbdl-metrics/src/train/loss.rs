//! Ground truth and losses of metric training.
//!
//! A sequence of 11 frames gives 55 pairs `(i, j)`, `i < j`, ordered by [`pairs`]: first the ten
//! reference pairs `(0, 1) .. (0, 10)`, then the others. The ground truth distance of a pair is
//! a function of `t = (j - i) / 10`:
//!
//! - [`GroundTruth::Linear`] (LSiM): `g = t`.
//! - [`GroundTruth::Fit2`] (VolSiM's "fit2"): `g = log(10^c t + 1) / log(10^c + 1)`, with `c`
//!   fitted per sequence by least squares ([`fit_log_coefficient`]) to the min-max-normalised
//!   correlation distances `1 - |corr(frame_0, frame_k)|`, `k = 1..10` ([`fit2_coefficient`]).
//!
//! Losses ([`metric_loss`]): `w_mse * mean_pairs (d - g)^2 + 0.7 * 0.5 * (1 - r)`, with `r` the
//! Pearson correlation of `d` and `g` over the ten reference pairs. LSiM uses `w_mse = 0.3`,
//! VolSiM `w_mse = 1.0` ([`LossConfig`]).

use crate::classic::pearson_values;
use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Number of frames per sequence.
const FRAMES: usize = super::data::FRAMES;

/// The 55 pairs `(i, j)` of an 11-frame sequence: the 10 reference pairs `(0, j)` first, then
/// `(i, j)` for `1 <= i < j <= 10` row by row.
pub fn pairs() -> Vec<(usize, usize)> {
    (0..FRAMES).flat_map(|i| (i + 1..FRAMES).map(move |j| (i, j))).collect()
}

/// Which ground truth distances a sequence's pairs get.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GroundTruth {
    /// `g = (j - i) / 10` (LSiM).
    #[default]
    Linear,
    /// VolSiM's "fit2": `g = log(10^c t + 1) / log(10^c + 1)`, `c` fitted per sequence.
    Fit2,
}

/// VolSiM's log curve `log(10^c t + 1) / log(10^c + 1)`: `0` at `t = 0`, `1` at `t = 1`,
/// concave for every `c`, tending to `t` as `c -> -inf`.
pub fn log_curve(t: f64, c: f64) -> f64 {
    let a = 10f64.powf(c);
    (a * t).ln_1p() / a.ln_1p()
}

/// Range of the fitted coefficient `c`. Below `-4` the curve is linear to 1e-4, above `6` a
/// step; scipy's unbounded fit would wander off there without changing the curve.
pub const FIT_RANGE: (f64, f64) = (-4.0, 6.0);

/// Least-squares `c` of `y_k ~ log_curve(x_k, c)` within [`FIT_RANGE`]: a grid scan followed
/// by golden-section refinement (the objective is smooth in `c`, one parameter).
///
/// Errors: different lengths, fewer than two points, non-finite values.
pub fn fit_log_coefficient(x: &[f64], y: &[f64]) -> Result<f64> {
    if x.len() != y.len() || x.len() < 2 {
        return Err(Error::invalid(
            "fit_log_coefficient",
            "x, y",
            format!("need two lists of one length >= 2, got {} and {}", x.len(), y.len()),
        ));
    }
    if x.iter().chain(y).any(|v| !v.is_finite()) {
        return Err(Error::invalid("fit_log_coefficient", "x, y", "values must be finite"));
    }
    let sse = |c: f64| x.iter().zip(y).map(|(&t, &v)| (log_curve(t, c) - v).powi(2)).sum::<f64>();
    let (lo, hi) = FIT_RANGE;
    let n = 200;
    let step = (hi - lo) / n as f64;
    let best = (0..=n).map(|k| lo + k as f64 * step).min_by(|a, b| sse(*a).total_cmp(&sse(*b))).expect("non-empty");
    let (mut a, mut b) = ((best - step).max(lo), (best + step).min(hi));
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c1, mut c2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (sse(c1), sse(c2));
    for _ in 0..80 {
        if f1 < f2 {
            b = c2;
            (c2, f2) = (c1, f1);
            c1 = b - g * (b - a);
            f1 = sse(c1);
        } else {
            a = c1;
            (c1, f1) = (c2, f2);
            c2 = a + g * (b - a);
            f2 = sse(c2);
        }
    }
    Ok(0.5 * (a + b))
}

/// Correlation distances `1 - |pearson(frame_0, frame_k)|`, `k = 1..10`, of a sequence
/// `[11, 1, y, x]`. A constant frame has no correlation; it counts as distance 1.
pub fn correlation_distances(frames: &Tensor) -> Result<Vec<f64>> {
    let f = frames.to_dtype(DType::F64)?.flatten_from(1)?.to_vec2::<f64>()?;
    if f.len() != FRAMES {
        return Err(Error::Shape {
            op: "correlation_distances",
            arg: "frames",
            expected: format!("[{FRAMES}, 1, y, x]"),
            got: frames.dims().to_vec(),
        });
    }
    Ok(f[1..].iter().map(|fk| pearson_values(&f[0], fk).map(|r| 1.0 - r.abs()).unwrap_or(1.0)).collect())
}

/// The "fit2" coefficient of a sequence: [`fit_log_coefficient`] of the min-max-normalised
/// [`correlation_distances`] against `t = 0.1 .. 1.0`. Errors when all ten distances are equal
/// (nothing to fit; use [`GroundTruth::Linear`] for such a sequence).
pub fn fit2_coefficient(frames: &Tensor) -> Result<f64> {
    let d = correlation_distances(frames)?;
    let (lo, hi) = d.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    if hi - lo <= 0.0 {
        return Err(Error::invalid("fit2_coefficient", "frames", "all ten correlation distances are equal"));
    }
    let y: Vec<f64> = d.iter().map(|v| (v - lo) / (hi - lo)).collect();
    let x: Vec<f64> = (1..FRAMES).map(|k| k as f64 / (FRAMES - 1) as f64).collect();
    fit_log_coefficient(&x, &y)
}

/// Ground truth of the 55 [`pairs`] of one sequence `[11, 1, y, x]`.
pub fn ground_truth(gt: GroundTruth, frames: &Tensor) -> Result<Vec<f64>> {
    let t = pairs().into_iter().map(|(i, j)| (j - i) as f64 / (FRAMES - 1) as f64);
    Ok(match gt {
        GroundTruth::Linear => t.collect(),
        GroundTruth::Fit2 => match fit2_coefficient(frames) {
            Ok(c) => t.map(|t| log_curve(t, c)).collect(),
            // A degenerate sequence (e.g. constant frames) falls back to the linear truth.
            Err(_) => t.collect(),
        },
    })
}

/// Weights of [`metric_loss`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossConfig {
    /// Weight of the mean squared error over all pairs (LSiM 0.3, VolSiM 1.0).
    pub mse: f64,
    /// Weight of `0.5 (1 - r)` (both papers 0.7).
    pub correlation: f64,
    /// How many leading pairs enter the correlation (10: the reference pairs).
    pub correlation_pairs: usize,
}

impl LossConfig {
    /// LSiM: `0.3 MSE + 0.7 * 0.5 (1 - r)`.
    pub const LSIM: Self = Self { mse: 0.3, correlation: 0.7, correlation_pairs: 10 };
    /// VolSiM: `1.0 MSE + 0.7 * 0.5 (1 - r)`.
    pub const VOLSIM: Self = Self { mse: 1.0, correlation: 0.7, correlation_pairs: 10 };
}

impl Default for LossConfig {
    fn default() -> Self {
        Self::LSIM
    }
}

/// Pearson correlation of two 1D tensors, differentiable; `eps` guards a zero denominator as the
/// official code does (`r = sum(xm ym) / max(|xm| |ym|, eps)`).
pub fn pearson_1d(x: &Tensor, y: &Tensor, eps: f64) -> Result<Tensor> {
    if x.rank() != 1 || x.dims() != y.dims() || x.dim(0)? < 2 {
        return Err(Error::Shape {
            op: "pearson_1d",
            arg: "x",
            expected: format!("a vector of length >= 2 like y {:?}", y.dims()),
            got: x.dims().to_vec(),
        });
    }
    let xm = x.broadcast_sub(&x.mean_keepdim(0)?)?;
    let ym = y.broadcast_sub(&y.mean_keepdim(0)?)?;
    let num = (&xm * &ym)?.sum_all()?;
    let den = (xm.sqr()?.sum_all()?.sqrt()? * ym.sqr()?.sum_all()?.sqrt()?)?.maximum(eps)?;
    Ok((num / den)?)
}

/// `cfg.mse * mean (d - g)^2 + cfg.correlation * 0.5 * (1 - pearson(d[..k], g[..k]))`,
/// `k = cfg.correlation_pairs`; `d`, `g` 1D of one length (the 55 pairs). Differentiable in `d`.
pub fn metric_loss(d: &Tensor, g: &Tensor, cfg: &LossConfig) -> Result<Tensor> {
    if d.rank() != 1 || d.dims() != g.dims() {
        return Err(Error::ShapeMismatch { op: "metric_loss", a: d.dims().to_vec(), b: g.dims().to_vec() });
    }
    let k = cfg.correlation_pairs;
    if k < 2 || k > d.dim(0)? {
        return Err(Error::invalid(
            "metric_loss",
            "correlation_pairs",
            format!("must be in [2, {}] (the number of pairs), got {k}", d.dim(0)?),
        ));
    }
    let mse = (d - g)?.sqr()?.mean_all()?;
    let r = pearson_1d(&d.narrow(0, 0, k)?, &g.narrow(0, 0, k)?, 1e-7)?;
    let corr = ((1.0 - r)? * (0.5 * cfg.correlation))?;
    Ok(((mse * cfg.mse)? + corr)?)
}
