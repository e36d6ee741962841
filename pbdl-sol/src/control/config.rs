//! The control problem's settings: grid, viscosity, time step, horizon, loss weighting.

use crate::{Error, Result};
use pbdl_grid::scalar_law::ScalarLaw;
use pbdl_grid::time_stepping::ButcherTableau;
use serde::{Deserialize, Serialize};

/// Settings of the forced 1D Burgers control problem (Holl et al. 2020, section 5.1).
///
/// The defaults are the paper's: 128 cells on the unit interval, `nu = 0.003`, `dt = 0.03`,
/// 32 controlled steps. `u_{t+1} = P(u_t) + dt F_t` where `P` is one step of pbdl-grid's
/// viscous Burgers ([`ScalarLaw::burgers_1d`], RK4 in `substeps` sub-steps) and `F_t` the
/// control force.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BurgersControlConfig {
    /// Cells of the periodic grid. Default 128.
    pub cells: usize,
    /// Length of the periodic domain. Default 1.
    pub length: f64,
    /// Viscosity. Default 0.003.
    pub nu: f64,
    /// Time step of one controlled step. Default 0.03.
    pub dt: f64,
    /// Controlled steps (a power of two: the observation predictors halve intervals). Default 32.
    pub steps: usize,
    /// Largest `|u|` the sub-stepping must be stable for; the number of RK4 sub-steps per
    /// `dt` is derived from it. Default 5 (initial bumps reach 3, forcing adds up to ~1.5).
    pub max_speed: f64,
    /// Weight `lambda` of the target term in `effort + lambda * ||u_T - u*||^2`. Default 1.
    pub target_weight: f64,
}

impl Default for BurgersControlConfig {
    fn default() -> Self {
        Self { cells: 128, length: 1.0, nu: 0.003, dt: 0.03, steps: 32, max_speed: 5.0, target_weight: 1.0 }
    }
}

impl BurgersControlConfig {
    /// Checks every setting; the error names the bad one and what to use instead.
    pub fn validate(&self) -> Result<()> {
        const C: &str = "BurgersControlConfig";
        if self.cells < 8 {
            return Err(Error::invalid(C, "cells", format!("must be at least 8, got {}", self.cells)));
        }
        if !(self.length > 0.0 && self.length.is_finite()) {
            return Err(Error::invalid(C, "length", format!("must be positive and finite, got {}", self.length)));
        }
        if !(self.nu >= 0.0 && self.nu.is_finite()) {
            return Err(Error::invalid(C, "nu", format!("must be finite and >= 0, got {}", self.nu)));
        }
        if !(self.dt > 0.0 && self.dt.is_finite()) {
            return Err(Error::invalid(C, "dt", format!("must be positive and finite, got {}", self.dt)));
        }
        if self.steps < 2 || !self.steps.is_power_of_two() {
            return Err(Error::invalid(
                C,
                "steps",
                format!("must be a power of two >= 2 (observation predictors halve intervals), got {}", self.steps),
            ));
        }
        if !(self.max_speed > 0.0 && self.max_speed.is_finite()) {
            return Err(Error::invalid(C, "max_speed", format!("must be positive and finite, got {}", self.max_speed)));
        }
        if !(self.target_weight >= 0.0 && self.target_weight.is_finite()) {
            return Err(Error::invalid(
                C,
                "target_weight",
                format!("must be finite and >= 0, got {}", self.target_weight),
            ));
        }
        Ok(())
    }

    /// The Burgers law of this grid.
    pub fn law(&self) -> Result<ScalarLaw> {
        self.validate()?;
        Ok(ScalarLaw::burgers_1d(self.cells, self.length, self.nu)?)
    }

    /// RK4 sub-steps per controlled step: the fewest whose step is within the RK4 stability
    /// bound of [`ScalarLaw::stable_time_step`] for `|u| <= max_speed`.
    pub fn substeps(&self) -> Result<usize> {
        let law = self.law()?;
        let stable = law.stable_time_step(self.max_speed, 1, &ButcherTableau::rk4());
        Ok(((self.dt / stable).ceil() as usize).max(1))
    }

    /// Cell-centre coordinates divided by the length (in `[0, 1)`).
    pub fn unit_centres(&self) -> Vec<f64> {
        (0..self.cells).map(|i| (i as f64 + 0.5) / self.cells as f64).collect()
    }

    /// The interval lengths `2, 4, ..., steps` of the observation predictors.
    pub fn predictor_horizons(&self) -> Vec<usize> {
        std::iter::successors(Some(2usize), |n| Some(n * 2)).take_while(|&n| n <= self.steps).collect()
    }
}
