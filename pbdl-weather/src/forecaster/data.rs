//! Training samples for the forecaster: several variables at several past times plus
//! constant fields (and the lead time) in, the target variables at `t + lead` out, each
//! channel normalised by its mean and standard deviation.

use crate::error::{Error, Result};
use crate::field::{Field, LeadForecast, Values};
use crate::grid::LatLonGrid;
use crate::time::Seconds;
use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};

/// Equally spaced multi-variable data `[time, variable, lat, lon]` plus constant maps.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// Variable names, in channel order.
    pub variables: Vec<String>,
    /// Times, equally spaced by `step_hours`.
    pub times: Vec<Seconds>,
    /// Hours between consecutive times.
    pub step_hours: f64,
    /// The grid.
    pub grid: LatLonGrid,
    /// Values `[time, variable, lat, lon]`.
    pub values: Vec<f32>,
    /// Constant maps `(name, [lat, lon])` (orography, land-sea mask, latitude, ...).
    pub constants: Vec<(String, Vec<f32>)>,
}

impl Dataset {
    /// Stacks fields that share times and grid; the times must be equally spaced.
    pub fn from_fields(fields: &[Field], constants: Vec<(String, Vec<f32>)>) -> Result<Self> {
        let first =
            fields.first().ok_or_else(|| Error::InvalidArgument("a dataset needs at least one field".into()))?;
        let times = first
            .times
            .clone()
            .ok_or_else(|| Error::InvalidArgument(format!("field '{}' has no times", first.name)))?;
        if times.len() < 2 {
            return Err(Error::InvalidArgument("a dataset needs at least two times".into()));
        }
        let step = times[1] - times[0];
        if step <= 0 || times.windows(2).any(|w| w[1] - w[0] != step) {
            return Err(Error::InvalidArgument(format!(
                "field '{}': times must be equally spaced and ascending",
                first.name
            )));
        }
        let plane = first.grid.n_lat() * first.grid.n_lon();
        for f in fields {
            if f.times.as_ref() != Some(&times) || f.grid != first.grid {
                return Err(Error::InvalidArgument(format!(
                    "field '{}' has other times or another grid than '{}'",
                    f.name, first.name
                )));
            }
        }
        for (name, c) in &constants {
            if c.len() != plane {
                return Err(Error::InvalidArgument(format!(
                    "constant '{name}' has {} values, the grid {plane}",
                    c.len()
                )));
            }
        }
        let per_field: Vec<Vec<f64>> = fields.iter().map(|f| f.values.to_f64()).collect();
        let mut values = Vec::with_capacity(times.len() * fields.len() * plane);
        for t in 0..times.len() {
            for v in &per_field {
                values.extend(v[t * plane..(t + 1) * plane].iter().map(|&x| x as f32));
            }
        }
        Ok(Self {
            variables: fields.iter().map(|f| f.name.clone()).collect(),
            times,
            step_hours: step as f64 / 3600.0,
            grid: first.grid.clone(),
            values,
            constants,
        })
    }

    /// Number of times.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether there are no times.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    fn plane(&self) -> usize {
        self.grid.n_lat() * self.grid.n_lon()
    }

    /// The times `a..b` as a dataset of their own (same variables, grid and constants).
    pub fn slice(&self, a: usize, b: usize) -> Self {
        let per_time = self.plane() * self.variables.len();
        Self {
            times: self.times[a..b].to_vec(),
            values: self.values[a * per_time..b * per_time].to_vec(),
            ..self.clone()
        }
    }

    /// Variable `v` at time index `t` as a `[lat, lon]` slice.
    pub fn map(&self, t: usize, v: usize) -> &[f32] {
        let p = self.plane();
        let start = (t * self.variables.len() + v) * p;
        &self.values[start..start + p]
    }

    /// Variable `v` over all times as a [`Field`].
    pub fn field(&self, v: usize) -> Field {
        let values = (0..self.len()).flat_map(|t| self.map(t, v).iter().map(|&x| x as f64)).collect();
        Field {
            name: self.variables[v].clone(),
            times: Some(self.times.clone()),
            grid: self.grid.clone(),
            values: Values::F64(values),
            source: Default::default(),
        }
    }
}

/// Per-channel mean and standard deviation (variables, then constants).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalizer {
    /// Mean of each variable.
    pub mean: Vec<f64>,
    /// Standard deviation of each variable.
    pub std: Vec<f64>,
    /// Mean of each constant.
    pub const_mean: Vec<f64>,
    /// Standard deviation of each constant (1 where the map is constant).
    pub const_std: Vec<f64>,
}

fn mean_std<'a>(values: impl Iterator<Item = &'a [f32]>) -> (f64, f64) {
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0usize);
    for chunk in values {
        for &x in chunk {
            s += x as f64;
            s2 += (x as f64) * (x as f64);
            n += 1;
        }
    }
    let m = s / n as f64;
    let sd = (s2 / n as f64 - m * m).max(0.0).sqrt();
    (m, if sd > 0.0 { sd } else { 1.0 })
}

impl Normalizer {
    /// The statistics of a (training) dataset.
    pub fn fit(data: &Dataset) -> Self {
        let (mean, std) = (0..data.variables.len()).map(|v| mean_std((0..data.len()).map(|t| data.map(t, v)))).unzip();
        let (const_mean, const_std) =
            data.constants.iter().map(|(_, c)| mean_std(std::iter::once(c.as_slice()))).unzip();
        Self { mean, std, const_mean, const_std }
    }
}

/// The lead time of samples.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Lead {
    /// One lead of this many steps (a direct model per lead).
    Fixed(usize),
    /// Any lead in `min..=max` steps, given to the network as a channel `lead_hours / 100`.
    Continuous {
        /// Shortest lead in steps.
        min: usize,
        /// Longest lead in steps.
        max: usize,
    },
}

/// What goes into a sample and what comes out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleSpec {
    /// Past offsets in steps, e.g. `[0, 1, 2]` for t, t-6h, t-12h at 6-hour steps.
    pub history: Vec<usize>,
    /// The lead time.
    pub lead: Lead,
    /// Indices of the predicted variables.
    pub targets: Vec<usize>,
}

impl SampleSpec {
    /// Input channels for a dataset with `n_vars` variables and `n_const` constants.
    pub fn in_channels(&self, n_vars: usize, n_const: usize) -> usize {
        self.history.len() * n_vars + n_const + usize::from(matches!(self.lead, Lead::Continuous { .. }))
    }

    fn max_lead(&self) -> usize {
        match self.lead {
            Lead::Fixed(l) => l,
            Lead::Continuous { max, .. } => max,
        }
    }

    /// The initialisation indices of `data` that have their whole history and the longest
    /// lead inside the data.
    pub fn init_indices(&self, data: &Dataset) -> Vec<usize> {
        let back = self.history.iter().copied().max().unwrap_or(0);
        let ahead = self.max_lead();
        if data.len() <= back + ahead {
            return Vec::new();
        }
        (back..data.len() - ahead).collect()
    }

    fn check(&self, data: &Dataset) -> Result<()> {
        if self.history.is_empty() || self.targets.is_empty() || self.targets.iter().any(|&v| v >= data.variables.len())
        {
            return Err(Error::InvalidArgument(format!(
                "sample spec needs a history and targets among {} variables: {self:?}",
                data.variables.len()
            )));
        }
        if let Lead::Continuous { min, max } = self.lead {
            if min == 0 || min > max {
                return Err(Error::InvalidArgument(format!(
                    "continuous lead needs 1 <= min <= max (got {min}..={max})"
                )));
            }
        }
        Ok(())
    }

    /// A batch `(x [B, in, lat, lon], y [B, targets, lat, lon])` of normalised samples
    /// initialised at `inits` with leads `leads` (steps).
    pub fn batch(
        &self,
        data: &Dataset,
        norm: &Normalizer,
        inits: &[usize],
        leads: &[usize],
        dev: &Device,
    ) -> Result<(Tensor, Tensor)> {
        self.check(data)?;
        let (nv, nc, p) = (data.variables.len(), data.constants.len(), data.plane());
        let cin = self.in_channels(nv, nc);
        let mut x = Vec::with_capacity(inits.len() * cin * p);
        let mut y = Vec::with_capacity(inits.len() * self.targets.len() * p);
        for (&t, &lead) in inits.iter().zip(leads) {
            for &h in &self.history {
                for v in 0..nv {
                    let (m, s) = (norm.mean[v], norm.std[v]);
                    x.extend(data.map(t - h, v).iter().map(|&a| ((a as f64 - m) / s) as f32));
                }
            }
            for (k, (_, c)) in data.constants.iter().enumerate() {
                let (m, s) = (norm.const_mean[k], norm.const_std[k]);
                x.extend(c.iter().map(|&a| ((a as f64 - m) / s) as f32));
            }
            if matches!(self.lead, Lead::Continuous { .. }) {
                x.extend(std::iter::repeat_n((lead as f64 * data.step_hours / 100.0) as f32, p));
            }
            for &v in &self.targets {
                let (m, s) = (norm.mean[v], norm.std[v]);
                y.extend(data.map(t + lead, v).iter().map(|&a| ((a as f64 - m) / s) as f32));
            }
        }
        let (h, w) = (data.grid.n_lat(), data.grid.n_lon());
        let x = Tensor::from_vec(x, (inits.len(), cin, h, w), dev).map_err(crate::forecaster::model::core_err)?;
        let y = Tensor::from_vec(y, (inits.len(), self.targets.len(), h, w), dev)
            .map_err(crate::forecaster::model::core_err)?;
        Ok((x, y))
    }

    /// Turns normalised network outputs `[B, targets, lat, lon]` for the inits `inits` at one
    /// lead into one [`LeadForecast`] per target variable, in physical units.
    pub fn to_forecasts(
        &self,
        data: &Dataset,
        norm: &Normalizer,
        inits: &[usize],
        lead: usize,
        out: &Tensor,
    ) -> Result<Vec<LeadForecast>> {
        let v = out.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(crate::forecaster::model::core_err)?;
        let p = data.plane();
        let nt = self.targets.len();
        Ok(self
            .targets
            .iter()
            .enumerate()
            .map(|(k, &var)| {
                let (m, s) = (norm.mean[var], norm.std[var]);
                let values = (0..inits.len())
                    .flat_map(|b| v[(b * nt + k) * p..(b * nt + k + 1) * p].iter().map(move |&a| a as f64 * s + m))
                    .collect();
                LeadForecast {
                    name: data.variables[var].clone(),
                    lead_hours: vec![lead as f64 * data.step_hours],
                    init_times: inits.iter().map(|&t| data.times[t]).collect(),
                    grid: data.grid.clone(),
                    values: Values::F64(values),
                    source: Default::default(),
                }
            })
            .collect())
    }
}
