//! Reading and writing weather fields: NetCDF (classic and NetCDF-4) and `.npy`.
//!
//! [`read_forecast`] and [`read_truth`] pick the reader by extension (`.npy`, anything else
//! as NetCDF, whose flavour is detected from the file's magic bytes).

pub mod netcdf;
pub mod npy;

use crate::error::Result;
use crate::field::{Field, Forecast};
use std::path::Path;

/// Which variable (and pressure level) to read.
#[derive(Clone, Debug, Default)]
pub struct Selection {
    /// Variable name; `None` takes the file's only data variable.
    pub var: Option<String>,
    /// Pressure level (hPa) when the variable has a `level` dimension; `None` takes 500 for `z`,
    /// 850 for `t` (as WeatherBench's `load_test_data`) or the only level.
    pub level: Option<f64>,
    /// Latitudes of a `.npy` field (degrees, ascending), required for `.npy`.
    pub lat: Option<Vec<f64>>,
}

fn is_npy(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy"))
}

/// Reads a forecast: a field at valid times, or a NetCDF forecast with a `lead_time`
/// (or `prediction_timedelta`) dimension.
pub fn read_forecast(path: &Path, sel: &Selection) -> Result<Forecast> {
    if is_npy(path) {
        npy::read_field(path, sel).map(Forecast::Direct)
    } else {
        netcdf::read(path, sel)
    }
}

/// Reads the truth: a field at valid times, complete (NaN and fill values are refused).
pub fn read_truth(path: &Path, sel: &Selection) -> Result<Field> {
    let field = if is_npy(path) {
        npy::read_field(path, sel)?
    } else {
        match netcdf::read(path, sel)? {
            Forecast::Direct(f) => f,
            Forecast::ByLead(_) => {
                return Err(crate::error::Error::InvalidArgument(format!(
                    "{}: the truth has a lead_time dimension; pass observations at valid times",
                    path.display()
                )))
            }
        }
    };
    field.require_finite()?;
    Ok(field)
}
