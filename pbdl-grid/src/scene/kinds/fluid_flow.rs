//! The kinds stepped by [`Fluid`] (smoke plume, flow past obstacles): shared stepping, output and
//! input. A state with a density is the smoke kind's ([`State::Smoke`]); without one it is a
//! plain velocity ([`State::Velocity`]).

use super::velocity::{check_finite_velocity, read_velocity, velocity_fields};
use super::{c, max_abs, FieldInput, PhysicsKind};
use crate::fluid::Advection;
use crate::obstacle::Obstacle as SolidShape;
use crate::scene::{Scene, SceneResult, State};
use crate::stability::stable_time_step;
use crate::time_stepping::ButcherTableau;
use crate::{Error, Fluid, FluidState, Grid};
use candle_core::Tensor;

/// A [`Fluid`] stepper, the density inflow rate (smoke) and the state.
pub(super) struct FluidFlow {
    fluid: Fluid,
    rate: Option<Tensor>,
    state: FluidState,
    operators: Vec<&'static str>,
}

impl FluidFlow {
    /// Wraps a built stepper and its (projected) initial state.
    pub fn new(fluid: Fluid, rate: Option<Tensor>, state: FluidState) -> Self {
        let operators = fluid.operators().to_vec();
        Self { fluid, rate, state, operators }
    }
}

impl PhysicsKind for FluidFlow {
    fn state(&self) -> State {
        match &self.state.density {
            Some(_) => State::Smoke(self.state.clone()),
            None => State::Velocity(self.state.velocity.clone()),
        }
    }

    fn step(&mut self, _dt: f64) -> SceneResult<()> {
        self.state = self.fluid.step(&self.state, self.rate.as_ref())?;
        Ok(())
    }

    fn check(&self, _dt: f64) -> SceneResult<()> {
        check_finite_velocity(&self.state.velocity)?;
        if let Some(rho) = &self.state.density {
            let m = max_abs(rho.values())?;
            if !m.is_finite() {
                return Err(Error::NonFinite { what: "density", value: m }.into());
            }
        }
        Ok(())
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        velocity_fields(&self.state.velocity, self.state.density.as_ref())
    }

    /// Takes `density` (when the state has one), the velocity (projected), or both; what is not
    /// given is kept.
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let mut used = Vec::new();
        let density = match (&self.state.density, input.find("density")) {
            (Some(rho), Some(t)) => {
                used.push("density".to_string());
                Some(rho.with_values(c(input.to4("density", &t, 1)?.to_dtype(input.dtype))?)?)
            }
            (rho, _) => rho.clone(),
        };
        let smoke = self.state.density.is_some();
        let has_velocity = input.find("velocity").is_some() || input.find("velocity_mac").is_some();
        if smoke && !has_velocity && !used.is_empty() {
            self.state = FluidState { velocity: self.state.velocity.clone(), density };
            return Ok(used);
        }
        let also = if smoke { ", `density`" } else { "" };
        let (u, name) = read_velocity(input, &self.state.velocity, also)?;
        let velocity = self.fluid.project(&u)?;
        used.insert(0, name.to_string());
        self.state = FluidState { velocity, density };
        Ok(used)
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }
}

/// The largest stable step of the [`Fluid`] velocity advection for speed `s`: infinite for the
/// semi-Lagrangian and MacCormack paths, the RK4 limit for the central flux form.
pub(super) fn fluid_stable_dt(grid: &Grid, advection: Advection, s: f64, nu: f64) -> f64 {
    match advection {
        Advection::CentralRk4 => stable_time_step(grid, [s, s], nu, &ButcherTableau::rk4()),
        _ => f64::INFINITY,
    }
}

/// The scene's obstacles in solver coordinates (the grid's origin at 0).
pub(super) fn solid_shapes(scene: &Scene) -> Vec<SolidShape> {
    let [x0, y0] = scene.grid.origin;
    scene
        .obstacles
        .iter()
        .map(|o| match *o {
            crate::scene::Obstacle::Circle { center, radius } => {
                SolidShape::Cylinder { center: [center[0] - x0, center[1] - y0], radius }
            }
            crate::scene::Obstacle::Box { lower, upper } => {
                SolidShape::Box { lo: [lower[0] - x0, lower[1] - y0], hi: [upper[0] - x0, upper[1] - y0] }
            }
        })
        .collect()
}
