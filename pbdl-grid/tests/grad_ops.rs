//! Finite-difference gradient checks (f64) of every custom op, on small grids with mixed
//! boundary conditions. Tolerance: relative error <= 1e-6 (pbdl_core::check_grad's max norm).

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::{
    advect, diffuse, fd, pressure, Bc, Boundaries, CenteredField, Grid, MacField, PressureSolver, ScalarBc,
    ScalarBoundaries,
};

// Finite-difference gradient checks in f64 (see the constant for why 1e-6).
use pbdl_core::tolerance::GRAD_CHECK_F64 as TOL;

fn opts() -> GradCheckOptions {
    GradCheckOptions { max_probes: 64, ..Default::default() }
}

fn grid() -> Grid {
    Grid::new(6, 5, 1.2, 1.0).unwrap()
}

/// Boundary sets that exercise every ghost rule.
fn velocity_bcs() -> Vec<Boundaries> {
    vec![
        Boundaries::periodic(),
        Boundaries::lid_driven_cavity(1.0),
        Boundaries::new(Bc::Inflow { velocity: [1.0, 0.2] }, Bc::Outflow, Bc::FreeSlip, Bc::NoSlip).unwrap(),
        Boundaries::new(Bc::Periodic, Bc::Periodic, Bc::NoSlip, Bc::Outflow).unwrap(),
    ]
}

fn rand(shape: (usize, usize, usize, usize), s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

fn mac(x: &Tensor, bc: Boundaries) -> candle_core::Result<MacField> {
    Ok(MacField::new(x.clone(), grid(), bc)?)
}

#[test]
fn divergence_gradient_matches_finite_differences() {
    for (k, bc) in velocity_bcs().into_iter().enumerate() {
        let x = rand((2, 2, 5, 6), k as u64);
        let r = check_grad(|xs| Ok(fd::divergence(&mac(&xs[0], bc)?)?.into_values()), &[x], &opts()).unwrap();
        r.ensure(TOL).unwrap_or_else(|e| panic!("{bc:?}: {e}"));
    }
}

#[test]
fn gradient_gradient_matches_finite_differences() {
    for (k, bc) in velocity_bcs().into_iter().enumerate() {
        let x = rand((2, 1, 5, 6), 10 + k as u64);
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            let p = CenteredField::new(xs[0].clone(), grid(), bc.pressure())?;
            Ok(fd::gradient(&p, &bc)?.into_values())
        };
        check_grad(f, &[x], &opts()).unwrap().ensure(TOL).unwrap_or_else(|e| panic!("{bc:?}: {e}"));
    }
}

#[test]
fn laplacian_gradient_matches_finite_differences() {
    let bcs = [
        ScalarBoundaries::periodic(),
        ScalarBoundaries::neumann(),
        ScalarBoundaries {
            x_lo: ScalarBc::Dirichlet { value: 1.5 },
            x_hi: ScalarBc::Neumann,
            y_lo: ScalarBc::Periodic,
            y_hi: ScalarBc::Periodic,
        },
    ];
    for (k, bc) in bcs.into_iter().enumerate() {
        let x = rand((1, 2, 5, 6), 20 + k as u64);
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(fd::laplacian(&CenteredField::new(xs[0].clone(), grid(), bc)?)?.into_values())
        };
        check_grad(f, &[x], &opts()).unwrap().ensure(TOL).unwrap_or_else(|e| panic!("{bc:?}: {e}"));
    }
}

#[test]
fn advection_and_diffusion_gradients_match_finite_differences() {
    for (k, bc) in velocity_bcs().into_iter().enumerate() {
        let x = rand((2, 2, 5, 6), 30 + k as u64);
        let adv =
            check_grad(|xs| Ok(advect::flux_form(&mac(&xs[0], bc)?)?.into_values()), std::slice::from_ref(&x), &opts())
                .unwrap();
        adv.ensure(TOL).unwrap_or_else(|e| panic!("advection {bc:?}: {e}"));
        let dif = check_grad(|xs| Ok(diffuse::explicit(&mac(&xs[0], bc)?, 0.3)?.into_values()), &[x], &opts()).unwrap();
        dif.ensure(TOL).unwrap_or_else(|e| panic!("diffusion {bc:?}: {e}"));
    }
}

#[test]
fn projection_gradient_is_an_adjoint_solve_that_matches_finite_differences() {
    for (k, bc) in velocity_bcs().into_iter().enumerate() {
        let solver = PressureSolver::new(grid(), &bc).unwrap();
        let x = rand((2, 2, 5, 6), 40 + k as u64);
        let r = check_grad(
            |xs| Ok(pressure::make_incompressible(&mac(&xs[0], bc)?, &solver)?.into_values()),
            &[x],
            &opts(),
        )
        .unwrap();
        r.ensure(TOL).unwrap_or_else(|e| panic!("{} {bc:?}: {e}", solver.method_name()));
    }
}

#[test]
fn poisson_solve_gradient_matches_finite_differences() {
    for (bc, force) in [
        (ScalarBoundaries::periodic(), false),
        (ScalarBoundaries::periodic(), true),
        (ScalarBoundaries::neumann(), false),
    ] {
        let solver = PressureSolver::for_scalar(grid(), &bc, force).unwrap();
        let x = rand((1, 1, 5, 6), 50);
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(pressure::solve_poisson(&CenteredField::new(xs[0].clone(), grid(), bc)?, &solver)?.into_values())
        };
        check_grad(f, &[x], &opts()).unwrap().ensure(TOL).unwrap_or_else(|e| panic!("{}: {e}", solver.method_name()));
    }
}

#[test]
fn navier_stokes_step_gradient_matches_finite_differences() {
    for bc in [Boundaries::periodic(), Boundaries::lid_driven_cavity(1.0)] {
        let cfg = pbdl_grid::NavierStokesConfig { nu: 0.05, dt: 0.01, scheme: pbdl_grid::Scheme::Rk4 };
        let ns = pbdl_grid::NavierStokes::new(grid(), bc, cfg).unwrap();
        let x = rand((1, 2, 5, 6), 60).affine(0.5, 0.0).unwrap();
        let r = check_grad(|xs| Ok(ns.step_unchecked(&mac(&xs[0], bc)?)?.into_values()), &[x], &opts()).unwrap();
        r.ensure(TOL).unwrap_or_else(|e| panic!("{bc:?}: {e}"));
    }
}

#[test]
fn fft_and_cholesky_projections_agree_on_a_periodic_domain() {
    let g = Grid::new(16, 12, 2.0, 1.5).unwrap();
    let x = seed::randn((1, 2, 12, 16), 0.0, 1.0, DType::F64, &Device::Cpu, 7).unwrap();
    let u = MacField::new(x, g, Boundaries::periodic()).unwrap();
    let fft = PressureSolver::new(g, &Boundaries::periodic()).unwrap();
    let chol = PressureSolver::for_scalar(g, &ScalarBoundaries::periodic(), true).unwrap();
    assert_eq!((fft.method_name(), chol.method_name()), ("fft", "sparse_cholesky"));
    let a = pressure::make_incompressible(&u, &fft).unwrap().into_values();
    let b = pressure::make_incompressible(&u, &chol).unwrap().into_values();
    let d = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
    assert!(d < 1e-11, "fft vs cholesky max difference {d:e}");
}

/// After projection, max |div u| is round-off relative to |u|/dx: <= 1e-11 in f64, <= 1e-4 in f32
/// (measured: see the assertion messages).
#[test]
fn projection_leaves_no_divergence_in_f32_and_f64() {
    let g = Grid::square(48, 1.0).unwrap();
    for (bc, dtype, bound) in [
        (Boundaries::periodic(), DType::F64, 1e-11),
        (Boundaries::lid_driven_cavity(1.0), DType::F64, 1e-11),
        (
            Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::NoSlip, Bc::FreeSlip).unwrap(),
            DType::F64,
            1e-11,
        ),
        (Boundaries::periodic(), DType::F32, 1e-4),
        (Boundaries::lid_driven_cavity(1.0), DType::F32, 1e-4),
    ] {
        let x = seed::randn((1, 2, 48, 48), 0.0, 1.0, dtype, &Device::Cpu, 3).unwrap();
        let u = MacField::new(x, g, bc).unwrap();
        let solver = PressureSolver::new(g, &bc).unwrap();
        let p = pressure::make_incompressible(&u, &solver).unwrap();
        let umax = p.max_abs().unwrap();
        let div = fd::divergence(&p)
            .unwrap()
            .into_values()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_dtype(DType::F64)
            .unwrap()
            .to_scalar::<f64>()
            .unwrap();
        let rel = div * g.dx() / umax;
        assert!(rel < bound, "{bc:?} {dtype:?}: max|div u| dx / max|u| = {rel:e}");
        eprintln!("{:?} {dtype:?}: max|div u| dx / max|u| = {rel:.2e}", bc.x_hi);
    }
}
