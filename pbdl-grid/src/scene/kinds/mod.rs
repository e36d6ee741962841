//! The physics kinds of a scene, one file each, behind one trait.
//!
//! Each kind is built from a [`Setup`] (the scene, its grid, precision and time-step rule) into
//! a value that owns its stepper *and* its state, so a stepper can never meet a state of another
//! kind. [`Simulation`](super::Simulation) holds it as a `Box<dyn PhysicsKind>`. A new kind is
//! a new file here, a [`Physics`] variant with its validation, and one arm in [`build`].

mod cylinder;
mod fluid_flow;
mod heat;
mod input;
mod momentum;
mod navier_stokes;
mod navier_stokes_spectral;
mod poisson;
mod scalar_law;
mod setup;
mod smoke;
mod smoke3d;
mod velocity;

pub(crate) use input::FieldInput;
pub(crate) use setup::Setup;

use super::{Physics, SceneError, SceneResult, State};
use crate::Error;
use candle_core::{DType, Tensor};

/// What a scene's physics kind does: steps its own state, checks it, writes and reads its output
/// fields, and lists its operators.
pub(crate) trait PhysicsKind: Send + Sync {
    /// The current state as the public enum (cheap: the tensors are shared, not copied).
    fn state(&self) -> State;

    /// One step of length `dt`.
    fn step(&mut self, dt: f64) -> SceneResult<()>;

    /// Checks the state (finite; for some kinds the step still stable for it).
    fn check(&self, dt: f64) -> SceneResult<()>;

    /// The output fields, each `[C, ny, nx]` (see [`Simulation::fields`](super::Simulation::fields)).
    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>>;

    /// Replaces the state (or the Poisson source) by arrays of an init file; returns the names used.
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>>;

    /// The operators of one step, in order (duplicates allowed; the simulation removes repeats).
    fn operators(&self) -> Vec<&'static str>;

    /// Name of the scalar a scalar kind evolves (`None` for velocity kinds).
    fn scalar_name(&self) -> Option<&'static str> {
        None
    }

    /// Steps of the planned run, given the scene's (the Poisson solve is one step).
    fn planned_steps(&self, steps: usize) -> usize {
        steps
    }
}

/// Builds the kind of `setup.scene` and returns it with its time step (before the last rounding
/// to `t_end`).
pub(crate) fn build(setup: &Setup<'_>) -> SceneResult<(Box<dyn PhysicsKind>, f64)> {
    fn boxed<K: PhysicsKind + 'static>((kind, dt): (K, f64)) -> (Box<dyn PhysicsKind>, f64) {
        (Box::new(kind), dt)
    }
    Ok(match &setup.scene.physics {
        Physics::Burgers1d { nu } => boxed(scalar_law::ScalarLawKind::burgers_1d(setup, *nu)?),
        Physics::AdvectionDiffusion { velocity, nu } => {
            boxed(scalar_law::ScalarLawKind::advection_diffusion(setup, *velocity, *nu)?)
        }
        Physics::Heat { kappa, boundaries } => boxed(heat::HeatKind::build(setup, *kappa, boundaries)?),
        Physics::Poisson { boundaries } => boxed(poisson::PoissonKind::build(setup, boundaries)?),
        Physics::Burgers2d { nu, boundaries } => boxed(momentum::Burgers2dKind::build(setup, *nu, boundaries)?),
        Physics::NavierStokes { nu, boundaries, forcing } => {
            boxed(navier_stokes::NavierStokesKind::build(setup, *nu, boundaries, forcing.as_ref())?)
        }
        Physics::NavierStokesSpectral { nu, forcing, .. } if setup.scene.grid.nz > 1 => {
            boxed(navier_stokes_spectral::SpectralKind3d::build(setup, *nu, forcing.as_ref())?)
        }
        Physics::NavierStokesSpectral { nu, forcing, .. } => {
            boxed(navier_stokes_spectral::SpectralKind::build(setup, *nu, forcing.as_ref())?)
        }
        Physics::Smoke {
            nu,
            buoyancy,
            boundaries,
            source,
            advection,
            density_advection,
            boundaries_z,
            obstacles3d,
            inflow_patch,
        } if setup.scene.grid.nz > 1 => boxed(smoke3d::Smoke3dKind::build(
            setup,
            smoke3d::Smoke3dKeys {
                nu: *nu,
                buoyancy: *buoyancy,
                boundaries,
                boundaries_z: boundaries_z.as_ref(),
                obstacles3d,
                inflow_patch: inflow_patch.as_ref(),
                source,
                advection: *advection,
                density_advection: *density_advection,
            },
        )?),
        Physics::Smoke { nu, buoyancy, boundaries, source, advection, density_advection, .. } => {
            boxed(smoke::build(setup, *nu, *buoyancy, boundaries, source, *advection, *density_advection)?)
        }
        Physics::Cylinder { nu, inflow, advection, kick, inflow_profile, walls, surface } => {
            boxed(cylinder::build(setup, *nu, *inflow, *advection, *kick, (*inflow_profile, *walls, *surface))?)
        }
    })
}

/// A candle result as a scene result.
pub(crate) fn c<T>(r: candle_core::Result<T>) -> SceneResult<T> {
    r.map_err(|e| SceneError::Grid(Error::from(e)))
}

/// `max |t|` as f64 (NaN/Inf propagate).
pub(crate) fn max_abs(t: &Tensor) -> SceneResult<f64> {
    c(t.abs().and_then(|t| t.max_all()).and_then(|t| t.to_dtype(DType::F64)).and_then(|t| t.to_scalar::<f64>()))
}

/// Typed error when a scalar state is not finite.
fn check_finite_scalar(t: &Tensor) -> SceneResult<()> {
    let m = max_abs(t)?;
    if !m.is_finite() {
        return Err(Error::NonFinite { what: "scalar", value: m }.into());
    }
    Ok(())
}
