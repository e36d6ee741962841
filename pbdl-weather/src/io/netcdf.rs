//! NetCDF fields in WeatherBench's layout, classic (CDF-1/2/5) and NetCDF-4 (HDF5), through
//! the pure-Rust `netcdf-reader` / `netcdf-writer` crates.
//!
//! Accepted dimension orders (WeatherBench 2 names in brackets):
//! `[lead_time (prediction_timedelta),] [time,] [level,] lat (latitude), lon (longitude)`.
//! Anything else is refused with the order found; nothing is transposed silently. Latitudes
//! must be ascending (WeatherBench v1; flip WeatherBench 2's descending ones first). Values
//! are read a block of times at a time into one buffer of the stored precision, so a year of
//! hourly data is held once. `_FillValue`/`missing_value` become NaN and `scale_factor`/
//! `add_offset` are applied (such variables are read as f64).

use crate::error::{Error, Result};
use crate::field::{Field, Forecast, LeadForecast, Values};
use crate::grid::{check_latitudes, LatLonGrid};
use crate::io::Selection;
use crate::time::{format_time, is_gregorian, unit_seconds, Seconds, TimeEncoding, HOUR};
use netcdf_reader::{NcFile, NcSliceInfo, NcSliceInfoElem, NcType, NcVariable};
use std::path::{Path, PathBuf};

/// Time steps read per slice call: large enough to amortise the call, small enough that the
/// temporary block stays a few MB.
const TIME_BLOCK: usize = 256;

/// The role of a dimension, from its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Axis {
    Lead,
    Time,
    Level,
    Lat,
    Lon,
}

fn axis_of(name: &str) -> Option<Axis> {
    match name {
        "lead_time" | "prediction_timedelta" => Some(Axis::Lead),
        "time" | "init_time" => Some(Axis::Time),
        "level" | "plev" | "pressure_level" => Some(Axis::Level),
        "lat" | "latitude" => Some(Axis::Lat),
        "lon" | "longitude" => Some(Axis::Lon),
        _ => None,
    }
}

const EXPECTED_ORDER: &str = "[lead_time,] [time,] [level,] lat, lon";

struct Reader<'a> {
    file: NcFile,
    path: &'a Path,
}

impl Reader<'_> {
    fn nc_err(&self, e: impl std::fmt::Display) -> Error {
        Error::NetCdf { file: self.path.to_path_buf(), reason: e.to_string() }
    }

    fn coord_err(&self, var: &str, coord: &str, problem: impl Into<String>) -> Error {
        Error::Coordinate {
            file: self.path.to_path_buf(),
            var: var.into(),
            coord: coord.into(),
            problem: problem.into(),
        }
    }

    /// Variables with at least a lat and a lon dimension that are not coordinates.
    fn data_variables(&self) -> Result<Vec<String>> {
        Ok(self
            .file
            .variables()
            .map_err(|e| self.nc_err(e))?
            .iter()
            .filter(|v| !v.is_coordinate_variable() && v.dimensions().len() >= 2)
            .filter(|v| {
                let names: Vec<Option<Axis>> = v.dimensions().iter().map(|d| axis_of(&d.name)).collect();
                names.contains(&Some(Axis::Lat)) && names.contains(&Some(Axis::Lon))
            })
            .map(|v| v.name().to_string())
            .collect())
    }

    fn pick_variable(&self, var: Option<&str>) -> Result<NcVariable> {
        let available = self.data_variables()?;
        let name = match var {
            Some(v) => {
                if self.file.variable(v).is_err() {
                    return Err(Error::MissingVariable { file: self.path.to_path_buf(), var: v.into(), available });
                }
                v.to_string()
            }
            None if available.len() == 1 => available[0].clone(),
            None => {
                return Err(Error::AmbiguousVariable {
                    file: self.path.to_path_buf(),
                    count: available.len(),
                    available,
                })
            }
        };
        self.file.variable(&name).cloned().map_err(|e| self.nc_err(e))
    }

    /// A 1-D coordinate variable's values; `None` when the file has no such variable.
    fn coordinate(&self, dim: &str) -> Result<Option<(Vec<f64>, &NcVariable)>> {
        match self.file.variable(dim) {
            Ok(v) if v.dimensions().len() == 1 => {
                let values = self.file.read_variable_as_f64(dim).map_err(|e| self.nc_err(e))?;
                Ok(Some((values.iter().copied().collect(), v)))
            }
            _ => Ok(None),
        }
    }

    fn times(&self, var: &str, dim: &str) -> Result<Vec<Seconds>> {
        let (values, v) = self.coordinate(dim)?.ok_or_else(|| {
            self.coord_err(var, dim, "no coordinate variable; times are needed to join forecast and truth")
        })?;
        let units = v.attribute("units").and_then(|a| a.value.as_string()).ok_or_else(|| {
            self.coord_err(var, dim, "no 'units' attribute (expected CF units such as 'hours since 1979-01-01')")
        })?;
        let enc = TimeEncoding::parse(&units).ok_or_else(|| {
            self.coord_err(var, dim, format!("units '{units}' are not '<seconds|minutes|hours|days> since <date>'"))
        })?;
        if let Some(cal) = v.attribute("calendar").and_then(|a| a.value.as_string()) {
            if !is_gregorian(&cal) {
                return Err(self.coord_err(
                    var,
                    dim,
                    format!("calendar '{cal}'; only the standard (Gregorian) calendar is supported"),
                ));
            }
        }
        if let Some(bad) = values.iter().find(|x| !x.is_finite()) {
            return Err(self.coord_err(var, dim, format!("non-finite time value {bad}")));
        }
        Ok(values.iter().map(|&x| enc.decode(x)).collect())
    }

    fn lead_hours(&self, var: &str, dim: &str) -> Result<Vec<f64>> {
        let (values, v) = self
            .coordinate(dim)?
            .ok_or_else(|| self.coord_err(var, dim, "no coordinate variable with the lead times"))?;
        // xarray writes timedeltas with units such as "hours" or "days"; WeatherBench's own
        // forecasts store plain integer hours without units.
        let scale = match v.attribute("units").and_then(|a| a.value.as_string()) {
            None => 1.0,
            Some(u) => unit_seconds(&u).map(|s| s / HOUR as f64).ok_or_else(|| {
                self.coord_err(var, dim, format!("units '{u}'; expected hours, days, minutes or seconds"))
            })?,
        };
        Ok(values.iter().map(|x| x * scale).collect())
    }
}

/// Reads the selected variable: a [`Forecast::Direct`] field, or [`Forecast::ByLead`] when
/// the variable has a lead-time dimension.
pub fn read(path: &Path, sel: &Selection) -> Result<Forecast> {
    let file = NcFile::open(path).map_err(|e| Error::NetCdf { file: path.to_path_buf(), reason: e.to_string() })?;
    let r = Reader { file, path };
    let var = r.pick_variable(sel.var.as_deref())?;
    let name = var.name().to_string();
    let dims: Vec<String> = var.dimensions().iter().map(|d| d.name.clone()).collect();
    let axes: Vec<Axis> =
        dims.iter().map(|d| axis_of(d)).collect::<Option<_>>().ok_or_else(|| Error::DimensionOrder {
            file: path.into(),
            var: name.clone(),
            found: dims.clone(),
            expected: EXPECTED_ORDER.into(),
        })?;
    // The axes must appear in the canonical order, each at most once, ending in lat, lon.
    let ordered = axes.windows(2).all(|w| (w[0] as u8) < (w[1] as u8));
    if !ordered || axes.len() < 2 || axes[axes.len() - 2..] != [Axis::Lat, Axis::Lon] {
        return Err(Error::DimensionOrder {
            file: path.into(),
            var: name,
            found: dims,
            expected: EXPECTED_ORDER.into(),
        });
    }
    let shape = var.shape();
    let pos = |a: Axis| axes.iter().position(|&x| x == a);

    let lat_dim = &dims[axes.len() - 2];
    let lon_dim = &dims[axes.len() - 1];
    let (lat, _) = r
        .coordinate(lat_dim)?
        .ok_or_else(|| r.coord_err(&name, lat_dim, "no coordinate variable with the latitudes"))?;
    check_latitudes(&lat).map_err(|e| r.coord_err(&name, lat_dim, e.to_string()))?;
    let lon = match r.coordinate(lon_dim)? {
        Some((lon, _)) => lon,
        None => return Err(r.coord_err(&name, lon_dim, "no coordinate variable with the longitudes")),
    };
    let grid = LatLonGrid { lat, lon };

    let level_index = match pos(Axis::Level) {
        None => None,
        Some(k) => Some(select_level(&r, &name, &dims[k], shape[k] as usize, sel.level)?),
    };
    let times = match pos(Axis::Time) {
        Some(k) => Some(r.times(&name, &dims[k])?),
        None => None,
    };
    let leads = match pos(Axis::Lead) {
        Some(k) => Some(r.lead_hours(&name, &dims[k])?),
        None => None,
    };
    if leads.is_some() && times.is_none() {
        return Err(Error::DimensionOrder {
            file: path.into(),
            var: name,
            found: dims,
            expected: "lead_time, time, [level,] lat, lon".into(),
        });
    }
    let values = read_values(&r, &var, &axes, level_index)?;
    let source = PathBuf::from(path);
    Ok(match leads {
        None => {
            let mut field = Field::new(name, times, grid, values)?;
            field.source = source;
            Forecast::Direct(field)
        }
        Some(lead_hours) => Forecast::ByLead(LeadForecast {
            name,
            lead_hours,
            init_times: times.unwrap_or_default(),
            grid,
            values,
            source,
        }),
    })
}

fn select_level(r: &Reader, var: &str, dim: &str, n: usize, wanted: Option<f64>) -> Result<usize> {
    let levels = r.coordinate(dim)?.map(|(v, _)| v);
    let wanted = match (wanted, var) {
        (Some(l), _) => l,
        (None, "z") => 500.0,
        (None, "t") => 850.0,
        (None, _) if n == 1 => return Ok(0),
        (None, _) => return Err(r.coord_err(var, dim, format!("{n} levels {levels:?}; choose one with --level"))),
    };
    let levels = levels.ok_or_else(|| r.coord_err(var, dim, "no coordinate variable with the levels"))?;
    levels
        .iter()
        .position(|&l| (l - wanted).abs() < 1e-6)
        .ok_or_else(|| r.coord_err(var, dim, format!("level {wanted} not in {levels:?}; choose one with --level")))
}

/// Reads all values of the variable, the level axis (if any) fixed, in blocks along the
/// outermost axis; f32 variables stay f32 unless they are packed or masked.
fn read_values(r: &Reader, var: &NcVariable, axes: &[Axis], level: Option<usize>) -> Result<Values> {
    let shape: Vec<usize> = var.shape().iter().map(|&s| s as usize).collect();
    let has = |name: &str| var.attribute(name).is_some();
    // A NaN fill value (xarray's default for floats) needs no masking: missing values are NaN already.
    let real_fill = |name: &str| var.attribute(name).and_then(|a| a.value.as_f64()).is_some_and(|x| !x.is_nan());
    let cf_decode = real_fill("_FillValue") || real_fill("missing_value") || has("scale_factor") || has("add_offset");
    let native_f32 = matches!(var.dtype(), NcType::Float) && !cf_decode;
    let full = |n: usize| NcSliceInfoElem::Slice { start: 0, end: n as u64, step: 1 };
    let total: usize = axes.iter().zip(&shape).filter(|(a, _)| **a != Axis::Level).map(|(_, &s)| s).product();
    // Blocks run along the first axis unless it is the level axis of a [level, lat, lon] map.
    let outer = if axes[0] == Axis::Lat || axes[0] == Axis::Level { None } else { Some(shape[0]) };
    let mut values =
        if native_f32 { Values::F32(Vec::with_capacity(total)) } else { Values::F64(Vec::with_capacity(total)) };
    // Without a level to pick, a stored float32 variable is read straight into its buffer.
    if let (Values::F32(v), None) = (&mut values, level) {
        v.resize(total, 0.0);
        r.file.read_variable_into::<f32>(var.name(), v).map_err(|e| r.nc_err(e))?;
        return Ok(values);
    }
    let blocks: Vec<(usize, usize)> = match outer {
        None => vec![(0, 1)],
        Some(n) => (0..n).step_by(TIME_BLOCK).map(|s| (s, (s + TIME_BLOCK).min(n))).collect(),
    };
    for (start, end) in blocks {
        let selections = axes
            .iter()
            .zip(&shape)
            .enumerate()
            .map(|(k, (&a, &n))| match a {
                Axis::Level => NcSliceInfoElem::Index(level.unwrap_or(0) as u64),
                _ if k == 0 && outer.is_some() => {
                    NcSliceInfoElem::Slice { start: start as u64, end: end as u64, step: 1 }
                }
                _ => full(n),
            })
            .collect();
        let info = NcSliceInfo { selections };
        match &mut values {
            Values::F32(v) => {
                let block = r.file.read_variable_slice::<f32>(var.name(), &info).map_err(|e| r.nc_err(e))?;
                v.extend(block.iter());
            }
            Values::F64(v) => {
                let block = if cf_decode {
                    r.file.read_variable_slice_unpacked_masked(var.name(), &info)
                } else {
                    r.file.read_variable_slice_as_f64(var.name(), &info)
                }
                .map_err(|e| r.nc_err(e))?;
                v.extend(block.iter());
            }
        }
    }
    if values.len() != total {
        return Err(r.nc_err(format!("read {} values of '{}', expected {total}", values.len(), var.name())));
    }
    Ok(values)
}

/// The NetCDF flavour to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flavour {
    /// Classic netCDF-3 (64-bit offsets where needed).
    Classic,
    /// NetCDF-4 (HDF5).
    Nc4,
}

/// Writes a forecast (or truth) in WeatherBench's layout, atomically: coordinates `time`
/// (hours since 1970-01-01, standard calendar), `lat`, `lon`, and for a [`LeadForecast`]
/// `lead_time` (hours) first; NaN marks missing values.
pub fn write(path: &Path, forecast: &Forecast, flavour: Flavour) -> Result<()> {
    use netcdf_writer::{NcAttrValue, NcFileBuilder};
    let werr = |e: netcdf_writer::Error| Error::NetCdf { file: path.to_path_buf(), reason: e.to_string() };
    let (name, grid, values, times, leads) = match forecast {
        Forecast::Direct(f) => (&f.name, &f.grid, &f.values, f.times.clone(), None),
        Forecast::ByLead(f) => (&f.name, &f.grid, &f.values, Some(f.init_times.clone()), Some(&f.lead_hours)),
    };
    let times = times.ok_or_else(|| {
        Error::InvalidArgument(format!(
            "{}: a field without times cannot be written as NetCDF; write .npy instead",
            path.display()
        ))
    })?;
    let mut b = NcFileBuilder::new();
    let text = |s: &str| NcAttrValue::Chars(s.to_string());
    let mut dim_ids = Vec::new();
    if let Some(leads) = leads {
        let d = b.add_dimension("lead_time", leads.len() as u64).map_err(werr)?;
        let v = b.add_variable::<f64>("lead_time", &[d]).map_err(werr)?;
        b.add_variable_attribute(v, "units", text("hours")).map_err(werr)?;
        b.write_variable(v, leads).map_err(werr)?;
        dim_ids.push(d);
    }
    let td = b.add_dimension("time", times.len() as u64).map_err(werr)?;
    let tv = b.add_variable::<f64>("time", &[td]).map_err(werr)?;
    b.add_variable_attribute(tv, "units", text("hours since 1970-01-01 00:00:00")).map_err(werr)?;
    b.add_variable_attribute(tv, "calendar", text("proleptic_gregorian")).map_err(werr)?;
    let hours: Vec<f64> = times.iter().map(|&t| t as f64 / HOUR as f64).collect();
    b.write_variable(tv, &hours).map_err(werr)?;
    dim_ids.push(td);
    dim_ids.extend(add_lat_lon(&mut b, grid).map_err(werr)?);
    match values {
        Values::F32(v) => {
            let id = b.add_variable::<f32>(name.as_str(), &dim_ids).map_err(werr)?;
            b.write_variable(id, v).map_err(werr)?;
        }
        Values::F64(v) => {
            let id = b.add_variable::<f64>(name.as_str(), &dim_ids).map_err(werr)?;
            b.write_variable(id, v).map_err(werr)?;
        }
    }
    b.add_attribute("first_time", text(&times.first().map(|&t| format_time(t)).unwrap_or_default())).map_err(werr)?;
    finish(&b, path, flavour)
}

/// Writes constant maps (`[lat, lon]` each, float32) with `lat`/`lon` coordinates, atomically,
/// as WeatherBench's `constants` file.
pub fn write_constants(
    path: &Path,
    grid: &LatLonGrid,
    constants: &[(String, Vec<f32>)],
    flavour: Flavour,
) -> Result<()> {
    use netcdf_writer::NcFileBuilder;
    let werr = |e: netcdf_writer::Error| Error::NetCdf { file: path.to_path_buf(), reason: e.to_string() };
    let mut b = NcFileBuilder::new();
    let mut dims = Vec::new();
    dims.extend(add_lat_lon(&mut b, grid).map_err(werr)?);
    for (name, values) in constants {
        if values.len() != grid.n_lat() * grid.n_lon() {
            return Err(Error::InvalidArgument(format!(
                "constant '{name}' has {} values for a {}x{} grid",
                values.len(),
                grid.n_lat(),
                grid.n_lon()
            )));
        }
        let v = b.add_variable::<f32>(name.as_str(), &dims).map_err(werr)?;
        b.write_variable(v, values).map_err(werr)?;
    }
    finish(&b, path, flavour)
}

/// Reads the named constant maps (`[lat, lon]`) of a constants file as float32.
pub fn read_constants(path: &Path, names: &[&str]) -> Result<Vec<(String, Vec<f32>)>> {
    names
        .iter()
        .map(|&name| {
            let sel = Selection { var: Some(name.into()), ..Default::default() };
            match read(path, &sel)? {
                Forecast::Direct(f) => {
                    f.require_finite()?;
                    Ok((name.to_string(), f.values.to_f64().into_iter().map(|x| x as f32).collect()))
                }
                Forecast::ByLead(_) => {
                    Err(Error::InvalidArgument(format!("{}: constant '{name}' has a lead time", path.display())))
                }
            }
        })
        .collect()
}

/// Adds the `lat` and `lon` dimensions and coordinate variables (degrees) to a file being built.
fn add_lat_lon(
    b: &mut netcdf_writer::NcFileBuilder,
    grid: &LatLonGrid,
) -> netcdf_writer::Result<Vec<netcdf_writer::DimensionId>> {
    let mut dims = Vec::with_capacity(2);
    for (dim, coords, units) in [("lat", &grid.lat, "degrees_north"), ("lon", &grid.lon, "degrees_east")] {
        let d = b.add_dimension(dim, coords.len() as u64)?;
        let v = b.add_variable::<f64>(dim, &[d])?;
        b.add_variable_attribute(v, "units", netcdf_writer::NcAttrValue::Chars(units.into()))?;
        b.write_variable(v, coords)?;
        dims.push(d);
    }
    Ok(dims)
}

/// Serialises a built file in the requested flavour and writes it atomically.
fn finish(b: &netcdf_writer::NcFileBuilder, path: &Path, flavour: Flavour) -> Result<()> {
    use netcdf_writer::{NcWriteFormat, NcWriteOptions};
    let format = match flavour {
        Flavour::Classic => NcWriteFormat::AutoClassic,
        Flavour::Nc4 => NcWriteFormat::Nc4,
    };
    let (_, bytes) = b
        .to_vec(NcWriteOptions { format })
        .map_err(|e| Error::NetCdf { file: path.to_path_buf(), reason: e.to_string() })?;
    pbdl_core::io::write_atomic(path, |w| std::io::Write::write_all(w, &bytes))
        .map_err(|e| Error::Io { file: path.to_path_buf(), source: std::io::Error::other(e.to_string()) })
}
