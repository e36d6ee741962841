//! `cargo xtask weather score --forecast F --truth T [--var z] [--metric rmse] [--lat LAT.npy]
//! [--level L]`: WeatherBench's official scores of a forecast file against a truth file, as one
//! JSON object on the last line. Reading and scoring live in [`pbdl_weather`].

use pbdl_weather::io::{npy, read_forecast, read_truth, Selection};
use pbdl_weather::score::{evaluate, Metric};
use std::path::PathBuf;

/// What `cargo xtask weather score` was asked to do.
pub struct ScoreArgs {
    /// Forecast file (.nc or .npy).
    pub forecast: PathBuf,
    /// Truth file (.nc or .npy).
    pub truth: PathBuf,
    /// Variable name.
    pub var: Option<String>,
    /// Metric name.
    pub metric: String,
    /// Latitudes for .npy inputs.
    pub lat: Option<PathBuf>,
    /// Pressure level.
    pub level: Option<f64>,
}

/// Prints `{"<metric>": x}` or `{"lead_time": [...], "<metric>": [...]}`.
pub fn score(args: ScoreArgs) -> anyhow::Result<()> {
    let metric: Metric = args.metric.parse()?;
    let lat = args.lat.as_deref().map(npy::read_coordinate).transpose()?;
    let sel = Selection { var: args.var, level: args.level, lat };
    let truth = read_truth(&args.truth, &sel)?;
    // A .npy forecast against a NetCDF truth takes the truth's latitudes when --lat is absent.
    let forecast_sel = Selection { lat: sel.lat.clone().or_else(|| Some(truth.grid.lat.clone())), ..sel };
    let forecast = read_forecast(&args.forecast, &forecast_sel)?;
    let result = evaluate(metric, &forecast, &truth)?;
    println!("{}", result.to_json(metric));
    Ok(())
}
