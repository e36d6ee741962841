//! WeatherBench's baselines on Lorenz-96 (K = 40, F = 8, 6-hour steps): the analytic limits of
//! climatology and persistence, and linear regression beating persistence at every lead.

use pbdl_weather::baselines::{persistence, Climatology, LinearRegression};
use pbdl_weather::lorenz96::Lorenz96;
use pbdl_weather::score::{score, score_by_lead, Metric};

const LEADS: [f64; 6] = [6.0, 24.0, 72.0, 120.0, 240.0, 480.0];

#[test]
fn climatology_persistence_and_regression_behave_as_the_analytic_limits_say() {
    let model = Lorenz96::default();
    let train = model.trajectory(1, 1000, 20_000).unwrap();
    let test = model.trajectory(2, 1000, 2_000).unwrap();
    let v = test.values.to_f64();
    // Climatological standard deviation of the test period: pooled per-point variance.
    let clim_test = pbdl_weather::score::time_mean(&v, 40);
    let sigma =
        (v.iter().enumerate().map(|(k, x)| (x - clim_test[k % 40]).powi(2)).sum::<f64>() / v.len() as f64).sqrt();

    let clim = Climatology::fit(&train).forecast(test.times.as_ref().unwrap());
    let clim_rmse = score(Metric::Rmse, &clim, &test).unwrap();
    let clim_acc = score(Metric::Acc, &clim, &test).unwrap();
    eprintln!("sigma_clim {sigma:.4}, climatology RMSE {clim_rmse:.4}, ACC {clim_acc:.4}");
    assert!((clim_rmse / sigma - 1.0).abs() < 0.03, "climatology RMSE {clim_rmse} vs sigma {sigma}");
    assert!(clim_acc.abs() < 0.05, "climatology ACC {clim_acc}");

    let pers = score_by_lead(Metric::Rmse, &persistence(&test, &LEADS).unwrap(), &test).unwrap();
    let mut lr_direct = Vec::new();
    for &lead in &LEADS {
        let lr = LinearRegression::fit(&train, lead, 5, 1e-10).unwrap();
        lr_direct.push(score_by_lead(Metric::Rmse, &lr.forecast(&test, 1).unwrap(), &test).unwrap()[0]);
    }
    let lr6 = LinearRegression::fit(&train, 6.0, 5, 1e-10).unwrap();
    let iterative = score_by_lead(Metric::Rmse, &lr6.forecast(&test, 80).unwrap(), &test).unwrap();
    eprintln!("| lead (h) | persistence | LR direct | LR iterative |");
    for (k, lead) in LEADS.iter().enumerate() {
        let it = iterative[(*lead / 6.0) as usize - 1];
        eprintln!("| {lead} | {:.4} | {:.4} | {:.4} |", pers[k], lr_direct[k], it);
    }
    // Persistence error grows with lead towards sqrt(2) sigma (decorrelated states).
    assert!(pers.windows(2).take(3).all(|w| w[1] > w[0]), "persistence not growing: {pers:?}");
    let limit = 2f64.sqrt() * sigma;
    assert!((pers[5] / limit - 1.0).abs() < 0.05, "persistence at 20 days {} vs sqrt(2) sigma {limit}", pers[5]);
    // Linear regression beats persistence at every lead; at long leads it tends to climatology.
    for k in 0..LEADS.len() {
        assert!(lr_direct[k] < pers[k], "lead {}: LR {} vs persistence {}", LEADS[k], lr_direct[k], pers[k]);
    }
    assert!((lr_direct[5] / clim_rmse - 1.0).abs() < 0.05, "LR at 20 days {} vs climatology {clim_rmse}", lr_direct[5]);
}
