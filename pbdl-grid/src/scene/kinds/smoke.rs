//! The buoyant smoke plume (`smoke`): density and velocity, Boussinesq buoyancy, a density inflow
//! disc, optional obstacles; stepped by [`Fluid`]. The density is advected by the scene's
//! `density_advection` (default: MacCormack, semi-Lagrangian when the velocity uses it).

use super::fluid_flow::{fluid_stable_dt, solid_shapes, FluidFlow};
use super::{c, Setup};
use crate::fluid::Advection;
use crate::obstacle::Obstacle as SolidShape;
use crate::scene::{SceneResult, Source};
use crate::{Bc, Boundaries, Fluid, FluidConfig, ScalarBc, ScalarBoundaries};
use candle_core::{Device, Tensor};

/// Builds the smoke stepper; the initial density is zero, the initial velocity projected.
/// `density_advection`: `None` keeps the default (MacCormack, semi-Lagrangian when the velocity
/// uses it).
pub(super) fn build(
    setup: &Setup<'_>,
    nu: f64,
    buoyancy: f64,
    boundaries: &Boundaries,
    source: &Source,
    advection: Advection,
    density_advection: Option<Advection>,
) -> SceneResult<(FluidFlow, f64)> {
    let grid = setup.grid2d()?;
    let [x0, y0] = setup.scene.grid.origin;
    let u = setup.velocity(grid, *boundaries)?;
    let (speed, s) = setup.speeds(&u, boundaries)?;
    let dt = setup.pick_dt(speed, fluid_stable_dt(&grid, advection, s, nu))?;
    let density_advection = density_advection.unwrap_or(if advection == Advection::SemiLagrangian {
        Advection::SemiLagrangian
    } else {
        Advection::MacCormack
    });
    let config = FluidConfig {
        dt,
        nu,
        advection,
        density_advection,
        buoyancy: Some(buoyancy),
        inflow: Some(SolidShape::Cylinder {
            center: [source.center[0] - x0, source.center[1] - y0],
            radius: source.radius,
        }),
        obstacles: solid_shapes(setup.scene),
    };
    let fluid = Fluid::new(grid, *boundaries, Some(density_boundaries(boundaries)), config)?;
    let mut state = fluid.rest(1, setup.dtype)?;
    state.velocity = fluid.project(&u)?;
    let rate = c(Tensor::new(&[source.rate], &Device::Cpu).and_then(|t| t.to_dtype(setup.dtype)))?;
    Ok((FluidFlow::new(fluid, Some(rate), state), dt))
}

/// Density conditions matching velocity ones: periodic where the velocity is, zero gradient
/// (walls, inflow, outflow) elsewhere.
fn density_boundaries(b: &Boundaries) -> ScalarBoundaries {
    let f = |bc: Bc| if bc == Bc::Periodic { ScalarBc::Periodic } else { ScalarBc::Neumann };
    ScalarBoundaries { x_lo: f(b.x_lo), x_hi: f(b.x_hi), y_lo: f(b.y_lo), y_hi: f(b.y_hi) }
}
