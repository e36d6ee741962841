//! Implicit (backward Euler) diffusion: FD gradient checks (f64, <= 1e-6) for centred scalars
//! and MAC velocities, and the cross-method check explicit (RK4) = implicit = Fourier decay on
//! the heat mode `sin x sin 2y` (periodic [0, 2 pi]^2, kappa = 0.1, t = 1).

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::diffuse::{implicit, ImplicitDiffusion};
use pbdl_grid::stability::stable_time_step;
use pbdl_grid::time_stepping::projected_runge_kutta;
use pbdl_grid::{fd, Bc, Boundaries, ButcherTableau, CenteredField, Grid, MacField, ScalarBc, ScalarBoundaries};
use std::f64::consts::PI;

fn opts() -> GradCheckOptions {
    GradCheckOptions { max_probes: 64, ..Default::default() }
}

#[test]
fn implicit_diffusion_gradients_match_finite_differences() {
    let g = Grid::new(7, 6, 1.4, 1.0).unwrap();
    let sbcs = [
        ScalarBoundaries::periodic(),
        ScalarBoundaries {
            x_lo: ScalarBc::Dirichlet { value: 0.7 },
            x_hi: ScalarBc::Neumann,
            y_lo: ScalarBc::Periodic,
            y_hi: ScalarBc::Periodic,
        },
    ];
    for (k, bc) in sbcs.into_iter().enumerate() {
        let x = seed::randn((2, 2, 6, 7), 0.0, 1.0, DType::F64, &Device::Cpu, 400 + k as u64).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(implicit(&CenteredField::new(xs[0].clone(), g, bc)?, 0.3, 0.1)?.into_values())
        };
        let r = check_grad(f, &[x], &opts()).unwrap();
        eprintln!("implicit scalar {:?}: {:.2e}", bc.x_lo, r.max_rel_error);
        r.ensure(1e-6).unwrap();
    }
    let vbcs = [
        Boundaries::periodic(),
        Boundaries::lid_driven_cavity(1.0),
        Boundaries::new(Bc::Inflow { velocity: [1.0, 0.2] }, Bc::Outflow, Bc::FreeSlip, Bc::NoSlip).unwrap(),
    ];
    for (k, bc) in vbcs.into_iter().enumerate() {
        let x = seed::randn((2, 2, 6, 7), 0.0, 1.0, DType::F64, &Device::Cpu, 410 + k as u64).unwrap();
        let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
            Ok(implicit(&MacField::new(xs[0].clone(), g, bc)?, 0.3, 0.1)?.into_values())
        };
        let r = check_grad(f, &[x], &opts()).unwrap();
        eprintln!("implicit velocity {:?}: {:.2e}", bc.x_lo, r.max_rel_error);
        r.ensure(1e-6).unwrap();
    }
}

/// A wall-bounded velocity keeps its wall faces and relaxes towards rest: energy decays.
#[test]
fn implicit_diffusion_keeps_wall_faces_and_dissipates() {
    let g = Grid::square(24, 1.0).unwrap();
    let bc = Boundaries::lid_driven_cavity(0.0);
    let x = seed::randn((1, 2, 24, 24), 0.0, 1.0, DType::F64, &Device::Cpu, 9).unwrap();
    let u = MacField::new(x, g, bc).unwrap();
    let op = ImplicitDiffusion::new(&u, 0.1, 0.05).unwrap();
    let u1 = op.apply(&u).unwrap();
    let col = u1.u().unwrap().narrow(2, 23, 1).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
    let row = u1.v().unwrap().narrow(1, 23, 1).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
    assert_eq!((col, row), (0.0, 0.0));
    let e = |u: &MacField| u.values().sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
    assert!(e(&u1) < 0.5 * e(&u), "{} -> {}", e(&u), e(&u1));
}

const KAPPA: f64 = 0.1;

fn mode(x: f64, y: f64) -> Vec<f64> {
    vec![x.sin() * (2.0 * y).sin()]
}

fn rel(a: &Tensor, b: &Tensor) -> f64 {
    let num = (a - b).unwrap().sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
    (num / b.sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap()).sqrt()
}

/// Measured here at 64^2: explicit (RK4) vs discrete Fourier 2.0e-11; implicit vs discrete
/// Fourier 1.24e-3 / 6.21e-4 at 100 / 200 steps (order 1.00; `|lambda|^2 t dt / 2` = 6.2e-4);
/// explicit vs implicit 6.2e-4; vs the continuous decay: explicit 1.36e-3 (five-point stencil),
/// implicit 1.99e-3 (stencil + time error).
#[test]
fn explicit_implicit_and_fourier_diffusion_agree() {
    let n = 64;
    let grid = Grid::square(n, 2.0 * PI).unwrap();
    let bc = ScalarBoundaries::periodic();
    let t0 = CenteredField::from_fn(grid, bc, 1, DType::F64, mode).unwrap();
    // Explicit RK4 at half the stable step.
    let rk4 = ButcherTableau::rk4();
    let steps = (1.0 / (0.5 * stable_time_step(&grid, [0.0, 0.0], KAPPA, &rk4))).ceil() as usize;
    let dt = 1.0 / steps as f64;
    let mut te = t0.clone();
    for _ in 0..steps {
        let v = projected_runge_kutta(
            te.values(),
            dt,
            &rk4,
            |x| Ok(fd::laplacian(&te.with_values(x.clone())?)?.into_values().affine(KAPPA, 0.0)?),
            |x| Ok(x.clone()),
        )
        .unwrap();
        te = te.with_values(v).unwrap();
    }
    // Implicit backward Euler, 100 and 200 steps.
    let run_implicit = |m: usize| {
        let op = ImplicitDiffusion::new(&t0, KAPPA, 1.0 / m as f64).unwrap();
        let mut t = t0.clone();
        for _ in 0..m {
            t = op.apply(&t).unwrap();
        }
        t
    };
    let (ti100, ti200) = (run_implicit(100), run_implicit(200));
    // Fourier: the discrete eigenvalue of the five-point Laplacian, and the continuous one.
    let h = grid.dx();
    let lam_d = KAPPA * ((2.0 * h.cos() - 2.0) + (2.0 * (2.0 * h).cos() - 2.0)) / (h * h);
    let fd_exact = t0.values().affine(lam_d.exp(), 0.0).unwrap();
    let exact = t0.values().affine((-5.0 * KAPPA).exp(), 0.0).unwrap();
    let e_exp = rel(te.values(), &fd_exact);
    let (e100, e200) = (rel(ti100.values(), &fd_exact), rel(ti200.values(), &fd_exact));
    let e_ei = rel(ti200.values(), te.values());
    let (c_exp, c_imp) = (rel(te.values(), &exact), rel(ti200.values(), &exact));
    eprintln!(
        "64^2 heat mode: explicit vs Fourier(discrete) {e_exp:.2e}; implicit 100/200 steps vs Fourier {e100:.2e}/{e200:.2e} (order {:.2}); explicit vs implicit {e_ei:.2e}; vs continuous: explicit {c_exp:.2e}, implicit {c_imp:.2e}",
        (e100 / e200).log2()
    );
    assert!(e_exp < 1e-7, "explicit vs Fourier {e_exp:e}");
    assert!(e200 < 1e-3, "implicit vs Fourier {e200:e}");
    assert!(((e100 / e200).log2() - 1.0).abs() < 0.1, "backward Euler order {}", (e100 / e200).log2());
    assert!(e_ei < 1e-3, "explicit vs implicit {e_ei:e}");
    assert!(c_exp < 2e-3 && c_imp < 3e-3, "vs continuous {c_exp:e} {c_imp:e}");
}
