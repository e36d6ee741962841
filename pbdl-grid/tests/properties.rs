//! Property tests (proptest) of the grid operators, on random grids, boundaries and fields:
//!
//! * adjoint identities `<A x, y> = <x, A^T y>` of the linear (or affine) operators, with `A^T`
//!   from the hand-written backward of each custom op, and the operator pairs that must be each
//!   other's (negative) transpose without any autograd: `D = -G^T` on the MAC grid (2D, 3D),
//!   the symmetric Laplacian, Poisson solve, implicit diffusion and projections;
//! * projection idempotence `P(P u) = P u` and the divergence left behind, 2D (FFT, Cholesky,
//!   obstacles by Cholesky and CG) and 3D (FFT, walled box by Cholesky and CG);
//! * conservation: divergence and Laplacian sum to 0 on periodic/closed domains, flux-form
//!   momentum and the scalar laws conserve their sums, implicit diffusion keeps the mean,
//!   central fluxes conserve energy.
//!
//! Every field is f64; tolerances are relative and stated with their reasons next to the checks.
//! The proptest seed is fixed (deterministic CI) unless `PROPTEST_RNG_SEED` is set;
//! `PROPTEST_CASES` overrides the case counts.

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed;
use pbdl_core::testing::{adjoint_gap_by_backward, dot, norm};
use pbdl_grid::grid3d::{self, BoxPressure, Grid3d, MacField3d, PoissonFft3d};
use pbdl_grid::pressure::{
    make_incompressible, make_incompressible_masked, make_incompressible_masked_cg, solve_poisson, CgPreconditioner,
    CgPressureSolver, CgSettings, MaskedPressureSolver,
};
use pbdl_grid::scalar_law::ScalarLaw;
use pbdl_grid::{
    advect, diffuse, fd, Bc, Boundaries, CenteredField, Grid, MacField, Obstacle, ObstacleMask, PressureSolver,
    ScalarBc, ScalarBoundaries,
};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// `cases` random cases (or `PROPTEST_CASES`), a fixed seed (or `PROPTEST_RNG_SEED`), and no
/// regression files written into the source tree (a failure prints its minimal input).
fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_none() {
        c.cases = cases;
    }
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_0025);
    }
    c.failure_persistence = None;
    c
}

fn randn(shape: &[usize], s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

fn sum(a: &Tensor) -> f64 {
    a.sum_all().unwrap().to_scalar::<f64>().unwrap()
}

fn max_abs(a: &Tensor) -> f64 {
    a.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
}

/// Velocity boundary sets that exercise every ghost rule (affine ones included: moving wall,
/// inflow), indexed by a proptest choice.
fn velocity_bc(k: usize) -> Boundaries {
    match k % 5 {
        0 => Boundaries::periodic(),
        1 => Boundaries::lid_driven_cavity(1.0),
        2 => Boundaries::new(Bc::Inflow { velocity: [1.0, 0.2] }, Bc::Outflow, Bc::FreeSlip, Bc::NoSlip).unwrap(),
        3 => Boundaries::new(Bc::Periodic, Bc::Periodic, Bc::NoSlip, Bc::Outflow).unwrap(),
        _ => Boundaries::new(Bc::NoSlip, Bc::FreeSlip, Bc::Periodic, Bc::Periodic).unwrap(),
    }
}

/// The linear velocity boundary sets (homogeneous conditions only), for the identities that need
/// a linear operator rather than an affine one.
fn linear_velocity_bc(k: usize) -> Boundaries {
    match k % 4 {
        0 => Boundaries::periodic(),
        1 => Boundaries::new(Bc::NoSlip, Bc::NoSlip, Bc::NoSlip, Bc::NoSlip).unwrap(),
        2 => Boundaries::new(Bc::FreeSlip, Bc::NoSlip, Bc::Periodic, Bc::Periodic).unwrap(),
        _ => Boundaries::new(Bc::Periodic, Bc::Periodic, Bc::FreeSlip, Bc::FreeSlip).unwrap(),
    }
}

/// Homogeneous scalar conditions (linear Laplacian), indexed by a proptest choice.
fn scalar_bc(k: usize) -> ScalarBoundaries {
    let d0 = ScalarBc::Dirichlet { value: 0.0 };
    match k % 4 {
        0 => ScalarBoundaries::periodic(),
        1 => ScalarBoundaries::neumann(),
        2 => ScalarBoundaries { x_lo: d0, x_hi: ScalarBc::Neumann, y_lo: ScalarBc::Periodic, y_hi: ScalarBc::Periodic },
        _ => ScalarBoundaries { x_lo: ScalarBc::Neumann, x_hi: ScalarBc::Neumann, y_lo: d0, y_hi: d0 },
    }
}

/// Zeroes the stored faces that `bc` fixes (walls, inflow at `x_hi`/`y_hi`), so that a random
/// velocity is admissible for the boundaries.
fn zero_fixed_faces(u: &Tensor, bc: &Boundaries) -> Tensor {
    let (_, _, ny, nx) = u.dims4().unwrap();
    let fixed = |b: Bc| !matches!(b, Bc::Periodic | Bc::Outflow);
    let mut m = vec![1.0f64; 2 * ny * nx];
    for j in 0..ny {
        for i in 0..nx {
            if fixed(bc.x_hi) && i == nx - 1 {
                m[j * nx + i] = 0.0;
            }
            if fixed(bc.y_hi) && j == ny - 1 {
                m[ny * nx + j * nx + i] = 0.0;
            }
        }
    }
    let m = Tensor::from_vec(m, (1, 2, ny, nx), &Device::Cpu).unwrap();
    u.broadcast_mul(&m).unwrap()
}

// Adjoint identities. Tolerance 1e-10 relative in f64: each inner product sums at most a few
// thousand products of O(1/h) terms, so round-off is ~1e-13 relative; a wrong stencil weight or a
// lost boundary term in a single cell moves the identity by ~1/sqrt(cells) >= 1e-2.
const ADJ_TOL: f64 = 1e-10;

proptest! {
    #![proptest_config(config(48))]

    /// `divergence`, `gradient`, `laplacian`: the hand-written backward is the transpose of the
    /// (affine) forward for every boundary set.
    #[test]
    fn fd_ops_backward_is_the_transpose(
        nx in 2usize..11, ny in 2usize..11, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        batch in 1usize..3, k in 0usize..5, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let bc = velocity_bc(k);
        let u = randn(&[batch, 2, ny, nx], s);
        let d = randn(&[batch, 1, ny, nx], s ^ 1);
        let div = |x: &Tensor| fd::divergence(&MacField::new(x.clone(), g, bc).unwrap()).unwrap().into_values();
        let e = adjoint_gap_by_backward(div, &u, &d);
        prop_assert!(e < ADJ_TOL, "divergence {bc:?}: {e:e}");
        let grad = |x: &Tensor| {
            fd::gradient(&CenteredField::new(x.clone(), g, bc.pressure()).unwrap(), &bc).unwrap().into_values()
        };
        let e = adjoint_gap_by_backward(grad, &d, &u);
        prop_assert!(e < ADJ_TOL, "gradient {bc:?}: {e:e}");
        let sbc = scalar_bc(k);
        let lap = |x: &Tensor| fd::laplacian(&CenteredField::new(x.clone(), g, sbc).unwrap()).unwrap().into_values();
        let p = randn(&[batch, 2, ny, nx], s ^ 2);
        let q = randn(&[batch, 2, ny, nx], s ^ 3);
        let e = adjoint_gap_by_backward(lap, &p, &q);
        prop_assert!(e < ADJ_TOL, "laplacian {sbc:?}: {e:e}");
    }

    /// `D = -G^T` on the MAC grid (summation by parts): `<div u, p> = -<u, grad p>` for
    /// admissible `u` (fixed faces 0) and the pressure conditions its boundaries imply; and the
    /// symmetric Laplacian `<L p, q> = <p, L q>` for homogeneous conditions. Forward ops only.
    #[test]
    fn divergence_is_minus_gradient_transposed_and_laplacian_is_symmetric(
        nx in 2usize..11, ny in 2usize..11, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        k in 0usize..4, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let bc = linear_velocity_bc(k);
        let u = zero_fixed_faces(&randn(&[1, 2, ny, nx], s), &bc);
        let p = randn(&[1, 1, ny, nx], s ^ 1);
        let du = fd::divergence(&MacField::new(u.clone(), g, bc).unwrap()).unwrap().into_values();
        let gp = fd::gradient(&CenteredField::new(p.clone(), g, bc.pressure()).unwrap(), &bc).unwrap().into_values();
        let (l, r) = (dot(&du, &p), -dot(&u, &gp));
        let e = (l - r).abs() / (norm(&du) * norm(&p) + norm(&u) * norm(&gp));
        prop_assert!(e < ADJ_TOL, "<Du, p> = {l}, -<u, Gp> = {r} ({bc:?}): {e:e}");

        let sbc = scalar_bc(k);
        let q = randn(&[1, 1, ny, nx], s ^ 2);
        let lap = |x: &Tensor| fd::laplacian(&CenteredField::new(x.clone(), g, sbc).unwrap()).unwrap().into_values();
        let (lp, lq) = (lap(&p), lap(&q));
        let (l, r) = (dot(&lp, &q), dot(&p, &lq));
        let e = (l - r).abs() / (norm(&lp) * norm(&q) + norm(&p) * norm(&lq));
        prop_assert!(e < ADJ_TOL, "<Lp, q> = {l}, <p, Lq> = {r} ({sbc:?}): {e:e}");
    }

    /// Semi-Lagrangian advection is affine in the advected field for a fixed velocity (bilinear
    /// interpolation at fixed departure points); its backward for the field is that map's
    /// transpose, for centred scalars and MAC velocities, any boundaries, any `dt` (CFL > 1 too).
    #[test]
    fn semi_lagrangian_backward_in_the_field_is_the_transpose(
        nx in 2usize..10, ny in 2usize..10, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        batch in 1usize..3, k in 0usize..5, dt in -2.0f64..2.0, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let bc = velocity_bc(k);
        let vel = MacField::new(randn(&[batch, 2, ny, nx], s), g, bc).unwrap();
        let q = randn(&[batch, 2, ny, nx], s ^ 1);
        let y = randn(&[batch, 2, ny, nx], s ^ 2);
        let sbc = scalar_bc(k);
        let scalar = |x: &Tensor| {
            advect::semi_lagrangian(&CenteredField::new(x.clone(), g, sbc).unwrap(), &vel, dt).unwrap().into_values()
        };
        let e = adjoint_gap_by_backward(scalar, &q, &y);
        prop_assert!(e < ADJ_TOL, "scalar {sbc:?}, dt {dt}: {e:e}");
        let velocity = |x: &Tensor| {
            advect::semi_lagrangian(&MacField::new(x.clone(), g, bc).unwrap(), &vel, dt).unwrap().into_values()
        };
        let e = adjoint_gap_by_backward(velocity, &q, &y);
        prop_assert!(e < ADJ_TOL, "velocity {bc:?}, dt {dt}: {e:e}");
    }

    /// Self-adjoint solves: `solve_poisson` (`L^+`, FFT or Cholesky) and implicit diffusion
    /// (`(I - nu dt L)^-1`) satisfy `<S b, c> = <b, S c>` (forward only), and their backward is
    /// the same operator. 1e-10: direct solves of a system with condition number <= ~1e3 here
    /// (10x10 cells, aspect ratio <= 10) lose at most ~1e-13 relative.
    #[test]
    fn poisson_solve_and_implicit_diffusion_are_symmetric(
        nx in 2usize..11, ny in 2usize..11, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        k in 0usize..5, nu_dt in 1e-3f64..10.0, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let bc = velocity_bc(k);
        let solver = PressureSolver::new(g, &bc).unwrap();
        let b = randn(&[1, 1, ny, nx], s);
        let c = randn(&[1, 1, ny, nx], s ^ 1);
        let solve = |x: &Tensor| {
            solve_poisson(&CenteredField::new(x.clone(), g, bc.pressure()).unwrap(), &solver).unwrap().into_values()
        };
        let (sb, sc) = (solve(&b), solve(&c));
        let e = (dot(&sb, &c) - dot(&b, &sc)).abs() / (norm(&sb) * norm(&c) + norm(&b) * norm(&sc));
        prop_assert!(e < ADJ_TOL, "poisson ({}) {bc:?}: {e:e}", solver.method_name());
        let e = adjoint_gap_by_backward(solve, &b, &c);
        prop_assert!(e < ADJ_TOL, "poisson backward ({}) {bc:?}: {e:e}", solver.method_name());

        let sbc = scalar_bc(k);
        let like = CenteredField::new(b.clone(), g, sbc).unwrap();
        let diff = diffuse::ImplicitDiffusion::new(&like, nu_dt, 1.0).unwrap();
        let h = |x: &Tensor| diff.apply(&CenteredField::new(x.clone(), g, sbc).unwrap()).unwrap().into_values();
        let (hb, hc) = (h(&b), h(&c));
        let e = (dot(&hb, &c) - dot(&b, &hc)).abs() / (norm(&hb) * norm(&c) + norm(&b) * norm(&hc));
        prop_assert!(e < ADJ_TOL, "implicit diffusion {sbc:?}: {e:e}");
        let e = adjoint_gap_by_backward(h, &b, &c);
        prop_assert!(e < ADJ_TOL, "implicit diffusion backward {sbc:?}: {e:e}");
    }

    /// 3D periodic MAC grid: `D = -G^T` by forward ops, and each op's backward is its transpose.
    #[test]
    fn divergence_gradient_3d_are_negative_transposes(
        nx in 2usize..7, ny in 2usize..7, nz in 2usize..7, l in prop::array::uniform3(0.3f64..3.0),
        s in any::<u64>(),
    ) {
        let g = Grid3d::new(nx, ny, nz, l[0], l[1], l[2]).unwrap();
        let u = randn(&[1, 3, nz, ny, nx], s);
        let p = randn(&[1, 1, nz, ny, nx], s ^ 1);
        let div = |x: &Tensor| grid3d::fd::divergence(&MacField3d::new(x.clone(), g).unwrap()).unwrap();
        let grad = |x: &Tensor| grid3d::fd::gradient(x, &g).unwrap().into_values();
        let (du, gp) = (div(&u), grad(&p));
        let e = (dot(&du, &p) + dot(&u, &gp)).abs() / (norm(&du) * norm(&p) + norm(&u) * norm(&gp));
        prop_assert!(e < ADJ_TOL, "<Du, p> + <u, Gp>: {e:e}");
        let e = adjoint_gap_by_backward(div, &u, &p);
        prop_assert!(e < ADJ_TOL, "3D divergence backward: {e:e}");
        let e = adjoint_gap_by_backward(grad, &p, &u);
        prop_assert!(e < ADJ_TOL, "3D gradient backward: {e:e}");
        // Conservation: the divergence of a periodic field sums to 0 (telescoping differences).
        let sd = sum(&du).abs();
        prop_assert!(sd < 1e-12 * du.abs().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap(), "sum div = {sd:e}");
    }
}

// Projections. A projection is idempotent and leaves no divergence; with linear boundaries it
// is an orthogonal projector, hence symmetric. Direct solves (FFT, Cholesky): 1e-10 relative,
// round-off of a solve whose condition number is <= ~1e3 on these grids.
//
// CG at relative tolerance `CG_TOL`: the documented bound `||D P u||_2 <= rel_tol ||D u||_2`
// (recursive residual) gets a factor 10 for the gap between recursive and true residual. A
// second projection removes `(I - P) P u = G L^+ D (P u)`, whose norm is at most
// `||G L^+|| ||D|| rel_tol ||u||`, i.e. `sqrt(cond L) rel_tol ||u||`; `sqrt(cond L)` is ~10 on
// grids up to 14 cells a side, so the bound is `100 rel_tol ||u||` (10 for the residual gap).
const CG_TOL: f64 = 1e-9;
proptest! {
    #![proptest_config(config(32))]

    /// 2D `make_incompressible` (FFT when periodic, Cholesky otherwise), every boundary set:
    /// `P(P u) = P u`, `div(P u) = 0`; symmetric `<P u, w> = <u, P w>` for linear boundaries.
    #[test]
    fn projection_2d_is_idempotent_divergence_free_and_symmetric(
        nx in 2usize..13, ny in 2usize..13, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        batch in 1usize..3, k in 0usize..5, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let bc = velocity_bc(k);
        let solver = PressureSolver::new(g, &bc).unwrap();
        let project = |x: &Tensor| {
            make_incompressible(&MacField::new(x.clone(), g, bc).unwrap(), &solver).unwrap().into_values()
        };
        let u = randn(&[batch, 2, ny, nx], s);
        let pu = project(&u);
        let ppu = project(&pu);
        let e = norm(&(&ppu - &pu).unwrap()) / norm(&pu).max(f64::MIN_POSITIVE);
        prop_assert!(e < 1e-10, "idempotence {bc:?} ({}): {e:e}", solver.method_name());
        let div = |x: &Tensor| fd::divergence(&MacField::new(x.clone(), g, bc).unwrap()).unwrap().into_values();
        let (d0, d1) = (max_abs(&div(&u)), max_abs(&div(&pu)));
        // An inflow face fixes a flux the closed remainder must carry; only with an outflow face
        // (or none fixed) is the projected field exactly solenoidal. All sets here qualify.
        prop_assert!(d1 < 1e-10 * d0.max(max_abs(&u) / g.dx().min(g.dy())), "div {d1:e} (before {d0:e}) {bc:?}");

        let lbc = linear_velocity_bc(k);
        let lsolver = PressureSolver::new(g, &lbc).unwrap();
        let lp = |x: &Tensor| {
            make_incompressible(&MacField::new(x.clone(), g, lbc).unwrap(), &lsolver).unwrap().into_values()
        };
        let w = randn(&[batch, 2, ny, nx], s ^ 1);
        let (pu, pw) = (lp(&u), lp(&w));
        let e = (dot(&pu, &w) - dot(&u, &pw)).abs() / (norm(&pu) * norm(&w) + norm(&u) * norm(&pw));
        prop_assert!(e < ADJ_TOL, "symmetry {lbc:?}: {e:e}");
        let e = adjoint_gap_by_backward(lp, &u, &w);
        prop_assert!(e < ADJ_TOL, "backward {lbc:?}: {e:e}");
    }

    /// Projection with obstacles (a random box), by Cholesky and by CG (MIC(0) and Jacobi):
    /// idempotent, no divergence in the fluid cells, zero normal velocity on obstacle faces.
    #[test]
    fn masked_projection_is_idempotent_and_divergence_free(
        n in 6usize..14, k in 0usize..5,
        lo in prop::array::uniform2(0.2f64..0.5), size in prop::array::uniform2(0.1f64..0.3),
        jacobi in any::<bool>(), s in any::<u64>(),
    ) {
        let g = Grid::new(n, n + 1, 1.0, 1.1).unwrap();
        let bc = velocity_bc(k);
        let hi = [lo[0] + size[0], 1.1 * (lo[1] + size[1])];
        let mask = ObstacleMask::new(g, &[Obstacle::Box { lo: [lo[0], 1.1 * lo[1]], hi }]);
        // Boxes that cover no cell centre are refused by the mask; nothing to test then.
        prop_assume!(mask.is_ok());
        let mask = mask.unwrap();
        let fluid = mask.fluid_tensor(DType::F64).unwrap();
        let u = randn(&[1, 2, n + 1, n], s);
        let div = |x: &Tensor| {
            let d = fd::divergence(&MacField::new(x.clone(), g, bc).unwrap()).unwrap().into_values();
            d.broadcast_mul(&fluid).unwrap()
        };
        let d0 = max_abs(&div(&u)).max(max_abs(&u) / g.dx().min(g.dy()));

        let chol = MaskedPressureSolver::new(g, &bc, &mask).unwrap();
        let project = |x: &Tensor| {
            make_incompressible_masked(&MacField::new(x.clone(), g, bc).unwrap(), &chol).unwrap().into_values()
        };
        let pu = project(&u);
        let e = norm(&(project(&pu) - &pu).unwrap()) / norm(&pu);
        prop_assert!(e < 1e-10, "Cholesky idempotence {bc:?}: {e:e}");
        let d1 = max_abs(&div(&pu));
        prop_assert!(d1 < 1e-10 * d0, "Cholesky divergence {d1:e} vs {d0:e} {bc:?}");

        let preconditioner = if jacobi { CgPreconditioner::Jacobi } else { CgSettings::default().preconditioner };
        let settings = CgSettings { rel_tol: CG_TOL, max_iter: 10_000, preconditioner };
        let cg = std::sync::Arc::new(CgPressureSolver::new(g, &bc, &mask, settings).unwrap());
        let project = |x: &Tensor| {
            make_incompressible_masked_cg(&MacField::new(x.clone(), g, bc).unwrap(), &cg).unwrap().into_values()
        };
        let pu = project(&u);
        let e = norm(&(project(&pu) - &pu).unwrap());
        prop_assert!(e < 100.0 * CG_TOL * norm(&u), "CG idempotence {bc:?}: {e:e} (|u| {})", norm(&u));
        let (dn0, dn1) = (norm(&div(&u)), norm(&div(&pu)));
        prop_assert!(dn1 <= 10.0 * CG_TOL * dn0, "CG divergence {dn1:e} vs {dn0:e} {bc:?}");
    }

    /// 3D projections: periodic (FFT) and the walled box (Cholesky and CG): idempotent and
    /// divergence-free; the periodic one symmetric.
    #[test]
    fn projection_3d_is_idempotent_and_divergence_free(
        nx in 2usize..7, ny in 2usize..7, nz in 2usize..7, l in prop::array::uniform3(0.3f64..3.0),
        s in any::<u64>(),
    ) {
        let g = Grid3d::new(nx, ny, nz, l[0], l[1], l[2]).unwrap();
        let h = g.min_spacing();
        let u = randn(&[1, 3, nz, ny, nx], s);
        let field = |x: &Tensor| MacField3d::new(x.clone(), g).unwrap();
        let div = |x: &Tensor| grid3d::fd::divergence(&field(x)).unwrap();
        let scale = max_abs(&div(&u)).max(max_abs(&u) / h);

        let fft = PoissonFft3d::new(g).unwrap();
        let p = |x: &Tensor| grid3d::pressure::make_incompressible(&field(x), &fft).unwrap().into_values();
        let pu = p(&u);
        let e = norm(&(p(&pu) - &pu).unwrap()) / norm(&pu);
        prop_assert!(e < 1e-10, "FFT idempotence: {e:e}");
        let d = max_abs(&div(&pu));
        prop_assert!(d < 1e-10 * scale, "FFT divergence {d:e}");
        let w = randn(&[1, 3, nz, ny, nx], s ^ 1);
        let pw = p(&w);
        let e = (dot(&pu, &w) - dot(&u, &pw)).abs() / (norm(&pu) * norm(&w) + norm(&u) * norm(&pw));
        prop_assert!(e < ADJ_TOL, "FFT symmetry: {e:e}");

        // The walled box treats the last face of each component along its own axis as a wall:
        // divergence is measured by the periodic operator, whose wrap-around reads exactly
        // those (zeroed) wall faces, so it is the box's divergence.
        let chol = BoxPressure::Cholesky.build(g).unwrap();
        let p = |x: &Tensor| grid3d::box_pressure::make_incompressible_box(&field(x), &chol).unwrap().into_values();
        let pu = p(&u);
        let e = norm(&(p(&pu) - &pu).unwrap()) / norm(&pu);
        prop_assert!(e < 1e-10, "Cholesky box idempotence: {e:e}");
        let d = max_abs(&div(&pu));
        prop_assert!(d < 1e-10 * scale, "Cholesky box divergence {d:e} (scale {scale:e})");
        // The walled projection zeroes the wall faces first: its divergence reference is that of
        // the walled `u`.
        let walled = |x: &Tensor| -> Tensor {
            let mut m = vec![1.0f64; 3 * nz * ny * nx];
            for (c, n) in [(0, nx), (1, ny), (2, nz)] {
                for z in 0..nz {
                    for y in 0..ny {
                        for xi in 0..nx {
                            if [xi, y, z][c] == n - 1 {
                                m[((c * nz + z) * ny + y) * nx + xi] = 0.0;
                            }
                        }
                    }
                }
            }
            x.broadcast_mul(&Tensor::from_vec(m, (1, 3, nz, ny, nx), &Device::Cpu).unwrap()).unwrap()
        };
        let settings = CgSettings { rel_tol: CG_TOL, max_iter: 10_000, ..Default::default() };
        let cg = BoxPressure::Cg(settings).build(g).unwrap();
        let p = |x: &Tensor| grid3d::box_pressure::make_incompressible_box(&field(x), &cg).unwrap().into_values();
        let pu = p(&u);
        let e = norm(&(p(&pu) - &pu).unwrap());
        prop_assert!(e < 100.0 * CG_TOL * norm(&u), "CG box idempotence: {e:e} (|u| {})", norm(&u));
        let (dn0, dn1) = (norm(&div(&walled(&u))), norm(&div(&pu)));
        prop_assert!(dn1 <= 10.0 * CG_TOL * dn0, "CG box divergence {dn1:e} vs {dn0:e}");
    }
}

// Conservation sums.
proptest! {
    #![proptest_config(config(48))]

    /// Periodic and closed domains: the divergence of an admissible velocity sums to 0 and so
    /// does the Laplacian (periodic, Neumann); flux-form advection conserves momentum on a
    /// periodic grid and, for a discretely divergence-free velocity, kinetic energy; implicit
    /// diffusion keeps the mean with periodic/Neumann conditions. 1e-12 relative to the sum of
    /// absolute values: the sums telescope exactly, so only round-off (~cells * 1e-16) remains.
    #[test]
    fn conservation_sums(
        nx in 2usize..13, ny in 2usize..13, lx in 0.3f64..3.0, ly in 0.3f64..3.0,
        k in 0usize..4, nu_dt in 1e-3f64..10.0, s in any::<u64>(),
    ) {
        let g = Grid::new(nx, ny, lx, ly).unwrap();
        let rel = |t: &Tensor| sum(t).abs() / t.abs().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
        let bc = linear_velocity_bc(k);
        let u = MacField::new(zero_fixed_faces(&randn(&[1, 2, ny, nx], s), &bc), g, bc).unwrap();
        let d = fd::divergence(&u).unwrap().into_values();
        prop_assert!(rel(&d) < 1e-12, "sum of divergence {bc:?}: {:e}", rel(&d));

        let sbc = if k % 2 == 0 { ScalarBoundaries::periodic() } else { ScalarBoundaries::neumann() };
        let c = randn(&[1, 1, ny, nx], s ^ 1);
        let lap = fd::laplacian(&CenteredField::new(c.clone(), g, sbc).unwrap()).unwrap().into_values();
        prop_assert!(rel(&lap) < 1e-12, "sum of Laplacian {sbc:?}: {:e}", rel(&lap));

        let cf = CenteredField::new(c.clone(), g, sbc).unwrap();
        let c1 = diffuse::implicit(&cf, nu_dt, 1.0).unwrap().into_values();
        let dm = (sum(&c1) - sum(&c)).abs() / c.abs().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
        prop_assert!(dm < 1e-12, "implicit diffusion changes the sum by {dm:e} ({sbc:?})");

        let per = Boundaries::periodic();
        let up = MacField::new(randn(&[1, 2, ny, nx], s ^ 2), g, per).unwrap();
        let n = advect::flux_form(&up).unwrap().into_values();
        for comp in 0..2 {
            let nc = n.narrow(1, comp, 1).unwrap();
            prop_assert!(rel(&nc) < 1e-12, "flux form momentum {comp}: {:e}", rel(&nc));
        }
        let solver = PressureSolver::new(g, &per).unwrap();
        let us = make_incompressible(&up, &solver).unwrap();
        let ns = advect::flux_form(&us).unwrap().into_values();
        let e = dot(us.values(), &ns).abs() / (norm(us.values()) * norm(&ns));
        prop_assert!(e < 1e-10, "flux form energy <u, N(u)> / (|u||N(u)|) = {e:e}");
    }

    /// Periodic scalar laws (`ScalarLaw::rhs`): the tendency sums to 0 (conservative fluxes);
    /// without viscosity `<c, rhs(c)> = 0` (the skew-symmetric Burgers flux and the central
    /// linear flux conserve `sum c^2`).
    #[test]
    fn scalar_law_conserves_sum_and_energy(
        nx in 2usize..20, ny in 1usize..8, dx in 0.05f64..1.0, dy in 0.05f64..1.0,
        a in prop::array::uniform2(-2.0f64..2.0), b in prop::array::uniform2(-2.0f64..2.0),
        nu in 0.0f64..0.5, s in any::<u64>(),
    ) {
        let c = randn(&[2, 1, ny, nx], s);
        let rhs = |nu: f64| ScalarLaw { dx, dy, velocity: a, burgers: b, nu }.rhs(&c).unwrap();
        let r = rhs(nu);
        let abs_sum = r.abs().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
        prop_assert!(sum(&r).abs() < 1e-12 * abs_sum.max(f64::MIN_POSITIVE), "sum of rhs {:e}", sum(&r));
        let r0 = rhs(0.0);
        let e = dot(&c, &r0).abs() / (norm(&c) * norm(&r0)).max(f64::MIN_POSITIVE);
        prop_assert!(e < 1e-12, "energy <c, rhs(c)> relative {e:e}");
    }
}
