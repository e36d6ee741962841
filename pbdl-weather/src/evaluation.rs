//! RMSE and ACC against lead time for every baseline and a trained forecaster, all scored on
//! the same initialisation times with [`crate::score`]'s official semantics.

use crate::baselines::{persistence, Climatology, LinearRegression, WeeklyClimatology};
use crate::error::Result;
use crate::field::{Field, LeadForecast, Values};
use crate::forecaster::{predict, Dataset, Forecaster, Normalizer, SampleSpec};
use crate::score::{score, score_by_lead, Metric};
use serde::{Deserialize, Serialize};

/// One model's scores for one variable at one lead.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LeadScore {
    /// Model name (`persistence`, `climatology`, `linear_regression_direct`, ...).
    pub model: String,
    /// Variable name.
    pub variable: String,
    /// Lead time in hours.
    pub lead_hours: f64,
    /// Latitude-weighted RMSE (one square root).
    pub rmse: f64,
    /// Anomaly correlation coefficient.
    pub acc: f64,
}

/// The field restricted to the given time indices.
pub fn select_times(field: &Field, indices: &[usize]) -> Field {
    let p = field.grid.n_lat() * field.grid.n_lon();
    let v = field.values.to_f64();
    let values = indices.iter().flat_map(|&t| v[t * p..(t + 1) * p].iter().copied()).collect();
    Field {
        times: field.times.as_ref().map(|t| indices.iter().map(|&i| t[i]).collect()),
        values: Values::F64(values),
        ..field.clone()
    }
}

fn per_lead(model: &str, fc: &LeadForecast, truth: &Field) -> Result<Vec<LeadScore>> {
    let rmse = score_by_lead(Metric::Rmse, fc, truth)?;
    let acc = score_by_lead(Metric::Acc, fc, truth)?;
    Ok(fc
        .lead_hours
        .iter()
        .zip(rmse.iter().zip(&acc))
        .map(|(&lead_hours, (&rmse, &acc))| LeadScore {
            model: model.into(),
            variable: truth.name.clone(),
            lead_hours,
            rmse,
            acc,
        })
        .collect())
}

/// Settings of [`baseline_scores`].
#[derive(Clone, Debug, PartialEq)]
pub struct BaselineOptions {
    /// Leads in steps of the data.
    pub leads: Vec<usize>,
    /// Every `stride`-th training time fits the regressions (WeatherBench: 5).
    pub stride: usize,
    /// Ridge of the regressions (relative to the mean diagonal of X^T X).
    pub ridge: f64,
    /// Also the weekly climatology (needs whole years of training data).
    pub weekly: bool,
}

/// Persistence, climatology, weekly climatology, direct linear regression (one per lead) and
/// iterative linear regression (one step applied repeatedly) for variable `var`, initialised
/// at `inits` of `test`; climatologies and regressions are fitted on `train`.
pub fn baseline_scores(
    train: &Dataset,
    test: &Dataset,
    var: usize,
    inits: &[usize],
    opts: &BaselineOptions,
) -> Result<Vec<LeadScore>> {
    let truth = test.field(var);
    let init_field = select_times(&truth, inits);
    let train_field = train.field(var);
    let hours: Vec<f64> = opts.leads.iter().map(|&l| l as f64 * test.step_hours).collect();
    let mut out = per_lead("persistence", &persistence(&init_field, &hours)?, &truth)?;
    let clim = Climatology::fit(&train_field);
    let weekly = if opts.weekly { Some(WeeklyClimatology::fit(&train_field)?) } else { None };
    for &h in &hours {
        let shift = (h * 3600.0).round() as i64;
        let valid: Vec<i64> =
            init_field.times.as_ref().map(|t| t.iter().map(|x| x + shift).collect()).unwrap_or_default();
        let at_valid: Vec<i64> =
            valid.into_iter().filter(|t| truth.times.as_ref().is_some_and(|tt| tt.binary_search(t).is_ok())).collect();
        let f = clim.forecast(&at_valid);
        out.push(LeadScore {
            model: "climatology".into(),
            variable: truth.name.clone(),
            lead_hours: h,
            rmse: score(Metric::Rmse, &f, &truth)?,
            acc: score(Metric::Acc, &f, &truth)?,
        });
        if let Some(w) = &weekly {
            let f = w.forecast(&at_valid)?;
            out.push(LeadScore {
                model: "weekly_climatology".into(),
                variable: truth.name.clone(),
                lead_hours: h,
                rmse: score(Metric::Rmse, &f, &truth)?,
                acc: score(Metric::Acc, &f, &truth)?,
            });
        }
    }
    for &h in &hours {
        let lr = LinearRegression::fit(&train_field, h, opts.stride, opts.ridge)?;
        out.extend(per_lead("linear_regression_direct", &lr.forecast(&init_field, 1)?, &truth)?);
    }
    let step = LinearRegression::fit(&train_field, test.step_hours, opts.stride, opts.ridge)?;
    let max_steps = opts.leads.iter().copied().max().unwrap_or(1);
    let iterative = step.forecast(&init_field, max_steps)?;
    let scores = per_lead("linear_regression_iterative", &iterative, &truth)?;
    out.extend(scores.into_iter().filter(|s| hours.contains(&s.lead_hours)));
    Ok(out)
}

/// The forecaster's forecasts at each lead (in steps) from `inits`: one [`LeadForecast`] per
/// target variable holding every lead, in physical units.
pub fn network_forecasts(
    net: &dyn Forecaster,
    test: &Dataset,
    norm: &Normalizer,
    spec: &SampleSpec,
    inits: &[usize],
    leads: &[usize],
) -> Result<Vec<LeadForecast>> {
    let mut merged: Vec<LeadForecast> = Vec::new();
    for &lead in leads {
        let fcs = predict(net, test, norm, spec, inits, lead, 32)?;
        if merged.is_empty() {
            merged = fcs;
            continue;
        }
        for (m, f) in merged.iter_mut().zip(fcs) {
            m.lead_hours.extend_from_slice(&f.lead_hours);
            if let (Values::F64(a), Values::F64(b)) = (&mut m.values, &f.values) {
                a.extend_from_slice(b);
            }
        }
    }
    Ok(merged)
}

/// RMSE and ACC per lead of forecasts of `test`'s variables (matched by name).
pub fn forecast_scores(model: &str, forecasts: &[LeadForecast], test: &Dataset) -> Result<Vec<LeadScore>> {
    let mut out = Vec::new();
    for fc in forecasts {
        let var = test.variables.iter().position(|v| *v == fc.name).ok_or_else(|| {
            crate::Error::InvalidArgument(format!("forecast of '{}' but the data hold {:?}", fc.name, test.variables))
        })?;
        out.extend(per_lead(model, fc, &test.field(var))?);
    }
    Ok(out)
}

/// The forecaster's scores at each lead (in steps) from `inits`, for each target variable.
pub fn network_scores(
    model: &str,
    net: &dyn Forecaster,
    test: &Dataset,
    norm: &Normalizer,
    spec: &SampleSpec,
    inits: &[usize],
    leads: &[usize],
) -> Result<Vec<LeadScore>> {
    forecast_scores(model, &network_forecasts(net, test, norm, spec, inits, leads)?, test)
}

/// A markdown table: one row per model, RMSE (and ACC) per lead for one variable.
pub fn markdown_table(scores: &[LeadScore], variable: &str) -> String {
    let mut leads: Vec<f64> = scores.iter().filter(|s| s.variable == variable).map(|s| s.lead_hours).collect();
    leads.sort_by(f64::total_cmp);
    leads.dedup();
    let mut models: Vec<&str> = Vec::new();
    for s in scores.iter().filter(|s| s.variable == variable) {
        if !models.contains(&s.model.as_str()) {
            models.push(&s.model);
        }
    }
    let mut md = format!(
        "| {variable}: RMSE / ACC | {} |\n|---|{}\n",
        leads.iter().map(|l| format!("{l} h")).collect::<Vec<_>>().join(" | "),
        "---|".repeat(leads.len())
    );
    for m in models {
        let cells: Vec<String> = leads
            .iter()
            .map(|l| {
                scores
                    .iter()
                    .find(|s| s.model == m && s.variable == variable && s.lead_hours == *l)
                    .map_or("-".into(), |s| format!("{:.4} / {:.3}", s.rmse, s.acc))
            })
            .collect();
        md.push_str(&format!("| {m} | {} |\n", cells.join(" | ")));
    }
    md
}
