//! The hierarchy of observation predictors `OP_n` and the control force estimator (CFE) for
//! smoke, executed with prediction refinement (Holl et al. 2020, section 4).

use super::config::SmokeControlConfig;
use super::network::{ConvNet2d, ConvNet2dConfig};
use super::physics::{SmokePhysics, SmokeState};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};

/// A controlled trajectory.
#[derive(Clone, Debug)]
pub struct Rollout {
    /// `T + 1` states (velocity and density).
    pub states: Vec<SmokeState>,
    /// `T` forces, masked (what acted), `[batch, 2, n, n]`.
    pub forces: Vec<Tensor>,
    /// The predicted densities `(t, o_t)` the predictors made, in the order they were made.
    pub predictions: Vec<(usize, Tensor)>,
}

impl Rollout {
    /// The final density `rho_T`.
    pub fn final_density(&self) -> Result<&Tensor> {
        self.states
            .last()
            .map(|s| &s.density)
            .ok_or_else(|| Error::invalid("smoke_control::Rollout", "states", "empty rollout"))
    }
}

/// Observation predictors `OP_n` (`n = 2, 4, .., T`: the density at the middle of an interval
/// of `n` steps from the density at its start and the (predicted or target) density at its end)
/// and the control force estimator (the force that takes the current state towards the
/// predicted next density), their variables in one [`VarMap`].
///
/// The observation is the density only (the velocity is hidden, as in the paper). `OP_n`:
/// inputs `[rho_t, o_{t+n}]`, output `(rho_t + o_{t+n}) / 2 + net`. CFE: inputs
/// `[u, v, rho_t, o_{t+1}, o_{t+1} - rho_t]`, output the two force components (masked).
pub struct SmokeController {
    problem: SmokeControlConfig,
    physics: SmokePhysics,
    predictors: Vec<(usize, ConvNet2d)>,
    cfe: ConvNet2d,
    varmap: VarMap,
}

impl std::fmt::Debug for SmokeController {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SmokeController")
            .field("problem", &self.problem)
            .field("horizons", &self.horizons())
            .field("parameters", &pbdl_nets::count_parameters(&self.varmap))
            .finish()
    }
}

impl SmokeController {
    /// Creates the networks for `problem` (one `OP_n` per horizon and the CFE), initialised
    /// from `seed` ([`pbdl_nets::seeded_init`]).
    pub fn new(
        problem: &SmokeControlConfig,
        net: &ConvNet2dConfig,
        dtype: DType,
        device: &Device,
        seed: u64,
    ) -> Result<Self> {
        problem.validate()?;
        net.validate(problem.cells)?;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, dtype, device);
        let mut predictors = Vec::new();
        for n in problem.predictor_horizons() {
            predictors.push((n, ConvNet2d::new(2, 1, net, problem.cells, vb.pp(format!("op{n:02}")))?));
        }
        let cfe = ConvNet2d::new(5, 2, net, problem.cells, vb.pp("cfe"))?;
        pbdl_nets::seeded_init(&varmap, seed)?;
        Ok(Self { problem: *problem, physics: SmokePhysics::new(problem, dtype, device)?, predictors, cfe, varmap })
    }

    /// The problem this controller was built for.
    pub fn problem(&self) -> &SmokeControlConfig {
        &self.problem
    }

    /// The physics stepper.
    pub fn physics(&self) -> &SmokePhysics {
        &self.physics
    }

    /// The predictors' horizons `2, 4, .., T`.
    pub fn horizons(&self) -> Vec<usize> {
        self.predictors.iter().map(|(n, _)| *n).collect()
    }

    /// All variables (save them with `pbdl_core::io::save_varmap`).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The variables whose names start with `prefix` (`"op08."`, `"cfe."`), in name order.
    pub fn vars_with_prefix(&self, prefix: &str) -> Vec<Var> {
        let data = self.varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        let mut named: Vec<(&String, &Var)> = data.iter().filter(|(k, _)| k.starts_with(prefix)).collect();
        named.sort_by(|a, b| a.0.cmp(b.0));
        named.into_iter().map(|(_, v)| v.clone()).collect()
    }

    /// `OP_n(rho, o_end)`: the predicted density halfway to `o_end`, `n` steps after `rho`.
    pub fn predict(&self, n: usize, rho: &Tensor, o_end: &Tensor) -> Result<Tensor> {
        self.physics.check("SmokeController::predict (rho)", rho, 1)?;
        self.physics.check("SmokeController::predict (o_end)", o_end, 1)?;
        let net = self.predictors.iter().find(|(m, _)| *m == n).map(|(_, net)| net).ok_or_else(|| {
            Error::invalid(
                "SmokeController::predict",
                "n",
                format!("no predictor for {n} steps; have {:?}", self.horizons()),
            )
        })?;
        let x = Tensor::cat(&[rho, o_end], 1)?;
        let mid = ((rho + o_end)? * 0.5)?;
        Ok((mid + net.forward(&x)?)?)
    }

    /// `CFE(s, o_next)`: the (masked) force for the step from `s` towards the density `o_next`.
    pub fn force(&self, s: &SmokeState, o_next: &Tensor) -> Result<Tensor> {
        self.physics.check("SmokeController::force (velocity)", &s.velocity, 2)?;
        self.physics.check("SmokeController::force (density)", &s.density, 1)?;
        self.physics.check("SmokeController::force (o_next)", o_next, 1)?;
        let x = Tensor::cat(&[&s.velocity, &s.density, o_next, &(o_next - &s.density)?], 1)?;
        self.physics.mask_force(&self.cfe.forward(&x)?)
    }

    /// Controls the densities `rho0` (velocity at rest) towards `target` for `T` steps: before
    /// each step the interval to the nearest predicted (or target) density is halved by `OP_n`
    /// until it is one step long, the CFE gives the force and the solver takes the step. Each
    /// `OP_n` starts from the density actually reached (prediction refinement): `OP_n` runs
    /// `T / n` times, the CFE `T` times. Differentiable end to end (networks and solver).
    pub fn rollout(&self, rho0: &Tensor, target: &Tensor) -> Result<Rollout> {
        self.physics.check("SmokeController::rollout (rho0)", rho0, 1)?;
        if target.dims() != rho0.dims() {
            return Err(Error::Shape {
                context: "SmokeController::rollout (target)",
                expected: format!("{:?} (rho0's shape)", rho0.dims()),
                got: target.dims().to_vec(),
            });
        }
        let steps = self.problem.steps;
        let mut anchors: Vec<(usize, Tensor)> = vec![(steps, target.clone())];
        let mut states = vec![self.physics.rest(rho0)?];
        let mut forces = Vec::with_capacity(steps);
        let mut predictions = Vec::new();
        for t in 0..steps {
            let s = states[t].clone();
            loop {
                let (ta, oa) = anchors
                    .last()
                    .cloned()
                    .ok_or_else(|| Error::invalid("SmokeController::rollout", "anchors", "empty"))?;
                let n = ta - t;
                if n == 1 {
                    break;
                }
                let mid = self.predict(n, &s.density, &oa)?;
                predictions.push((t + n / 2, mid.clone()));
                anchors.push((t + n / 2, mid));
            }
            let (_, next) =
                anchors.pop().ok_or_else(|| Error::invalid("SmokeController::rollout", "anchors", "empty"))?;
            let f = self.force(&s, &next)?;
            states.push(self.physics.step(&s, &f)?);
            forces.push(f);
        }
        Ok(Rollout { states, forces, predictions })
    }
}
