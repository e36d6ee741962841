//! Latent-space physics on 2D smoke plumes at CPU size: simulate, train the pressure
//! autoencoder and the LSTM, score them on held-out scenes and run hybrid rollouts at several
//! solve intervals against the pure solver.
//!
//! `cargo run --release -p pbdl-latent --example latent_smoke [res=32] [train=12] [test=4]
//! [frames=160] [ae_steps=2000] [lstm_steps=3000] [latent=8] [widths=16,32,64] [steps=200]
//! [warmup=50] [intervals=2,5,10] [seed=0] [residual=0|1] [nu=0] [grad_weight=0] [dir=PATH] [model=PATH] [sensitivity]`

use pbdl_latent::autoencoder::AutoencoderConfig;
use pbdl_latent::data::{generate, PlumeData};
use pbdl_latent::eval::{autoencoder_error, prediction_error, rollout, rollout_autoencoder_only, RolloutScore};
use pbdl_latent::hybrid::Schedule;
use pbdl_latent::model::LatentModel;
use pbdl_latent::predictor::PredictorConfig;
use pbdl_latent::train::{train, LatentTrainConfig, PhaseSettings};
use std::path::PathBuf;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).and_then(|v| v.parse().ok())).unwrap_or(default)
}

fn list(name: &str, default: &str) -> Vec<usize> {
    arg(name, default.to_string()).split(',').filter_map(|s| s.parse().ok()).collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let res: usize = arg("res", 32);
    let data_cfg = PlumeData {
        resolution: res,
        train_scenes: arg("train", 12),
        test_scenes: arg("test", 4),
        frames: arg("frames", 160),
        seed: arg("seed", 0),
        nu: arg("nu", 0.0),
        ..PlumeData::default()
    };
    if std::env::args().any(|a| a == "sensitivity") {
        return sensitivity(&data_cfg, arg("steps", 200), arg("warmup", 50));
    }
    let t = std::time::Instant::now();
    let data = generate(&data_cfg)?;
    println!(
        "data: {} + {} scenes of {} frames at {res}^2 in {:.1} s",
        data.train.len(),
        data.test.len(),
        data_cfg.frames,
        t.elapsed().as_secs_f64()
    );
    let cfg = LatentTrainConfig {
        autoencoder: AutoencoderConfig {
            resolution: res,
            widths: list("widths", "16,32,64"),
            latent_channels: arg("latent", 8),
            ..AutoencoderConfig::default()
        },
        autoencoder_training: PhaseSettings { steps: arg("ae_steps", 2000), ..PhaseSettings::default() },
        predictor_training: PhaseSettings { steps: arg("lstm_steps", 3000), batch: 16, lr: arg("lstm_lr", 3e-4) },
        predictor: PredictorConfig { residual: arg("residual", 0) == 1, ..PredictorConfig::default() },
        seed: arg("seed", 0),
        gradient_loss_weight: arg("grad_weight", 0.0),
    };
    let dir: Option<PathBuf> = std::env::args().find_map(|a| a.strip_prefix("dir=").map(PathBuf::from));
    let t = std::time::Instant::now();
    // `model=PATH` scores a saved model instead of training one.
    let model = match std::env::args().find_map(|a| a.strip_prefix("model=").map(PathBuf::from)) {
        Some(path) => LatentModel::load(&path)?,
        None => train(&data, &cfg, dir.as_deref())?,
    };
    println!("trained in {:.1} s (code {} entries)", t.elapsed().as_secs_f64(), model.autoencoder.code_size());
    println!(
        "autoencoder held-out rel L2: {:.4} (train {:.4})",
        autoencoder_error(&model, &data.test)?,
        autoencoder_error(&model, &data.train)?
    );
    let p = prediction_error(&model, &data.test)?;
    println!(
        "one-step prediction held-out: rel L2 {:.4}, AE floor {:.4}, ratio {:.2}; latent MAE {:.4} (persistence {:.4})",
        p.predicted, p.floor, p.ratio, p.latent_mae, p.persistence_latent_mae
    );
    let steps: usize = arg("steps", 200);
    let warmup: usize = arg("warmup", 50);
    println!("{}", RolloutScore::MARKDOWN_HEADER);
    for s in &data.test {
        let r = rollout_autoencoder_only(&model, &data.config.scene(s.param), Schedule { warmup, interval: 2 }, steps)?;
        println!("{}", r.markdown_row(s.param, "2 (autoencoder only)"));
    }
    for interval in list("intervals", "2,5,10") {
        for s in &data.test {
            let r = rollout(&model, &data.config.scene(s.param), Schedule { warmup, interval }, steps)?;
            println!("{}", r.markdown_row(s.param, &interval.to_string()));
        }
    }
    Ok(())
}

/// How far the plume departs from the solver when every 2nd step after the warm-up corrects
/// the velocity with the solver's own pressure scaled by `1 + eps` (a uniform relative
/// pressure error of `eps`): the density rel L2 against the exact run, largest over the run.
fn sensitivity(cfg: &PlumeData, steps: usize, warmup: usize) -> Result<(), Box<dyn std::error::Error>> {
    use pbdl_grid::{CenteredField, FluidState};
    let (_, params) = cfg.parameters();
    println!("| scene x | pressure error eps | max density rel L2 over {steps} steps |");
    for &x in &params {
        let scene = cfg.scene(x);
        let fluid = scene.fluid()?;
        let rate = scene.rate()?;
        for eps in [1e-4, 1e-3, 1e-2, 1e-1] {
            let (mut a, mut b) = (scene.start(&fluid)?, scene.start(&fluid)?);
            let mut worst = 0.0f64;
            for k in 0..steps {
                a = fluid.step(&a, Some(&rate))?;
                let before = fluid.step_unprojected(&b, Some(&rate))?;
                let (v, p) = fluid.project_keep_pressure(&before.velocity)?;
                let v = if k >= warmup && k % 2 == 1 {
                    let scaled =
                        CenteredField::new((p.values() * (1.0 + eps))?, *fluid.grid(), fluid.boundaries().pressure())?;
                    fluid.correct_with_pressure(&before.velocity, &scaled)?
                } else {
                    v
                };
                b = FluidState { velocity: v, density: before.density };
                let e = pbdl_latent::eval::relative_l2(
                    b.density.as_ref().unwrap().values(),
                    a.density.as_ref().unwrap().values(),
                )?;
                worst = worst.max(e);
            }
            println!("| {x:.3} | {eps:.0e} | {worst:.4} |");
        }
    }
    Ok(())
}
