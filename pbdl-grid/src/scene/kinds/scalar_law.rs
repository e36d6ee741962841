//! Scalar conservation laws on the periodic grid (1D/2D): viscous Burgers (`burgers_1d`) and
//! advection-diffusion by a constant velocity (`advection_diffusion`), via [`ScalarLaw`].

use super::{c, check_finite_scalar, max_abs, FieldInput, PhysicsKind, Setup};
use crate::scalar_law::ScalarLaw;
use crate::scene::{SceneResult, State};
use crate::time_stepping::ButcherTableau;
use crate::Error;
use candle_core::Tensor;

/// A scalar law and its scalar `[1, 1, ny, nx]`.
pub(super) struct ScalarLawKind {
    law: ScalarLaw,
    tableau: ButcherTableau,
    u: Tensor,
    name: &'static str,
    ny: usize,
    operators: Vec<&'static str>,
}

impl ScalarLawKind {
    /// 1D viscous Burgers (scalar `u`); the step follows the initial `max |u|`.
    pub fn burgers_1d(setup: &Setup<'_>, nu: f64) -> SceneResult<(Self, f64)> {
        let law = ScalarLaw { dx: setup.dx, dy: setup.dy, velocity: [0.0; 2], burgers: [1.0, 0.0], nu };
        let u = setup.scalar(true)?;
        let m = max_abs(&u)?;
        let stable = law.stable_time_step(setup.scene.time.speed.unwrap_or(m), setup.scene.grid.ny, &setup.tableau);
        let dt = setup.pick_dt(m, stable)?;
        Ok((Self::new(setup, law, u, "u"), dt))
    }

    /// Advection-diffusion by a constant velocity (scalar `concentration`).
    pub fn advection_diffusion(setup: &Setup<'_>, velocity: [f64; 2], nu: f64) -> SceneResult<(Self, f64)> {
        let law = ScalarLaw { dx: setup.dx, dy: setup.dy, velocity, burgers: [0.0; 2], nu };
        let stable = law.stable_time_step(0.0, setup.scene.grid.ny, &setup.tableau);
        let dt = setup.pick_dt(velocity[0].abs().max(velocity[1].abs()), stable)?;
        let u = setup.scalar(true)?;
        Ok((Self::new(setup, law, u, "concentration"), dt))
    }

    fn new(setup: &Setup<'_>, law: ScalarLaw, u: Tensor, name: &'static str) -> Self {
        let mut operators = law.operators();
        operators.push(setup.time_stepping());
        Self { law, tableau: setup.tableau.clone(), u, name, ny: setup.scene.grid.ny, operators }
    }
}

impl PhysicsKind for ScalarLawKind {
    fn state(&self) -> State {
        State::Scalar(self.u.clone())
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        self.u = self.law.step(&self.u, dt, &self.tableau)?;
        Ok(())
    }

    /// Finite, and the step still stable for the largest value.
    fn check(&self, dt: f64) -> SceneResult<()> {
        check_finite_scalar(&self.u)?;
        let m = max_abs(&self.u)?;
        let stable = self.law.stable_time_step(m, self.ny, &self.tableau);
        if dt > stable * (1.0 + 1e-12) {
            return Err(Error::Unstable {
                what: "time step for the current max |u|",
                value: dt,
                limit: stable,
                scheme: self.tableau.name.clone(),
                dt,
                stable_dt: stable,
            }
            .into());
        }
        Ok(())
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        Ok(vec![(self.name.to_string(), c(self.u.squeeze(0))?)])
    }

    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        self.u = input.scalar(self.name)?;
        Ok(vec![self.name.into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    fn scalar_name(&self) -> Option<&'static str> {
        Some(self.name)
    }
}
