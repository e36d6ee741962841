//! The closed 3D box (`grid3d::walls`, `grid3d::cg`, `grid3d::Cavity3d`): the Neumann CG solve
//! against analytic eigenpairs, the projection's divergence bound, finite-difference gradient
//! checks (f64, relative error <= 1e-6) of the walled ops, and a lid-driven cavity smoke test.
//!
//! Bounds from the analysis:
//! * after a projection, `||D P u||_2` is the CG residual: `<= rel_tol ||D u||_2`, and
//!   `||D u||_2 <= sum_a (2 / h_a) ||u_a||_2 <= (6 / h) ||u||_2` on a cube, so
//!   `||D P u||_2 h / ||u||_2 <= 6 rel_tol` (1.1x margin for the recursive-vs-true residual).
//! * the cavity is mirror-symmetric about `z = lz / 2` and starts at rest: the discrete solution
//!   is symmetric up to the CG tolerance, at most `rel_tol` per projection (4 per step), times
//!   a factor 10 for the growth between projections.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::grid3d::cg::make_incompressible_walls;
use pbdl_grid::grid3d::walls::momentum_rhs_walls;
use pbdl_grid::grid3d::{fd, Cavity3d, CavityWalls, CgBox3d, Grid3d, MacField3d, NavierStokes3dConfig};
use pbdl_grid::pressure::{CgPreconditioner, CgSettings};
use pbdl_grid::{Error, Scheme};

fn scalar(t: &Tensor) -> f64 {
    t.to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
}

fn l2(t: &Tensor) -> f64 {
    scalar(&t.to_dtype(DType::F64).unwrap().sqr().unwrap().sum_all().unwrap()).sqrt()
}

fn cg(rel_tol: f64) -> CgSettings {
    CgSettings { rel_tol, max_iter: 2000, preconditioner: CgPreconditioner::Mic0 { tau: 0.97 } }
}

/// The Neumann seven-point matrix has eigenvectors `prod_a cos(pi k_a (i_a + 1/2) / n_a)` with
/// eigenvalues `sum_a (2 - 2 cos(pi k_a / n_a)) / h_a^2`: `A^+ (lambda phi) = phi`.
#[test]
fn cg_solves_the_neumann_laplacian_eigenpairs() {
    let grid = Grid3d::new(12, 9, 7, 1.2, 0.9, 1.4).unwrap();
    let [dx, dy, dz] = grid.spacing();
    for pre in [CgPreconditioner::Mic0 { tau: 0.97 }, CgPreconditioner::Mic0 { tau: 0.0 }, CgPreconditioner::Jacobi] {
        let solver = CgBox3d::new(grid, CgSettings { rel_tol: 1e-12, max_iter: 2000, preconditioner: pre }).unwrap();
        for (kx, ky, kz) in [(1, 0, 0), (2, 3, 1), (5, 8, 6)] {
            let ev =
                |k: usize, n: usize, h: f64| (2.0 - 2.0 * (std::f64::consts::PI * k as f64 / n as f64).cos()) / (h * h);
            let lam = ev(kx, 12, dx) + ev(ky, 9, dy) + ev(kz, 7, dz);
            let mut phi = vec![0.0; grid.cells()];
            for k in 0..7 {
                for j in 0..9 {
                    for i in 0..12 {
                        let c = |k_: usize, i_: usize, n: usize| {
                            (std::f64::consts::PI * k_ as f64 * (i_ as f64 + 0.5) / n as f64).cos()
                        };
                        phi[(k * 9 + j) * 12 + i] = c(kx, i, 12) * c(ky, j, 9) * c(kz, k, 7);
                    }
                }
            }
            let mut b: Vec<f64> = phi.iter().map(|p| lam * p).collect();
            let mut x = vec![0.0; grid.cells()];
            let st = solver.solve(&mut b, &mut x).unwrap();
            let err = x.iter().zip(&phi).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            eprintln!("{pre:?} mode ({kx},{ky},{kz}): {} iterations, max error {err:.1e}", st.iterations);
            assert!(err < 1e-9, "{pre:?} ({kx},{ky},{kz}): {err:e}");
        }
    }
}

#[test]
fn walled_projection_leaves_divergence_below_the_cg_tolerance() {
    let grid = Grid3d::cube(12, 1.0).unwrap();
    let h = grid.min_spacing();
    for rel_tol in [1e-6, 1e-10] {
        let solver = CgBox3d::new(grid, cg(rel_tol)).unwrap();
        let x = seed::randn((2, 3, 12, 12, 12), 0.0, 1.0, DType::F64, &Device::Cpu, 11).unwrap();
        let u = MacField3d::new(x, grid).unwrap();
        let p = make_incompressible_walls(&u, &solver).unwrap();
        let rd = l2(&fd::divergence(&p).unwrap()) * h / l2(p.values());
        eprintln!("rel_tol {rel_tol:e}: ||D P u|| h / ||u|| = {rd:.2e}");
        assert!(rd <= 1.1 * 6.0 * rel_tol, "{rd:e}");
        // Idempotent up to the tolerance, and the wall faces are 0.
        let pp = make_incompressible_walls(&p, &solver).unwrap();
        let d = l2(&(pp.values() - p.values()).unwrap()) / l2(p.values());
        assert!(d < 100.0 * rel_tol, "{d:e}");
        let wall_u = p.values().narrow(1, 0, 1).unwrap().narrow(4, 11, 1).unwrap();
        assert_eq!(l2(&wall_u), 0.0);
    }
}

#[test]
fn walled_ops_gradients_match_finite_differences() {
    let grid = Grid3d::new(6, 5, 4, 1.2, 1.0, 0.9).unwrap();
    let walls = CavityWalls { lid_velocity: 0.7 };
    let opts = GradCheckOptions { max_probes: 64, ..Default::default() };
    let x = seed::randn((2, 3, 4, 5, 6), 0.0, 1.0, DType::F64, &Device::Cpu, 21).unwrap();
    let f = |xs: &[Tensor]| Ok(momentum_rhs_walls(&MacField3d::new(xs[0].clone(), grid)?, &walls, 0.05)?.into_values());
    let r = check_grad(f, std::slice::from_ref(&x), &opts).unwrap();
    eprintln!("momentum_rhs_walls: {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
    let solver = CgBox3d::new(grid, cg(1e-14)).unwrap();
    let f =
        |xs: &[Tensor]| Ok(make_incompressible_walls(&MacField3d::new(xs[0].clone(), grid)?, &solver)?.into_values());
    let r = check_grad(f, &[x], &opts).unwrap();
    eprintln!("make_incompressible_walls: {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
}

#[test]
fn lid_driven_cavity_smoke() {
    let n = 16;
    let grid = Grid3d::cube(n, 1.0).unwrap();
    let walls = CavityWalls { lid_velocity: 1.0 };
    let rel_tol = 1e-8;
    let cfg = NavierStokes3dConfig { nu: 0.01, dt: 1e-6, scheme: Scheme::Rk4 };
    let probe = Cavity3d::new(grid, walls, cfg.clone(), cg(rel_tol)).unwrap();
    let dt = 0.9 * probe.stable_time_step([1.0, 1.0, 1.0]);
    let cav = Cavity3d::new(grid, walls, NavierStokes3dConfig { dt, ..cfg }, cg(rel_tol)).unwrap();
    let steps = 40;
    let mut u = MacField3d::zeros(grid, 1, DType::F64).unwrap();
    let t0 = std::time::Instant::now();
    for _ in 0..steps {
        u = cav.step(&u).unwrap();
    }
    let h = grid.min_spacing();
    let rd = l2(&fd::divergence(&u).unwrap()) * h / l2(u.values());
    let v = u.values().squeeze(0).unwrap();
    let ke = 0.5 * l2(u.values()).powi(2) * h * h * h;
    // u on the vertical centre line x = 1/2 (face i = n/2 - 1), z = 1/2 (average of the two middle cells).
    let line: Vec<f64> = (0..n)
        .map(|j| {
            let at = |k: usize| scalar(&v.get(0).unwrap().get(k).unwrap().get(j).unwrap().get(n / 2 - 1).unwrap());
            0.5 * (at(n / 2 - 1) + at(n / 2))
        })
        .collect();
    // Mirror about z = 1/2: u(k) = u(n-1-k), w(k) = -w(n-2-k).
    let uu = v.get(0).unwrap();
    let mirror_u = (&uu - uu.flip(&[0]).unwrap()).unwrap();
    let ww = v.get(2).unwrap().narrow(0, 0, n - 1).unwrap();
    let mirror_w = (&ww + ww.flip(&[0]).unwrap()).unwrap();
    let asym = (l2(&mirror_u) + l2(&mirror_w)) / l2(u.values());
    eprintln!(
        "cavity 16^3 Re 100, {steps} steps of dt {dt:.4} ({:.1} s): ||D u|| h/||u|| {rd:.1e}, KE {ke:.4}, \
         centre-line u top {:.3} min {:.3}, mirror asymmetry {asym:.1e}",
        t0.elapsed().as_secs_f64(),
        line[n - 1],
        line.iter().cloned().fold(f64::INFINITY, f64::min)
    );
    assert!(line.iter().all(|x| x.is_finite()) && ke.is_finite());
    assert!(rd <= 1.1 * 6.0 * rel_tol, "divergence {rd:e}");
    // At most the kinetic energy of the whole box moving at the lid speed.
    assert!(ke > 0.0 && ke < 0.5, "KE {ke}");
    // The primary vortex: forward flow under the lid, return flow below.
    assert!(line[n - 1] > 0.0 && line.iter().cloned().fold(f64::INFINITY, f64::min) < 0.0, "{line:?}");
    assert!(asym <= 10.0 * 4.0 * steps as f64 * rel_tol, "asymmetry {asym:e}");
    assert!(matches!(
        cav.step(&MacField3d::zeros(Grid3d::cube(8, 1.0).unwrap(), 1, DType::F64).unwrap()),
        Err(Error::Invalid { .. })
    ));
}

/// MIC(0) cuts the condition number from O(h^-2) (Jacobi) to O(h^-1): fewer iterations on a
/// random right-hand side, and the advantage grows with the grid.
#[test]
fn mic0_needs_fewer_iterations_than_jacobi() {
    let mut ratio = Vec::new();
    for n in [12, 24] {
        let grid = Grid3d::cube(n, 1.0).unwrap();
        let b0 = seed::randn(grid.cells(), 0.0, 1.0, DType::F64, &Device::Cpu, 31).unwrap().to_vec1::<f64>().unwrap();
        let iters = |pre| {
            let s = CgBox3d::new(grid, CgSettings { rel_tol: 1e-8, max_iter: 5000, preconditioner: pre }).unwrap();
            let (mut b, mut x) = (b0.clone(), vec![0.0; grid.cells()]);
            s.solve(&mut b, &mut x).unwrap().iterations
        };
        let (mic, jac) = (iters(CgPreconditioner::Mic0 { tau: 0.97 }), iters(CgPreconditioner::Jacobi));
        eprintln!("{n}^3 random rhs, rel_tol 1e-8: MIC(0) {mic} iterations, Jacobi {jac}");
        assert!(mic < jac, "{n}^3: MIC(0) {mic} >= Jacobi {jac}");
        ratio.push(jac as f64 / mic as f64);
    }
    assert!(ratio[1] > ratio[0], "advantage did not grow: {ratio:?}");
}

/// One RK4 step of the cavity (walled right-hand side, four CG projections), f64.
#[test]
fn cavity_step_gradient_matches_finite_differences() {
    let grid = Grid3d::new(5, 4, 4, 1.0, 0.8, 0.8).unwrap();
    let cfg = NavierStokes3dConfig { nu: 0.05, dt: 0.01, scheme: Scheme::Rk4 };
    let cav = Cavity3d::new(grid, CavityWalls { lid_velocity: 1.0 }, cfg, cg(1e-14)).unwrap();
    let x = seed::randn((1, 3, 4, 4, 5), 0.0, 1.0, DType::F64, &Device::Cpu, 41).unwrap();
    let x = cav.project(&MacField3d::new(x, grid).unwrap()).unwrap().into_values();
    let f = |xs: &[Tensor]| Ok(cav.step(&MacField3d::new(xs[0].clone(), grid)?)?.into_values());
    let r = check_grad(f, &[x], &GradCheckOptions { max_probes: 64, ..Default::default() }).unwrap();
    eprintln!("Cavity3d::step: {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
}
