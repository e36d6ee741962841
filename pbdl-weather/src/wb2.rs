//! WeatherBench 2's score variants (Rasp et al. 2024): area weights, the RMSE as the square
//! root of the time-mean MSE, the ACC computed per time against a climatology by day of year
//! and hour (no centring) and then averaged over time.
//!
//! The climatology is [`DayHourClimatology`]: the mean of the training data per (day of year,
//! hour of day), optionally over a window of days around each day (WeatherBench 2's ERA5
//! climatology uses 1990-2019 with a 61-day window).

use crate::error::{Error, Result};
use crate::field::Field;
use crate::grid::area_weights;
use crate::score::join_times;
use crate::time::{day_of_year_and_hour, Seconds};
use std::collections::BTreeMap;

fn times(field: &Field) -> Result<&[Seconds]> {
    field.times.as_deref().ok_or_else(|| Error::InvalidArgument(format!("field '{}' has no times", field.name)))
}

/// Mean per (day of year 1..=366, hour of day).
#[derive(Clone, Debug, PartialEq)]
pub struct DayHourClimatology {
    plane: usize,
    /// `(day of year, hour) -> mean plane`.
    pub means: BTreeMap<(u32, u32), Vec<f64>>,
}

impl DayHourClimatology {
    /// Fits the climatology of `train`: for each (day, hour) present, the mean over all training
    /// times at that hour whose day of year is within `window_days / 2` (circular over the
    /// year; `window_days = 1` is the plain per-day mean).
    pub fn fit(train: &Field, window_days: u32) -> Result<Self> {
        let t = times(train)?;
        let plane = train.grid.n_lat() * train.grid.n_lon();
        let v = train.values.to_f64();
        // Sums per exact (day, hour) first, then windowed.
        let mut exact: BTreeMap<(u32, u32), (Vec<f64>, usize)> = BTreeMap::new();
        for (i, &ti) in t.iter().enumerate() {
            let e = exact.entry(day_of_year_and_hour(ti)).or_insert_with(|| (vec![0.0; plane], 0));
            e.0.iter_mut().zip(&v[i * plane..(i + 1) * plane]).for_each(|(a, b)| *a += b);
            e.1 += 1;
        }
        let half = (window_days.max(1) - 1) / 2;
        let circular = |a: u32, b: u32| {
            let d = a.abs_diff(b);
            d.min(366 - d)
        };
        let mut means = BTreeMap::new();
        for &(day, hour) in exact.keys() {
            let mut sum = vec![0.0; plane];
            let mut n = 0;
            for (&(d, h), (s, c)) in &exact {
                if h == hour && circular(d, day) <= half {
                    sum.iter_mut().zip(s).for_each(|(a, b)| *a += b);
                    n += c;
                }
            }
            means.insert((day, hour), sum.into_iter().map(|x| x / n as f64).collect());
        }
        Ok(Self { plane, means })
    }

    /// The climatology at a time.
    pub fn at(&self, t: Seconds) -> Result<&[f64]> {
        let key = day_of_year_and_hour(t);
        self.means.get(&key).map(Vec::as_slice).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "no climatology for day {} hour {}: fit on whole years at the same hours",
                key.0, key.1
            ))
        })
    }
}

/// `sqrt(mean_t mean_{i,j} w_i (f - o)^2)` with area weights (NaN skipped per time).
pub fn rmse(forecast: &Field, truth: &Field) -> Result<f64> {
    let pairs = join_times(forecast, truth)?;
    let w = area_weights(&truth.grid.lat);
    let n_lon = truth.grid.n_lon();
    let p = w.len() * n_lon;
    let (f, o) = (forecast.values.to_f64(), truth.values.to_f64());
    let mut per_time = Vec::with_capacity(pairs.len());
    for &(i, j) in &pairs {
        let (mut s, mut n) = (0.0, 0usize);
        for q in 0..p {
            let e = f[i * p + q] - o[j * p + q];
            if !e.is_nan() {
                s += w[q / n_lon] * e * e;
                n += 1;
            }
        }
        if n > 0 {
            per_time.push(s / n as f64);
        }
    }
    Ok((per_time.iter().sum::<f64>() / per_time.len() as f64).sqrt())
}

/// The time mean of per-time ACCs `sum w f' o' / sqrt(sum w f'^2 sum w o'^2)` with anomalies
/// from `clim` at each valid time, area weights, no centring.
pub fn acc(forecast: &Field, truth: &Field, clim: &DayHourClimatology) -> Result<f64> {
    let pairs = join_times(forecast, truth)?;
    let w = area_weights(&truth.grid.lat);
    let n_lon = truth.grid.n_lon();
    let p = w.len() * n_lon;
    if clim.plane != p {
        return Err(Error::InvalidArgument(format!("climatology has {} points per map, the fields {p}", clim.plane)));
    }
    let tt = times(truth)?;
    let (f, o) = (forecast.values.to_f64(), truth.values.to_f64());
    let mut per_time = Vec::new();
    for &(i, j) in &pairs {
        let c = clim.at(tt[j])?;
        let (mut fo, mut ff, mut oo) = (0.0, 0.0, 0.0);
        for q in 0..p {
            let (fa, oa) = (f[i * p + q] - c[q], o[j * p + q] - c[q]);
            if !(fa.is_nan() || oa.is_nan()) {
                let wq = w[q / n_lon];
                fo += wq * fa * oa;
                ff += wq * fa * fa;
                oo += wq * oa * oa;
            }
        }
        let a = fo / (ff * oo).sqrt();
        if a.is_finite() {
            per_time.push(a);
        }
    }
    Ok(per_time.iter().sum::<f64>() / per_time.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::Values;
    use crate::grid::LatLonGrid;

    #[test]
    fn wb2_scores_of_analytic_cases() {
        let grid = LatLonGrid::weatherbench(4);
        // Two years of 12-hourly data: a seasonal cycle plus a weather signal.
        let times: Vec<i64> = (0..2 * 730).map(|k| 1_483_228_800 + 43_200 * k).collect();
        let signal = |k: usize, q: usize| ((k * 7 + q * 3) % 11) as f64 - 5.0;
        let season = |t: i64| 10.0 * ((t as f64) / (365.25 * 86_400.0) * std::f64::consts::TAU).sin();
        let values: Vec<f64> =
            times.iter().enumerate().flat_map(|(k, &t)| (0..32).map(move |q| season(t) + signal(k, q))).collect();
        let truth = Field::new("z", Some(times.clone()), grid.clone(), Values::F64(values.clone())).unwrap();
        let clim = DayHourClimatology::fit(&truth, 1).unwrap();
        // A perfect forecast: RMSE 0 and ACC 1; a constant bias b: RMSE = b.
        assert_eq!(rmse(&truth, &truth).unwrap(), 0.0);
        assert!((acc(&truth, &truth, &clim).unwrap() - 1.0).abs() < 1e-12);
        let biased = Field { values: Values::F64(values.iter().map(|x| x + 3.0).collect()), ..truth.clone() };
        assert!((rmse(&biased, &truth).unwrap() - 3.0).abs() < 1e-12);
        // The climatology itself as forecast has zero anomalies: ACC undefined (skipped), so
        // use the negated anomalies instead: ACC = -1 at every time.
        let mut mirrored = Vec::with_capacity(values.len());
        for (k, &t) in times.iter().enumerate() {
            let c = clim.at(t).unwrap();
            mirrored.extend((0..32).map(|q| 2.0 * c[q] - values[k * 32 + q]));
        }
        let neg = Field { values: Values::F64(mirrored), ..truth.clone() };
        assert!((acc(&neg, &truth, &clim).unwrap() + 1.0).abs() < 1e-12);
    }
}
