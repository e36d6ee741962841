//! Training: supervised pre-training on direct-optimisation trajectories, then end-to-end
//! training through the differentiable solver.

use super::controller::SmokeController;
use super::loss::objective;
use super::optimize::{optimize_forces, DirectOptimConfig};
use super::scene::SmokeScenes;
use crate::{Error, Result};
use candle_core::{Tensor, Var};
use pbdl_core::train::{train_step, AdamConfig, ClipConfig, NanGuard, OptimizerConfig};
use rand::{seq::index::sample, Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// Settings of one training phase.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SmokeTrainConfig {
    /// Updates (at most). Default 200.
    pub iterations: usize,
    /// Scenes per update. Default 8.
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

impl Default for SmokeTrainConfig {
    fn default() -> Self {
        Self { iterations: 200, batch: 8, lr: 1e-3, clip_norm: 0.0, seed: 0, time_budget_s: None }
    }
}

impl SmokeTrainConfig {
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
}

/// What a training phase did.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct SmokeTrainReport {
    /// Loss of each update.
    pub losses: Vec<f64>,
    /// Wall-clock seconds.
    pub seconds: f64,
}

impl SmokeTrainReport {
    /// Mean loss of the first `k` updates.
    pub fn head_mean(&self, k: usize) -> f64 {
        let k = k.min(self.losses.len()).max(1);
        self.losses.iter().take(k).sum::<f64>() / k as f64
    }

    /// Mean loss of the last `k` updates.
    pub fn tail_mean(&self, k: usize) -> f64 {
        let k = k.min(self.losses.len()).max(1);
        self.losses.iter().rev().take(k).sum::<f64>() / k as f64
    }
}

/// Supervision for the supervised-only controller: the direct optimiser's trajectories on the
/// training scenes (the paper's supervised baseline fits the networks to reference
/// trajectories; shape transitions have no natural reference, so the optimiser makes one).
#[derive(Clone, Debug)]
pub struct Supervision {
    /// The training scenes.
    pub scenes: SmokeScenes,
    /// Densities `rho_0 .. rho_T` of the optimised trajectories, `[N, 1, n, n]` each.
    pub densities: Vec<Tensor>,
    /// Velocities `v_0 .. v_T`, `[N, 2, n, n]` each.
    pub velocities: Vec<Tensor>,
    /// Masked forces `F_0 .. F_{T-1}`, `[N, 2, n, n]` each.
    pub forces: Vec<Tensor>,
    /// The optimiser's mean final-density error on these scenes.
    pub target_error: f64,
    /// Seconds the optimiser took.
    pub seconds: f64,
}

impl Supervision {
    /// Runs [`optimize_forces`] on `scenes` in chunks of `chunk` scenes (each chunk gets
    /// `cfg.max_iterations` updates and `cfg.time_budget_s`).
    pub fn generate(
        ctrl: &SmokeController,
        scenes: &SmokeScenes,
        cfg: &DirectOptimConfig,
        chunk: usize,
    ) -> Result<Self> {
        if chunk == 0 {
            return Err(Error::invalid("Supervision::generate", "chunk", "must be at least 1"));
        }
        let p = *ctrl.problem();
        let start = Instant::now();
        let (mut dens, mut vels, mut forces) =
            (vec![vec![]; p.steps + 1], vec![vec![]; p.steps + 1], vec![vec![]; p.steps]);
        let mut err_sum = 0.0;
        let mut lo = 0;
        while lo < scenes.len() {
            let hi = (lo + chunk).min(scenes.len());
            let part = scenes.select(&(lo..hi).collect::<Vec<_>>())?;
            let r = optimize_forces(&p, &part.initial, &part.target, cfg)?;
            err_sum += r.score.target_error * (hi - lo) as f64;
            for (t, s) in r.states.iter().enumerate() {
                dens[t].push(s.density.clone());
                vels[t].push(s.velocity.clone());
            }
            for (t, f) in r.forces.iter().enumerate() {
                forces[t].push(f.clone());
            }
            lo = hi;
        }
        let cat = |v: Vec<Vec<Tensor>>| -> Result<Vec<Tensor>> { v.iter().map(|ts| Ok(Tensor::cat(ts, 0)?)).collect() };
        Ok(Self {
            scenes: scenes.clone(),
            densities: cat(dens)?,
            velocities: cat(vels)?,
            forces: cat(forces)?,
            target_error: err_sum / scenes.len() as f64,
            seconds: start.elapsed().as_secs_f64(),
        })
    }
}

fn mse(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    Ok((a - b)?.sqr()?.mean_all()?)
}

fn run(
    context: &'static str,
    cfg: &SmokeTrainConfig,
    scenes: usize,
    vars: Vec<Var>,
    mut loss_of: impl FnMut(&[usize], &mut rand::rngs::StdRng) -> Result<Tensor>,
) -> Result<SmokeTrainReport> {
    cfg.validate(context, scenes)?;
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() }).build(vars.clone())?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(cfg.seed);
    let mut guard = NanGuard::new();
    let clip = if cfg.clip_norm > 0.0 { ClipConfig::Norm { max_norm: cfg.clip_norm } } else { ClipConfig::None };
    let start = Instant::now();
    let budget = cfg.time_budget_s.map(Duration::from_secs_f64);
    let mut report = SmokeTrainReport::default();
    for it in 0..cfg.iterations {
        if budget.is_some_and(|b| start.elapsed() >= b) {
            break;
        }
        let idx = sample(&mut rng, scenes, cfg.batch).into_vec();
        let loss = loss_of(&idx, &mut rng)?;
        let info = train_step(it as u64, &loss, &mut opt, &vars, &clip, &mut guard)?;
        report.losses.push(info.loss);
    }
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Supervised pre-training of all `OP_n` and the CFE on the optimised trajectories: per update
/// and network a random interval start `t` (a multiple of `n`, where the hierarchy calls
/// `OP_n`), `OP_n(rho_t, rho_{t+n})` (the target at `t + n = T`) against `rho_{t+n/2}`, and
/// `CFE(v_t, rho_t, rho_{t+1})` against `F_t`; the loss is the sum of the mean squared errors.
pub fn pretrain_supervised(
    ctrl: &SmokeController,
    data: &Supervision,
    cfg: &SmokeTrainConfig,
) -> Result<SmokeTrainReport> {
    let steps = ctrl.problem().steps;
    if data.densities.len() != steps + 1 || data.forces.len() != steps {
        return Err(Error::invalid(
            "smoke_control::pretrain_supervised",
            "data",
            format!(
                "needs {} densities and {steps} forces, got {} and {}",
                steps + 1,
                data.densities.len(),
                data.forces.len()
            ),
        ));
    }
    let dev = data.scenes.initial.device().clone();
    run("smoke_control::pretrain_supervised", cfg, data.scenes.len(), ctrl.varmap().all_vars(), |idx, rng| {
        let ids = Tensor::new(idx.iter().map(|&i| i as u32).collect::<Vec<_>>(), &dev)?;
        let pick = |t: &Tensor| t.index_select(&ids, 0);
        let mut total: Option<Tensor> = None;
        for n in ctrl.horizons() {
            let t = n * rng.random_range(0..steps / n);
            let end = if t + n == steps { pick(&data.scenes.target)? } else { pick(&data.densities[t + n])? };
            let pred = ctrl.predict(n, &pick(&data.densities[t])?, &end)?;
            let l = mse(&pred, &pick(&data.densities[t + n / 2])?)?;
            total = Some(match total {
                None => l,
                Some(a) => (a + l)?,
            });
        }
        let t = rng.random_range(0..steps);
        let s = super::physics::SmokeState { velocity: pick(&data.velocities[t])?, density: pick(&data.densities[t])? };
        let f = ctrl.force(&s, &pick(&data.densities[t + 1])?)?;
        let l = mse(&f, &pick(&data.forces[t])?)?;
        Ok(match total {
            None => l,
            Some(a) => (a + l)?,
        })
    })
}

/// End-to-end training of all networks through the solver: each update controls a batch of
/// scenes for all `T` steps ([`SmokeController::rollout`]) and minimises the mean objective
/// ([`super::loss::objective`]: multi-scale final-density error + effort weight * effort).
pub fn train_end_to_end(
    ctrl: &SmokeController,
    scenes: &SmokeScenes,
    cfg: &SmokeTrainConfig,
) -> Result<SmokeTrainReport> {
    let p = *ctrl.problem();
    run("smoke_control::train_end_to_end", cfg, scenes.len(), ctrl.varmap().all_vars(), |idx, _| {
        let b = scenes.select(idx)?;
        let r = ctrl.rollout(&b.initial, &b.target)?;
        Ok(objective(&r.forces, r.final_density()?, &b.target, p.loss_levels, p.effort_weight)?.mean_all()?)
    })
}
