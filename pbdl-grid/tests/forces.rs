//! The control-volume force ([`pbdl_grid::forces`]), the parabolic inflow and the immersed
//! boundary, on cases with known answers. All fast (debug profile).
//!
//! * Taylor-Green vortex (an exact unsteady Navier-Stokes solution, no body): the net force on
//!   an off-centre rectangle is 0 while its parts (momentum flux, pressure, viscous, unsteady)
//!   are not, and the residual falls at second order with the grid.
//! * Plane Poiseuille flow (exact, no body): the recovered pressure force on a rectangle is the
//!   known pressure drop `G L_x L_y`, `G = 8 nu U_m / H^2`, the viscous force its negative.
//! * The [`pbdl_grid::Fluid`] stepper with a parabolic inflow and no-slip walls keeps the exact
//!   Poiseuille profile (an empty channel).
//! * A cylinder on the axis of a symmetric channel (immersed boundary): zero lift, positive drag,
//!   the same drag from two different control volumes; the forcing's adjoint is its transpose.

use candle_core::{DType, Device, Tensor};
use pbdl_grid::boundary::InflowProfile;
use pbdl_grid::fluid::{Advection, FluidOptions};
use pbdl_grid::forces::{coefficients, ControlVolume};
use pbdl_grid::obstacle::{ImmersedBoundary, ObstacleTreatment};
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle};
use std::f64::consts::PI;

fn taylor_green(n: usize, nu: f64, t: f64) -> (MacField, Tensor) {
    let grid = Grid::square(n, 2.0 * PI).unwrap();
    let e = (-2.0 * nu * t).exp();
    let u = MacField::from_fn(grid, Boundaries::periodic(), DType::F64, |x, y| {
        [x.sin() * y.cos() * e, -x.cos() * y.sin() * e]
    })
    .unwrap();
    // du/dt = -2 nu u.
    let dudt = u.values().affine(-2.0 * nu, 0.0).unwrap();
    (u, dudt)
}

/// Net force of an exact solution on an empty control volume: 0, at second order.
#[test]
fn control_volume_force_vanishes_for_taylor_green_at_second_order() {
    let nu = 0.05;
    let mut residual = Vec::new();
    for n in [32, 64, 128] {
        let (u, dudt) = taylor_green(n, nu, 0.3);
        let cv = ControlVolume::from_rect(u.grid(), [1.1, 0.7], [4.3, 3.6]).unwrap();
        let f = cv.force(&u, nu, Some(&dudt)).unwrap();
        let size = |a: [f64; 2]| a[0].abs().max(a[1].abs());
        eprintln!("taylor-green n={n}: {f:?}");
        // The parts are O(1); only their sum vanishes.
        assert!(size(f.momentum_flux) > 0.1 && size(f.pressure) > 0.1, "{f:?}");
        assert!(size(f.viscous) > 1e-3 && size(f.unsteady) > 1e-3, "{f:?}");
        residual.push(size(f.total));
    }
    eprintln!("taylor-green residuals {residual:?}");
    assert!(residual[2] < 2e-3, "{residual:?}");
    for k in 1..residual.len() {
        let order = (residual[k - 1] / residual[k]).log2();
        assert!(order > 1.5, "order {order:.2} between refinements ({residual:?})");
    }
    // Without the unsteady part the balance must fail: the test can tell.
    let (u, _) = taylor_green(64, nu, 0.3);
    let cv = ControlVolume::from_rect(u.grid(), [1.1, 0.7], [4.3, 3.6]).unwrap();
    let f = cv.force(&u, nu, None).unwrap();
    assert!(f.total[0].abs().max(f.total[1].abs()) > 10.0 * residual[1], "{f:?}");
}

/// Poiseuille: the recovered pressure force is the exact pressure drop.
#[test]
fn control_volume_recovers_the_poiseuille_pressure_drop() {
    let (h, um, nu) = (0.41, 0.3, 1e-3);
    let grid = Grid::new(80, 41, 0.8, h).unwrap();
    let bc = Boundaries::channel(0.0);
    let u = MacField::from_fn(grid, bc, DType::F64, |_, y| [4.0 * um * y * (h - y) / (h * h), 0.0]).unwrap();
    let cv = ControlVolume::from_rect(&grid, [0.2, 0.05], [0.6, 0.3]).unwrap();
    let f = cv.force(&u, nu, None).unwrap();
    let (lx, ly) = (0.4, 0.25);
    let g = 8.0 * nu * um / (h * h);
    eprintln!("poiseuille: {f:?}, expected pressure force {}", g * lx * ly);
    assert!((f.pressure[0] - g * lx * ly).abs() < 1e-9, "{f:?}");
    assert!((f.viscous[0] + g * lx * ly).abs() < 1e-9, "{f:?}");
    assert!(f.total[0].abs() < 1e-12 && f.total[1].abs() < 1e-12, "{f:?}");
    assert_eq!(coefficients([1.0, -0.5], 1.0, 2.0, 0.5), [1.0, -0.5]);
}

fn channel_fluid(grid: Grid, obstacles: Vec<Obstacle>, um: f64, nu: f64, dt: f64, iterations: usize) -> Fluid {
    let cfg = FluidConfig {
        dt,
        nu,
        advection: Advection::CentralRk4,
        density_advection: Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles,
    };
    let options = FluidOptions {
        obstacle_treatment: ObstacleTreatment::ImmersedBoundary { iterations },
        inflow_profile: InflowProfile::Parabolic { max_velocity: um },
    };
    Fluid::with_options(grid, Boundaries::channel(0.0), None, cfg, options).unwrap()
}

/// The parabolic inflow held at `x = dx` with no-slip walls: an empty channel started at rest
/// fills with Poiseuille flow, to the O(h^2) of the wall stencil (the error falls ~4x per
/// refinement).
#[test]
fn parabolic_inflow_gives_poiseuille_flow_in_an_empty_channel() {
    let (h, um, nu) = (1.0, 1.0, 0.1);
    let mut errs = Vec::new();
    for (ny, dt) in [(12, 0.02), (24, 0.005)] {
        let grid = Grid::new(2 * ny, ny, 2.0, h).unwrap();
        let fluid = channel_fluid(grid, vec![], um, nu, dt, 1);
        assert!(fluid.operators().contains(&"inflow.profile"), "{:?}", fluid.operators());
        let mut s = fluid.rest(1, DType::F64).unwrap();
        s.velocity = fluid.project(&s.velocity).unwrap();
        // The inflow faces carry the profile right after the first projection.
        let u0 = s.velocity.u().unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        for j in 0..grid.ny {
            let y = (j as f64 + 0.5) * grid.dy();
            assert!((u0[j * grid.nx] - 4.0 * um * y * (h - y)).abs() < 1e-12);
        }
        for _ in 0..(12.0 / dt) as usize {
            s = fluid.step(&s, None).unwrap();
        }
        let u = s.velocity.u().unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let v = s.velocity.v().unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
        let mut err: f64 = 0.0;
        for j in 0..grid.ny {
            let y = (j as f64 + 0.5) * grid.dy();
            for i in 0..grid.nx {
                err = err.max((u[j * grid.nx + i] - 4.0 * um * y * (h - y)).abs());
            }
        }
        eprintln!("poiseuille channel {}x{ny}, t = 12: max |u - u_exact| = {err:.2e}, max |v| = {v:.2e}", 2 * ny);
        assert!(err < 0.01 && v < 0.01, "err {err}, v {v}");
        errs.push(err);
    }
    assert!(errs[0] / errs[1] > 3.0, "not second order: {errs:?}");
    // Uniform stays the default of Fluid::new.
    assert_eq!(FluidOptions::default().inflow_profile, InflowProfile::Uniform);
}

/// A cylinder on the axis of a symmetric channel (Re = U D / nu = 10 with the mean speed):
/// drag > 0, lift ~ 0, two control volumes agree.
#[test]
fn cylinder_on_the_axis_has_drag_and_no_lift() {
    let (h, um, nu, d) = (1.0, 1.0, 0.1 / 1.5, 0.25);
    let dx = 1.0 / 24.0;
    let grid = Grid::new(72, 24, 3.0, h).unwrap();
    let cyl = Obstacle::Cylinder { center: [0.75 + dx, 0.5], radius: d / 2.0 };
    let fluid = channel_fluid(grid, vec![cyl], um, nu, 0.005, 2);
    let ib = fluid.immersed_boundary().unwrap();
    assert!(ib.forcing_points() > 0 && ib.inside_faces() > 0);
    let mut s =
        FluidState { velocity: fluid.project(&fluid.rest(1, DType::F64).unwrap().velocity).unwrap(), density: None };
    for _ in 0..600 {
        s = fluid.step(&s, None).unwrap();
    }
    let prev = s.velocity.clone();
    s = fluid.step(&s, None).unwrap();
    let dudt = ((s.velocity.values() - prev.values()).unwrap() / 0.005).unwrap();
    let u_mean = 2.0 * um / 3.0;
    let small = ControlVolume::from_rect(&grid, [0.5, 0.2], [1.1, 0.8]).unwrap();
    let large = ControlVolume::from_rect(&grid, [0.4, 0.1], [1.5, 0.9]).unwrap();
    let fs = small.force(&s.velocity, nu, Some(&dudt)).unwrap();
    let fl = large.force(&s.velocity, nu, Some(&dudt)).unwrap();
    let (cs, cl) = (coefficients(fs.total, 1.0, u_mean, d), coefficients(fl.total, 1.0, u_mean, d));
    eprintln!("axis cylinder: small CV c = {cs:?} ({fs:?}); large CV c = {cl:?}");
    assert!(cs[0] > 1.0 && cl[0] > 1.0, "drag {cs:?} {cl:?}");
    assert!((cs[0] - cl[0]).abs() < 0.03 * cs[0], "the two control volumes disagree: {cs:?} vs {cl:?}");
    assert!(cs[1].abs() < 1e-6 * cs[0] && cl[1].abs() < 1e-6 * cl[0], "lift {cs:?} {cl:?}");
}

/// The forcing is linear: <M x, g> == <x, M^T g> through candle's backward.
#[test]
fn immersed_boundary_adjoint_is_the_transpose() {
    let grid = Grid::new(20, 16, 1.25, 1.0).unwrap();
    let bc = Boundaries::new(Bc::NoSlip, Bc::Outflow, Bc::NoSlip, Bc::NoSlip).unwrap();
    let ib = ImmersedBoundary::new(grid, &bc, &[Obstacle::Cylinder { center: [0.6, 0.45], radius: 0.2 }]).unwrap();
    let x = candle_core::Var::from_tensor(&Tensor::randn(0.0f64, 1.0, (2, 2, 16, 20), &Device::Cpu).unwrap()).unwrap();
    let g = Tensor::randn(0.0f64, 1.0, (2, 2, 16, 20), &Device::Cpu).unwrap();
    let y = ib.apply(x.as_tensor()).unwrap();
    let lhs = (&y * &g).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
    let grads = (&y * &g).unwrap().sum_all().unwrap().backward().unwrap();
    let gx = grads.get(x.as_tensor()).unwrap();
    let rhs = (x.as_tensor() * gx).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
    assert!((lhs - rhs).abs() < 1e-10 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
    // Faces inside are zeroed.
    assert!(ib.inside_faces() > 10 && ib.forcing_points() > 8);
}

/// The cylinder scene with `inflow_profile = "parabolic"`, no-slip walls and the immersed
/// boundary builds those operators and holds the profile; the shipped scene is unchanged.
#[test]
fn cylinder_scene_takes_parabolic_inflow_no_slip_walls_and_immersed_boundary() {
    use pbdl_grid::scene::Scene;
    let text = r#"
name = "st_small"
precision = "f64"
[grid]
nx = 45
ny = 16
lx = 2.25
ly = 0.8
[physics]
kind = "cylinder"
nu = 0.01
inflow = 1.0
inflow_profile = "parabolic"
walls = { kind = "no_slip" }
surface = { kind = "immersed_boundary", iterations = 2 }
advection = "central_rk4"
kick = 0.0
[[obstacles]]
kind = "circle"
center = [0.45, 0.4]
radius = 0.1
[time]
steps = 5
cfl = 0.5
frames = 2
"#;
    let mut sim = Scene::from_toml_str(text, "test").unwrap().build().unwrap();
    let ops = sim.operators().to_vec();
    assert!(ops.contains(&"inflow.profile") && ops.contains(&"obstacles.immersed_boundary"), "{ops:?}");
    assert!(!ops.contains(&"obstacles"), "{ops:?}");
    sim.run(|_| {}).unwrap();
    let u = sim.state().velocity().unwrap().u().unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    for j in 0..16 {
        let y = (j as f64 + 0.5) * 0.05;
        assert!((u[j * 45] - 4.0 * y * (0.8 - y) / 0.64).abs() < 1e-12, "row {j}: {}", u[j * 45]);
    }
    // Defaults: the shipped scene keeps the staircase and the uniform inflow.
    let ops = Scene::builtin("cylinder").unwrap().with_resolution(64).build().unwrap().operators().to_vec();
    assert!(ops.contains(&"obstacles") && !ops.contains(&"inflow.profile"), "{ops:?}");
    // Bad keys are refused.
    let bad = text.replace(r#"walls = { kind = "no_slip" }"#, r#"walls = { kind = "outflow" }"#);
    assert!(Scene::from_toml_str(&bad, "test").and_then(|s| s.build()).is_err());
}
