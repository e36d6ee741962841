//! Finite-difference gradient checks (f64, relative error <= 1e-6, pbdl_core::check_grad's max
//! norm) of the 3D custom ops on small anisotropic periodic grids, batch 2.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::grid3d::{
    fd, momentum, pressure, Grid3d, MacField3d, NavierStokes3d, NavierStokes3dConfig, PoissonFft3d,
};
use pbdl_grid::Scheme;

// Finite-difference gradient checks in f64 (see the constant for why 1e-6).
use pbdl_core::tolerance::GRAD_CHECK_F64 as TOL;

fn opts() -> GradCheckOptions {
    GradCheckOptions { max_probes: 64, ..Default::default() }
}

fn grid() -> Grid3d {
    Grid3d::new(6, 5, 4, 1.2, 1.0, 0.9).unwrap()
}

fn rand(c: usize, s: u64) -> Tensor {
    seed::randn((2, c, 4, 5, 6), 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

fn mac(x: &Tensor) -> candle_core::Result<MacField3d> {
    Ok(MacField3d::new(x.clone(), grid())?)
}

fn report(name: &str, r: pbdl_core::GradCheckReport) {
    eprintln!("{name}: max rel error {:.2e} over {} probes", r.max_rel_error, r.probes);
    r.ensure(TOL).unwrap_or_else(|e| panic!("{name}: {e}"));
}

#[test]
fn divergence_and_gradient() {
    let r = check_grad(|xs| Ok(fd::divergence(&mac(&xs[0])?)?), &[rand(3, 1)], &opts()).unwrap();
    report("divergence", r);
    let r = check_grad(|xs| Ok(fd::gradient(&xs[0], &grid())?.into_values()), &[rand(1, 2)], &opts()).unwrap();
    report("gradient", r);
}

#[test]
fn flux_form_viscous_and_fused_rhs() {
    let r = check_grad(|xs| Ok(momentum::flux_form(&mac(&xs[0])?)?.into_values()), &[rand(3, 3)], &opts()).unwrap();
    report("flux_form", r);
    let r = check_grad(|xs| Ok(momentum::viscous(&mac(&xs[0])?, 0.3)?.into_values()), &[rand(3, 4)], &opts()).unwrap();
    report("viscous", r);
    let f = |xs: &[Tensor]| Ok(momentum::momentum_rhs(&mac(&xs[0])?, 0.05)?.into_values());
    report("momentum_rhs", check_grad(f, &[rand(3, 5)], &opts()).unwrap());
}

#[test]
fn projection_and_poisson_solve() {
    let solver = PoissonFft3d::new(grid()).unwrap();
    let f = |xs: &[Tensor]| Ok(pressure::make_incompressible(&mac(&xs[0])?, &solver)?.into_values());
    report("make_incompressible", check_grad(f, &[rand(3, 6)], &opts()).unwrap());
    let f = |xs: &[Tensor]| Ok(pressure::solve_poisson(&xs[0], &solver)?);
    report("solve_poisson", check_grad(f, &[rand(1, 7)], &opts()).unwrap());
}

/// Two full RK4 steps (fused stage updates and projections, flux form, viscosity).
#[test]
fn navier_stokes_steps() {
    let ns = NavierStokes3d::new(grid(), NavierStokes3dConfig { nu: 0.01, dt: 0.02, scheme: Scheme::Rk4 }).unwrap();
    let x0 = ns.project(&mac(&rand(3, 8)).unwrap()).unwrap().into_values();
    let f = |xs: &[Tensor]| {
        let u = mac(&xs[0])?;
        let u = ns.step(&u)?;
        Ok(ns.step(&u)?.into_values())
    };
    report("NavierStokes3d::step x2", check_grad(f, &[x0], &opts()).unwrap());
}
