//! Training: supervised pre-training on the scenes' forced trajectories, then end-to-end
//! training through the differentiable solver.
//!
//! Both phases run pbdl-core's [`TrainLoop`]; [`pretrain_supervised_resumable`] and
//! [`train_end_to_end_resumable`] are the same phases in a run directory ([`RunDir`]): crash-safe
//! atomic checkpoints of the weights and Adam's state, `loss.csv`, and an exact resume (the
//! batches of the steps before the checkpoint are replayed from the seed). Use one directory
//! per phase.

use super::controller::Controller;
use super::loss::combined;
use super::resume::{canonical, check_resume, digest, layout, logged_losses, RunDir};
use super::scene::ControlScenes;
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::rngs::StdRng;
use rand::{seq::index::sample, SeedableRng};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// Settings of one training phase.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainConfig {
    /// Updates (at most). Default 500.
    pub iterations: usize,
    /// Scenes per update. Default 16.
    pub batch: usize,
    /// Adam learning rate. Default 1e-3.
    pub lr: f64,
    /// Global gradient-norm clip (0: none). Default 0.
    pub clip_norm: f64,
    /// Seed of the batch sampling.
    pub seed: u64,
    /// Stop after the update that spends this many seconds of updates, even if `iterations`
    /// are not done (`None`: no limit). A resumable run counts the seconds of each call, so
    /// with a budget it is not reproducible.
    pub time_budget_s: Option<f64>,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self { iterations: 500, batch: 16, lr: 1e-3, clip_norm: 0.0, seed: 0, time_budget_s: None }
    }
}

impl TrainConfig {
    fn validate(&self, context: &'static str, scenes: usize) -> Result<()> {
        if self.batch == 0 || self.batch > scenes {
            return Err(Error::invalid(
                context,
                "batch",
                format!("must be in 1..={scenes} (the scenes given), got {}", self.batch),
            ));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::invalid(context, "lr", format!("must be positive, got {}", self.lr)));
        }
        if !(self.clip_norm >= 0.0 && self.clip_norm.is_finite()) {
            return Err(Error::invalid(context, "clip_norm", format!("must be >= 0, got {}", self.clip_norm)));
        }
        if let Some(b) = self.time_budget_s {
            if b.is_nan() || b <= 0.0 {
                return Err(Error::invalid(context, "time_budget_s", format!("must be positive, got {b}")));
            }
        }
        Ok(())
    }

    fn clip(&self) -> ClipConfig {
        if self.clip_norm > 0.0 {
            ClipConfig::Norm { max_norm: self.clip_norm }
        } else {
            ClipConfig::None
        }
    }
}

/// What a training phase did.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TrainReport {
    /// Loss of each update (in a run directory: of the whole run, the updates before a resume
    /// read back from its `loss.csv`).
    pub losses: Vec<f64>,
    /// Wall-clock seconds (of this call).
    pub seconds: f64,
    /// The update this call started from: the resumed checkpoint's, 0 for a fresh run.
    #[serde(default)]
    pub resumed_from: u64,
}

impl TrainReport {
    /// Mean loss of the last `k` updates.
    pub fn tail_mean(&self, k: usize) -> f64 {
        let k = k.min(self.losses.len()).max(1);
        self.losses.iter().rev().take(k).sum::<f64>() / k as f64
    }
}

fn mse(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    Ok((a - b)?.sqr()?.mean_all()?)
}

/// The name a phase records in its checkpoints.
fn trainer(context: &str) -> String {
    format!("pbdl_sol::control::{context}")
}

/// One phase: `draw(rng)` gives an update's random choices (the batch's scene indices first,
/// then whatever the loss needs), `loss_of(batch, &draw)` its loss. In a run directory the
/// draws of the updates before the resumed checkpoint are replayed (none depends on the
/// networks).
fn run<D>(
    context: &'static str,
    cfg: &TrainConfig,
    ctrl: &Controller,
    scenes: &ControlScenes,
    run_dir: Option<&RunDir>,
    draw: impl Fn(&mut StdRng) -> (Vec<usize>, D),
    loss_of: impl Fn(&ControlScenes, &D) -> Result<Tensor>,
) -> Result<TrainReport> {
    cfg.validate(context, scenes.len())?;
    let start_time = Instant::now();
    let dir = run_dir.map(|r| r.dir.as_path());
    let run_cfg = match dir {
        Some(dir) => {
            let c = canonical(serde_json::json!({
                "trainer": trainer(context),
                "train": { "batch": cfg.batch, "lr": cfg.lr, "clip_norm": cfg.clip_norm, "seed": cfg.seed },
                "problem": ctrl.problem(),
                "network": layout(ctrl.varmap()),
                "scenes": {
                    "count": scenes.len(),
                    "dtype": format!("{:?}", scenes.initial.dtype()),
                    "digest": digest([&scenes.initial, &scenes.target, &scenes.force])?,
                },
            }))?;
            check_resume(context, dir, &c, cfg.iterations)?;
            c
        }
        None => serde_json::Value::Null,
    };
    let loop_cfg = LoopConfig {
        steps: cfg.iterations as u64,
        checkpoint_every: run_dir.map_or(0, |r| r.checkpoint_every),
        dir: dir.map(Path::to_path_buf),
        clip: cfg.clip(),
        progress: false,
        time_budget_seconds: cfg.time_budget_s,
        ..Default::default()
    };
    let run = TrainLoop::resume(ctrl.varmap(), loop_cfg)?;
    let start = run.start();
    let mut rng = StdRng::seed_from_u64(cfg.seed);
    for _ in 0..start {
        draw(&mut rng);
    }
    let meta = |step: u64| CheckpointMeta { step, seed: Some(cfg.seed), config: run_cfg.clone() };
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() });
    let report = run.run::<Error>(
        &adam,
        |_| cfg.lr,
        meta,
        |_| {
            let (idx, d) = draw(&mut rng);
            loss_of(&scenes.select(&idx)?, &d)
        },
    )?;
    let losses = match dir {
        Some(dir) => logged_losses(dir)?,
        None => report.losses.iter().map(|&(_, l)| l).collect(),
    };
    Ok(TrainReport { losses, seconds: start_time.elapsed().as_secs_f64(), resumed_from: start })
}

/// Supervised pre-training of all `OP_n` and the CFE on the forced ("natural") trajectories:
/// `OP_n(u_t, u_{t+n})` against `u_{t+n/2}` and `CFE(u_t, u_{t+1})` against the scene's force,
/// a random `t` per network and update; the loss is the sum of the mean squared errors.
pub fn pretrain_supervised(ctrl: &Controller, scenes: &ControlScenes, cfg: &TrainConfig) -> Result<TrainReport> {
    pretrain(ctrl, scenes, cfg, None)
}

/// [`pretrain_supervised`] in the run directory `run_dir`, crash-safe and resumable: every
/// update is logged to `loss.csv`, and the checkpoint `step-<n>` is written every
/// [`RunDir::checkpoint_every`] updates and after the last, each one atomic commit of all
/// networks' weights, Adam's moments and update count, and the phase's settings. A call on a
/// directory with checkpoints loads the newest into `ctrl`, replays the batches before it from
/// the seed and continues, so that a run stopped at any point (`kill -9` included) and called
/// again ends with the same weights, losses and files, bit for bit, as one that never stopped
/// (without a time budget). `iterations` may grow between calls.
///
/// Errors: [`Error::ResumeMismatch`] when the directory holds a run of other settings (batch,
/// lr, clipping, seed, problem, networks, scenes, or the other phase), naming the setting;
/// nothing is loaded then.
pub fn pretrain_supervised_resumable(
    ctrl: &Controller,
    scenes: &ControlScenes,
    cfg: &TrainConfig,
    run_dir: &RunDir,
) -> Result<TrainReport> {
    pretrain(ctrl, scenes, cfg, Some(run_dir))
}

fn pretrain(ctrl: &Controller, scenes: &ControlScenes, cfg: &TrainConfig, dir: Option<&RunDir>) -> Result<TrainReport> {
    let steps = ctrl.problem().steps;
    let horizons = ctrl.horizons();
    let n = scenes.len();
    let draw = |rng: &mut StdRng| {
        use rand::Rng;
        let idx = sample(rng, n, cfg.batch.min(n)).into_vec();
        let mut times: Vec<usize> = horizons.iter().map(|&h| rng.random_range(0..=steps - h)).collect();
        times.push(rng.random_range(0..steps));
        (idx, times)
    };
    run("pretrain_supervised", cfg, ctrl, scenes, dir, draw, |b, times| {
        let mut total: Option<Tensor> = None;
        let mut add = |l: Tensor| -> Result<()> {
            total = Some(match total.take() {
                None => l,
                Some(t) => (t + l)?,
            });
            Ok(())
        };
        for (&n, &t) in horizons.iter().zip(times) {
            let pred = ctrl.predict(n, &b.trajectory[t], &b.trajectory[t + n])?;
            add(mse(&pred, &b.trajectory[t + n / 2])?)?;
        }
        let t = times[horizons.len()];
        let f = ctrl.force(&b.trajectory[t], &b.trajectory[t + 1])?;
        add(mse(&f, &b.force)?)?;
        total.ok_or_else(|| Error::invalid("pretrain_supervised", "networks", "none"))
    })
}

/// End-to-end training of all networks through the solver: each update controls a batch of
/// scenes for all `T` steps ([`Controller::rollout`]) and minimises the mean of
/// `effort + target_weight * ||u_T - u*||^2`.
pub fn train_end_to_end(ctrl: &Controller, scenes: &ControlScenes, cfg: &TrainConfig) -> Result<TrainReport> {
    end_to_end(ctrl, scenes, cfg, None)
}

/// [`train_end_to_end`] in the run directory `run_dir` (its own, not the pre-training's),
/// crash-safe and resumable as [`pretrain_supervised_resumable`]. A fresh directory starts from
/// `ctrl`'s current weights (e.g. those of the pre-training); a directory with checkpoints from
/// its newest.
pub fn train_end_to_end_resumable(
    ctrl: &Controller,
    scenes: &ControlScenes,
    cfg: &TrainConfig,
    run_dir: &RunDir,
) -> Result<TrainReport> {
    end_to_end(ctrl, scenes, cfg, Some(run_dir))
}

fn end_to_end(
    ctrl: &Controller,
    scenes: &ControlScenes,
    cfg: &TrainConfig,
    dir: Option<&RunDir>,
) -> Result<TrainReport> {
    let p = *ctrl.problem();
    let n = scenes.len();
    let draw = |rng: &mut StdRng| (sample(rng, n, cfg.batch.min(n)).into_vec(), ());
    run("train_end_to_end", cfg, ctrl, scenes, dir, draw, |b, _| {
        let r = ctrl.rollout(&b.initial, &b.target)?;
        let last = r.states.last().ok_or_else(|| Error::invalid("train_end_to_end", "steps", "no states"))?;
        Ok(combined(&r.forces, p.dt, last, &b.target, p.target_weight)?.mean_all()?)
    })
}
