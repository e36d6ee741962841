//! Training of the [`Model`]s on normalised sequences: random windows, Adam, gradient
//! clipping, the NaN guard, a progress bar and atomic, resumable checkpoints.

use super::data::{CHANNELS, FIELDS};
use super::model::{Method, Model};
use crate::ddpm::Loss;
use crate::{Error, Result};
use candle_core::{Tensor, D};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, LoopReport, OptimizerConfig, TrainLoop};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Settings of a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Parameter updates.
    pub steps: usize,
    /// Windows per update.
    pub batch: usize,
    /// Adam learning rate of the first `lr_late_from` updates.
    pub lr: f64,
    /// The update from which Adam runs at `lr_late` (0: never). CPU runs start fast at `lr` and
    /// then drop to the official 1e-4: at 1e-3 the noise prediction jitters too much to sample
    /// cleanly (measured: one-step sample error 0.43 at 1075 updates, 0.14 after 100 more at 1e-4).
    #[serde(default)]
    pub lr_late_from: usize,
    /// The learning rate from `lr_late_from` on.
    #[serde(default = "official_lr")]
    pub lr_late: f64,
    /// Global gradient-norm clip.
    pub clip_norm: f64,
    /// Seed of window selection and noise.
    pub seed: u64,
    /// Updates between checkpoints (0: only at the end).
    pub checkpoint_every: usize,
}

/// The official ACDM learning rate.
fn official_lr() -> f64 {
    1e-4
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            steps: 2000,
            batch: 16,
            lr: 1e-3,
            lr_late_from: 1000,
            lr_late: official_lr(),
            clip_norm: 1.0,
            seed: 0,
            checkpoint_every: 250,
        }
    }
}

impl TrainConfig {
    /// The learning rate of update `step` (0-based).
    pub fn lr_at(&self, step: u64) -> f64 {
        if self.lr_late_from > 0 && step >= self.lr_late_from as u64 {
            self.lr_late
        } else {
            self.lr
        }
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.batch == 0 {
            return bad("batch", "0".into(), "use at least 1 window per update (official: 64; CPU runs: 16)");
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return bad("lr", self.lr.to_string(), "use a positive finite learning rate, e.g. 1e-3");
        }
        if self.lr_late_from > 0 && !(self.lr_late > 0.0 && self.lr_late.is_finite()) {
            return bad("lr_late", self.lr_late.to_string(), "use a positive finite late learning rate, e.g. 1e-4");
        }
        if self.clip_norm.is_nan() || self.clip_norm <= 0.0 {
            return bad("clip_norm", self.clip_norm.to_string(), "use a positive gradient-norm bound, e.g. 1");
        }
        Ok(())
    }
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    /// `(step, loss)` of every update of this run.
    pub losses: Vec<(u64, f64)>,
    /// The step the run started from (a resumed checkpoint's, else 0).
    pub resumed_from: u64,
    /// Wall-clock seconds of this run.
    pub seconds: f64,
    /// Mean seconds per update.
    pub seconds_per_step: f64,
}

/// Frames a training window needs: history, then 1 target (or `m` for unrolled training).
fn window_len(method: Method) -> usize {
    method.history()
        + match method {
            Method::UnetUnrolled { m } => m,
            _ => 1,
        }
}

/// A batch of windows `[B, L, C, ny, nx]` drawn from `seqs` (each `[T, C, ny, nx]`).
pub fn sample_windows(seqs: &[Tensor], len: usize, batch: usize, rng: &mut impl Rng) -> Result<Tensor> {
    let usable: Vec<&Tensor> = seqs.iter().filter(|s| s.dim(0).map(|t| t >= len).unwrap_or(false)).collect();
    if usable.is_empty() {
        return Err(Error::InvalidConfig {
            name: "training sequences",
            value: format!("{} sequences", seqs.len()),
            hint: "give at least one sequence with as many frames as a window (history + targets)",
        });
    }
    // The same draws as pbdl-core's sampler over the usable sequences (checked above).
    Ok(pbdl_core::data::sample_windows(seqs, len, batch, rng)?)
}

/// The training loss of `model` on a window batch `[B, L, C, ny, nx]`.
pub fn loss(model: &Model, windows: &Tensor, seed: u64) -> Result<Tensor> {
    let (b, l, c, ny, nx) = windows.dims5()?;
    let method = model.config().method;
    if c != CHANNELS || l != window_len(method) {
        return Err(Error::shape("training windows", [b, window_len(method), CHANNELS, ny, nx], windows.dims()));
    }
    let h = method.history();
    let cond = windows.narrow(1, 0, h)?.reshape((b, h * c, ny, nx))?;
    let target = windows.narrow(1, h, 1)?.squeeze(1)?;
    let unet = model.unet();
    match method {
        Method::Acdm | Method::AcdmNcn => {
            let diff = model.diffusion().ok_or_else(|| Error::shape("diffusion model", "a schedule", "none"))?;
            diff.loss(unet, &target, Some(&cond), Loss::Huber, seed)
        }
        Method::Unet => Ok((unet.forward(&cond, None)? - &target)?.sqr()?.mean_all()?),
        Method::UnetNoise { sigma } => {
            let noise = pbdl_core::seed::randn(cond.shape(), 0.0, sigma, cond.dtype(), cond.device(), seed)?;
            Ok((unet.forward(&(cond + noise)?, None)? - &target)?.sqr()?.mean_all()?)
        }
        Method::UnetUnrolled { m } => {
            let re = windows.narrow(2, FIELDS, 1)?.narrow(1, 0, 1)?.squeeze(1)?;
            let mut x = cond;
            let mut total: Option<Tensor> = None;
            for k in 0..m {
                let pred = unet.forward(&x, None)?;
                let truth = windows.narrow(1, h + k, 1)?.squeeze(1)?;
                let l = (&pred - &truth)?.sqr()?.mean_all()?;
                total = Some(match total {
                    Some(t) => (t + l)?,
                    None => l,
                });
                // As in the rollouts: the Re channel is reset to its true value.
                x = Tensor::cat(&[pred.narrow(1, 0, FIELDS)?, re.clone()], D::Minus(3))?;
            }
            Ok((total.expect("m >= 1 (validated)") / m as f64)?)
        }
    }
}

/// Trains `model` on normalised sequences `[T, 4, ny, nx]`. With `dir`, resumes from its latest
/// checkpoint (weights, Adam's moments and update count; the batches of the earlier updates are
/// replayed, so a run killed at any point resumes to the same losses and weights as one that
/// never stopped), logs every update to `dir/loss.csv` and writes `dir/step-<n>` (weights and
/// Adam state, atomically) every `checkpoint_every` updates and at the end. Stops with [`Error::Core`] (diverged) on a
/// non-finite loss or gradient, leaving the last checkpoint intact.
pub fn train(model: &Model, seqs: &[Tensor], config: &TrainConfig, dir: Option<&Path>) -> Result<TrainReport> {
    config.validate()?;
    let loop_cfg = LoopConfig {
        steps: config.steps as u64,
        checkpoint_every: config.checkpoint_every as u64,
        dir: dir.map(Path::to_path_buf),
        clip: ClipConfig::Norm { max_norm: config.clip_norm },
        progress: true,
        ..Default::default()
    };
    let run = TrainLoop::resume(model.varmap(), loop_cfg)?;
    let len = window_len(model.config().method);
    // One stream of window and noise draws per seed. A resumed run replays the draws of the
    // updates before its checkpoint (no network involved, so cheap) and then trains on exactly
    // the batches an uninterrupted run would: with the weights and Adam state of the
    // checkpoint, the resumed loss curve is the uninterrupted one, bit for bit.
    let mut rng = pbdl_core::seed::rng(config.seed);
    for _ in 0..run.start() {
        sample_windows(seqs, len, config.batch, &mut rng)?;
        let _noise_seed: u64 = rng.random();
    }
    let meta = |step: u64| CheckpointMeta {
        step,
        seed: Some(config.seed),
        config: serde_json::json!({ "model": model.config(), "train": config }),
    };
    let adam = OptimizerConfig::Adam(AdamConfig { lr: config.lr, ..Default::default() });
    let report = run.run(
        &adam,
        |step| config.lr_at(step),
        meta,
        |_| {
            let w = sample_windows(seqs, len, config.batch, &mut rng)?;
            loss(model, &w, rng.random())
        },
    )?;
    let LoopReport { losses, resumed_from, seconds, seconds_per_step, .. } = report;
    Ok(TrainReport { losses, resumed_from, seconds, seconds_per_step })
}
