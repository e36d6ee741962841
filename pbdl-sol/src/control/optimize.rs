//! The iterative baseline: per-scene optimisation of all `T` force fields by Adam through the
//! differentiable solver, under a wall-clock budget.

use super::config::BurgersControlConfig;
use super::loss::{combined, ControlScore};
use super::physics::ForcedBurgers;
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
    /// Adam learning rate on the force values. Default 0.1 (forces are O(1)).
    pub lr: f64,
    /// Most Adam updates. Default 10,000.
    pub max_iterations: usize,
    /// Wall-clock budget in seconds: no update starts after it is spent (the update running
    /// when it runs out finishes). Default 10.
    pub time_budget_s: f64,
}

impl Default for DirectOptimConfig {
    fn default() -> Self {
        Self { lr: 0.1, max_iterations: 10_000, time_budget_s: 10.0 }
    }
}

/// What [`optimize_forces`] found.
#[derive(Clone, Debug)]
pub struct DirectOptimResult {
    /// The optimised forces `F_0 .. F_{T-1}`, `[batch, 1, 1, cells]` each.
    pub forces: Vec<Tensor>,
    /// The final state under them.
    pub final_state: Tensor,
    /// Their score (evaluated after the budget, not charged to it).
    pub score: ControlScore,
    /// Adam updates taken.
    pub iterations: usize,
    /// Seconds spent in updates.
    pub seconds: f64,
}

/// Optimises the forces of each scene of the batch (`u0`, `target`: `[batch, 1, 1, cells]`)
/// from zero by Adam on `sum over scenes of effort + target_weight * target error` (scenes do
/// not interact: each scene's forces see only its own gradient), until the budget is spent.
pub fn optimize_forces(
    problem: &BurgersControlConfig,
    u0: &Tensor,
    target: &Tensor,
    cfg: &DirectOptimConfig,
) -> Result<DirectOptimResult> {
    const C: &str = "optimize_forces";
    if !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return Err(Error::invalid(C, "lr", format!("must be positive, got {}", cfg.lr)));
    }
    if !(cfg.time_budget_s >= 0.0 && cfg.time_budget_s.is_finite()) {
        return Err(Error::invalid(C, "time_budget_s", format!("must be finite and >= 0, got {}", cfg.time_budget_s)));
    }
    let physics = ForcedBurgers::new(problem)?;
    physics.check_state("optimize_forces (u0)", u0)?;
    if target.dims() != u0.dims() {
        return Err(Error::Shape {
            context: "optimize_forces (target)",
            expected: format!("{:?}", u0.dims()),
            got: target.dims().to_vec(),
        });
    }
    let vars: Vec<Var> =
        (0..problem.steps).map(|_| Var::from_tensor(&u0.zeros_like()?)).collect::<candle_core::Result<_>>()?;
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() }).build(vars.clone())?;
    let budget = Duration::from_secs_f64(cfg.time_budget_s);
    let start = Instant::now();
    let mut iterations = 0;
    while iterations < cfg.max_iterations && start.elapsed() < budget {
        let forces: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
        let states = physics.rollout(u0, &forces)?;
        let loss = combined(&forces, problem.dt, &states[problem.steps], target, problem.target_weight)?.sum_all()?;
        let value = loss.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
        if !value.is_finite() {
            return Err(Error::NonFinite { context: C, step: iterations });
        }
        opt.backward_step(&loss)?;
        iterations += 1;
    }
    let seconds = start.elapsed().as_secs_f64();
    let forces: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().detach()).collect();
    let states = physics.rollout(u0, &forces)?;
    let final_state = states[problem.steps].clone();
    let score = ControlScore::of(&forces, problem.dt, &final_state, target, problem.target_weight)?;
    Ok(DirectOptimResult { forces, final_state, score, iterations, seconds })
}
