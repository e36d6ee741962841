//! The data model: a variable on a lat-lon grid over time, and forecasts by lead time.
//!
//! Values keep the precision they were stored in (WeatherBench's float32 stays 4 bytes a value,
//! so a year of hourly 32x64 fields is 72 MB, held once); every score converts to f64 as it
//! reads and accumulates in f64.

use crate::error::{Error, Result};
use crate::grid::{check_latitudes, LatLonGrid};
use crate::time::Seconds;
use std::path::PathBuf;

/// Field values `[time, lat, lon]` (or `[lead, time, lat, lon]`), lon fastest, in the precision
/// they were read in.
#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    /// 4-byte floats (WeatherBench files).
    F32(Vec<f32>),
    /// 8-byte floats.
    F64(Vec<f64>),
}

impl Values {
    /// Number of values.
    pub fn len(&self) -> usize {
        match self {
            Values::F32(v) => v.len(),
            Values::F64(v) => v.len(),
        }
    }

    /// Whether there are no values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of values that are NaN or infinite.
    pub fn count_non_finite(&self) -> usize {
        match self {
            Values::F32(v) => v.iter().filter(|x| !x.is_finite()).count(),
            Values::F64(v) => v.iter().filter(|x| !x.is_finite()).count(),
        }
    }

    /// The values converted to f64.
    pub fn to_f64(&self) -> Vec<f64> {
        match self {
            Values::F32(v) => v.iter().map(|&x| x as f64).collect(),
            Values::F64(v) => v.clone(),
        }
    }
}

/// One variable on a lat-lon grid at a sequence of times, `[time, lat, lon]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    /// Variable name (`z`, `t`, ...).
    pub name: String,
    /// Valid times (seconds since 1970), or `None` where the source has none (`.npy`): then
    /// fields are matched by position.
    pub times: Option<Vec<Seconds>>,
    /// The grid.
    pub grid: LatLonGrid,
    /// The values, `[time, lat, lon]`.
    pub values: Values,
    /// Where the field came from (for messages); empty for fields built in memory.
    pub source: PathBuf,
}

impl Field {
    /// A field built in memory; checks the shape and the latitudes.
    pub fn new(name: impl Into<String>, times: Option<Vec<Seconds>>, grid: LatLonGrid, values: Values) -> Result<Self> {
        check_latitudes(&grid.lat)?;
        let plane = grid.n_lat() * grid.n_lon();
        if plane == 0 || values.len() % plane != 0 {
            return Err(Error::InvalidArgument(format!(
                "{} values do not fill whole {}x{} lat-lon planes",
                values.len(),
                grid.n_lat(),
                grid.n_lon()
            )));
        }
        if let Some(t) = &times {
            if t.len() * plane != values.len() {
                return Err(Error::InvalidArgument(format!(
                    "{} times but {} lat-lon planes of values",
                    t.len(),
                    values.len() / plane
                )));
            }
        }
        Ok(Self { name: name.into(), times, grid, values, source: PathBuf::new() })
    }

    /// Number of times.
    pub fn n_time(&self) -> usize {
        self.values.len() / (self.grid.n_lat() * self.grid.n_lon())
    }

    /// Refuses NaN, Inf and masked fill values (the truth must be complete).
    pub fn require_finite(&self) -> Result<()> {
        match self.values.count_non_finite() {
            0 => Ok(()),
            count => Err(Error::NonFinite { file: self.source.clone(), var: self.name.clone(), count }),
        }
    }
}

/// An iterative (or per-lead direct) forecast: `[lead, time, lat, lon]` with `time` the
/// initialisation time; NaN where a forecast was not made (e.g. valid time past the data).
#[derive(Clone, Debug, PartialEq)]
pub struct LeadForecast {
    /// Variable name.
    pub name: String,
    /// Lead times in hours.
    pub lead_hours: Vec<f64>,
    /// Initialisation times.
    pub init_times: Vec<Seconds>,
    /// The grid.
    pub grid: LatLonGrid,
    /// The values, `[lead, time, lat, lon]`.
    pub values: Values,
    /// Where it came from.
    pub source: PathBuf,
}

impl LeadForecast {
    /// The forecast at lead index `k` as a field whose times are the valid times `init + lead`.
    pub fn at_lead(&self, k: usize) -> Field {
        let per_lead = self.init_times.len() * self.grid.n_lat() * self.grid.n_lon();
        let range = k * per_lead..(k + 1) * per_lead;
        let values = match &self.values {
            Values::F32(v) => Values::F32(v[range].to_vec()),
            Values::F64(v) => Values::F64(v[range].to_vec()),
        };
        let shift = (self.lead_hours[k] * 3600.0).round() as Seconds;
        Field {
            name: self.name.clone(),
            times: Some(self.init_times.iter().map(|t| t + shift).collect()),
            grid: self.grid.clone(),
            values,
            source: self.source.clone(),
        }
    }
}

/// What a forecast file holds: one field at valid times, or fields per lead time.
#[derive(Clone, Debug, PartialEq)]
pub enum Forecast {
    /// `[time, lat, lon]` at valid times.
    Direct(Field),
    /// `[lead_time, time, lat, lon]` at initialisation times.
    ByLead(LeadForecast),
}
