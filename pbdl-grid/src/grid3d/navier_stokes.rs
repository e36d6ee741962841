//! Incompressible Navier-Stokes on a periodic 3D MAC grid: central flux-form advection, explicit
//! viscosity, an FFT projection after every Runge-Kutta stage.
//!
//! A [`NavierStokes3d`] is built once from a grid and a [`NavierStokes3dConfig`]: it plans the
//! FFTs and keeps only the operators the configuration needs (no viscous term at `nu = 0`);
//! [`NavierStokes3d::operators`] lists them. It is a [`pbdl_core::stepper::Stepper`].

use super::field::MacField3d;
use super::momentum::{check_nu, MomentumRhs3d};
use super::pressure::{CombineProject3d, PoissonFft3d, Projection3d};
use super::stability::{check_time_step, stable_time_step};
use super::Grid3d;
use crate::stability::StabilityReport;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau, Scheme};
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::op::apply3;
use pbdl_core::stepper::{Differentiability, Stepper};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Physical and numerical parameters of a 3D Navier-Stokes stepper.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavierStokes3dConfig {
    /// Kinematic viscosity (>= 0; 0 builds an inviscid stepper without the viscous operator).
    pub nu: f64,
    /// Time step.
    pub dt: f64,
    /// Runge-Kutta scheme. Default: RK4.
    #[serde(default)]
    pub scheme: Scheme,
}

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
        check_nu(config.nu)?;
        let tableau = config.scheme.tableau();
        tableau.validate()?;
        check_time_step(&grid, [0.0; 3], config.nu, &tableau, config.dt)?;
        let projection = Projection3d { solver: PoissonFft3d::new(grid)? };
        let rhs = MomentumRhs3d { grid, advect: true, nu: config.nu };
        let mut operators = vec!["grid3d.advect.flux_form"];
        if config.nu > 0.0 {
            operators.push("grid3d.diffuse.explicit");
        }
        operators.push("grid3d.pressure.fft");
        operators.push(match config.scheme {
            Scheme::Rk4 => "time_stepping.rk4",
            Scheme::SspRk3 => "time_stepping.ssp_rk3",
            Scheme::ForwardEuler => "time_stepping.forward_euler",
        });
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
        let (u0, dt, tab) = (u.values(), self.config.dt, &self.tableau);
        let mut k: Vec<Tensor> = Vec::with_capacity(tab.stages());
        k.push(self.rhs.apply(u0)?);
        for i in 1..tab.stages() {
            let ui = self.combine_project(u0, dt, &tab.a[i], &k)?;
            k.push(self.rhs.apply(&ui)?);
        }
        Ok(MacField3d::from_parts(self.combine_project(u0, dt, &tab.b, &k)?, self.grid))
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

    /// `P(u0 + dt sum_j w_j k_j)`, two terms per fused op, the projection in the last one.
    fn combine_project(&self, u0: &Tensor, dt: f64, w: &[f64], k: &[Tensor]) -> Result<Tensor> {
        let terms: Vec<(f64, &Tensor)> =
            w.iter().zip(k).filter(|(w, _)| **w != 0.0).map(|(w, k)| (dt * w, k)).collect();
        let mut acc = u0.clone();
        let mut rest = &terms[..];
        loop {
            let last = rest.len() <= 2;
            let projection = if last { Some(self.projection.clone()) } else { None };
            let (w1, k1, w2, k2) = match rest {
                [] => return Ok(self.projection.apply(&acc)?),
                [(w1, k1)] => (*w1, *k1, 0.0, *k1),
                [(w1, k1), (w2, k2), ..] => (*w1, *k1, *w2, *k2),
            };
            acc = apply3(&acc, k1, k2, CombineProject3d { w: [w1, w2], projection })?;
            if last {
                return Ok(acc);
            }
            rest = &rest[2..];
        }
    }

    fn check_field(&self, u: &MacField3d) -> Result<()> {
        if u.grid() != &self.grid {
            return Err(Error::Invalid {
                field: "u",
                reason: format!("the field lives on {:?}; the stepper was built for {:?}", u.grid(), self.grid),
            });
        }
        Ok(())
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
