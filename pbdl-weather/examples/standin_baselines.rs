//! Runs the stand-in climate for a year (after a spin-up), then scores persistence,
//! climatology and linear regression on its second half (fitted on the first) with WeatherBench's scores.
//!
//! `cargo run --release -p pbdl-weather --example standin_baselines [-- DAYS]`

use pbdl_weather::baselines::{persistence, Climatology, LinearRegression};
use pbdl_weather::evaluation::select_times;
use pbdl_weather::score::{score, score_by_lead, Metric};
use pbdl_weather::standin::{run, ClimateConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let days: f64 = std::env::args().nth(1).map_or(Ok(365.0), |s| s.parse())?;
    // Optional JSON with fields of ClimateConfig to change, e.g. '{"relaxation_days": 2.0}'.
    let mut cfg = serde_json::to_value(ClimateConfig::default())?;
    if let Some(patch) = std::env::args().nth(2) {
        let patch: serde_json::Value = serde_json::from_str(&patch)?;
        for (k, v) in patch.as_object().ok_or("the patch must be a JSON object")? {
            cfg[k] = v.clone();
        }
    }
    let cfg: ClimateConfig = serde_json::from_value(cfg)?;
    let t0 = std::time::Instant::now();
    let climate = run(&cfg, 1_483_228_800, 100.0, days, |_| {})?;
    println!("{days} days (+100 spin-up) in {:.1} s: {cfg:?}", t0.elapsed().as_secs_f64());
    for field in [&climate.z, &climate.t] {
        let n = field.n_time();
        let split = n / 2;
        let train = select_times(field, &(0..split).collect::<Vec<_>>());
        let test = select_times(field, &(split..n).collect::<Vec<_>>());
        let v = test.values.to_f64();
        let (min, max) = v.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        let clim = Climatology::fit(&train).forecast(test.times.as_ref().unwrap());
        println!(
            "{}: range {min:.1}..{max:.1}, climatology RMSE {:.3}",
            field.name,
            score(Metric::Rmse, &clim, &test)?
        );
        let leads = [6.0, 24.0, 72.0, 120.0];
        let ridge: f64 = std::env::var("RIDGE").map_or(1e-6, |r| r.parse().unwrap_or(1e-6));
        let pers = score_by_lead(Metric::Rmse, &persistence(&test, &leads)?, &test)?;
        for (k, &lead) in leads.iter().enumerate() {
            let lr = LinearRegression::fit(&train, lead, 1, ridge)?;
            let lr_rmse = score_by_lead(Metric::Rmse, &lr.forecast(&test, 1)?, &test)?[0];
            println!("  lead {lead:>5} h: persistence {:.3}, linear regression {lr_rmse:.3}", pers[k]);
        }
    }
    Ok(())
}
