//! `cargo xtask temporal train|eval|upscale`: temporally coherent super-resolution of smoke
//! (pbdl_temporal).
//!
//! `train` simulates the plume scenes, pre-trains the generator with L1 and trains the three
//! objectives (baseline, per-frame GAN, temporal GAN) from it in a resumable run directory
//! (`pretrain/`, `baseline/`, `per_frame/`, `temporal/` with checkpoints and `loss.csv`), saves
//! the models to `<out>/models/<kind>.safetensors`, the settings to `<out>/data.json` and
//! `<out>/train.json`. `eval` re-simulates the held-out scenes of a run and writes the score
//! table (per-frame PSNR / SSIM / LSiM, tOF, tLSiM, time per frame against the solver's time
//! per step): `<out>.md` and `<out>.json`. `upscale` runs a model on an `.npz` file.

use crate::run_files::write_json;
use anyhow::Context as _;
use pbdl_temporal::data::{generate, SmokeData};
use pbdl_temporal::gan::LossWeights;
use pbdl_temporal::generator::GeneratorConfig;
use pbdl_temporal::model::{upscale_npz, LoadedModel, ModelKind, TemporalModel};
use pbdl_temporal::train::{train_all, PhaseSettings, TrainConfig};
use std::path::{Path, PathBuf};

/// `cargo xtask temporal ...`.
#[derive(clap::Subcommand)]
pub enum TemporalCommand {
    /// Simulate, pre-train, train the baseline, per-frame GAN and temporal GAN (resumable).
    Train(TrainArgs),
    /// Score the models of a run on its held-out scenes: <out>.md, <out>.json.
    Eval(EvalArgs),
    /// Upscale the `density` of an .npz file (4x by default) with a trained model.
    Upscale(UpscaleArgs),
}

/// Arguments of `temporal train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Run directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Low-resolution cells per side (the high resolution is 4x).
    #[arg(long, default_value_t = 16)]
    pub lr_res: usize,
    /// Training scenes.
    #[arg(long, default_value_t = 12)]
    pub train_scenes: usize,
    /// Held-out scenes.
    #[arg(long, default_value_t = 4)]
    pub test_scenes: usize,
    /// Frames per scene.
    #[arg(long, default_value_t = 48)]
    pub frames: usize,
    /// L1 pre-training updates (batch 16 frames).
    #[arg(long, default_value_t = 1000)]
    pub pretrain_steps: u64,
    /// Updates of each objective (batch 4 frame triplets).
    #[arg(long, default_value_t = 800)]
    pub steps: u64,
    /// Generator width.
    #[arg(long, default_value_t = 32)]
    pub channels: usize,
    /// Weight of the temporal discriminator's term in the temporal GAN's generator loss.
    #[arg(long, default_value_t = 1.0)]
    pub temporal_weight: f64,
    /// Seed of the scenes, the weights and the batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Toy size (8^2 -> 32^2, 2 + 1 scenes of 8 frames, width 8, 30 + 6 updates): seconds.
    #[arg(long)]
    pub quick: bool,
}

/// Arguments of `temporal eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// A run directory written by `temporal train`.
    #[arg(long)]
    pub run: PathBuf,
    /// Output path: writes <out>.md and <out>.json (an extension given is replaced).
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `temporal upscale`.
#[derive(clap::Args)]
pub struct UpscaleArgs {
    /// A model file (`models/<kind>.safetensors` of a run, or a recurrent TecoGAN model saved by
    /// `RecurrentModel::save`, e.g. `--example tecogan_gan -- --save M`), or a run directory
    /// (its temporal GAN is used).
    #[arg(long)]
    pub model: PathBuf,
    /// Input .npz with `density` [T, 1, Y, X] and optionally `velocity` [T, 2, Y, X].
    #[arg(long)]
    pub input: PathBuf,
    /// Output .npz; gets `density` [T, 1, 4Y, 4X].
    #[arg(long)]
    pub out: PathBuf,
}

/// The data and training settings of `train`.
pub fn configs(a: &TrainArgs) -> (SmokeData, TrainConfig) {
    if a.quick {
        let data = SmokeData {
            lr_resolution: 8,
            train_scenes: 2,
            test_scenes: 1,
            frames: 8,
            warmup: 20,
            seed: a.seed,
            ..Default::default()
        };
        let cfg = TrainConfig {
            generator: GeneratorConfig { channels: 8, ..Default::default() },
            pretrain: PhaseSettings { steps: 30, batch: 4, lr: 2e-3 },
            finetune: PhaseSettings { steps: 6, batch: 2, lr: 2e-4 },
            discriminator_widths: vec![8, 8],
            seed: a.seed,
            ..Default::default()
        };
        return (data, cfg);
    }
    let data = SmokeData {
        lr_resolution: a.lr_res,
        train_scenes: a.train_scenes,
        test_scenes: a.test_scenes,
        frames: a.frames,
        seed: a.seed,
        ..Default::default()
    };
    let base = TrainConfig::default();
    let cfg = TrainConfig {
        generator: GeneratorConfig { channels: a.channels, ..Default::default() },
        pretrain: PhaseSettings { steps: a.pretrain_steps, ..base.pretrain.clone() },
        finetune: PhaseSettings { steps: a.steps, ..base.finetune.clone() },
        loss: LossWeights { temporal: a.temporal_weight, ..base.loss.clone() },
        seed: a.seed,
        ..base
    };
    (data, cfg)
}

fn read_json<T: serde::de::DeserializeOwned>(run: &Path, name: &str) -> anyhow::Result<T> {
    crate::run_files::read_json(run, name, "temporal train")
}

/// The model file of `path`: the file itself, or a run directory's temporal GAN.
pub fn model_path(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join("models").join(format!("{}.safetensors", ModelKind::Temporal.name()))
    } else {
        path.to_path_buf()
    }
}

/// The models of a run directory, in [`ModelKind::ALL`] order.
pub fn load_models(run: &Path) -> anyhow::Result<Vec<TemporalModel>> {
    ModelKind::ALL
        .iter()
        .map(|k| {
            let p = run.join("models").join(format!("{}.safetensors", k.name()));
            TemporalModel::load(&p).with_context(|| format!("loading {}", p.display()))
        })
        .collect()
}

/// Runs `cargo xtask temporal ...`.
pub fn run(cmd: TemporalCommand) -> anyhow::Result<()> {
    match cmd {
        TemporalCommand::Train(a) => {
            let (data_cfg, cfg) = configs(&a);
            std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
            // A run directory of other data is refused before anything is simulated or written
            // (each phase's own guard then checks the training settings).
            if a.out.join("data.json").exists() {
                let stored: SmokeData = read_json(&a.out, "data.json")?;
                if stored != data_cfg {
                    anyhow::bail!(
                        "{}: the run in this directory was made with other data settings (data.json: seed {}, {} + {} scenes of {} frames at {}^2); use a new run directory, or the same settings",
                        a.out.display(),
                        stored.seed,
                        stored.train_scenes,
                        stored.test_scenes,
                        stored.frames,
                        stored.lr_resolution
                    );
                }
            }
            let t = std::time::Instant::now();
            let data = generate(&data_cfg)?;
            let sim_seconds = t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            let models = train_all(&data, &cfg, Some(&a.out))?;
            // The settings are written once the models they describe exist.
            write_json(a.out.join("data.json"), &data_cfg)?;
            write_json(a.out.join("train.json"), &cfg)?;
            let train_seconds = t.elapsed().as_secs_f64();
            let phases: Vec<serde_json::Value> =
                models.iter().map(|(m, s)| serde_json::json!({ "kind": m.info.kind, "phase": s })).collect();
            write_json(
                a.out.join("summary.json"),
                &serde_json::json!({
                    "simulation_seconds": sim_seconds, "training_seconds": train_seconds, "phases": phases,
                }),
            )?;
            for (m, s) in &models {
                println!(
                    "{:>10}: final loss {:.4}, median {:.0} ms per update",
                    m.info.kind.name(),
                    s.final_loss,
                    s.median_step_seconds * 1e3
                );
            }
            println!("run directory: {} (models in models/)", a.out.display());
            Ok(())
        }
        TemporalCommand::Eval(a) => {
            let data_cfg: SmokeData = read_json(&a.run, "data.json")?;
            let models = load_models(&a.run)?;
            let report = pbdl_temporal::eval::evaluate_run(&data_cfg, &models)?;
            let out = a.out.with_extension("");
            let md = report.markdown();
            print!("{md}");
            pbdl_core::io::write_atomic(out.with_extension("md"), |w| std::io::Write::write_all(w, md.as_bytes()))?;
            write_json(out.with_extension("json"), &report)?;
            println!("wrote {}.md, .json", out.display());
            Ok(())
        }
        TemporalCommand::Upscale(a) => {
            let path = model_path(&a.model);
            let model = LoadedModel::load(&path).with_context(|| format!("loading the model {}", path.display()))?;
            let shape = upscale_npz(&model, &a.input, &a.out)
                .with_context(|| format!("upscaling {} with {}", a.input.display(), path.display()))?;
            println!("wrote {} (density {shape:?}, {})", a.out.display(), model.describe());
            Ok(())
        }
    }
}
