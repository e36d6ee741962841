//! Flow past obstacles (`cylinder`, the Karman street): uniform inflow at `x = 0`, outflow at
//! `x = lx`, free-slip walls; stepped by [`Fluid`] without density.

use super::fluid_flow::{fluid_stable_dt, solid_shapes, FluidFlow};
use super::Setup;
use crate::fluid::Advection;
use crate::obstacle::Obstacle as SolidShape;
use crate::scene::{Init, SceneResult};
use crate::{Bc, Boundaries, Fluid, FluidConfig, FluidState, MacField};

/// Builds the obstacle-flow stepper; the initial velocity (uniform inflow unless `init` gives
/// one, plus the kick behind the first circle) projected.
pub(super) fn build(
    setup: &Setup<'_>,
    nu: f64,
    inflow: f64,
    advection: Advection,
    kick: f64,
) -> SceneResult<(FluidFlow, f64)> {
    let grid = setup.grid2d()?;
    let bc = Boundaries::new(Bc::Inflow { velocity: [inflow, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip)?;
    let shapes = solid_shapes(setup.scene);
    let u = initial_velocity(setup, grid, bc, &shapes, inflow, kick)?;
    let (speed, s) = setup.speeds(&u, &bc)?;
    let dt = setup.pick_dt(speed, fluid_stable_dt(&grid, advection, s, nu))?;
    let config = FluidConfig {
        dt,
        nu,
        advection,
        density_advection: Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles: shapes,
    };
    let fluid = Fluid::new(grid, bc, None, config)?;
    let velocity = fluid.project(&u)?;
    Ok((FluidFlow::new(fluid, None, FluidState { velocity, density: None }), dt))
}

/// The uniform inflow (or the `init` velocity), with the kick: a transverse velocity
/// `kick * inflow` in a square of one diameter behind the first circle.
fn initial_velocity(
    setup: &Setup<'_>,
    grid: crate::Grid,
    bc: Boundaries,
    shapes: &[SolidShape],
    inflow: f64,
    kick: f64,
) -> SceneResult<MacField> {
    let g = setup.scene.grid;
    let [x0, y0] = g.origin;
    let behind = shapes.iter().find_map(|o| match *o {
        SolidShape::Cylinder { center, radius } => Some((center, radius)),
        _ => None,
    });
    let (u_in, k) = (inflow, kick * inflow);
    let f = setup.scene.init.velocity(g.lx, g.ly);
    let uniform = matches!(setup.scene.init, Init::Zero);
    Ok(MacField::from_fn(grid, bc, setup.dtype, move |x, y| {
        let mut v = if uniform { [u_in, 0.0] } else { f(x + x0, y + y0) };
        if let Some((c, r)) = behind {
            let d = 2.0 * r;
            if (x - c[0] - 1.5 * d).abs() < 0.5 * d && (y - c[1] - 0.5 * d).abs() < 0.5 * d {
                v[1] += k;
            }
        }
        v
    })?)
}
