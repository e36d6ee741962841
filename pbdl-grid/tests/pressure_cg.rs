//! The CG pressure solver against the sparse Cholesky path on the same masked system (64^2,
//! cylinder obstacle, closed cavity, periodic box and channel with outflow).
//!
//! Checks that do not trust the solver's own bookkeeping: the residual of the pressure system is
//! the divergence of the projected velocity, measured with `fd::divergence`; the right-hand side
//! norm is `||D w||` recomputed from the public operators (`w = u_cg + m G p`); the distance to
//! the Cholesky projection is bounded by `||r||_2 / sqrt(lambda_min)` (energy-norm error of a
//! residual `r`), with `lambda_min >= (pi/2)^2 / 2` for the unit square (the mixed
//! Neumann/Dirichlet value, halved as margin for the obstacle).

use candle_core::{DType, Tensor};
use pbdl_grid::pressure::{
    make_incompressible_masked, make_incompressible_masked_cg, CgPreconditioner, CgPressureSolver, CgSettings,
    MaskedPressureSolver,
};
use pbdl_grid::{fd, Bc, Boundaries, CenteredField, Error, Grid, MacField, Obstacle, ObstacleMask};
use std::time::Instant;

fn cases() -> Vec<(&'static str, Boundaries)> {
    vec![
        ("cavity", Boundaries::lid_driven_cavity(1.0)),
        ("periodic", Boundaries::periodic()),
        ("channel", Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::NoSlip, Bc::NoSlip).unwrap()),
    ]
}

fn setup(n: usize) -> (Grid, ObstacleMask) {
    let g = Grid::square(n, 1.0).unwrap();
    let mask = ObstacleMask::new(g, &[Obstacle::Cylinder { center: [0.35, 0.5], radius: 0.12 }]).unwrap();
    (g, mask)
}

/// A smooth, strongly divergent f64 velocity.
fn velocity(g: Grid, bc: Boundaries, phase: f64) -> MacField {
    MacField::from_fn(g, bc, DType::F64, |x, y| {
        [(7.0 * x + phase).sin() * (5.0 * y).cos() + x * y, (3.0 * x * y + phase).cos() - y * y]
    })
    .unwrap()
}

fn settings(rel_tol: f64, preconditioner: CgPreconditioner) -> CgSettings {
    CgSettings { rel_tol, max_iter: 5000, preconditioner }
}

const MIC: CgPreconditioner = CgPreconditioner::Mic0 { tau: 0.97 };

/// 2-norm over fluid cells of `div u`, and its maximum.
fn div_norms(u: &MacField, mask: &ObstacleMask) -> (f64, f64) {
    let fluid = mask.fluid_tensor(DType::F64).unwrap();
    let d = fd::divergence(u).unwrap().into_values().broadcast_mul(&fluid).unwrap();
    let l2 = d.sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap().sqrt();
    (l2, d.abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap())
}

/// `||D w||_2` over fluid cells with `w = u_cg + m G p` (the projection's right-hand side).
fn rhs_norm(u_cg: &MacField, p: &[f64], mask: &ObstacleMask) -> f64 {
    let g = *u_cg.grid();
    let pt = Tensor::from_slice(p, (1, 1, g.ny, g.nx), &candle_core::Device::Cpu).unwrap();
    let pf = CenteredField::new(pt, g, u_cg.bc().pressure()).unwrap();
    let open = mask.face_tensor(u_cg.bc(), DType::F64).unwrap();
    let mgp = fd::gradient(&pf, u_cg.bc()).unwrap().into_values().broadcast_mul(&open).unwrap();
    let w = u_cg.with_values((u_cg.values() + mgp).unwrap()).unwrap();
    div_norms(&w, mask).0
}

fn l2_diff(a: &MacField, b: &MacField) -> f64 {
    (a.values() - b.values()).unwrap().sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap().sqrt()
}

/// Bound: `max|div u_cg| <= ||div u_cg||_2 <= rel_tol ||D w||_2` (the solver's stopping rule,
/// checked on the divergence measured independently), closed faces exactly 0, and the distance
/// to the Cholesky projection within `||div u_cg||_2 / sqrt(lambda_min)`.
#[test]
fn cg_projection_agrees_with_cholesky_and_meets_the_divergence_bound() {
    let (g, mask) = setup(64);
    let lambda_min = (std::f64::consts::PI / 2.0).powi(2) / 2.0;
    for (name, bc) in cases() {
        let u = velocity(g, bc, 0.3);
        let chol = make_incompressible_masked(&u, &MaskedPressureSolver::new(g, &bc, &mask).unwrap()).unwrap();
        for tol in [1e-6, 1e-10] {
            let cg = CgPressureSolver::new(g, &bc, &mask, settings(tol, MIC)).unwrap();
            let mut p = Vec::new();
            let t = Instant::now();
            let (u_cg, st) = cg.project(&u, &mut p).unwrap();
            let secs = t.elapsed().as_secs_f64();
            let (div2, divmax) = div_norms(&u_cg, &mask);
            let b = rhs_norm(&u_cg, &p, &mask);
            let diff = l2_diff(&u_cg, &chol);
            let closed = mask.face_tensor(&bc, DType::F64).unwrap().affine(-1.0, 1.0).unwrap();
            let wall = u_cg.values().broadcast_mul(&closed).unwrap().abs().unwrap().max_all().unwrap();
            let wall = wall.to_scalar::<f64>().unwrap();
            println!(
                "{name} tol {tol:e}: {} its, {secs:.3}s, ||div||/||Dw|| = {:.2e}, max|div| dx/max|u| = {:.2e}, \
                 ||u_cg - u_chol||_2 = {diff:.2e} (bound {:.2e}), max closed-face |u| = {wall:e}",
                st.iterations,
                div2 / b,
                divmax * g.dx() / u_cg.max_abs().unwrap(),
                div2 / lambda_min.sqrt()
            );
            assert!(b > 1.0, "{name}: the test velocity should be strongly divergent, ||Dw|| = {b}");
            assert!(divmax <= div2 && div2 <= tol * b * (1.0 + 1e-6), "{name} {tol:e}: {div2:e} vs {:e}", tol * b);
            assert!(diff <= div2 / lambda_min.sqrt() + 1e-12 * b, "{name} {tol:e}: {diff:e}");
            assert_eq!(wall, 0.0, "{name}: closed faces");
        }
    }
}

/// MIC(0) needs fewer iterations than Jacobi (its count grows like `n^(1/2)` instead of `n`);
/// IC(0) (`tau = 0`) lies in between or near MIC. Prints the counts.
#[test]
fn mic0_needs_fewer_iterations_than_jacobi() {
    for n in [32, 64] {
        let (g, mask) = setup(n);
        let bc = Boundaries::lid_driven_cavity(1.0);
        let u = velocity(g, bc, 0.3);
        let its = |pc| {
            let cg = CgPressureSolver::new(g, &bc, &mask, settings(1e-6, pc)).unwrap();
            cg.project(&u, &mut Vec::new()).unwrap().1.iterations
        };
        let (jac, ic, mic) = (its(CgPreconditioner::Jacobi), its(CgPreconditioner::Mic0 { tau: 0.0 }), its(MIC));
        println!("{n}^2 cavity + cylinder, rel_tol 1e-6: Jacobi {jac}, IC(0) {ic}, MIC(0) {mic} iterations");
        assert!(mic < jac && ic < jac, "{n}: Jacobi {jac}, IC(0) {ic}, MIC(0) {mic}");
    }
}

/// Warm start from the previous pressure: the same system converges in 0 iterations, a slightly
/// changed one in fewer than from zero.
#[test]
fn warm_start_reuses_the_previous_pressure() {
    let (g, mask) = setup(64);
    let bc = Boundaries::lid_driven_cavity(1.0);
    let cg = CgPressureSolver::new(g, &bc, &mask, settings(1e-6, MIC)).unwrap();
    let mut p = Vec::new();
    let cold = cg.project(&velocity(g, bc, 0.3), &mut p).unwrap().1;
    let again = cg.project(&velocity(g, bc, 0.3), &mut p).unwrap().1;
    let next = velocity(g, bc, 0.31);
    let warm = cg.project(&next, &mut p).unwrap().1;
    let cold_next = cg.project(&next, &mut Vec::new()).unwrap().1;
    println!("cold {cold:?}, same again {again:?}, perturbed warm {warm:?}, perturbed cold {cold_next:?}");
    assert_eq!(again.iterations, 0);
    assert!(warm.iterations < cold_next.iterations, "warm {warm:?} vs cold {cold_next:?}");
}

#[test]
fn non_convergence_and_bad_settings_are_typed_errors() {
    let (g, mask) = setup(32);
    let bc = Boundaries::lid_driven_cavity(1.0);
    let cg = CgPressureSolver::new(g, &bc, &mask, CgSettings { max_iter: 3, ..CgSettings::default() }).unwrap();
    match cg.project(&velocity(g, bc, 0.3), &mut Vec::new()) {
        Err(Error::Solver { reason, .. }) => {
            assert!(reason.contains("relative residual") && reason.contains("max_iter"), "{reason}")
        }
        other => panic!("expected a solver error, got {other:?}"),
    }
    for bad in [
        CgSettings { rel_tol: 0.0, ..CgSettings::default() },
        CgSettings { max_iter: 0, ..CgSettings::default() },
        CgSettings { preconditioner: CgPreconditioner::Mic0 { tau: 1.5 }, ..CgSettings::default() },
    ] {
        assert!(matches!(CgPressureSolver::new(g, &bc, &mask, bad), Err(Error::Invalid { .. })), "{bad:?}");
    }
    let mut x = vec![0.0; 3];
    assert!(matches!(cg.solve(&[0.0; 3], &mut x), Err(Error::Shape { .. })));
}

/// The CG projection's gradient (one adjoint CG solve) against central differences, f64. The
/// projection is linear, so a large step (1e-2) has no truncation error and keeps the CG
/// stopping noise (`rel_tol * |u| / eps`) far below the 1e-6 bound of the Cholesky path's test.
#[test]
fn cg_projection_gradient_matches_finite_differences() {
    use pbdl_core::{check_grad, seed, GradCheckOptions};
    let g = Grid::new(9, 7, 1.3, 1.0).unwrap();
    let mask = ObstacleMask::new(g, &[Obstacle::Box { lo: [0.4, 0.3], hi: [0.7, 0.6] }]).unwrap();
    for (k, (name, bc)) in cases().into_iter().enumerate() {
        let cg = std::sync::Arc::new(CgPressureSolver::new(g, &bc, &mask, settings(1e-12, MIC)).unwrap());
        let x = seed::randn((2, 2, 7, 9), 0.0, 1.0, DType::F64, &candle_core::Device::Cpu, 90 + k as u64).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(make_incompressible_masked_cg(&MacField::new(xs[0].clone(), g, bc)?, &cg)?.into_values())
        };
        let opts = GradCheckOptions { eps: 1e-2, max_probes: 64, ..Default::default() };
        let r = check_grad(f, &[x], &opts).unwrap();
        eprintln!("CG masked projection {name}: max rel error {:.2e}", r.max_rel_error);
        r.ensure(1e-6).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}
