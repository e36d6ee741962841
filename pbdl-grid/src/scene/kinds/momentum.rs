//! 2D viscous Burgers for a MAC velocity (`burgers_2d`): the Navier-Stokes momentum equation
//! without pressure.

use super::velocity::{check_finite_velocity, read_velocity, velocity_fields};
use super::{FieldInput, PhysicsKind, Setup};
use crate::advect::MomentumRhs;
use crate::scene::{SceneResult, State};
use crate::stability::stable_time_step;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau};
use crate::{Boundaries, MacField};
use candle_core::Tensor;

/// The momentum tendency, the scheme and the velocity.
pub(super) struct Burgers2dKind {
    rhs: MomentumRhs,
    tableau: ButcherTableau,
    u: MacField,
    operators: Vec<&'static str>,
}

impl Burgers2dKind {
    /// Builds the tendency and samples the initial velocity (not projected).
    pub fn build(setup: &Setup<'_>, nu: f64, boundaries: &Boundaries) -> SceneResult<(Self, f64)> {
        let grid = setup.grid2d()?;
        let u = setup.velocity(grid, *boundaries)?;
        let (speed, s) = setup.speeds(&u, boundaries)?;
        let dt = setup.pick_dt(speed, stable_time_step(&grid, [s, s], nu, &setup.tableau))?;
        let rhs = MomentumRhs::new(&u, true, nu);
        let mut operators = vec!["advect.flux_form"];
        if nu > 0.0 {
            operators.push("diffuse.explicit");
        }
        operators.push(setup.time_stepping());
        Ok((Self { rhs, tableau: setup.tableau.clone(), u, operators }, dt))
    }
}

impl PhysicsKind for Burgers2dKind {
    fn state(&self) -> State {
        State::Velocity(self.u.clone())
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        let rhs = &self.rhs;
        let v = projected_runge_kutta(self.u.values(), dt, &self.tableau, |x| Ok(rhs.apply(x)?), |x| Ok(x.clone()))?;
        self.u = self.u.with_values(v)?;
        Ok(())
    }

    fn check(&self, _dt: f64) -> SceneResult<()> {
        check_finite_velocity(&self.u)
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        velocity_fields(&self.u, None)
    }

    /// Takes the velocity as given (no projection: Burgers has no pressure).
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let (u, name) = read_velocity(input, &self.u, "")?;
        self.u = u;
        Ok(vec![name.into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }
}
