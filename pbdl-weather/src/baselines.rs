//! WeatherBench's baselines: persistence, climatology, weekly climatology and linear
//! regression (direct and iterative), on any [`Field`].
//!
//! Definitions as in the WeatherBench notebooks: persistence is the truth at initialisation
//! time; climatology the per-point time mean of the training data; weekly climatology the mean
//! per ISO week of year (pandas' `time.dt.week`); linear regression maps the flattened field at
//! time t (plus a bias) to the field at t + lead, fitted on every `stride`-th training time
//! (WeatherBench: every 5th) by least squares. Forecasts come out as [`LeadForecast`]s (or
//! [`Field`]s at valid times) ready for [`crate::score`].

use crate::error::{Error, Result};
use crate::field::{Field, LeadForecast, Values};
use crate::time::{civil_from_days, days_from_civil, Seconds, HOUR};
use faer::linalg::solvers::Solve;
use faer::{Mat, Side};
use std::collections::HashMap;

fn times_of(field: &Field) -> Result<&[Seconds]> {
    field.times.as_deref().ok_or_else(|| {
        Error::InvalidArgument(format!("field '{}' has no times; baselines need time coordinates", field.name))
    })
}

fn plane_len(field: &Field) -> usize {
    field.grid.n_lat() * field.grid.n_lon()
}

/// Persistence: for every initialisation time of `truth` and every lead, the state at
/// initialisation. Scoring joins valid times, so leads past the data's end drop out.
pub fn persistence(truth: &Field, lead_hours: &[f64]) -> Result<LeadForecast> {
    let init_times = times_of(truth)?.to_vec();
    let v = truth.values.to_f64();
    let mut values = Vec::with_capacity(v.len() * lead_hours.len());
    for _ in lead_hours {
        values.extend_from_slice(&v);
    }
    Ok(LeadForecast {
        name: truth.name.clone(),
        lead_hours: lead_hours.to_vec(),
        init_times,
        grid: truth.grid.clone(),
        values: Values::F64(values),
        source: Default::default(),
    })
}

/// Per-point time mean of the training data.
#[derive(Clone, Debug, PartialEq)]
pub struct Climatology {
    /// The template (name and grid) forecasts are built on.
    template: Field,
    /// Mean per grid point.
    pub mean: Vec<f64>,
}

impl Climatology {
    /// Fits the per-point mean of `train`.
    pub fn fit(train: &Field) -> Self {
        let p = plane_len(train);
        let mean = with_f64(&train.values, |v| crate::score::time_mean(v, p));
        Self { template: empty_like(train), mean }
    }

    /// The climatology at each of `times`.
    pub fn forecast(&self, times: &[Seconds]) -> Field {
        let mut values = Vec::with_capacity(times.len() * self.mean.len());
        for _ in times {
            values.extend_from_slice(&self.mean);
        }
        Field { times: Some(times.to_vec()), values: Values::F64(values), ..self.template.clone() }
    }
}

fn empty_like(f: &Field) -> Field {
    Field { times: None, values: Values::F64(Vec::new()), ..f.clone() }
}

fn with_f64<R>(values: &Values, f: impl FnOnce(&[f64]) -> R) -> R {
    match values {
        Values::F64(v) => f(v),
        Values::F32(v) => f(&v.iter().map(|&x| x as f64).collect::<Vec<_>>()),
    }
}

/// ISO 8601 week number (1..=53) of a time, as pandas' `Timestamp.week`.
pub fn iso_week(t: Seconds) -> u32 {
    let days = t.div_euclid(86_400);
    // 1970-01-01 was a Thursday; ISO weekday 1 = Monday.
    let weekday = (days + 3).rem_euclid(7) + 1;
    // The week belongs to the year of its Thursday.
    let thursday = days - weekday + 4;
    let (year, _, _) = civil_from_days(thursday);
    ((thursday - days_from_civil(year, 1, 1)) / 7 + 1) as u32
}

/// Mean per ISO week of year.
#[derive(Clone, Debug, PartialEq)]
pub struct WeeklyClimatology {
    template: Field,
    /// Mean plane per week 1..=53 (index week - 1); `None` where training had no such week.
    pub by_week: Vec<Option<Vec<f64>>>,
}

impl WeeklyClimatology {
    /// Fits the mean per ISO week of `train`.
    pub fn fit(train: &Field) -> Result<Self> {
        let times = times_of(train)?;
        let p = plane_len(train);
        let v = train.values.to_f64();
        let mut sums = vec![(vec![0.0; p], 0usize); 53];
        for (i, &t) in times.iter().enumerate() {
            let (s, n) = &mut sums[iso_week(t) as usize - 1];
            s.iter_mut().zip(&v[i * p..(i + 1) * p]).for_each(|(a, b)| *a += b);
            *n += 1;
        }
        let by_week =
            sums.into_iter().map(|(s, n)| (n > 0).then(|| s.into_iter().map(|x| x / n as f64).collect())).collect();
        Ok(Self { template: empty_like(train), by_week })
    }

    /// The weekly mean at each of `times`.
    pub fn forecast(&self, times: &[Seconds]) -> Result<Field> {
        let mut values = Vec::new();
        for &t in times {
            let w = iso_week(t);
            let plane = self.by_week[w as usize - 1].as_ref().ok_or_else(|| {
                Error::InvalidArgument(format!("ISO week {w} is not in the training data; train on whole years"))
            })?;
            values.extend_from_slice(plane);
        }
        Ok(Field { times: Some(times.to_vec()), values: Values::F64(values), ..self.template.clone() })
    }
}

/// A linear map from the field at t (and a bias) to the field at t + lead.
#[derive(Clone, Debug, PartialEq)]
pub struct LinearRegression {
    template: Field,
    /// The lead it predicts, hours.
    pub lead_hours: f64,
    /// Coefficients, `(P + 1) x P` row-major: row 0 is the bias, row 1 + q the weight of input
    /// point q.
    pub coef: Vec<f64>,
}

impl LinearRegression {
    /// Least squares on the pairs `(x(t), x(t + lead))` of `train` for every `stride`-th t,
    /// with a ridge `ridge * mean(diag(X^T X))` on the weights (0 gives plain least squares;
    /// a tiny value keeps the normal equations solvable when points are collinear).
    pub fn fit(train: &Field, lead_hours: f64, stride: usize, ridge: f64) -> Result<Self> {
        let times = times_of(train)?;
        if stride == 0 || ridge.is_nan() || ridge < 0.0 {
            return Err(Error::InvalidArgument(format!("stride must be >= 1 and ridge >= 0 (got {stride}, {ridge})")));
        }
        let p = plane_len(train);
        let index: HashMap<Seconds, usize> = times.iter().enumerate().map(|(i, &t)| (t, i)).collect();
        let shift = (lead_hours * HOUR as f64).round() as Seconds;
        let pairs: Vec<(usize, usize)> =
            (0..times.len()).step_by(stride).filter_map(|i| index.get(&(times[i] + shift)).map(|&j| (i, j))).collect();
        if pairs.len() < 2 {
            return Err(Error::InvalidArgument(format!("only {} training pairs {lead_hours} h apart", pairs.len())));
        }
        let v = train.values.to_f64();
        let x = Mat::<f64>::from_fn(pairs.len(), p + 1, |r, c| if c == 0 { 1.0 } else { v[pairs[r].0 * p + c - 1] });
        let y = Mat::<f64>::from_fn(pairs.len(), p, |r, c| v[pairs[r].1 * p + c]);
        let mut xtx = x.transpose() * &x;
        let xty = x.transpose() * &y;
        let mean_diag = (1..=p).map(|i| xtx[(i, i)]).sum::<f64>() / p as f64;
        for i in 1..=p {
            xtx[(i, i)] += ridge * mean_diag;
        }
        let llt = xtx.llt(Side::Lower).map_err(|_| {
            Error::InvalidArgument("the normal equations are singular: use a ridge > 0 or more training times".into())
        })?;
        let w = llt.solve(&xty);
        let coef = (0..=p).flat_map(|r| (0..p).map(move |c| (r, c))).map(|(r, c)| w[(r, c)]).collect();
        Ok(Self { template: empty_like(train), lead_hours, coef })
    }

    /// One application of the map to a plane.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        let p = x.len();
        let mut y = self.coef[..p].to_vec();
        for (q, &xq) in x.iter().enumerate() {
            let row = &self.coef[(q + 1) * p..(q + 2) * p];
            y.iter_mut().zip(row).for_each(|(a, w)| *a += xq * w);
        }
        y
    }

    /// Forecasts from every time of `init`: lead `k * self.lead_hours` for `k = 1..=steps`,
    /// applying the map `k` times (direct when `steps = 1`, iterative beyond).
    pub fn forecast(&self, init: &Field, steps: usize) -> Result<LeadForecast> {
        let init_times = times_of(init)?.to_vec();
        let p = plane_len(init);
        if p * (p + 1) != self.coef.len() {
            return Err(Error::InvalidArgument(format!(
                "the regression was fitted on {} points, not {p}",
                self.coef.len() / (p + 1)
            )));
        }
        let v = init.values.to_f64();
        let n = init_times.len();
        // All initial states at once: one matrix product [n, P + 1] x [P + 1, P] per step.
        let w = Mat::<f64>::from_fn(p + 1, p, |r, c| self.coef[r * p + c]);
        let mut state = Mat::<f64>::from_fn(n, p + 1, |i, c| if c == 0 { 1.0 } else { v[i * p + c - 1] });
        let mut values = vec![0.0; steps * n * p];
        for k in 0..steps {
            let next = &state * &w;
            for i in 0..n {
                for c in 0..p {
                    values[(k * n + i) * p + c] = next[(i, c)];
                }
            }
            state = Mat::<f64>::from_fn(n, p + 1, |i, c| if c == 0 { 1.0 } else { next[(i, c - 1)] });
        }
        Ok(LeadForecast {
            name: init.name.clone(),
            lead_hours: (1..=steps).map(|k| k as f64 * self.lead_hours).collect(),
            init_times,
            grid: init.grid.clone(),
            values: Values::F64(values),
            source: Default::default(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso_weeks_match_pandas() {
        let at = |y, m, d| days_from_civil(y, m, d) * 86_400;
        // pandas: Timestamp('2017-01-01').week == 52, '2017-01-02' == 1, '2020-12-31' == 53,
        // '2018-12-31' == 1.
        assert_eq!(iso_week(at(2017, 1, 1)), 52);
        assert_eq!(iso_week(at(2017, 1, 2)), 1);
        assert_eq!(iso_week(at(2020, 12, 31)), 53);
        assert_eq!(iso_week(at(2018, 12, 31)), 1);
    }

    #[test]
    fn regression_recovers_an_exact_linear_map() {
        // Even hours hold random states, odd hours A x + b of the hour before: fitting every
        // 2nd time with a 1 h lead sees exact pairs and must return A and b.
        let grid = crate::grid::LatLonGrid { lat: vec![0.0], lon: vec![0.0, 120.0, 240.0] };
        let (a, b) = ([[0.9, -0.2, 0.1], [0.2, 0.8, 0.0], [0.0, 0.3, 0.7]], [0.5, -1.0, 2.0]);
        let mut values = Vec::new();
        for t in 0..20 {
            let x = [(t as f64 * 1.3).sin(), (t as f64 * 0.7).cos() * 2.0, (t * t % 7) as f64 - 3.0];
            values.extend_from_slice(&x);
            values.extend((0..3).map(|r| b[r] + (0..3).map(|c| a[r][c] * x[c]).sum::<f64>()));
        }
        let times: Vec<i64> = (0..40).map(|t| t * 3600).collect();
        let f = Field::new("x", Some(times), grid, Values::F64(values)).unwrap();
        let lr = LinearRegression::fit(&f, 1.0, 2, 0.0).unwrap();
        for c in 0..3 {
            assert!((lr.coef[c] - b[c]).abs() < 1e-9, "bias {c}: {}", lr.coef[c]);
            for q in 0..3 {
                // row 1 + q holds the weight of input q on output c: A[c][q].
                assert!((lr.coef[(1 + q) * 3 + c] - a[c][q]).abs() < 1e-9);
            }
        }
        let two = lr.forecast(&f, 2).unwrap();
        assert_eq!(two.lead_hours, vec![1.0, 2.0]);
    }
}
