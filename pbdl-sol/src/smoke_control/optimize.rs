//! The iterative baseline: per-scene optimisation of the `T` force fields by Adam through the
//! differentiable solver, under a wall-clock budget. Also the source of the supervised
//! controller's training data ([`super::train::Supervision`]).

use super::config::SmokeControlConfig;
use super::loss::{objective, SmokeScore};
use super::physics::{SmokePhysics, SmokeState};
use crate::{Error, Result};
use candle_core::{Tensor, Var};
use candle_nn::Optimizer;
use pbdl_core::train::{AdamConfig, OptimizerConfig};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// Settings of [`optimize_forces`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DirectOptimConfig {
    /// Adam learning rate on the force values (cells per step per step). Default 0.03.
    pub lr: f64,
    /// Most Adam updates. Default 10,000.
    pub max_iterations: usize,
    /// Wall-clock budget in seconds: no update starts after it is spent. Default 10.
    pub time_budget_s: f64,
}

impl Default for DirectOptimConfig {
    fn default() -> Self {
        Self { lr: 0.03, max_iterations: 10_000, time_budget_s: 10.0 }
    }
}

/// What [`optimize_forces`] found.
#[derive(Clone, Debug)]
pub struct DirectOptimResult {
    /// The optimised (masked) forces `F_0 .. F_{T-1}`, `[batch, 2, n, n]` each.
    pub forces: Vec<Tensor>,
    /// The trajectory `s_0 .. s_T` under them (detached).
    pub states: Vec<SmokeState>,
    /// Their score (evaluated after the budget, not charged to it).
    pub score: SmokeScore,
    /// Adam updates taken.
    pub iterations: usize,
    /// Seconds spent in updates.
    pub seconds: f64,
}

/// Optimises the forces of each scene of the batch (`rho0`, `target`: `[batch, 1, n, n]`,
/// velocity at rest) from zero by Adam on the sum over scenes of the objective
/// ([`super::loss::objective`]); scenes do not interact, so each scene's forces see only their
/// own gradient. Stops after `max_iterations` or when the budget is spent.
pub fn optimize_forces(
    problem: &SmokeControlConfig,
    rho0: &Tensor,
    target: &Tensor,
    cfg: &DirectOptimConfig,
) -> Result<DirectOptimResult> {
    const C: &str = "smoke_control::optimize_forces";
    if !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return Err(Error::invalid(C, "lr", format!("must be positive, got {}", cfg.lr)));
    }
    if !(cfg.time_budget_s >= 0.0 && cfg.time_budget_s.is_finite()) {
        return Err(Error::invalid(C, "time_budget_s", format!("must be finite and >= 0, got {}", cfg.time_budget_s)));
    }
    let physics = SmokePhysics::new(problem, rho0.dtype(), rho0.device())?;
    let s0 = physics.rest(rho0)?;
    if target.dims() != rho0.dims() {
        return Err(Error::Shape {
            context: "smoke_control::optimize_forces (target)",
            expected: format!("{:?}", rho0.dims()),
            got: target.dims().to_vec(),
        });
    }
    let vars: Vec<Var> =
        (0..problem.steps).map(|_| Var::from_tensor(&s0.velocity.zeros_like()?)).collect::<candle_core::Result<_>>()?;
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() }).build(vars.clone())?;
    let budget = Duration::from_secs_f64(cfg.time_budget_s);
    let masked =
        |vars: &[Var]| -> Result<Vec<Tensor>> { vars.iter().map(|v| physics.mask_force(v.as_tensor())).collect() };
    let start = Instant::now();
    let mut iterations = 0;
    while iterations < cfg.max_iterations && start.elapsed() < budget {
        let forces = masked(&vars)?;
        let states = physics.rollout(&s0, &forces)?;
        let loss =
            objective(&forces, &states[problem.steps].density, target, problem.loss_levels, problem.effort_weight)?
                .sum_all()?;
        let value = loss.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
        if !value.is_finite() {
            return Err(Error::NonFinite { context: C, step: iterations });
        }
        opt.backward_step(&loss)?;
        iterations += 1;
    }
    let seconds = start.elapsed().as_secs_f64();
    let forces: Vec<Tensor> = masked(&vars)?.into_iter().map(|f| f.detach()).collect();
    let states: Vec<SmokeState> = physics
        .rollout(&s0, &forces)?
        .into_iter()
        .map(|s| SmokeState { velocity: s.velocity.detach(), density: s.density.detach() })
        .collect();
    let score =
        SmokeScore::of(&forces, &states[problem.steps].density, target, problem.loss_levels, problem.effort_weight)?;
    Ok(DirectOptimResult { forces, states, score, iterations, seconds })
}
