//! Incompressible Navier-Stokes (`navier_stokes`: Taylor-Green, lid-driven cavity, Kolmogorov
//! flow) via [`NavierStokes`], with an optional Kolmogorov body force.

use super::velocity::{read_velocity, velocity_fields};
use super::{c, FieldInput, PhysicsKind, Setup};
use crate::scene::{Forcing, SceneResult, State};
use crate::stability::stable_time_step;
use crate::{Bc, Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig};
use candle_core::Tensor;

/// A body force `f` and a linear drag coefficient, added by operator splitting after each step.
struct BodyForce {
    force: Tensor,
    drag: f64,
}

/// The stepper, its optional forcing and the velocity.
pub(super) struct NavierStokesKind {
    ns: NavierStokes,
    forcing: Option<BodyForce>,
    u: MacField,
    operators: Vec<&'static str>,
}

impl NavierStokesKind {
    /// Builds the stepper (and forcing) and projects the initial velocity.
    pub fn build(
        setup: &Setup<'_>,
        nu: f64,
        boundaries: &Boundaries,
        forcing: Option<&Forcing>,
    ) -> SceneResult<(Self, f64)> {
        let grid = setup.grid2d()?;
        let u = setup.velocity(grid, *boundaries)?;
        let (speed, s) = setup.speeds(&u, boundaries)?;
        let dt = setup.pick_dt(speed, stable_time_step(&grid, [s, s], nu, &setup.tableau))?;
        let ns = NavierStokes::new(grid, *boundaries, NavierStokesConfig { nu, dt, scheme: setup.scene.time.scheme })?;
        let u = ns.project(&u)?;
        let mut operators: Vec<&'static str> = ns.operators().to_vec();
        let forcing = match forcing {
            None => None,
            Some(f) => Some(body_force(setup, grid, boundaries, f, &mut operators)?),
        };
        Ok((Self { ns, forcing, u, operators }, dt))
    }
}

/// The force field of a [`Forcing`]; appends its operators.
fn body_force(
    setup: &Setup<'_>,
    grid: Grid,
    boundaries: &Boundaries,
    forcing: &Forcing,
    operators: &mut Vec<&'static str>,
) -> SceneResult<BodyForce> {
    match *forcing {
        Forcing::Kolmogorov { amplitude, wavenumber, drag } => {
            if boundaries.x_lo != Bc::Periodic {
                return Err(setup.invalid(
                    "physics.forcing",
                    "Kolmogorov forcing needs periodic x faces (it is divergence-free only then)".into(),
                ));
            }
            let (a, k, ly) = (amplitude, wavenumber as f64, setup.scene.grid.ly);
            let f = MacField::from_fn(grid, *boundaries, setup.dtype, move |_, y| {
                [a * (2.0 * std::f64::consts::PI * k * y / ly).sin(), 0.0]
            })?;
            operators.push("forcing.kolmogorov");
            if drag > 0.0 {
                operators.push("forcing.linear_drag");
            }
            Ok(BodyForce { force: f.into_values(), drag })
        }
    }
}

impl PhysicsKind for NavierStokesKind {
    fn state(&self) -> State {
        State::Velocity(self.u.clone())
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        let mut v = self.ns.step(&self.u)?;
        if let Some(BodyForce { force, drag }) = &self.forcing {
            // Operator splitting: u += dt (f - drag u); f is divergence-free, so no projection.
            let vals = c(v.values().affine(1.0 - dt * *drag, 0.0).and_then(|x| x + force.affine(dt, 0.0)?))?;
            v = v.with_values(vals)?;
        }
        self.u = v;
        Ok(())
    }

    /// Finite and the step stable for the velocity ([`NavierStokes::check`]).
    fn check(&self, _dt: f64) -> SceneResult<()> {
        self.ns.check(&self.u)?;
        Ok(())
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        velocity_fields(&self.u, None)
    }

    /// Takes the velocity and projects it.
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let (u, name) = read_velocity(input, &self.u, "")?;
        self.u = self.ns.project(&u)?;
        Ok(vec![name.into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }
}
