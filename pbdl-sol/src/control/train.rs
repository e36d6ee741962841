//! Training: supervised pre-training on the scenes' forced trajectories, then end-to-end
//! training through the differentiable solver.

use super::controller::Controller;
use super::loss::combined;
use super::scene::ControlScenes;
use crate::{Error, Result};
use candle_core::{Tensor, Var};
use pbdl_core::train::{train_step, AdamConfig, ClipConfig, NanGuard, OptimizerConfig};
use rand::{seq::index::sample, SeedableRng};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

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
    /// Stop after this many seconds even if `iterations` are not done (`None`: no limit).
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
    /// Loss of each update.
    pub losses: Vec<f64>,
    /// Wall-clock seconds.
    pub seconds: f64,
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

fn run(
    context: &'static str,
    cfg: &TrainConfig,
    scenes: &ControlScenes,
    vars: Vec<Var>,
    mut loss_of: impl FnMut(&ControlScenes, &mut rand::rngs::StdRng) -> Result<Tensor>,
) -> Result<TrainReport> {
    cfg.validate(context, scenes.len())?;
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() }).build(vars.clone())?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(cfg.seed);
    let mut guard = NanGuard::new();
    let clip = cfg.clip();
    let start = Instant::now();
    let budget = cfg.time_budget_s.map(Duration::from_secs_f64);
    let mut report = TrainReport::default();
    for it in 0..cfg.iterations {
        if budget.is_some_and(|b| start.elapsed() >= b) {
            break;
        }
        let idx = sample(&mut rng, scenes.len(), cfg.batch).into_vec();
        let batch = scenes.select(&idx)?;
        let loss = loss_of(&batch, &mut rng)?;
        let info = train_step(it as u64, &loss, &mut opt, &vars, &clip, &mut guard)?;
        report.losses.push(info.loss);
    }
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Supervised pre-training of all `OP_n` and the CFE on the forced ("natural") trajectories:
/// `OP_n(u_t, u_{t+n})` against `u_{t+n/2}` and `CFE(u_t, u_{t+1})` against the scene's force,
/// a random `t` per network and update; the loss is the sum of the mean squared errors.
pub fn pretrain_supervised(ctrl: &Controller, scenes: &ControlScenes, cfg: &TrainConfig) -> Result<TrainReport> {
    let steps = ctrl.problem().steps;
    let vars = ctrl.varmap().all_vars();
    run("pretrain_supervised", cfg, scenes, vars, |b, rng| {
        use rand::Rng;
        let mut total: Option<Tensor> = None;
        let mut add = |l: Tensor| -> Result<()> {
            total = Some(match total.take() {
                None => l,
                Some(t) => (t + l)?,
            });
            Ok(())
        };
        for n in ctrl.horizons() {
            let t = rng.random_range(0..=steps - n);
            let pred = ctrl.predict(n, &b.trajectory[t], &b.trajectory[t + n])?;
            add(mse(&pred, &b.trajectory[t + n / 2])?)?;
        }
        let t = rng.random_range(0..steps);
        let f = ctrl.force(&b.trajectory[t], &b.trajectory[t + 1])?;
        add(mse(&f, &b.force)?)?;
        total.ok_or_else(|| Error::invalid("pretrain_supervised", "networks", "none"))
    })
}

/// End-to-end training of all networks through the solver: each update controls a batch of
/// scenes for all `T` steps ([`Controller::rollout`]) and minimises the mean of
/// `effort + target_weight * ||u_T - u*||^2`.
pub fn train_end_to_end(ctrl: &Controller, scenes: &ControlScenes, cfg: &TrainConfig) -> Result<TrainReport> {
    let p = *ctrl.problem();
    let vars = ctrl.varmap().all_vars();
    run("train_end_to_end", cfg, scenes, vars, |b, _| {
        let r = ctrl.rollout(&b.initial, &b.target)?;
        let last = r.states.last().ok_or_else(|| Error::invalid("train_end_to_end", "steps", "no states"))?;
        Ok(combined(&r.forces, p.dt, last, &b.target, p.target_weight)?.mean_all()?)
    })
}
