//! The hybrid simulation loop of latent-space physics: the solver's own pressure solve runs on
//! the warm-up steps and then only on every `interval`-th step; on the other steps the LSTM
//! predicts the next pressure code from the codes of the last `window` steps, the decoder turns
//! it into a pressure and that pressure corrects the velocity (`u <- u - G p`). Every step's
//! code, solved (and re-encoded) or predicted, enters the history.
//!
//! [`HybridSmoke`] is a [`Stepper`] over pbdl-grid's [`Fluid`]: it calls the fluid's own
//! operators through its pressure split ([`Fluid::step_unprojected`],
//! [`Fluid::project_keep_pressure`], [`Fluid::correct_with_pressure`]), so the transport,
//! buoyancy and inflow are the solver's, not a copy; its [`Stepper::operators`] lists the
//! fluid's operators and the latent ones.

use crate::model::LatentModel;
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::stepper::{Differentiability, Stepper};
use pbdl_grid::{CenteredField, Fluid, FluidState};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// When the solver solves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Schedule {
    /// Steps from the start that all use the solver (>= the predictor's window). The paper
    /// uses 50.
    pub warmup: usize,
    /// After the warm-up the solver solves on every `interval`-th step (>= 1; 1 is the pure
    /// solver). The paper shows 2 to 10 and more.
    pub interval: usize,
}

impl Schedule {
    /// Whether step `k` (0-based from the start) runs the solver's pressure solve.
    pub fn solves(&self, k: u64) -> bool {
        let k = k as usize;
        k < self.warmup || (k - self.warmup) % self.interval == 0
    }
}

/// Which pressure a step used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PressureSource {
    /// The solver's solve (its pressure encoded into the history).
    Solver,
    /// The LSTM's prediction, decoded.
    Predicted,
}

/// The state of a [`HybridSmoke`]: the fluid state, the last `window` normalised codes
/// (`[1, code]`, oldest first) and the steps taken.
#[derive(Clone, Debug)]
pub struct HybridState {
    /// Velocity and density.
    pub fluid: FluidState,
    /// The last codes, oldest first (fewer than `window` only during the warm-up).
    pub history: VecDeque<Tensor>,
    /// Steps taken from the start.
    pub steps: u64,
    /// The pressure source of the last step (`None` before the first).
    pub last: Option<PressureSource>,
}

impl HybridState {
    /// A state at the start of a run.
    pub fn new(fluid: FluidState) -> Self {
        Self { fluid, history: VecDeque::new(), steps: 0, last: None }
    }
}

/// The hybrid stepper (see the module docs). Batch 1.
pub struct HybridSmoke<'a> {
    fluid: Fluid,
    rate: Tensor,
    model: &'a LatentModel,
    schedule: Schedule,
    operators: Vec<&'static str>,
    autoencoder_only: bool,
}

impl<'a> HybridSmoke<'a> {
    /// Wraps `fluid` (with its inflow `rate`) and a trained `model`.
    ///
    /// # Errors
    /// [`Error::Config`] for an interval of 0, a warm-up shorter than the predictor's window,
    /// or a model for another resolution; pbdl-grid's error for a fluid without a single
    /// projection per step.
    pub fn new(fluid: Fluid, rate: Tensor, model: &'a LatentModel, schedule: Schedule) -> Result<Self> {
        let window = model.predictor.config().window;
        if schedule.interval == 0 {
            return Err(Error::config("interval", "0; use 1 (solver only) or more"));
        }
        if schedule.warmup < window {
            return Err(Error::config(
                "warmup",
                format!("{} is shorter than the predictor's window {window}; use at least {window}", schedule.warmup),
            ));
        }
        let n = model.autoencoder.config().resolution;
        let grid = *fluid.grid();
        if grid.nx != n || grid.ny != n {
            return Err(Error::config(
                "model",
                format!("trained at {n}^2, the fluid is {}x{}; train a model at this resolution", grid.nx, grid.ny),
            ));
        }
        let mut operators: Vec<&'static str> = fluid.operators().to_vec();
        operators.extend([
            "latent.encode(pressure)",
            "latent.lstm(pressure)",
            "latent.decode(pressure)",
            "pressure.correct(predicted)",
        ]);
        Ok(Self { fluid, rate, model, schedule, operators, autoencoder_only: false })
    }

    /// A diagnostic variant: on the predicted steps the solver still solves, and its pressure
    /// is replaced by the autoencoder's reconstruction `decode(encode(p))` (a perfect LSTM).
    /// Its error against the solver is the floor that the autoencoder alone sets; it saves no
    /// time.
    pub fn autoencoder_only(mut self) -> Self {
        self.autoencoder_only = true;
        self
    }

    /// The schedule.
    pub fn schedule(&self) -> Schedule {
        self.schedule
    }

    /// The wrapped solver.
    pub fn fluid(&self) -> &Fluid {
        &self.fluid
    }
}

impl Stepper for HybridSmoke<'_> {
    type State = HybridState;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.fluid.config().dt
    }

    /// The fluid's operators (its pressure solve runs on the solver steps only), then
    /// `latent.encode(pressure)` (solver steps: the solved pressure into the history),
    /// `latent.lstm(pressure)`, `latent.decode(pressure)` and `pressure.correct(predicted)`
    /// (predicted steps).
    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    fn differentiability(&self) -> Differentiability {
        Differentiability::None
    }

    fn step(&self, state: &HybridState) -> Result<HybridState> {
        let before = self.fluid.step_unprojected(&state.fluid, Some(&self.rate))?;
        let window = self.model.predictor.config().window;
        let (velocity, code, source) = if self.schedule.solves(state.steps) {
            let (v, p) = self.fluid.project_keep_pressure(&before.velocity)?;
            (v, self.model.encode_pressure(p.values())?, PressureSource::Solver)
        } else {
            if state.history.len() < window {
                return Err(Error::config(
                    "history",
                    format!("{} codes, the predictor needs {window}; start from HybridState::new", state.history.len()),
                ));
            }
            let z = if self.autoencoder_only {
                let (_, p) = self.fluid.project_keep_pressure(&before.velocity)?;
                self.model.encode_pressure(p.values())?
            } else {
                let h: Vec<Tensor> = state.history.iter().cloned().collect();
                self.model.predict(&Tensor::stack(&h, 1)?)?
            };
            let p = self.model.decode_pressure(&z)?;
            let p = CenteredField::new(
                p.to_dtype(before.velocity.values().dtype())?,
                *self.fluid.grid(),
                self.fluid_pressure_bc(),
            )?;
            (self.fluid.correct_with_pressure(&before.velocity, &p)?, z, PressureSource::Predicted)
        };
        let mut history = state.history.clone();
        history.push_back(code);
        while history.len() > window {
            history.pop_front();
        }
        Ok(HybridState {
            fluid: FluidState { velocity, density: before.density },
            history,
            steps: state.steps + 1,
            last: Some(source),
        })
    }
}

impl HybridSmoke<'_> {
    fn fluid_pressure_bc(&self) -> pbdl_grid::ScalarBoundaries {
        self.fluid.boundaries().pressure()
    }
}
