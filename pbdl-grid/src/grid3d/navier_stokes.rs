//! Incompressible Navier-Stokes on a periodic 3D MAC grid: central flux-form advection, explicit
//! viscosity, an FFT projection after every Runge-Kutta stage.
//!
//! A [`NavierStokes3d`] is built once from a grid and a [`NavierStokes3dConfig`]: it plans the
//! FFTs and keeps only the operators the configuration needs (no viscous term at `nu = 0`);
//! [`NavierStokes3d::operators`] lists them. It is a [`pbdl_core::stepper::Stepper`].

use super::field::MacField3d;
use super::momentum::MomentumRhs3d;
use super::pressure::{PoissonFft3d, Projection3d};
use super::stability::{check_time_step, stable_time_step};
use super::Grid3d;
use crate::stability::StabilityReport;
use crate::time_stepping::fused::fused_projected_runge_kutta;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau};
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::stepper::{Differentiability, Stepper};
use std::sync::Arc;

/// Physical and numerical parameters of a 3D Navier-Stokes stepper: the 2D
/// [`crate::NavierStokesConfig`] (viscosity, time step, scheme).
pub type NavierStokes3dConfig = crate::NavierStokesConfig;

/// A built 3D Navier-Stokes stepper (periodic box).
pub struct NavierStokes3d {
    grid: Grid3d,
    config: NavierStokes3dConfig,
    tableau: ButcherTableau,
    rhs: MomentumRhs3d,
    projection: Projection3d,
    operators: Vec<&'static str>,
}

impl std::fmt::Debug for NavierStokes3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NavierStokes3d")
            .field("grid", &self.grid)
            .field("config", &self.config)
            .field("operators", &self.operators)
            .finish()
    }
}

impl NavierStokes3d {
    /// Builds the stepper: validates the parameters, refuses a `dt` beyond the diffusive limit,
    /// and plans the FFTs.
    pub fn new(grid: Grid3d, config: NavierStokes3dConfig) -> Result<Self> {
        grid.validate()?;
        let tableau = config.tableau()?;
        check_time_step(&grid, [0.0; 3], config.nu, &tableau, config.dt)?;
        let projection = Projection3d { solver: PoissonFft3d::new(grid)? };
        let rhs = MomentumRhs3d { grid, advect: true, nu: config.nu };
        let operators = config.operators("grid3d.advect.flux_form", "grid3d.diffuse.explicit", "grid3d.pressure.fft");
        Ok(Self { grid, config, tableau, rhs, projection, operators })
    }

    /// The operators this stepper runs, e.g. `["grid3d.advect.flux_form",
    /// "grid3d.diffuse.explicit", "grid3d.pressure.fft", "time_stepping.rk4"]`.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The configuration.
    pub fn config(&self) -> &NavierStokes3dConfig {
        &self.config
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The Poisson solver (shared).
    pub fn solver(&self) -> &Arc<PoissonFft3d> {
        &self.projection.solver
    }

    /// The largest stable time step for a velocity with the largest speeds `[|u|, |v|, |w|]`.
    pub fn stable_time_step(&self, max_speed: [f64; 3]) -> f64 {
        stable_time_step(&self.grid, max_speed, self.config.nu, &self.tableau)
    }

    /// Projects `u` onto divergence-free fields (use once on an initial condition).
    pub fn project(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        Ok(MacField3d::from_parts(self.projection.apply(u.values())?, self.grid))
    }

    /// The momentum tendency `-div(u u) + nu lap u` (before projection).
    pub fn rhs(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        Ok(MacField3d::from_parts(self.rhs.apply(u.values())?, self.grid))
    }

    /// Checks that `dt` is stable for `u`; returns the CFL and diffusion numbers.
    pub fn check(&self, u: &MacField3d) -> Result<StabilityReport> {
        check_time_step(&self.grid, u.max_abs_components()?, self.config.nu, &self.tableau, self.config.dt)
    }

    /// One time step. Refuses (typed error) when `dt` is unstable for `u` or `u` is not finite.
    pub fn step(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        self.check(u)?;
        self.step_unchecked(u)
    }

    /// One time step without the stability check. Each stage's linear combination is fused with
    /// its projection; the numbers equal [`Self::step_reference`]'s to round-off.
    pub fn step_unchecked(&self, u: &MacField3d) -> Result<MacField3d> {
        let rhs = |x: &Tensor| Ok(self.rhs.apply(x)?);
        let out = fused_projected_runge_kutta(u.values(), self.config.dt, &self.tableau, rhs, &self.projection)?;
        Ok(MacField3d::from_parts(out, self.grid))
    }

    /// The same step through the generic [`projected_runge_kutta`] (unfused; for cross-checks).
    pub fn step_reference(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        let out = projected_runge_kutta(
            u.values(),
            self.config.dt,
            &self.tableau,
            |x| Ok(self.rhs.apply(x)?),
            |x| Ok(self.projection.apply(x)?),
        )?;
        Ok(MacField3d::from_parts(out, self.grid))
    }

    fn check_field(&self, u: &MacField3d) -> Result<()> {
        u.check_stepper_grid(&self.grid)
    }
}

/// [`NavierStokes3d`] as a [`pbdl_core::stepper::Stepper`] (state: the [`MacField3d`] velocity):
/// [`Stepper::step`] is [`NavierStokes3d::step`] (checked); every operator has a hand-written
/// adjoint.
impl Stepper for NavierStokes3d {
    type State = MacField3d;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config.dt
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    /// Full: flux-form advection, the fused combine-and-project and the FFT projection all have
    /// hand-written adjoints.
    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }

    fn step(&self, u: &MacField3d) -> Result<MacField3d> {
        NavierStokes3d::step(self, u)
    }
}
