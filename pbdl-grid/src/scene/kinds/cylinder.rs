//! Flow past obstacles (`cylinder`, the Karman street): uniform inflow at `x = 0`, outflow at
//! `x = lx`, free-slip walls by default; stepped by [`Fluid`] without density. Options: a
//! parabolic inflow (held on the `u` faces at `x = dx`), no-slip walls, the immersed-boundary
//! surface treatment ([`crate::obstacle::ObstacleTreatment`]).

use super::fluid_flow::{fluid_stable_dt, solid_shapes, FluidFlow};
use super::Setup;
use crate::boundary::InflowShape;
use crate::fluid::{Advection, FluidOptions};
use crate::obstacle::Obstacle as SolidShape;
use crate::obstacle::ObstacleTreatment;
use crate::scene::{Init, SceneResult};
use crate::{Bc, Boundaries, Fluid, FluidConfig, FluidState, MacField};

/// Builds the obstacle-flow stepper; the initial velocity (the inflow profile unless `init`
/// gives one, plus the kick behind the first circle) projected. `(profile, walls, surface)`:
/// the inflow shape, the condition at `y = 0, ly`, the obstacle treatment.
pub(super) fn build(
    setup: &Setup<'_>,
    nu: f64,
    inflow: f64,
    advection: Advection,
    kick: f64,
    (profile, walls, surface): (InflowShape, Bc, ObstacleTreatment),
) -> SceneResult<(FluidFlow, f64)> {
    let grid = setup.grid2d()?;
    // With a profile the x_lo face only bounds the buffer column: a wall at rest.
    let x_lo = match profile {
        InflowShape::Uniform => Bc::Inflow { velocity: [inflow, 0.0] },
        InflowShape::Parabolic => Bc::Inflow { velocity: [0.0, 0.0] },
    };
    let bc = Boundaries::new(x_lo, Bc::Outflow, walls, walls)?;
    let shapes = solid_shapes(setup.scene);
    let ly = grid.ly;
    let shape = move |y: f64| match profile {
        InflowShape::Uniform => inflow,
        InflowShape::Parabolic => 4.0 * inflow * y * (ly - y) / (ly * ly),
    };
    let u = initial_velocity(setup, grid, bc, &shapes, shape, inflow, kick)?;
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
    let options = FluidOptions { obstacle_treatment: surface, inflow_profile: profile.profile(inflow) };
    let fluid = Fluid::with_options(grid, bc, None, config, options)?;
    let velocity = fluid.project(&u)?;
    Ok((FluidFlow::new(fluid, None, FluidState { velocity, density: None }), dt))
}

/// The inflow profile `shape(y)` everywhere (or the `init` velocity), with the kick: a
/// transverse velocity `kick * inflow` in a square of one diameter behind the first circle.
fn initial_velocity(
    setup: &Setup<'_>,
    grid: crate::Grid,
    bc: Boundaries,
    shapes: &[SolidShape],
    shape: impl Fn(f64) -> f64 + 'static,
    inflow: f64,
    kick: f64,
) -> SceneResult<MacField> {
    let g = setup.scene.grid;
    let [x0, y0] = g.origin;
    let behind = shapes.iter().find_map(|o| match *o {
        SolidShape::Cylinder { center, radius } => Some((center, radius)),
        _ => None,
    });
    let k = kick * inflow;
    let f = setup.scene.init.velocity(g.lx, g.ly);
    let uniform = matches!(setup.scene.init, Init::Zero);
    Ok(MacField::from_fn(grid, bc, setup.dtype, move |x, y| {
        let mut v = if uniform { [shape(y), 0.0] } else { f(x + x0, y + y0) };
        if let Some((c, r)) = behind {
            let d = 2.0 * r;
            if (x - c[0] - 1.5 * d).abs() < 0.5 * d && (y - c[1] - 0.5 * d).abs() < 0.5 * d {
                v[1] += k;
            }
        }
        v
    })?)
}
