//! The hierarchy of observation predictors `OP_n` and the control force estimator (CFE),
//! executed with prediction refinement (Holl et al. 2020, section 4).

use super::config::BurgersControlConfig;
use super::network::{ConvNet1d, ConvNetConfig};
use super::physics::ForcedBurgers;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};

/// A controlled trajectory: states `u_0 .. u_T` and forces `F_0 .. F_{T-1}`.
#[derive(Clone, Debug)]
pub struct Rollout {
    /// `T + 1` states, `[batch, 1, 1, cells]`.
    pub states: Vec<Tensor>,
    /// `T` forces, `[batch, 1, 1, cells]`.
    pub forces: Vec<Tensor>,
}

/// Observation predictors `OP_n` (`n = 2, 4, .., T`: the state at the middle of an interval of
/// `n` steps from the state at its start and the (predicted or target) state at its end) and
/// the control force estimator (the force that takes the current state to the predicted next
/// one), with their variables in one [`VarMap`].
///
/// Inputs of `OP_n`: `[u_t, o_{t+n}]`; output: `(u_t + o_{t+n}) / 2 + net` (a residual on the
/// linear interpolation). Inputs of the CFE: `[u_t, o_{t+1}, (o_{t+1} - u_t) / dt]`; output
/// the force.
pub struct Controller {
    problem: BurgersControlConfig,
    physics: ForcedBurgers,
    predictors: Vec<(usize, ConvNet1d)>,
    cfe: ConvNet1d,
    varmap: VarMap,
}

impl std::fmt::Debug for Controller {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Controller")
            .field("problem", &self.problem)
            .field("horizons", &self.horizons())
            .field("parameters", &pbdl_nets::count_parameters(&self.varmap))
            .finish()
    }
}

impl Controller {
    /// Creates the networks for `problem` (one `OP_n` per horizon and the CFE), initialised
    /// from `seed` ([`pbdl_nets::seeded_init`]).
    pub fn new(
        problem: &BurgersControlConfig,
        net: &ConvNetConfig,
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
            predictors.push((n, ConvNet1d::new(2, 1, net, problem.cells, vb.pp(format!("op{n}")))?));
        }
        let cfe = ConvNet1d::new(3, 1, net, problem.cells, vb.pp("cfe"))?;
        pbdl_nets::seeded_init(&varmap, seed)?;
        Ok(Self { problem: *problem, physics: ForcedBurgers::new(problem)?, predictors, cfe, varmap })
    }

    /// The problem this controller was built for.
    pub fn problem(&self) -> &BurgersControlConfig {
        &self.problem
    }

    /// The physics stepper.
    pub fn physics(&self) -> &ForcedBurgers {
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

    /// The variables whose names start with `prefix` (`"op8."`, `"cfe."`), in name order.
    pub fn vars_with_prefix(&self, prefix: &str) -> Vec<Var> {
        let data = self.varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        let mut named: Vec<(&String, &Var)> = data.iter().filter(|(k, _)| k.starts_with(prefix)).collect();
        named.sort_by(|a, b| a.0.cmp(b.0));
        named.into_iter().map(|(_, v)| v.clone()).collect()
    }

    fn channels_first(t: &Tensor) -> Result<Tensor> {
        let (b, _, _, n) = t.dims4()?;
        Ok(t.reshape((b, 1, n))?)
    }

    fn state_layout(t: &Tensor) -> Result<Tensor> {
        let (b, _, n) = t.dims3()?;
        Ok(t.reshape((b, 1, 1, n))?)
    }

    /// `OP_n(u, o_end)`: the predicted state halfway to `o_end`, `n` steps after `u`.
    pub fn predict(&self, n: usize, u: &Tensor, o_end: &Tensor) -> Result<Tensor> {
        self.physics.check_state("Controller::predict (u)", u)?;
        self.physics.check_state("Controller::predict (o_end)", o_end)?;
        let net = self.predictors.iter().find(|(m, _)| *m == n).map(|(_, net)| net).ok_or_else(|| {
            Error::invalid(
                "Controller::predict",
                "n",
                format!("no predictor for {n} steps; have {:?}", self.horizons()),
            )
        })?;
        let x = Tensor::cat(&[Self::channels_first(u)?, Self::channels_first(o_end)?], 1)?;
        let mid = ((u + o_end)? * 0.5)?;
        Ok((mid + Self::state_layout(&net.forward(&x)?)?)?)
    }

    /// `CFE(u, o_next)`: the force for the step from `u` towards `o_next`.
    pub fn force(&self, u: &Tensor, o_next: &Tensor) -> Result<Tensor> {
        self.physics.check_state("Controller::force (u)", u)?;
        self.physics.check_state("Controller::force (o_next)", o_next)?;
        let rate = ((o_next - u)? * (1.0 / self.problem.dt))?;
        let x =
            Tensor::cat(&[Self::channels_first(u)?, Self::channels_first(o_next)?, Self::channels_first(&rate)?], 1)?;
        Self::state_layout(&self.cfe.forward(&x)?)
    }

    /// Controls `u0` towards `target` for `T` steps: before each step, the interval to the
    /// nearest predicted (or target) state is halved by `OP_n` until it is one step long, the
    /// CFE gives the force, and the solver takes the step. Every `OP_n` starts from the state
    /// actually reached (prediction refinement); `OP_n` runs `T / n` times, the CFE `T` times.
    /// Differentiable end to end (networks and solver).
    pub fn rollout(&self, u0: &Tensor, target: &Tensor) -> Result<Rollout> {
        self.physics.check_state("Controller::rollout (u0)", u0)?;
        if target.dims() != u0.dims() {
            return Err(Error::Shape {
                context: "Controller::rollout (target)",
                expected: format!("{:?} (u0's shape)", u0.dims()),
                got: target.dims().to_vec(),
            });
        }
        let steps = self.problem.steps;
        let mut anchors: Vec<(usize, Tensor)> = vec![(steps, target.clone())];
        let mut states = vec![u0.clone()];
        let mut forces = Vec::with_capacity(steps);
        for t in 0..steps {
            let u = states[t].clone();
            loop {
                let (ta, oa) =
                    anchors.last().cloned().ok_or_else(|| Error::invalid("Controller::rollout", "anchors", "empty"))?;
                let n = ta - t;
                if n == 1 {
                    break;
                }
                let mid = self.predict(n, &u, &oa)?;
                anchors.push((t + n / 2, mid));
            }
            let (_, next) = anchors.pop().ok_or_else(|| Error::invalid("Controller::rollout", "anchors", "empty"))?;
            let f = self.force(&u, &next)?;
            states.push(self.physics.step(&u, &f)?);
            forces.push(f);
        }
        Ok(Rollout { states, forces })
    }
}
