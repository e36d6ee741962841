//! The WeatherBench (v1) scores, with the semantics of the official `src/score.py`.
//!
//! * Weights `w_i = cos(lat_i) / mean cos(lat)` ([`crate::grid::lat_weights`]).
//! * [`Metric::Rmse`]: `sqrt(mean_{t,i,j} w_i (f - o)^2)`, ONE square root over time and space
//!   together (what `compute_weighted_rmse` returns with its default `mean_dims`).
//! * [`Metric::RmseMeanPerTime`]: the paper's formula, the time mean of per-forecast RMSEs
//!   `mean_t sqrt(mean_{i,j} w_i (f - o)^2)`; larger or equal by Jensen's inequality.
//! * [`Metric::Mae`]: `mean_{t,i,j} w_i |f - o|`.
//! * [`Metric::Acc`]: climatology `C` = the time mean of the whole truth passed in; anomalies
//!   `f' = f - C`, `o' = o - C` at the common times, each centred by its own unweighted mean over
//!   all times and points; `ACC = sum w f'' o'' / sqrt(sum w f''^2 sum w o''^2)`.
//!
//! Times are joined as xarray does (inner join on the time coordinate); fields without times
//! (`.npy`) are matched by position. NaN values are skipped in every mean and sum, as xarray's
//! `skipna` does, so a forecast with NaN where no truth exists scores on the rest. A forecast
//! by lead time is scored per lead with valid time = init + lead ([`score_by_lead`]).

use crate::error::{Error, Result};
use crate::field::{Field, Forecast, LeadForecast, Values};
use crate::grid::lat_weights;
use rayon::prelude::*;
use std::collections::HashMap;
use std::str::FromStr;

/// Calls `$body` with `$f` and `$o` bound to the typed slices of two [`Values`].
macro_rules! with_slices {
    ($a:expr, $b:expr, |$f:ident, $o:ident| $body:expr) => {
        match ($a, $b) {
            (Values::F32($f), Values::F32($o)) => $body,
            (Values::F32($f), Values::F64($o)) => $body,
            (Values::F64($f), Values::F32($o)) => $body,
            (Values::F64($f), Values::F64($o)) => $body,
        }
    };
}

/// A score of `score.py`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// Latitude-weighted RMSE, one square root over time and space (score.py's default).
    Rmse,
    /// The paper's RMSE: the mean over forecast times of per-time RMSEs.
    RmseMeanPerTime,
    /// Latitude-weighted mean absolute error.
    Mae,
    /// Latitude-weighted anomaly correlation coefficient.
    Acc,
}

impl Metric {
    /// The name used on the command line and as the JSON key.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Rmse => "rmse",
            Metric::RmseMeanPerTime => "rmse_mean_per_time",
            Metric::Mae => "mae",
            Metric::Acc => "acc",
        }
    }

    /// All metrics.
    pub const ALL: [Metric; 4] = [Metric::Rmse, Metric::RmseMeanPerTime, Metric::Mae, Metric::Acc];
}

impl FromStr for Metric {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Metric::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| {
            Error::InvalidArgument(format!("unknown metric '{s}'; use rmse, rmse_mean_per_time, mae or acc"))
        })
    }
}

/// A score: one number, or one per lead time.
#[derive(Clone, Debug, PartialEq)]
pub enum Score {
    /// A forecast at valid times.
    Single(f64),
    /// A forecast by lead time: `(lead hours, score)` per lead.
    PerLead {
        /// Lead times in hours.
        lead_hours: Vec<f64>,
        /// The score at each lead.
        values: Vec<f64>,
    },
}

impl Score {
    /// The JSON object the CLI prints: `{"rmse": x}` or `{"lead_time": [...], "rmse": [...]}`
    /// (NaN, where no time matched, as `null`).
    pub fn to_json(&self, metric: Metric) -> serde_json::Value {
        let num = |x: f64| if x.is_finite() { serde_json::json!(x) } else { serde_json::Value::Null };
        let mut obj = serde_json::Map::new();
        match self {
            Score::Single(x) => {
                obj.insert(metric.name().into(), num(*x));
            }
            Score::PerLead { lead_hours, values } => {
                let leads = lead_hours
                    .iter()
                    .map(|&h| if h.fract() == 0.0 { serde_json::json!(h as i64) } else { serde_json::json!(h) })
                    .collect();
                obj.insert("lead_time".into(), serde_json::Value::Array(leads));
                obj.insert(metric.name().into(), serde_json::Value::Array(values.iter().map(|&x| num(x)).collect()));
            }
        }
        serde_json::Value::Object(obj)
    }
}

/// Scores a forecast file's content against the truth.
pub fn evaluate(metric: Metric, forecast: &Forecast, truth: &Field) -> Result<Score> {
    match forecast {
        Forecast::Direct(f) => score(metric, f, truth).map(Score::Single),
        Forecast::ByLead(f) => {
            score_by_lead(metric, f, truth).map(|values| Score::PerLead { lead_hours: f.lead_hours.clone(), values })
        }
    }
}

/// `evaluate_iterative_forecast`: the score at each lead, valid time = init + lead. A lead
/// whose valid times miss the truth entirely scores NaN.
pub fn score_by_lead(metric: Metric, forecast: &LeadForecast, truth: &Field) -> Result<Vec<f64>> {
    (0..forecast.lead_hours.len())
        .map(|k| match score(metric, &forecast.at_lead(k), truth) {
            Err(Error::Mismatch(m)) if m.starts_with(NO_COMMON_TIMES) => Ok(f64::NAN),
            other => other,
        })
        .collect()
}

const NO_COMMON_TIMES: &str = "no common times";

/// One score of a forecast at valid times against the truth.
pub fn score(metric: Metric, forecast: &Field, truth: &Field) -> Result<f64> {
    check_grids(forecast, truth)?;
    let pairs = join_times(forecast, truth)?;
    let weights = lat_weights(&truth.grid.lat);
    let n_lon = truth.grid.n_lon();
    Ok(with_slices!(&forecast.values, &truth.values, |f, o| match metric {
        Metric::Rmse => rmse(f, o, &pairs, &weights, n_lon),
        Metric::RmseMeanPerTime => rmse_mean_per_time(f, o, &pairs, &weights, n_lon),
        Metric::Mae => mae(f, o, &pairs, &weights, n_lon),
        Metric::Acc => acc(f, o, &pairs, &weights, n_lon),
    }))
}

/// A stored value read as f64.
pub trait Sample: Copy + Send + Sync {
    /// The value in f64.
    fn get(self) -> f64;
}
impl Sample for f32 {
    #[inline(always)]
    fn get(self) -> f64 {
        self as f64
    }
}
impl Sample for f64 {
    #[inline(always)]
    fn get(self) -> f64 {
        self
    }
}

/// Same latitudes (to 1e-6 degrees) and the same number of longitudes; nothing is regridded.
fn check_grids(forecast: &Field, truth: &Field) -> Result<()> {
    let (gf, gt) = (&forecast.grid, &truth.grid);
    if gf.n_lat() != gt.n_lat() || gf.n_lon() != gt.n_lon() {
        return Err(Error::Mismatch(format!(
            "forecast grid {}x{} ({}) vs truth grid {}x{} ({}); regrid one of them first",
            gf.n_lat(),
            gf.n_lon(),
            forecast.source.display(),
            gt.n_lat(),
            gt.n_lon(),
            truth.source.display()
        )));
    }
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6);
    if !close(&gf.lat, &gt.lat) {
        return Err(Error::Mismatch(format!(
            "latitudes differ between {} and {} (first: {} vs {})",
            forecast.source.display(),
            truth.source.display(),
            gf.lat[0],
            gt.lat[0]
        )));
    }
    if !close(&gf.lon, &gt.lon) {
        return Err(Error::Mismatch(format!(
            "longitudes differ between {} and {}",
            forecast.source.display(),
            truth.source.display()
        )));
    }
    Ok(())
}

/// `(forecast time index, truth time index)` of the inner join on time, in forecast order;
/// by position when either field has no times.
pub fn join_times(forecast: &Field, truth: &Field) -> Result<Vec<(usize, usize)>> {
    let (nf, nt) = (forecast.n_time(), truth.n_time());
    let pairs: Vec<(usize, usize)> = match (&forecast.times, &truth.times) {
        (Some(tf), Some(tt)) => {
            let mut index = HashMap::with_capacity(tt.len());
            for (j, t) in tt.iter().enumerate() {
                if index.insert(*t, j).is_some() {
                    return Err(Error::Coordinate {
                        file: truth.source.clone(),
                        var: truth.name.clone(),
                        coord: "time".into(),
                        problem: format!("time {} occurs twice", crate::time::format_time(*t)),
                    });
                }
            }
            tf.iter().enumerate().filter_map(|(i, t)| index.get(t).map(|&j| (i, j))).collect()
        }
        _ if nf == nt => (0..nf).map(|i| (i, i)).collect(),
        _ => {
            return Err(Error::Mismatch(format!(
                "{nf} forecast times ({}) vs {nt} truth times ({}); without time coordinates (.npy) the fields are matched by position and need the same length",
                forecast.source.display(),
                truth.source.display()
            )))
        }
    };
    if pairs.is_empty() {
        return Err(Error::Mismatch(format!(
            "{NO_COMMON_TIMES} between {} and {}",
            forecast.source.display(),
            truth.source.display()
        )));
    }
    Ok(pairs)
}

/// Per time pair, `(sum_{i,j} w_i g(f, o), number of non-NaN terms)`, in pair order (so the
/// final sums do not depend on thread scheduling).
fn weighted_sums<F: Sample, O: Sample>(
    f: &[F],
    o: &[O],
    pairs: &[(usize, usize)],
    weights: &[f64],
    n_lon: usize,
    g: impl Fn(f64) -> f64 + Sync,
) -> Vec<(f64, usize)> {
    let plane = weights.len() * n_lon;
    pairs
        .par_iter()
        .map(|&(i, j)| {
            let (fp, op) = (&f[i * plane..(i + 1) * plane], &o[j * plane..(j + 1) * plane]);
            let (mut sum, mut count) = (0.0, 0usize);
            for (row, &w) in weights.iter().enumerate() {
                let (fr, or) = (&fp[row * n_lon..(row + 1) * n_lon], &op[row * n_lon..(row + 1) * n_lon]);
                let mut row_sum = 0.0;
                // Branch-free so that the loop vectorises: NaN terms add 0 and count 0.
                let mut row_count = 0usize;
                for (a, b) in fr.iter().zip(or) {
                    let e = a.get() - b.get();
                    let valid = !e.is_nan();
                    row_sum += if valid { g(e) } else { 0.0 };
                    row_count += valid as usize;
                }
                count += row_count;
                sum += w * row_sum;
            }
            (sum, count)
        })
        .collect()
}

fn rmse<F: Sample, O: Sample>(f: &[F], o: &[O], pairs: &[(usize, usize)], w: &[f64], n_lon: usize) -> f64 {
    let sums = weighted_sums(f, o, pairs, w, n_lon, |e| e * e);
    let (s, n) = sums.iter().fold((0.0, 0usize), |(s, n), &(a, b)| (s + a, n + b));
    (s / n as f64).sqrt()
}

fn rmse_mean_per_time<F: Sample, O: Sample>(
    f: &[F],
    o: &[O],
    pairs: &[(usize, usize)],
    w: &[f64],
    n_lon: usize,
) -> f64 {
    let sums = weighted_sums(f, o, pairs, w, n_lon, |e| e * e);
    // Times with no valid point give NaN and are skipped in the time mean, as xarray's mean.
    let per_time: Vec<f64> = sums.iter().filter(|(_, n)| *n > 0).map(|&(s, n)| (s / n as f64).sqrt()).collect();
    per_time.iter().sum::<f64>() / per_time.len() as f64
}

fn mae<F: Sample, O: Sample>(f: &[F], o: &[O], pairs: &[(usize, usize)], w: &[f64], n_lon: usize) -> f64 {
    let sums = weighted_sums(f, o, pairs, w, n_lon, f64::abs);
    let (s, n) = sums.iter().fold((0.0, 0usize), |(s, n), &(a, b)| (s + a, n + b));
    s / n as f64
}

/// The per-point time mean of a whole field (NaN skipped): score.py's `da_true.mean('time')`.
pub fn time_mean<O: Sample>(o: &[O], plane: usize) -> Vec<f64> {
    let n_time = o.len() / plane;
    let chunk = 256;
    let mut mean = vec![0.0; plane];
    mean.par_chunks_mut(chunk).enumerate().for_each(|(c, out)| {
        let start = c * chunk;
        let mut count = vec![0usize; out.len()];
        for t in 0..n_time {
            let src = &o[t * plane + start..t * plane + start + out.len()];
            for ((m, n), x) in out.iter_mut().zip(count.iter_mut()).zip(src) {
                let x = x.get();
                if !x.is_nan() {
                    *m += x;
                    *n += 1;
                }
            }
        }
        for (m, n) in out.iter_mut().zip(count) {
            *m /= n as f64; // NaN where a point is never valid, as xarray
        }
    });
    mean
}

fn acc<F: Sample, O: Sample>(f: &[F], o: &[O], pairs: &[(usize, usize)], w: &[f64], n_lon: usize) -> f64 {
    let plane = w.len() * n_lon;
    let clim = time_mean(o, plane);
    // One pass over the common times. Centring by the means m_f, m_o is applied afterwards by
    // expanding the sums, e.g. sum w (f' - m_f)(o' - m_o) = sum w f'o' - m_o sum w f' - m_f
    // sum w o' + m_f m_o sum w, each sum over the points where its own terms are not NaN (as
    // xarray's skipna sums them separately).
    let sums: Vec<[f64; 14]> = pairs
        .par_iter()
        .map(|&(i, j)| {
            let (fp, op) = (&f[i * plane..(i + 1) * plane], &o[j * plane..(j + 1) * plane]);
            let mut t = [0.0; 14];
            for (row, &wr) in w.iter().enumerate() {
                // Per row: sum f', n_f, sum o', n_o (unweighted), then both-valid sums f'o', f',
                // o', n and f-valid f'^2, f', n and o-valid o'^2, o', n (weighted below).
                let mut r = [0.0; 14];
                let cols = row * n_lon..(row + 1) * n_lon;
                for ((a, b), c) in fp[cols.clone()].iter().zip(&op[cols.clone()]).zip(&clim[cols]) {
                    let (fa, oa) = (a.get() - c, b.get() - c);
                    let (fv, ov) = (!fa.is_nan(), !oa.is_nan());
                    let (fz, oz) = (if fv { fa } else { 0.0 }, if ov { oa } else { 0.0 });
                    let both = fv && ov;
                    let (fb, ob) = (if both { fz } else { 0.0 }, if both { oz } else { 0.0 });
                    r[0] += fz;
                    r[1] += fv as u8 as f64;
                    r[2] += oz;
                    r[3] += ov as u8 as f64;
                    r[4] += fb * ob;
                    r[5] += fb;
                    r[6] += ob;
                    r[7] += both as u8 as f64;
                    r[8] += fz * fz;
                    r[9] += fz;
                    r[10] += fv as u8 as f64;
                    r[11] += oz * oz;
                    r[12] += oz;
                    r[13] += ov as u8 as f64;
                }
                for k in 0..4 {
                    t[k] += r[k];
                }
                for k in 4..14 {
                    t[k] += wr * r[k];
                }
            }
            t
        })
        .collect();
    let mut t = [0.0; 14];
    for s in &sums {
        for k in 0..14 {
            t[k] += s[k];
        }
    }
    let (mf, mo) = (t[0] / t[1], t[2] / t[3]);
    let num = t[4] - mo * t[5] - mf * t[6] + mf * mo * t[7];
    let dff = t[8] - 2.0 * mf * t[9] + mf * mf * t[10];
    let doo = t[11] - 2.0 * mo * t[12] + mo * mo * t[13];
    num / (dff * doo).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::LatLonGrid;

    fn field(times: Vec<i64>, values: Vec<f64>) -> Field {
        Field::new("z", Some(times), LatLonGrid::weatherbench(4), Values::F64(values)).unwrap()
    }

    fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect()
    }

    #[test]
    fn constant_bias_gives_rmse_and_mae_equal_to_the_bias_and_acc_one() {
        let truth = field(vec![0, 3600, 7200], noise(3 * 32, 1).iter().map(|x| 300.0 + 10.0 * x).collect());
        let fc =
            Field { values: Values::F64(truth.values.to_f64().iter().map(|x| x + 2.5).collect()), ..truth.clone() };
        for m in [Metric::Rmse, Metric::RmseMeanPerTime, Metric::Mae] {
            assert!((score(m, &fc, &truth).unwrap() - 2.5).abs() < 1e-12, "{m:?}");
        }
        assert!((score(Metric::Acc, &fc, &truth).unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(score(Metric::Rmse, &truth, &truth).unwrap(), 0.0);
    }

    #[test]
    fn latitude_only_error_gives_the_closed_form_weighted_rmse() {
        // error e_i on latitude row i: RMSE = sqrt(sum_i w_i e_i^2 / n_lat) with weights of mean 1.
        let grid = LatLonGrid::weatherbench(4);
        let e = [1.0, -2.0, 3.0, 0.5];
        let truth = field(vec![0, 3600], vec![0.0; 64]);
        let fc = field(vec![0, 3600], (0..64).map(|k| e[(k % 32) / 8]).collect());
        let w: Vec<f64> = grid.lat.iter().map(|l| l.to_radians().cos()).collect();
        let wm = w.iter().sum::<f64>() / 4.0;
        let expected = (w.iter().zip(e).map(|(w, e)| w / wm * e * e).sum::<f64>() / 4.0).sqrt();
        assert!((score(Metric::Rmse, &fc, &truth).unwrap() - expected).abs() < 1e-12);
    }

    #[test]
    fn rmse_has_one_square_root_and_the_paper_form_averages_per_time_rmses() {
        // time 0 error 1 everywhere, time 1 error 3: one root sqrt(5), per-time mean 2.
        let truth = field(vec![0, 3600], vec![0.0; 64]);
        let fc = field(vec![0, 3600], (0..64).map(|k| if k < 32 { 1.0 } else { 3.0 }).collect());
        assert!((score(Metric::Rmse, &fc, &truth).unwrap() - 5f64.sqrt()).abs() < 1e-12);
        assert!((score(Metric::RmseMeanPerTime, &fc, &truth).unwrap() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn times_join_inner_and_nan_is_skipped() {
        let truth = field(vec![0, 3600, 7200], (0..96).map(|k| (k / 32) as f64).collect());
        // forecast at 3600 (exact) and 10800 (no truth) and 7200 with NaN at one point.
        let mut v: Vec<f64> = (0..96).map(|k| [1.0, 0.0, 2.0][k / 32]).collect();
        v[70] = f64::NAN;
        let fc = field(vec![3600, 10800, 7200], v);
        assert_eq!(score(Metric::Rmse, &fc, &truth).unwrap(), 0.0);
        let none = field(vec![99, 98, 97], vec![0.0; 96]);
        assert!(matches!(score(Metric::Rmse, &none, &truth), Err(Error::Mismatch(_))));
    }

    #[test]
    fn acc_of_a_perfect_forecast_is_one_and_of_independent_noise_near_zero() {
        let n = 200;
        let truth = field((0..n as i64).map(|t| t * 3600).collect(), noise(n * 32, 7));
        assert!((score(Metric::Acc, &truth, &truth).unwrap() - 1.0).abs() < 1e-12);
        let fc = field((0..n as i64).map(|t| t * 3600).collect(), noise(n * 32, 8));
        let acc = score(Metric::Acc, &fc, &truth).unwrap();
        assert!(acc.abs() < 0.1, "acc of independent noise {acc}");
        // Mirrored about the climatology: anomalies of opposite sign, ACC = -1.
        let o = truth.values.to_f64();
        let clim = time_mean(&o, 32);
        let mirrored = o.iter().enumerate().map(|(k, x)| 2.0 * clim[k % 32] - x).collect();
        let neg = Field { values: Values::F64(mirrored), ..truth.clone() };
        assert!((score(Metric::Acc, &neg, &truth).unwrap() + 1.0).abs() < 1e-12);
    }
}
