//! `pbdl-weather`'s entries for `cargo xtask` (see [`crate::registry`]).
//!
//! * tour `standin_forecast`: 120 days of the stand-in climate, baselines and a small ResNet
//!   trained for about a minute; RMSE against lead time and maps of truth, forecast and error.
//! * bench `score_year`: WeatherBench's RMSE, MAE and ACC of a year of hourly 32x64 float32
//!   fields held in memory, and reading that year from NetCDF-4 and classic files (the files
//!   `bench/peers/weather_run.sh` wrote with xarray, where present, else pbdl's own). The peer
//!   script times the official score.py and xarray on the same sizes; `cargo xtask bench`
//!   merges its rows.
//! * stress `standin_years`: 50 simulated years of the stand-in climate in one run (2 with
//!   `--quick`), checking finiteness and physical bounds at every stored time.
//! * stress `acceptance`: the README's Williamson numbers from their `#[ignore]`d tests
//!   ([`crate::acceptance`]); the T170 convergence bar is not met at day 14 (README), so it fails.

use crate::acceptance::AcceptanceTest;
use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_weather::field::Values;
use pbdl_weather::io::netcdf::{write, Flavour};
use pbdl_weather::io::{read_truth, Selection};
use pbdl_weather::score::{score, Metric};
use pbdl_weather::standin::{run_streaming, ClimateConfig};
use pbdl_weather::{Field, Forecast, LatLonGrid};
use std::path::PathBuf;

/// The entries of `pbdl-weather`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "weather",
        tour: vec![Entry {
            name: "standin_forecast",
            about: "Stand-in climate (120 days), baselines and a small ResNet: RMSE against lead time, maps of truth, forecast and error.",
            run: tour_standin_forecast,
        }],
        bench: vec![Entry {
            name: "score_year",
            about: "RMSE/MAE/ACC of a year of hourly 32x64 float32 fields; reading the year from NetCDF-4 and classic files.",
            run: bench_score_year,
        }],
        stress: vec![
            Entry {
                name: "standin_years",
                about: "50 simulated years of the stand-in climate (2 with --quick): finite and inside physical bounds.",
                run: stress_standin_years,
            },
            Entry {
                name: "dt_limit",
                about: "Stand-in climate at 1..18x its 1200 s step for 60 days (20 quick): largest multiple that stays finite and in bounds.",
                run: super::stability::weather_dt_limit,
            },
            Entry {
                name: "acceptance",
                about: "The README's Williamson 2/6 table and T170 convergence: runs their #[ignore]d tests in release (about 25 min; quick: the Williamson 2 and 6 runs).",
                run: stress_acceptance,
            },
        ],
    }
}

/// A year (or `n_time` hours) of a Z500-like float32 field with seeded noise.
fn year_of_fields(seed: u64, n_time: usize) -> Field {
    let grid = LatLonGrid::weatherbench(32);
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut values = Vec::with_capacity(n_time * 2048);
    for _ in 0..n_time {
        for lat in &grid.lat {
            for _ in 0..64 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                values.push((54_000.0 + 2000.0 * lat.to_radians().cos() + 600.0 * u) as f32);
            }
        }
    }
    let times = (0..n_time as i64).map(|t| 1_483_228_800 + 3600 * t).collect(); // from 2017-01-01
    Field::new("z", Some(times), grid, Values::F32(values)).expect("valid synthetic field")
}

fn bench_score_year(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let n_time = if ctx.quick { 876 } else { 8760 };
    let reps = if ctx.quick { 3 } else { 9 };
    let size = format!("{n_time}x32x64_f32");
    let (truth, fc) = (year_of_fields(0, n_time), year_of_fields(1, n_time));
    let mut rows = Vec::new();
    let row = |case: String, size: String, seconds: f64, unit: &str| BenchRow {
        case,
        method: "pbdl".into(),
        size,
        seconds,
        unit: unit.into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads: ctx.threads,
    };
    for metric in [Metric::Rmse, Metric::Mae, Metric::Acc] {
        let s = median_seconds(1, reps, || score(metric, &fc, &truth).expect("scores"));
        rows.push(row(format!("score_year_{}", metric.name()), size.clone(), s, "call"));
    }
    // The peer script's files (written by xarray / libnetcdf) when present, else our own.
    let peer_dir = PathBuf::from("target/pbdl/weather-bench");
    for (flavour, tag) in [(Flavour::Nc4, "nc4"), (Flavour::Classic, "nc3")] {
        let peer_file = peer_dir.join(format!("truth_year_{tag}.nc"));
        let (path, method) = if peer_file.is_file() && !ctx.quick {
            (peer_file, "pbdl (file by xarray)")
        } else {
            let p = ctx.out_dir.join(format!("truth_year_{tag}.nc"));
            write(&p, &Forecast::Direct(truth.clone()), flavour)?;
            (p, "pbdl (file by pbdl)")
        };
        let mb = std::fs::metadata(&path)?.len() as f64 / 1e6;
        let sel = Selection { var: Some("z".into()), ..Default::default() };
        let s = median_seconds(1, reps, || read_truth(&path, &sel).expect("reads"));
        let mut r = row(format!("read_year_{tag}"), format!("{size}_{mb:.0}MB"), s, "file");
        r.method = method.into();
        rows.push(r);
    }
    Ok(rows)
}

/// 50 simulated years of the stand-in climate (2 with `--quick`) in one continuous run: the
/// fields stay finite and inside physical bounds.
fn stress_standin_years(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let years = if ctx.quick { 2.0 } else { 50.0 };
    let (mut outputs, mut out_of_bounds, mut z_range, mut t_range) =
        (0u64, None, (f64::MAX, f64::MIN), (f64::MAX, f64::MIN));
    let result = run_streaming(
        &ClimateConfig::default(),
        0,
        100.0,
        years * 365.0,
        |_| {},
        |o| {
            for &z in o.z {
                z_range = (z_range.0.min(z), z_range.1.max(z));
            }
            for &t in o.t {
                t_range = (t_range.0.min(t), t_range.1.max(t));
            }
            // Plausible Z500 (m^2/s^2) and T850 (K) ranges; a blow-up leaves them long before NaN.
            if out_of_bounds.is_none()
                && (z_range.0 < 2.0e4 || z_range.1 > 8.0e4 || t_range.0 < 150.0 || t_range.1 > 350.0)
            {
                out_of_bounds = Some(outputs);
            }
            outputs += 1;
            Ok(())
        },
    );
    let blew_up = result.as_ref().err().map(|e| e.to_string());
    let stable = blew_up.is_none() && out_of_bounds.is_none();
    Ok(vec![StressCheck {
        invariant: format!(
            "stand-in climate, {years} years in one run: finite, z in 2e4..8e4 m^2/s^2, t in 150..350 K"
        ),
        passed: blew_up.is_none() && out_of_bounds.is_none(),
        first_broken_step: out_of_bounds.or(blew_up.as_ref().map(|_| outputs)),
        detail: blew_up.unwrap_or_else(|| {
            format!(
                "{outputs} 6-hourly outputs; z {:.0}..{:.0}, t {:.1}..{:.1}",
                z_range.0, z_range.1, t_range.0, t_range.1
            )
        }),
        // In model steps (the outputs are 6-hourly).
        measure: stable.then(|| StressMeasure::StableSteps(outputs * 6 * 3600 / ClimateConfig::default().dt as u64)),
    }])
}

/// The stand-in climate for 120 days, baselines and a small ResNet (continuous lead, 6 h to 3
/// days) trained for a minute on its first 80 days and scored on the last 30: RMSE against lead
/// time (PNG), maps of truth, forecast and error at a one-day lead.
fn tour_standin_forecast(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    use candle_core::{DType, Device};
    use candle_nn::{VarBuilder, VarMap};
    use pbdl_weather::evaluation::{baseline_scores, markdown_table, network_scores, BaselineOptions};
    use pbdl_weather::forecaster::{
        predict, train, Dataset, Lead, Normalizer, ResNetConfig, SampleSpec, TrainConfig, WeatherResNet,
    };
    let t0 = std::time::Instant::now();
    let climate = pbdl_weather::standin::run(&ClimateConfig::default(), 1_483_228_800, 100.0, 120.0, |_| {})?;
    let gen_seconds = t0.elapsed().as_secs_f64();
    let all = Dataset::from_fields(&[climate.z.clone(), climate.t.clone()], climate.constants.clone())?;
    let (tr, va, te) = (all.slice(0, 320), all.slice(320, 360), all.slice(360, 480));
    let norm = Normalizer::fit(&tr);
    let spec = SampleSpec { history: vec![0, 1, 2], lead: Lead::Continuous { min: 1, max: 12 }, targets: vec![0, 1] };
    let varmap = VarMap::new();
    let cfg = ResNetConfig { width: 16, blocks: 2, dropout: 0.0, ..ResNetConfig::cpu_size(spec.in_channels(2, 3), 2) };
    let net = WeatherResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
    pbdl_nets::seeded_init(&varmap, 0)?;
    let steps = if ctx.quick { 10 } else { 40 };
    let tc = TrainConfig {
        lr: 2e-3,
        max_epochs: 4,
        steps_per_epoch: Some(steps),
        batch: 16,
        progress: false,
        ..Default::default()
    };
    let t1 = std::time::Instant::now();
    train(&net, &varmap, &tr, &va, &norm, &spec, &tc)?;
    let train_seconds = t1.elapsed().as_secs_f64();
    let leads = [1, 4, 12];
    let inits = spec.init_indices(&te);
    let opts = BaselineOptions { leads: leads.to_vec(), stride: 1, ridge: 1e-3, weekly: false };
    let mut scores = baseline_scores(&tr, &te, 0, &inits, &opts)?;
    scores.extend(network_scores("resnet", &net, &te, &norm, &spec, &inits, &leads)?);
    let mut series = Vec::new();
    for m in ["persistence", "linear_regression_direct", "linear_regression_iterative", "resnet"] {
        let pts: Vec<_> = scores.iter().filter(|s| s.model == m && s.variable == "z").collect();
        series.push(pbdl_core::viz::Series::new(
            m,
            pts.iter().map(|s| s.lead_hours).collect(),
            pts.iter().map(|s| s.rmse).collect(),
        ));
    }
    let style = pbdl_core::viz::PlotStyle {
        title: "stand-in z: RMSE against lead time".into(),
        x_label: "lead time [h]".into(),
        y_label: "latitude-weighted RMSE [m^2/s^2]".into(),
        ..Default::default()
    };
    pbdl_core::viz::line_plot(ctx.out_dir.join("weather_rmse_z.png"), &series, &style)?;
    // Maps at a one-day lead from the first test initialisation.
    let fc = predict(&net, &te, &norm, &spec, &inits[..1], 4, 1)?;
    let forecast = fc[0].values.to_f64();
    let truth: Vec<f64> = te.map(inits[0] + 4, 0).iter().map(|&x| x as f64).collect();
    let error: Vec<f64> = forecast.iter().zip(&truth).map(|(f, o)| f - o).collect();
    let map_style = pbdl_core::viz::FieldStyle { upscale: Some(6), ..Default::default() };
    pbdl_core::viz::field_to_png(ctx.out_dir.join("weather_truth_z.png"), &truth, 32, 64, &map_style)?;
    pbdl_core::viz::field_to_png(ctx.out_dir.join("weather_forecast_z.png"), &forecast, 32, 64, &map_style)?;
    let err_style = pbdl_core::viz::FieldStyle { upscale: Some(6), ..pbdl_core::viz::FieldStyle::diverging() };
    pbdl_core::viz::field_to_png(ctx.out_dir.join("weather_error_z.png"), &error, 32, 64, &err_style)?;
    let get = |m: &str, lead: f64| {
        scores.iter().find(|s| s.model == m && s.lead_hours == lead && s.variable == "z").map_or(f64::NAN, |s| s.rmse)
    };
    let markdown = format!(
        "## weather: stand-in climate and ResNet\n\n120 days of the stand-in climate ({gen_seconds:.1} s), a width-16 ResNet trained for {train_seconds:.0} s on the first 80 days, scored on the last 30 (z, latitude-weighted RMSE, m^2/s^2):\n\n{}\n![RMSE](weather_rmse_z.png)\n\nOne-day forecast from the first test time: truth, forecast, error\n\n![truth](weather_truth_z.png) ![forecast](weather_forecast_z.png) ![error](weather_error_z.png)\n",
        markdown_table(&scores, "z")
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: "stand-in climate 120 d + ResNet, z at 1 day".into(),
            seconds: gen_seconds + train_seconds,
            error: Some(get("resnet", 24.0)),
            error_kind: "RMSE z 1 day".into(),
            note: format!(
                "LR {:.0}, persistence {:.0}",
                get("linear_regression_direct", 24.0),
                get("persistence", 24.0)
            ),
        }],
        files: ["weather_rmse_z.png", "weather_truth_z.png", "weather_forecast_z.png", "weather_error_z.png"]
            .iter()
            .map(PathBuf::from)
            .collect(),
        markdown,
    })
}

/// The `#[ignore]`d tests behind the README's Williamson numbers (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[
    AcceptanceTest {
        package: "pbdl-weather",
        file: "williamson",
        test: "test2_steady_zonal_flow_t63_t85",
        claim: "Williamson 2 at T63/T85: l1, l2 < 1e-8, linf < 1e-7",
        minutes: 2.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-weather",
        file: "williamson",
        test: "test6_rossby_haurwitz_wave_day14",
        claim: "Williamson 6 day 14 at T21/T42/T63: |phase error| < 10%, l2 < 0.05, phase speeds within 3%",
        minutes: 3.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-weather",
        file: "williamson",
        test: "test6_convergence_against_t170_reference",
        claim: "Williamson 6 vs T170: errors fall T21 > T42 > T63 at days 7 and 14 (README: not met at day 14)",
        minutes: 20.0,
        env: &[],
    },
];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}
