//! The smoke control problem's settings: grid, time step, horizon, schemes, loss weights.

use crate::{Error, Result};
use pbdl_grid::fluid::Advection;
use serde::{Deserialize, Serialize};

/// Settings of the 2D incompressible smoke shape-transition problem (Holl et al. 2020,
/// section 5.3, at a CPU-sized resolution).
///
/// A closed square box of free-slip walls, `cells x cells` cells of width 1 (lengths and speeds
/// are in cells and cells per step), `steps` controlled steps of `dt`. The paper used 128x128
/// cells; the default here is 32x32 with 16 steps so that training takes minutes on two cores.
/// One step: `v' = v + dt F` (F masked to the faces the walls leave free), `v'` advected by
/// itself and made divergence-free by pbdl-grid's pressure projection ([`pbdl_grid::Fluid`]
/// without density), then the density advected by the new velocity.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SmokeControlConfig {
    /// Cells per side of the square box. Default 32.
    pub cells: usize,
    /// Time step of one controlled step (cell widths are 1). Default 1.
    pub dt: f64,
    /// Controlled steps (a power of two: the observation predictors halve intervals). Default 16.
    pub steps: usize,
    /// Velocity self-advection: `semi_lagrangian` (default; smooth, so finite differences see
    /// no limiter kinks) or `mac_cormack`.
    pub velocity_advection: Advection,
    /// Density advection: `conservative` (default: pbdl-grid's flux-corrected transport, mass
    /// conserved to round-off in the closed box), `semi_lagrangian` or `mac_cormack`.
    pub density_advection: Advection,
    /// Weight `w` of the effort in `target error + w * sum_t ||F_t||^2`. Default 0.01.
    pub effort_weight: f64,
    /// Levels of the multi-scale target loss used for training and for the direct optimiser
    /// (level `k` compares the densities averaged over `2^k x 2^k` blocks, weighted by `4^k`;
    /// 1 = the plain L2). Coarse levels see a target that does not overlap the density yet,
    /// where the plain L2 has no gradient towards it. Default 4.
    pub loss_levels: usize,
}

impl Default for SmokeControlConfig {
    fn default() -> Self {
        Self {
            cells: 32,
            dt: 1.0,
            steps: 16,
            velocity_advection: Advection::SemiLagrangian,
            density_advection: Advection::Conservative,
            effort_weight: 0.01,
            loss_levels: 4,
        }
    }
}

impl SmokeControlConfig {
    /// Smallest accepted grid.
    pub const MIN_CELLS: usize = 8;

    /// Checks every setting; the error names the bad one and what to use instead.
    pub fn validate(&self) -> Result<()> {
        const C: &str = "SmokeControlConfig";
        if self.cells < Self::MIN_CELLS || self.cells % 4 != 0 {
            return Err(Error::invalid(
                C,
                "cells",
                format!("must be a multiple of 4 and at least {}, got {}", Self::MIN_CELLS, self.cells),
            ));
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
        if !matches!(self.velocity_advection, Advection::SemiLagrangian | Advection::MacCormack) {
            return Err(Error::invalid(
                C,
                "velocity_advection",
                format!("must be semi_lagrangian or mac_cormack, got {:?}", self.velocity_advection),
            ));
        }
        if self.density_advection == Advection::CentralRk4 {
            return Err(Error::invalid(
                C,
                "density_advection",
                "central_rk4 is a velocity scheme; use conservative, semi_lagrangian or mac_cormack",
            ));
        }
        if !(self.effort_weight >= 0.0 && self.effort_weight.is_finite()) {
            return Err(Error::invalid(
                C,
                "effort_weight",
                format!("must be finite and >= 0, got {}", self.effort_weight),
            ));
        }
        let max_levels = self.cells.trailing_zeros() as usize + 1;
        if self.loss_levels == 0 || self.loss_levels > max_levels {
            return Err(Error::invalid(
                C,
                "loss_levels",
                format!(
                    "must be in 1..={max_levels} (each level halves the {} cells), got {}",
                    self.cells, self.loss_levels
                ),
            ));
        }
        Ok(())
    }

    /// The interval lengths `2, 4, ..., steps` of the observation predictors.
    pub fn predictor_horizons(&self) -> Vec<usize> {
        std::iter::successors(Some(2usize), |n| Some(n * 2)).take_while(|&n| n <= self.steps).collect()
    }
}
