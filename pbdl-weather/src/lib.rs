//! # pbdl-weather
//!
//! WeatherBench (Rasp et al. 2020) for pbdl: lat-lon fields read from the benchmark's files,
//! scored exactly as the official `score.py` scores them; its baselines; the Rasp & Thuerey
//! (2021) ResNet forecaster; and stand-in data made by the crate's own models (Lorenz-96 and a
//! spectral shallow-water model on the sphere), since nothing is downloaded. The example
//! `examples/standin_baselines.rs` runs the stand-in climate and scores the baselines on it.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`grid`] | [`LatLonGrid`] (ascending latitudes without poles, longitudes 0..360), latitude and area weights |
//! | [`time`] | CF time units to seconds, calendar dates, day of year |
//! | [`field`] | [`Field`] `[time, lat, lon]`, [`LeadForecast`] `[lead, time, lat, lon]`, [`Forecast`] |
//! | [`io`] | NetCDF (classic and NetCDF-4, pure Rust) and `.npy` readers and writers with typed errors |
//! | [`score`] | latitude-weighted RMSE (one root; and the paper's per-time mean), MAE, ACC; per lead time |
//! | [`wb2`] | WeatherBench 2 variants: area weights, RMSE of the time-mean MSE, per-time ACC against a day-of-year x hour climatology |
//! | [`baselines`] | persistence, climatology, weekly climatology, linear regression (direct and iterative) |
//! | [`lorenz96`] | Lorenz-96 trajectories as fields: the unit-test tier of stand-in data |
//! | [`shallow_water`] | global spectral shallow-water model (Gaussian grid, T21/T42, semi-implicit), Williamson tests 2 and 6 |
//! | [`standin`] | the stand-in climate: forced-dissipative shallow water with seasons, mountains and a T850-like tracer; a biased "climate model" variant |
//! | [`forecaster`] | the Rasp & Thuerey ResNet (periodic in longitude, LeakyReLU, BatchNorm, dropout) |
//! | [`evaluation`] | RMSE and ACC against lead time for every baseline and a trained forecaster, markdown tables |
//! | [`error`] | [`Error`], [`Result`] |
//!
//! ```
//! use pbdl_weather::{field::Values, score::{score, Metric}, Field, LatLonGrid};
//! let grid = LatLonGrid::weatherbench(32); // 5.625 degrees: 32 x 64
//! let truth = Field::new("z", Some(vec![0, 3600]), grid.clone(), Values::F64(vec![50_000.0; 2 * 32 * 64]))?;
//! let forecast = Field::new("z", Some(vec![0, 3600]), grid, Values::F64(vec![50_100.0; 2 * 32 * 64]))?;
//! assert!((score(Metric::Rmse, &forecast, &truth)? - 100.0).abs() < 1e-9);
//! # Ok::<(), pbdl_weather::Error>(())
//! ```
#![warn(missing_docs)]

pub mod baselines;
pub mod error;
pub mod evaluation;
pub mod field;
pub mod forecaster;
pub mod grid;
pub mod io;
pub mod lorenz96;
pub mod score;
pub mod shallow_water;
pub mod standin;
pub mod time;
pub mod wb2;

pub use error::{Error, Result};
pub use field::{Field, Forecast, LeadForecast};
pub use grid::LatLonGrid;
