//! Obstacles: after the masked projection every face touching a solid cell carries exactly zero
//! normal velocity and the fluid cells are divergence-free to round-off; the projection's
//! gradient (one adjoint solve) matches finite differences; bad obstacles are typed errors.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::pressure::{make_incompressible_masked, MaskedPressureSolver};
use pbdl_grid::{fd, Bc, Boundaries, Error, Grid, MacField, Obstacle, ObstacleMask};

fn channel() -> Boundaries {
    Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip).unwrap()
}

fn bcs() -> Vec<Boundaries> {
    vec![
        channel(),
        Boundaries::lid_driven_cavity(1.0),
        Boundaries::periodic(),
        Boundaries::new(Bc::Periodic, Bc::Periodic, Bc::NoSlip, Bc::NoSlip).unwrap(),
    ]
}

fn shapes(g: &Grid) -> Vec<Obstacle> {
    vec![
        Obstacle::Cylinder { center: [0.3 * g.lx, 0.45 * g.ly], radius: 0.12 * g.ly },
        // A box touching the right edge: exercises the periodic wrap of the face masks.
        Obstacle::Box { lo: [0.8 * g.lx, 0.1 * g.ly], hi: [g.lx, 0.3 * g.ly] },
    ]
}

/// `max |div u|` over fluid cells times `dx / max|u|`, and `max |u|` over closed faces.
fn check(u: &MacField, mask: &ObstacleMask) -> (f64, f64) {
    let g = *u.grid();
    let div = fd::divergence(u).unwrap().into_values().to_dtype(DType::F64).unwrap();
    let fluid = mask.fluid_tensor(DType::F64).unwrap();
    let d = div.broadcast_mul(&fluid).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
    let closed = mask.face_tensor(u.bc(), DType::F64).unwrap().affine(-1.0, 1.0).unwrap();
    let wall = u
        .values()
        .to_dtype(DType::F64)
        .unwrap()
        .broadcast_mul(&closed)
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f64>()
        .unwrap();
    (d * g.dx() / u.max_abs().unwrap(), wall)
}

/// Bounds: max |div u| dx / max|u| <= 1e-11 (f64), 1e-4 (f32); closed faces exactly 0.
#[test]
fn projection_with_obstacles_zeroes_normal_velocity_and_divergence() {
    let g = Grid::new(48, 32, 1.5, 1.0).unwrap();
    let mask = ObstacleMask::new(g, &shapes(&g)).unwrap();
    assert!(mask.solid_cells() > 50);
    for bc in bcs() {
        let solver = MaskedPressureSolver::new(g, &bc, &mask).unwrap();
        for (dtype, bound) in [(DType::F64, 1e-11), (DType::F32, 1e-4)] {
            let x = seed::randn((2, 2, 32, 48), 0.0, 1.0, dtype, &Device::Cpu, 5).unwrap();
            let u = MacField::new(x, g, bc).unwrap();
            let p = make_incompressible_masked(&u, &solver).unwrap();
            let (div, wall) = check(&p, &mask);
            eprintln!(
                "{:?}/{:?} {dtype:?}: max|div| dx/max|u| = {div:.2e}, max |u| on obstacle faces = {wall:e}",
                bc.x_lo, bc.y_lo
            );
            assert!(div < bound, "{bc:?} {dtype:?}: divergence {div:e}");
            assert_eq!(wall, 0.0, "{bc:?} {dtype:?}: obstacle faces carry {wall:e}");
            // A projection is idempotent.
            let p2 = make_incompressible_masked(&p, &solver).unwrap();
            let d = (p2.values() - p.values())
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_dtype(DType::F64)
                .unwrap()
                .to_scalar::<f64>()
                .unwrap();
            assert!(d < 1e4 * bound, "not idempotent: {d:e}");
        }
    }
}

#[test]
fn masked_projection_gradient_matches_finite_differences() {
    let g = Grid::new(9, 7, 1.3, 1.0).unwrap();
    let mask = ObstacleMask::new(g, &[Obstacle::Box { lo: [0.4, 0.3], hi: [0.7, 0.6] }]).unwrap();
    for (k, bc) in bcs().into_iter().enumerate() {
        let solver = MaskedPressureSolver::new(g, &bc, &mask).unwrap();
        let x = seed::randn((2, 2, 7, 9), 0.0, 1.0, DType::F64, &Device::Cpu, 70 + k as u64).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(make_incompressible_masked(&MacField::new(xs[0].clone(), g, bc)?, &solver)?.into_values())
        };
        let r = check_grad(f, &[x], &GradCheckOptions { max_probes: 64, ..Default::default() }).unwrap();
        eprintln!("masked projection {:?}: max rel error {:.2e}", bc.x_lo, r.max_rel_error);
        r.ensure(1e-6).unwrap_or_else(|e| panic!("{bc:?}: {e}"));
    }
}

#[test]
fn bad_obstacles_are_typed_errors() {
    let g = Grid::square(16, 1.0).unwrap();
    let outside = ObstacleMask::new(g, &[Obstacle::Cylinder { center: [0.95, 0.5], radius: 0.1 }]).unwrap_err();
    assert!(matches!(outside, Error::Invalid { field: "obstacles", .. }), "{outside}");
    assert!(outside.to_string().contains("outside the domain"), "{outside}");
    let negative = ObstacleMask::new(g, &[Obstacle::Cylinder { center: [0.5, 0.5], radius: -0.1 }]).unwrap_err();
    assert!(negative.to_string().contains("radius"), "{negative}");
    let tiny = ObstacleMask::new(g, &[Obstacle::Cylinder { center: [0.5, 0.5], radius: 0.001 }]).unwrap_err();
    assert!(tiny.to_string().contains("at least one cell"), "{tiny}");
    // A wall of solid cells that cuts the channel in two: the solve cannot be factored.
    let cut = ObstacleMask::new(g, &[Obstacle::Box { lo: [0.5, 0.0], hi: [0.6, 1.0] }]).unwrap();
    let e = MaskedPressureSolver::new(g, &Boundaries::lid_driven_cavity(1.0), &cut).unwrap_err();
    assert!(matches!(e, Error::Solver { .. }), "{e}");
}
