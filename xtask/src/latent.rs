//! `cargo xtask latent train|eval`: latent-space physics (pbdl_latent) on 2D smoke plumes.
//!
//! `train` simulates the plume scenes, trains the pressure autoencoder and the LSTM in a
//! resumable run directory (`autoencoder/`, `predictor/` with checkpoints and `loss.csv`), saves
//! the model to `<out>/model` and the data settings to `<out>/data.json`, and writes
//! `summary.json` (held-out reconstruction and one-step prediction errors). `eval` re-simulates
//! the held-out scenes of a trained run and writes the time-against-error table of hybrid
//! rollouts (solver every `i`-th step) against the pure solver: `<out>.md`, `<out>.json` and a
//! Pareto plot `<out>.png` (ms per step against the density error).

use crate::run_files::write_json;
use anyhow::Context as _;
use pbdl_core::viz::{pareto_plot, ParetoPoint, PlotStyle};
use pbdl_latent::autoencoder::AutoencoderConfig;
use pbdl_latent::data::{generate, simulate, PlumeData};
use pbdl_latent::eval::{autoencoder_error, prediction_error, rollout, RolloutScore};
use pbdl_latent::hybrid::Schedule;
use pbdl_latent::model::LatentModel;
use pbdl_latent::predictor::PredictorConfig;
use pbdl_latent::train::{train, LatentTrainConfig, PhaseSettings};
use std::path::PathBuf;

/// `cargo xtask latent ...`.
#[derive(clap::Subcommand)]
pub enum LatentCommand {
    /// Simulate, train the autoencoder and the LSTM into a run directory (resumable), score them.
    Train(TrainArgs),
    /// Hybrid rollouts of a trained run against the solver: <out>.md, .json, .png.
    Eval(EvalArgs),
}

/// Arguments of `latent train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Run directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Cells per side.
    #[arg(long, default_value_t = 32)]
    pub res: usize,
    /// Training scenes.
    #[arg(long, default_value_t = 12)]
    pub train_scenes: usize,
    /// Held-out scenes.
    #[arg(long, default_value_t = 4)]
    pub test_scenes: usize,
    /// Frames per scene.
    #[arg(long, default_value_t = 160)]
    pub frames: usize,
    /// Autoencoder updates.
    #[arg(long, default_value_t = 2000)]
    pub ae_steps: u64,
    /// LSTM updates.
    #[arg(long, default_value_t = 3000)]
    pub lstm_steps: u64,
    /// Channels of the autoencoder's latent map.
    #[arg(long, default_value_t = 8)]
    pub latent: usize,
    /// Seed of the scenes and the networks.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Toy size (16^2, 3 + 1 scenes of 40 frames, small networks, 60 updates each): seconds.
    #[arg(long)]
    pub quick: bool,
}

/// Arguments of `latent eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// A run directory written by `latent train`.
    #[arg(long)]
    pub run: PathBuf,
    /// Solve intervals, comma-separated.
    #[arg(long, default_value = "2,5,10")]
    pub intervals: String,
    /// Steps per rollout (warm-up included).
    #[arg(long, default_value_t = 200)]
    pub steps: usize,
    /// Warm-up steps with the solver.
    #[arg(long, default_value_t = 50)]
    pub warmup: usize,
    /// Output path: writes <out>.md, <out>.json and <out>.png (an extension given is replaced).
    #[arg(long)]
    pub out: PathBuf,
}

/// The data and training settings of `train`.
pub fn configs(a: &TrainArgs) -> (PlumeData, LatentTrainConfig) {
    if a.quick {
        let data = PlumeData {
            resolution: 16,
            train_scenes: 3,
            test_scenes: 1,
            frames: 40,
            seed: a.seed,
            ..Default::default()
        };
        let cfg = LatentTrainConfig {
            autoencoder: AutoencoderConfig {
                resolution: 16,
                widths: vec![8, 16],
                latent_channels: 4,
                ..Default::default()
            },
            predictor: PredictorConfig { window: 4, encoder_units: 32, decoder_units: 32, ..Default::default() },
            autoencoder_training: PhaseSettings { steps: 60, batch: 8, lr: 2e-3 },
            predictor_training: PhaseSettings { steps: 60, batch: 8, lr: 2e-3 },
            seed: a.seed,
            gradient_loss_weight: 0.0,
        };
        return (data, cfg);
    }
    let data = PlumeData {
        resolution: a.res,
        train_scenes: a.train_scenes,
        test_scenes: a.test_scenes,
        frames: a.frames,
        seed: a.seed,
        ..Default::default()
    };
    let cfg = LatentTrainConfig {
        autoencoder: AutoencoderConfig::for_resolution(a.res, a.latent),
        autoencoder_training: PhaseSettings { steps: a.ae_steps, ..PhaseSettings::default() },
        predictor_training: PhaseSettings { steps: a.lstm_steps, batch: 16, lr: 3e-4 },
        seed: a.seed,
        ..LatentTrainConfig::default()
    };
    (data, cfg)
}

/// Runs `cargo xtask latent ...`.
pub fn run(cmd: LatentCommand) -> anyhow::Result<()> {
    match cmd {
        LatentCommand::Train(a) => {
            let (data_cfg, cfg) = configs(&a);
            std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
            let t = std::time::Instant::now();
            let data = generate(&data_cfg)?;
            let sim_seconds = t.elapsed().as_secs_f64();
            write_json(a.out.join("data.json"), &data_cfg)?;
            let t = std::time::Instant::now();
            let model = train(&data, &cfg, Some(&a.out))?;
            let train_seconds = t.elapsed().as_secs_f64();
            let ae = autoencoder_error(&model, &data.test)?;
            let p = prediction_error(&model, &data.test)?;
            let summary = serde_json::json!({
                "data": data_cfg, "training": cfg, "code_size": model.autoencoder.code_size(),
                "simulation_seconds": sim_seconds, "training_seconds": train_seconds,
                "autoencoder_rel_l2_heldout": ae, "prediction_heldout": p,
            });
            write_json(a.out.join("summary.json"), &summary)?;
            println!("held-out pressure reconstruction rel L2 {ae:.4}");
            println!(
                "held-out one-step prediction rel L2 {:.4} = {:.2} x the autoencoder floor {:.4}; latent MAE {:.4} (persistence {:.4})",
                p.predicted, p.ratio, p.floor, p.latent_mae, p.persistence_latent_mae
            );
            println!("run directory: {} (model in model/)", a.out.display());
            Ok(())
        }
        LatentCommand::Eval(a) => {
            let text = std::fs::read_to_string(a.run.join("data.json"))
                .with_context(|| format!("{}: not a `latent train` run directory (no data.json)", a.run.display()))?;
            let data_cfg: PlumeData = serde_json::from_str(&text).context("data.json")?;
            let model = LatentModel::load(&a.run.join("model"))?;
            let intervals: Vec<usize> = a
                .intervals
                .split(',')
                .map(|s| s.trim().parse().with_context(|| format!("interval `{s}` is not a positive integer")))
                .collect::<anyhow::Result<_>>()?;
            let (_, test_params) = data_cfg.parameters();
            let mut md = format!(
                "# latent eval: {0}^2 smoke plumes, {1} held-out scenes, {2} steps (warm-up {3})\n\n\
                 {4}\n",
                data_cfg.resolution,
                test_params.len(),
                a.steps,
                a.warmup,
                RolloutScore::MARKDOWN_HEADER
            );
            let test: Vec<_> =
                test_params.iter().map(|&p| simulate(&data_cfg.scene(p), data_cfg.frames)).collect::<Result<_, _>>()?;
            let ae = autoencoder_error(&model, &test)?;
            let pred = prediction_error(&model, &test)?;
            let mut rows: Vec<(f64, RolloutScore)> = Vec::new();
            for &i in &intervals {
                for &p in &test_params {
                    let r = rollout(&model, &data_cfg.scene(p), Schedule { warmup: a.warmup, interval: i }, a.steps)?;
                    let line = r.markdown_row(p, &i.to_string());
                    println!("{line}");
                    md.push_str(&line);
                    md.push('\n');
                    rows.push((p, r));
                }
            }
            md.push_str(&format!(
                "\nHeld-out pressure reconstruction rel L2 {ae:.4}; one-step prediction rel L2 {:.4} ({:.2} x the \
                 autoencoder floor).\n",
                pred.predicted, pred.ratio
            ));
            let out = a.out.with_extension("");
            pbdl_core::io::write_atomic(out.with_extension("md"), |w| std::io::Write::write_all(w, md.as_bytes()))?;
            let json: Vec<serde_json::Value> =
                rows.iter().map(|(p, r)| serde_json::json!({ "scene_x": p, "rollout": r })).collect();
            write_json(
                out.with_extension("json"),
                &serde_json::json!({ "autoencoder_rel_l2": ae, "prediction": pred, "rollouts": json }),
            )?;
            let points: Vec<ParetoPoint> = rows
                .iter()
                .filter(|(_, r)| r.finite && r.density_error_max > 0.0)
                .map(|(p, r)| ParetoPoint {
                    method: format!("interval {}", r.interval),
                    time: r.hybrid_seconds_per_step * 1e3,
                    error: r.density_error_max,
                    label: Some(format!("x={p:.2}")),
                })
                .collect();
            if !points.is_empty() {
                let style = PlotStyle {
                    title: format!("hybrid smoke {0}^2: ms per step vs density error", data_cfg.resolution),
                    x_label: "ms per step".into(),
                    y_label: "max density rel L2 vs solver".into(),
                    ..PlotStyle::pareto()
                };
                pareto_plot(out.with_extension("png"), &points, &style)?;
            }
            println!("wrote {}.md, .json{}", out.display(), if points.is_empty() { "" } else { ", .png" });
            Ok(())
        }
    }
}
