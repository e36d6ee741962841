//! The grid solvers as `pbdl_core::stepper::Stepper`s: `rollout(&u0, n)` is `n` calls of the
//! solver's own `step`, bit for bit, and the trait reports the solver's operators and time step.

use candle_core::{DType, Tensor};
use pbdl_core::stepper::{Differentiability, Stepper};
use pbdl_grid::grid3d::{Grid3d, MacField3d, NavierStokes3d, NavierStokes3dConfig};
use pbdl_grid::{
    scene::Advection, Bc, Boundaries, CenteredField, Fluid, FluidConfig, FluidState, Grid, MacField, NavierStokes,
    NavierStokesConfig, Obstacle, ScalarBc, ScalarBoundaries, Scheme,
};
use std::f64::consts::PI;

const STEPS: usize = 5;

fn bits(t: &Tensor) -> Vec<u64> {
    t.to_dtype(DType::F64)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f64>()
        .unwrap()
        .iter()
        .map(|v| v.to_bits())
        .collect()
}

#[test]
fn navier_stokes_rollout_is_its_steps() {
    let (grid, bc) = (Grid::new(16, 16, 2.0 * PI, 2.0 * PI).unwrap(), Boundaries::periodic());
    let ns = NavierStokes::new(grid, bc, NavierStokesConfig { nu: 0.01, dt: 0.05, scheme: Scheme::Rk4 }).unwrap();
    let u0 = MacField::from_fn(grid, bc, DType::F32, |x, y| [x.sin() * y.cos() + 0.1, -x.cos() * y.sin()]).unwrap();
    let u0 = ns.project(&u0).unwrap();
    let states = ns.rollout(&u0, STEPS).unwrap();
    assert_eq!(states.len(), STEPS + 1);
    let mut u = u0.clone();
    assert_eq!(bits(states[0].values()), bits(u.values()));
    for (k, s) in states.iter().enumerate().skip(1) {
        u = ns.step(&u).unwrap();
        assert_eq!(bits(s.values()), bits(u.values()), "step {k}");
    }
    assert_eq!(bits(ns.advance(&u0, STEPS).unwrap().values()), bits(u.values()));
    assert_eq!(Stepper::operators(&ns), ns.operators());
    assert_eq!(Stepper::dt(&ns), 0.05);
    assert_eq!(ns.differentiability(), Differentiability::Full);
}

#[test]
fn navier_stokes_3d_rollout_is_its_steps() {
    let grid = Grid3d::cube(8, 2.0 * PI).unwrap();
    let ns = NavierStokes3d::new(grid, NavierStokes3dConfig { nu: 0.01, dt: 0.05, scheme: Scheme::Rk4 }).unwrap();
    let u0 = MacField3d::from_fn(grid, DType::F64, |x, y, z| [z.sin() + y.cos(), x.sin() + z.cos(), y.sin() + x.cos()])
        .unwrap();
    let states = ns.rollout(&u0, STEPS).unwrap();
    assert_eq!(states.len(), STEPS + 1);
    let mut u = u0.clone();
    for (k, s) in states.iter().enumerate().skip(1) {
        u = ns.step(&u).unwrap();
        assert_eq!(bits(s.values()), bits(u.values()), "step {k}");
    }
    assert_eq!(Stepper::operators(&ns), ns.operators());
    assert_eq!(ns.differentiability(), Differentiability::Full);
}

#[test]
fn fluid_rollout_is_its_steps() {
    // Flow past a cylinder with a passive density (no inflow: the trait passes no rate).
    let grid = Grid::new(32, 16, 4.0, 2.0).unwrap();
    let bc = Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip).unwrap();
    let n = ScalarBc::Neumann;
    let density_bc = ScalarBoundaries { x_lo: n, x_hi: n, y_lo: n, y_hi: n };
    let config = FluidConfig {
        dt: 0.02,
        nu: 0.01,
        advection: Advection::MacCormack,
        density_advection: Advection::MacCormack,
        buoyancy: Some(0.5),
        inflow: None,
        obstacles: vec![Obstacle::Cylinder { center: [1.0, 1.0], radius: 0.25 }],
    };
    let fluid = Fluid::new(grid, bc, Some(density_bc), config).unwrap();
    let mut s0 = fluid.rest(1, DType::F32).unwrap();
    s0.velocity = fluid.project(&MacField::from_fn(grid, bc, DType::F32, |_, y| [1.0, 0.1 * y]).unwrap()).unwrap();
    let blob = |x: f64, y: f64| vec![(-((x - 0.5).powi(2) + (y - 1.0).powi(2)) * 8.0).exp()];
    s0.density = Some(CenteredField::from_fn(grid, density_bc, 1, DType::F32, blob).unwrap());
    let states = fluid.rollout(&s0, STEPS).unwrap();
    assert_eq!(states.len(), STEPS + 1);
    let mut s: FluidState = s0.clone();
    for (k, t) in states.iter().enumerate().skip(1) {
        s = fluid.step(&s, None).unwrap();
        assert_eq!(bits(t.velocity.values()), bits(s.velocity.values()), "velocity, step {k}");
        let (a, b) = (t.density.as_ref().unwrap(), s.density.as_ref().unwrap());
        assert_eq!(bits(a.values()), bits(b.values()), "density, step {k}");
    }
    assert_eq!(Stepper::operators(&fluid), fluid.operators());
    assert_eq!(fluid.differentiability(), Differentiability::Full);
}
