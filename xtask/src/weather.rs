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

// ---------------------------------------------------------------------------------------------
// generate | train | eval on the stand-in climate

use anyhow::Context as _;
use candle_core::{DType, Device};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::shard::{generate_shard, open_shards, Shard, ShardSet};
use pbdl_core::train::Progress;
use pbdl_weather::evaluation::{
    baseline_scores, forecast_scores, markdown_table, network_forecasts, BaselineOptions, LeadScore,
};
use pbdl_weather::field::Values;
use pbdl_weather::forecaster::{
    train, Dataset, Lead, Normalizer, ResNetConfig, SampleSpec, TrainConfig, WeatherResNet,
};
use pbdl_weather::io::netcdf::{read_constants, write, write_constants, Flavour};
use pbdl_weather::standin::{run as run_climate, ClimateConfig, StandIn};
use pbdl_weather::{Field, Forecast, LatLonGrid};
use std::path::Path;

/// First stored time of the truth run (2015-01-01) and of the climate run (1980-01-01).
const TRUTH_START: i64 = 1_420_070_400;
const CLIMATE_START: i64 = 315_532_800;
const CONSTANTS: [&str; 3] = ["orography", "lsm", "lat2d"];
/// Leads scored by `eval`, in 6-hour steps: 6 h, 1, 3 and 5 days.
const EVAL_LEADS: [usize; 4] = [1, 4, 12, 20];
/// Ridge of the linear regressions, relative to the mean diagonal of X^T X: chosen among 1e-6,
/// 1e-3 and 1e-1 on an exploratory two-year run (seed 0, first year fit, second scored), not
/// on the data `eval` scores.
const LR_RIDGE: f64 = 1e-3;

/// What `cargo xtask weather generate` was asked to do.
pub struct GenerateArgs {
    /// Output directory.
    pub out: PathBuf,
    /// Years of the unbiased "truth" run (train, valid, test: the last two years are valid and test).
    pub truth_years: f64,
    /// Years of the biased "climate model" run.
    pub climate_years: f64,
    /// Seed of the truth run (the climate run uses seed + 1000).
    pub seed: u64,
    /// Write this job's runs as data shards (item 0 the truth, item 1 the climate run).
    pub shard: Option<Shard>,
}

/// The generator named in the manifests of `weather generate --shard`.
const GENERATOR: &str = "pbdl-weather/standin";
/// The items of a sharded `weather generate`, in index order.
const ITEMS: [&str; 2] = ["truth", "climate"];
/// Days the stand-in climate spins up before its first stored field.
const SPINUP_DAYS: f64 = 100.0;

fn write_run(dir: &Path, tag: &str, z: &Field, t: &Field) -> anyhow::Result<()> {
    for f in [z, t] {
        write(&dir.join(format!("{tag}_{}.nc", f.name)), &Forecast::Direct(f.clone()), Flavour::Nc4)?;
    }
    Ok(())
}

/// Maps of the first truth fields, `map_{z,t}.png`.
fn write_maps(dir: &Path, run: &StandIn) -> anyhow::Result<()> {
    let (h, w) = (run.z.grid.n_lat(), run.z.grid.n_lon());
    for f in [&run.z, &run.t] {
        let v = f.values.to_f64();
        let style = pbdl_core::viz::FieldStyle { upscale: Some(8), ..Default::default() };
        pbdl_core::viz::field_to_png(dir.join(format!("map_{}.png", f.name)), &v[..h * w], h, w, &style)?;
    }
    Ok(())
}

/// Runs the truth and the biased climate model. Without a shard: writes `truth_{z,t}.nc`,
/// `climate_{z,t}.nc`, `constants.nc` (WeatherBench's layout) and maps of the first truth fields.
/// With `--shard i/n`: the two runs are items 0 (truth) and 1 (climate) of a sharded data set,
/// each one `item-<k>.npz` (see [`write_item`]), plus `manifest-i-of-n.json`; item `k` depends
/// on the settings and `k` only, so two jobs write the same files as one.
pub fn generate(args: GenerateArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)?;
    let runs = [
        (ClimateConfig { seed: args.seed, ..Default::default() }, TRUTH_START, args.truth_years),
        (ClimateConfig::biased(args.seed + 1000), CLIMATE_START, args.climate_years),
    ];
    let simulate = |k: usize| -> anyhow::Result<StandIn> {
        let (cfg, start, years) = &runs[k];
        let t0 = std::time::Instant::now();
        let progress = Progress::new(1000);
        let run = run_climate(cfg, *start, SPINUP_DAYS, years * 365.0, |f| progress.update((f * 1000.0) as u64, 0.0))?;
        progress.finish();
        println!(
            "{}: {years} years ({} fields of z and t) in {:.1} s",
            ITEMS[k],
            run.z.n_time(),
            t0.elapsed().as_secs_f64()
        );
        Ok(run)
    };
    let Some(shard) = args.shard else {
        for (k, tag) in ITEMS.iter().enumerate() {
            let run = simulate(k)?;
            write_run(&args.out, tag, &run.z, &run.t)?;
            if k == 0 {
                write_constants(&args.out.join("constants.nc"), &run.z.grid, &run.constants, Flavour::Nc4)?;
                write_maps(&args.out, &run)?;
            }
        }
        println!("wrote {}", args.out.display());
        return Ok(());
    };
    // Everything that decides the two runs; shards of other settings are refused by the reader.
    let config = serde_json::json!({
        "items": ITEMS, "truth_years": args.truth_years, "climate_years": args.climate_years,
        "seed": args.seed, "spinup_days": SPINUP_DAYS, "truth_start": TRUTH_START,
        "climate_start": CLIMATE_START, "truth": runs[0].0, "climate": runs[1].0,
    });
    let m = generate_shard(&args.out, GENERATOR, &config, ITEMS.len(), shard, |k, path| {
        let written = simulate(k).and_then(|run| {
            write_item(path, &run.z, &run.t, (k == 0).then_some(run.constants.as_slice()))?;
            if k == 0 {
                write_maps(&args.out, &run)?;
            }
            Ok(())
        });
        written.map_err(|e| pbdl_core::Error::invalid("weather generate", "--shard", e.to_string()))
    })?;
    let items: Vec<&str> = shard.items(ITEMS.len()).map(|k| ITEMS[k]).collect();
    println!(
        "shard {}: {} written to {} ({})",
        m.shard,
        if items.is_empty() { "no runs".to_string() } else { items.join(" and ") },
        args.out.display(),
        m.shard.manifest_name()
    );
    Ok(())
}

/// One run as a shard item: an `.npz` with `z` and `t` `[time, lat, lon]` (as stored, f32),
/// `time` `[time]` (i64 seconds since 1970), `lat` and `lon` (f64 degrees) and, for the truth
/// (item 0), the constant maps `orography`, `lsm`, `lat2d` `[lat, lon]` (f32). The two NetCDF
/// variables of a run travel as one file, so that one SHA-256 covers the item.
fn write_item(path: &Path, z: &Field, t: &Field, constants: Option<&[(String, Vec<f32>)]>) -> anyhow::Result<()> {
    use candle_core::Tensor;
    let grid = &z.grid;
    let (nlat, nlon) = (grid.n_lat(), grid.n_lon());
    let times = z.times.clone().ok_or_else(|| anyhow::anyhow!("field `{}` has no times", z.name))?;
    anyhow::ensure!(
        t.times.as_ref() == Some(&times) && t.grid == *grid,
        "z and t of one run must share times and grid"
    );
    let cpu = &Device::Cpu;
    let mut arrays: Vec<(String, Tensor)> = Vec::new();
    for f in [z, t] {
        let shape = (times.len(), nlat, nlon);
        let tensor = match &f.values {
            Values::F32(v) => Tensor::from_slice(v, shape, cpu)?,
            Values::F64(v) => Tensor::from_slice(v, shape, cpu)?,
        };
        arrays.push((f.name.clone(), tensor));
    }
    arrays.push(("time".into(), Tensor::from_slice(&times, times.len(), cpu)?));
    arrays.push(("lat".into(), Tensor::from_slice(&grid.lat, nlat, cpu)?));
    arrays.push(("lon".into(), Tensor::from_slice(&grid.lon, nlon, cpu)?));
    for (name, v) in constants.unwrap_or_default() {
        arrays.push((name.clone(), Tensor::from_slice(v, (nlat, nlon), cpu)?));
    }
    pbdl_core::io::write_npz(path, &arrays)?;
    Ok(())
}

/// Reads the `z` and `t` of an item written by [`write_item`].
fn read_item_fields(path: &Path) -> anyhow::Result<Vec<Field>> {
    use pbdl_core::io::read_npz_array;
    let vec1 = |name: &str| -> anyhow::Result<candle_core::Tensor> { Ok(read_npz_array(path, name)?.flatten_all()?) };
    let grid = LatLonGrid { lat: vec1("lat")?.to_vec1::<f64>()?, lon: vec1("lon")?.to_vec1::<f64>()? };
    let times: Vec<i64> = vec1("time")?.to_vec1::<i64>()?;
    ["z", "t"]
        .iter()
        .map(|&var| {
            let v = vec1(var)?;
            let values = match v.dtype() {
                DType::F64 => Values::F64(v.to_vec1::<f64>()?),
                _ => Values::F32(v.to_dtype(DType::F32)?.to_vec1::<f32>()?),
            };
            let mut field = Field::new(var, Some(times.clone()), grid.clone(), values)?;
            field.source = path.to_path_buf();
            Ok(field)
        })
        .collect()
}

/// Where `train` and `eval` read the runs from: a directory of `weather generate` (NetCDF), or a
/// directory of its shards (`--shard i/n`), checked whole by [`open_shards`].
enum DataDir {
    Plain(PathBuf),
    Shards(ShardSet),
}

/// A directory with `manifest-*.json` files is read as shards (every item present once, hashes
/// as recorded, written by `weather generate`); any other as the plain layout.
fn open_data(dir: &Path) -> anyhow::Result<DataDir> {
    let has_manifest = std::fs::read_dir(dir).is_ok_and(|entries| {
        entries
            .filter_map(|e| e.ok())
            .any(|e| e.file_name().to_str().is_some_and(|n| n.starts_with("manifest-") && n.ends_with(".json")))
    });
    if !has_manifest {
        return Ok(DataDir::Plain(dir.to_path_buf()));
    }
    let set = open_shards(dir).with_context(|| format!("reading the weather data shards of {}", dir.display()))?;
    anyhow::ensure!(
        set.generator == GENERATOR && set.files.len() == ITEMS.len(),
        "{}: shards of `{}` ({} items), not of `weather generate --shard` ({GENERATOR}, {} items)",
        dir.display(),
        set.generator,
        set.files.len(),
        ITEMS.len()
    );
    Ok(DataDir::Shards(set))
}

/// The `z` and `t` of a run (`truth` or `climate`) plus the truth's constants, as one dataset.
fn load(data: &DataDir, tag: &str) -> anyhow::Result<Dataset> {
    match data {
        DataDir::Plain(dir) => {
            let read = |var: &str| -> anyhow::Result<Field> {
                let sel = Selection { var: Some(var.into()), ..Default::default() };
                Ok(read_truth(&dir.join(format!("{tag}_{var}.nc")), &sel)?)
            };
            let constants = read_constants(&dir.join("constants.nc"), &CONSTANTS)?;
            Ok(Dataset::from_fields(&[read("z")?, read("t")?], constants)?)
        }
        DataDir::Shards(set) => {
            let k = ITEMS.iter().position(|&i| i == tag).ok_or_else(|| anyhow::anyhow!("no run `{tag}`"))?;
            let fields = read_item_fields(&set.files[k])?;
            // The constants travel with the truth (item 0), as `constants.nc` does beside it.
            let truth = &set.files[0];
            let constants = CONSTANTS
                .iter()
                .map(|&name| {
                    let v = pbdl_core::io::read_npz_array(truth, name)?.flatten_all()?.to_dtype(DType::F32)?;
                    Ok((name.to_string(), v.to_vec1::<f32>()?))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            Ok(Dataset::from_fields(&fields, constants)?)
        }
    }
}

/// Truth splits: all but the last two years for training, then one year each for validation and test.
fn truth_splits(d: &Dataset) -> anyhow::Result<(Dataset, Dataset, Dataset)> {
    let year = (365.0 * 24.0 / d.step_hours).round() as usize;
    anyhow::ensure!(
        d.len() >= 3 * year,
        "the truth run has {} times; generate at least 3 years (--truth-years 3)",
        d.len()
    );
    let n = d.len();
    Ok((d.slice(0, n - 2 * year), d.slice(n - 2 * year, n - year), d.slice(n - year, n)))
}

fn spec() -> SampleSpec {
    // z and t at t, t-6h, t-12h; any lead from 6 h to 5 days as an input channel.
    SampleSpec { history: vec![0, 1, 2], lead: Lead::Continuous { min: 1, max: 20 }, targets: vec![0, 1] }
}

/// What `cargo xtask weather train` was asked to do.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Data directory of `weather generate`, plain or its shards (default: target/pbdl/weather/data).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Run directory (checkpoints every epoch; an existing one resumes).
    #[arg(long)]
    pub out: PathBuf,
    /// climate (pretraining) or truth.
    #[arg(long, default_value = "truth")]
    pub source: String,
    /// Start from the best weights of this run directory (fine-tuning).
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Most epochs (early stopping after 5 without improvement).
    #[arg(long, default_value_t = 20)]
    pub epochs: usize,
    /// Updates per epoch (batch 32).
    #[arg(long, default_value_t = 100)]
    pub steps_per_epoch: usize,
    /// Learning rate (Adam; cut by 5 after 2 epochs without improvement).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// ResNet width.
    #[arg(long, default_value_t = 32)]
    pub width: usize,
    /// Residual blocks.
    #[arg(long, default_value_t = 4)]
    pub blocks: usize,
    /// Train on only the latest this many truth training years (a short record).
    #[arg(long)]
    pub truth_train_years: Option<f64>,
    /// Seed of the initialisation, sample order and dropout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Trains the CPU-sized ResNet on the climate run or the truth's training years, validating on
/// the truth's validation year; normalisation always from the truth's training years.
pub fn train_cmd(args: TrainArgs) -> anyhow::Result<()> {
    let dir = args.data.clone().unwrap_or_else(|| crate::report::target_dir().join("weather/data"));
    let data = open_data(&dir)?;
    let truth = load(&data, "truth")?;
    let (mut tr, va, _) = truth_splits(&truth)?;
    if let Some(years) = args.truth_train_years {
        let n = ((years * 365.0 * 24.0 / tr.step_hours).round() as usize).min(tr.len());
        tr = tr.slice(tr.len() - n, tr.len());
    }
    let norm = Normalizer::fit(&tr);
    let source = match args.source.as_str() {
        "truth" => tr,
        "climate" => load(&data, "climate")?,
        other => anyhow::bail!("--source must be climate or truth, not {other}"),
    };
    let spec = spec();
    let cfg = ResNetConfig {
        width: args.width,
        blocks: args.blocks,
        ..ResNetConfig::cpu_size(spec.in_channels(2, CONSTANTS.len()), 2)
    };
    let varmap = VarMap::new();
    let net = WeatherResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
    pbdl_nets::seeded_init(&varmap, args.seed)?;
    if let Some(init) = &args.init {
        pbdl_core::io::load_varmap(init.join("best"), &varmap)?;
        println!("starting from {}", init.join("best").display());
    }
    let tc = TrainConfig {
        lr: args.lr,
        max_epochs: args.epochs,
        steps_per_epoch: Some(args.steps_per_epoch),
        seed: args.seed,
        dir: Some(args.out.clone()),
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let state = train(&net, &varmap, &source, &va, &norm, &spec, &tc)?;
    for r in &state.history {
        println!("epoch {:>3}: train {:.4}  valid {:.4}  lr {:.1e}", r.epoch, r.train_loss, r.valid_loss, r.lr);
    }
    let summary = serde_json::json!({
        "source": args.source, "init": args.init, "net": cfg, "train": tc, "normalizer": norm,
        "truth_train_times": source.len(), "best_epoch": state.best_epoch, "best_valid": state.best_valid,
        "stopped_early": state.stopped_early, "seconds": t0.elapsed().as_secs_f64(), "history": state.history,
    });
    pbdl_core::io::write_atomic(args.out.join("summary.json"), |w| {
        std::io::Write::write_all(w, serde_json::to_string_pretty(&summary).unwrap_or_default().as_bytes())
    })?;
    println!(
        "best epoch {} (valid {:.4}) after {:.0} s; wrote {}",
        state.best_epoch,
        state.best_valid,
        t0.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(())
}

/// What `cargo xtask weather eval` was asked to do.
pub struct EvalArgs {
    /// Data directory of `generate` (plain, or a directory of its shards).
    pub data: PathBuf,
    /// Run directories to score (their `best` weights, the net config in `summary.json`).
    pub runs: Vec<PathBuf>,
    /// Output directory.
    pub out: PathBuf,
}

/// Scores every baseline and every run on the truth's test year at 6 h, 1, 3 and 5 days;
/// writes `scores.json` (one row per model, variable and lead), `report.md` and RMSE-vs-lead plots.
pub fn eval(args: EvalArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)?;
    let truth = load(&open_data(&args.data)?, "truth")?;
    let (tr, _, te) = truth_splits(&truth)?;
    let spec = spec();
    let inits = spec.init_indices(&te);
    let opts = BaselineOptions { leads: EVAL_LEADS.to_vec(), stride: 5, ridge: LR_RIDGE, weekly: true };
    let mut scores: Vec<LeadScore> = Vec::new();
    for var in 0..te.variables.len() {
        scores.extend(baseline_scores(&tr, &te, var, &inits, &opts)?);
    }
    for run in &args.runs {
        let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join("summary.json"))?)?;
        let cfg: ResNetConfig = serde_json::from_value(summary["net"].clone())?;
        let norm: Normalizer = serde_json::from_value(summary["normalizer"].clone())?;
        let varmap = VarMap::new();
        let net = WeatherResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
        pbdl_core::io::load_varmap(run.join("best"), &varmap)?;
        let name = format!("resnet_{}", run.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default());
        let forecasts = network_forecasts(&net, &te, &norm, &spec, &inits, &EVAL_LEADS)?;
        scores.extend(forecast_scores(&name, &forecasts, &te)?);
        // z by lead as float32 NetCDF-4, scorable by `weather score` (and score.py).
        let Some(mut z) = forecasts.into_iter().next() else { continue };
        z.values = pbdl_weather::field::Values::F32(z.values.to_f64().into_iter().map(|x| x as f32).collect());
        write(&args.out.join(format!("forecast_{name}_z.nc")), &Forecast::ByLead(z), Flavour::Nc4)?;
    }
    // The test year's truth, so that `weather score` can re-score the forecast files.
    write(&args.out.join("truth_test_z.nc"), &Forecast::Direct(te.field(0)), Flavour::Nc4)?;
    let mut md = format!("# Stand-in WeatherBench: {} test forecasts, leads 6 h to 5 days\n\n", inits.len());
    for (k, var) in te.variables.iter().enumerate() {
        // The climatological standard deviation of the test year (pooled per-point variance
        // about each point's time mean), the analytic RMSE of a climatology forecast.
        let f = te.field(k);
        let v = f.values.to_f64();
        let plane = te.grid.n_lat() * te.grid.n_lon();
        let mean = pbdl_weather::score::time_mean(&v, plane);
        let w = pbdl_weather::grid::lat_weights(&te.grid.lat);
        let n_lon = te.grid.n_lon();
        let var_sum: f64 =
            v.iter().enumerate().map(|(i, x)| w[(i % plane) / n_lon] * (x - mean[i % plane]).powi(2)).sum();
        let sigma = (var_sum / v.len() as f64).sqrt();
        md.push_str(&format!(
            "{var}: latitude-weighted climatological standard deviation of the test year {sigma:.4}\n\n"
        ));
        md.push_str(&markdown_table(&scores, var));
        md.push('\n');
        let mut models: Vec<String> = scores.iter().filter(|s| &s.variable == var).map(|s| s.model.clone()).collect();
        models.dedup();
        let mut series = Vec::new();
        for m in models.iter().filter(|m| !m.contains("climatology")) {
            let pts: Vec<&LeadScore> = scores.iter().filter(|s| &s.model == m && &s.variable == var).collect();
            if !pts.is_empty() && !series.iter().any(|s: &pbdl_core::viz::Series| &s.name == m) {
                series.push(pbdl_core::viz::Series::new(
                    m.clone(),
                    pts.iter().map(|s| s.lead_hours).collect(),
                    pts.iter().map(|s| s.rmse).collect(),
                ));
            }
        }
        let style = pbdl_core::viz::PlotStyle {
            title: format!("{var}: RMSE against lead time (stand-in test year)"),
            x_label: "lead time [h]".into(),
            y_label: "latitude-weighted RMSE".into(),
            ..Default::default()
        };
        pbdl_core::viz::line_plot(args.out.join(format!("rmse_{var}.png")), &series, &style)?;
        md.push_str(&format!("![RMSE {var}](rmse_{var}.png)\n\n"));
    }
    pbdl_core::io::write_atomic(args.out.join("scores.json"), |w| {
        std::io::Write::write_all(w, serde_json::to_string_pretty(&scores).unwrap_or_default().as_bytes())
    })?;
    pbdl_core::io::write_atomic(args.out.join("report.md"), |w| std::io::Write::write_all(w, md.as_bytes()))?;
    println!("{md}");
    println!("wrote {}", args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small run of 12 six-hourly times on the 32 x 64 grid, different per `seed`.
    fn run(seed: u32, start: i64) -> StandIn {
        let grid = LatLonGrid::weatherbench(32);
        let plane = grid.n_lat() * grid.n_lon();
        let times: Vec<i64> = (0..12).map(|k| start + 6 * 3600 * k).collect();
        let values = |offset: f32| {
            (0..12 * plane).map(|k| offset + ((k as u32).wrapping_mul(2654435761) ^ seed) as f32 % 97.0).collect()
        };
        let field = |name: &str, offset: f32| {
            Field::new(name, Some(times.clone()), grid.clone(), Values::F32(values(offset))).unwrap()
        };
        let constants = CONSTANTS
            .iter()
            .enumerate()
            .map(|(c, n)| (n.to_string(), (0..plane).map(|q| (q * (c + 1) % 13) as f32).collect()))
            .collect();
        StandIn { z: field("z", 5.0e4), t: field("t", 250.0), constants }
    }

    #[test]
    fn train_and_eval_read_the_same_data_from_shards_as_from_netcdf() {
        let (plain, shards) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let runs = [run(1, TRUTH_START), run(2, CLIMATE_START)];
        for (tag, r) in ITEMS.iter().zip(&runs) {
            write_run(plain.path(), tag, &r.z, &r.t).unwrap();
        }
        write_constants(&plain.path().join("constants.nc"), &runs[0].z.grid, &runs[0].constants, Flavour::Nc4).unwrap();
        let config = serde_json::json!({ "test": 1 });
        for i in [1, 0] {
            generate_shard(shards.path(), GENERATOR, &config, 2, Shard::new(i, 2).unwrap(), |k, path| {
                let r = &runs[k];
                write_item(path, &r.z, &r.t, (k == 0).then_some(r.constants.as_slice()))
                    .map_err(|e| pbdl_core::Error::invalid("test", "item", e.to_string()))
            })
            .unwrap();
        }
        let (p, s) = (open_data(plain.path()).unwrap(), open_data(shards.path()).unwrap());
        assert!(matches!(p, DataDir::Plain(_)) && matches!(s, DataDir::Shards(_)));
        for tag in ITEMS {
            let (a, b) = (load(&p, tag).unwrap(), load(&s, tag).unwrap());
            assert_eq!(a.len(), 12);
            assert_eq!(a, b, "{tag}");
        }
        assert_ne!(load(&s, "truth").unwrap().values, load(&s, "climate").unwrap().values);
        // Shards of another generator are not weather data.
        let other = tempfile::tempdir().unwrap();
        generate_shard(other.path(), "pbdl-grid/sim", &config, 2, Shard::WHOLE, |k, path| {
            let r = &runs[k];
            write_item(path, &r.z, &r.t, None).map_err(|e| pbdl_core::Error::invalid("test", "item", e.to_string()))
        })
        .unwrap();
        let e = open_data(other.path()).err().unwrap().to_string();
        assert!(e.contains("not of `weather generate --shard`"), "{e}");
        // A missing shard is named.
        std::fs::remove_file(shards.path().join("manifest-1-of-2.json")).unwrap();
        let e = format!("{:#}", open_data(shards.path()).err().unwrap());
        assert!(e.contains("run --shard 1/2"), "{e}");
    }
}
