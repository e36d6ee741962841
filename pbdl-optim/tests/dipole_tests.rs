//! The quantum dipole (Crank-Nicolson) against conservation, the analytic eigenstate phase and
//! finite differences; the infidelity loss gradient against finite differences; the HIG
//! right-hand side for a general loss against finite differences of the batch loss.

use pbdl_optim::hig::{composed_jacobian, evaluate_with_loss, HigConfig, HigTrainer, Loss};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Physics, QuantumDipole};
use pbdl_optim::Error;
use rand::Rng;

fn random(n: usize, lo: f64, hi: f64, seed: u64) -> Vec<f64> {
    let mut rng = pbdl_core::seed::rng(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Crank-Nicolson is a Cayley transform of a Hermitian matrix: unitary, so a random state keeps
/// its norm to round-off under a strong random field over the paper's 384 steps.
#[test]
fn crank_nicolson_preserves_the_norm() {
    let d = QuantumDipole::hig_paper();
    let mut x = random(28, -1.0, 1.0, 1);
    let n0 = norm(&x);
    x.iter_mut().for_each(|v| *v /= n0);
    let u = random(384, -20.0, 20.0, 2);
    let mut y = vec![0.0; 28];
    d.forward(&x, &u, &mut y).unwrap();
    let drift = (norm(&y) - 1.0).abs();
    eprintln!("norm drift after 384 steps: {drift:e}");
    assert!(drift < 1e-12, "norm drift {drift:e}");
    // The field did something (not a trivially identical state).
    assert!(y.iter().zip(&x).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) > 0.1);
}

/// Without field an eigenstate `phi_m` only turns its phase. Per step by exactly the Cayley
/// factor `(1 - i h E) / (1 + i h E)` (`h = dt/2`, `E` the discrete eigenvalue), to round-off;
/// against `exp(-i E T)` the phase error is `T E^3 dt^2 / 12` to leading order (second order),
/// checked at `T = 19.2` (the paper's horizon) with `E dt <= 0.14` so that the leading term rules.
#[test]
fn eigenstates_only_change_phase() {
    for (m, refine) in [(1, 1), (2, 4), (3, 8)] {
        let d = QuantumDipole::hig_paper();
        let phi = d.eigenstate(m).unwrap();
        let e = d.eigenvalue(m).unwrap();
        let phase_error = |dt: f64, steps: usize| {
            let d = QuantumDipole { dt, steps, ..QuantumDipole::hig_paper() };
            let mut y = vec![0.0; 28];
            d.forward(&phi, &vec![0.0; steps], &mut y).unwrap();
            // Exact discrete propagation: z^N phi.
            let h = 0.5 * dt;
            let angle = -2.0 * steps as f64 * (h * e).atan();
            let (c, s) = (angle.cos(), angle.sin());
            let err: f64 = y
                .chunks_exact(2)
                .zip(phi.chunks_exact(2))
                .map(|(yy, p)| (yy[0] - c * p[0]).abs().max((yy[1] - s * p[0]).abs()))
                .fold(0.0, f64::max);
            assert!(err < 1e-12, "m = {m}, dt = {dt}: state vs Cayley phase {err:e}");
            // Phase of <phi|y> against exp(-i E T).
            let re: f64 = y.chunks_exact(2).zip(phi.chunks_exact(2)).map(|(yy, p)| yy[0] * p[0]).sum();
            let im: f64 = y.chunks_exact(2).zip(phi.chunks_exact(2)).map(|(yy, p)| yy[1] * p[0]).sum();
            let t = dt * steps as f64;
            let diff = im.atan2(re) + e * t;
            (diff + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
        };
        let (dt, steps) = (0.05 / refine as f64, 384 * refine);
        let (p1, p2) = (phase_error(dt, steps), phase_error(0.5 * dt, 2 * steps));
        let predicted = 19.2 * e.powi(3) * dt * dt / 12.0;
        eprintln!("m = {m}, dt = {dt}: E = {e:.6}, phase error {p1:.4e} (predicted {predicted:.4e}), at dt/2 {p2:.4e}");
        // CN lags: the discrete phase 2 atan(hE) per step is smaller than E dt.
        assert!((p1 - predicted).abs() < 0.05 * predicted, "m = {m}: {p1:e} vs {predicted:e}");
        let order = (p1 / p2).log2();
        assert!((order - 2.0).abs() < 0.05, "m = {m}: observed order {order}");
    }
    // The discrete eigenvalues approach the continuum (pi m / L)^2 as the grid is refined.
    let fine = QuantumDipole { points: 255, ..QuantumDipole::hig_paper() };
    let e1 = fine.eigenvalue(1).unwrap();
    let exact = (std::f64::consts::PI / 2.0).powi(2);
    assert!((e1 - exact).abs() < 1e-4 * exact, "{e1} vs {exact}");
}

/// Max |J - J_fd| / max |J| of the control Jacobian.
fn fd_error(d: &QuantumDipole, x: &[f64], u: &[f64]) -> f64 {
    let (ny, nu) = (d.output_dim(), d.control_dim());
    let mut y = vec![0.0; ny];
    let mut jac = vec![0.0; ny * nu];
    d.jacobian(x, u, &mut y, &mut jac).unwrap();
    let mut y_check = vec![0.0; ny];
    d.forward(x, u, &mut y_check).unwrap();
    assert_eq!(y, y_check, "jacobian() and forward() must give the same outcome");
    let h = 1e-6;
    let (mut up, mut dn) = (vec![0.0; ny], vec![0.0; ny]);
    let mut uu = u.to_vec();
    let mut worst = 0.0f64;
    for k in 0..nu {
        uu[k] = u[k] + h;
        d.forward(x, &uu, &mut up).unwrap();
        uu[k] = u[k] - h;
        d.forward(x, &uu, &mut dn).unwrap();
        uu[k] = u[k];
        for i in 0..ny {
            worst = worst.max((jac[i * nu + k] - (up[i] - dn[i]) / (2.0 * h)).abs());
        }
    }
    worst / jac.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

#[test]
fn dipole_jacobian_matches_finite_differences() {
    let d = QuantumDipole::hig_paper();
    let x = d.eigenstate(1).unwrap();
    let u = random(384, -2.0, 2.0, 3);
    let err = fd_error(&d, &x, &u);
    eprintln!("dipole Jacobian vs central FD: rel {err:e}");
    assert!(err < 1e-6, "rel {err:e}");
}

/// The single-row adjoint (VJP) against the full Jacobian transposed times the cotangent.
#[test]
fn dipole_vjp_matches_jacobian_transpose() {
    let d = QuantumDipole::hig_paper();
    let x = d.eigenstate(1).unwrap();
    let u = random(384, -2.0, 2.0, 4);
    let cot = random(28, -1.0, 1.0, 5);
    let mut y = vec![0.0; 28];
    let mut jac = vec![0.0; 28 * 384];
    d.jacobian(&x, &u, &mut y, &mut jac).unwrap();
    let mut vjp = vec![0.0; 384];
    d.vjp(&x, &u, &cot, &mut vjp).unwrap();
    let direct: Vec<f64> = (0..384).map(|k| (0..28).map(|i| cot[i] * jac[i * 384 + k]).sum()).collect();
    let err = vjp.iter().zip(&direct).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) / norm(&direct);
    assert!(err < 1e-12, "rel {err:e}");
}

/// The paper's data: unit-norm targets in span{phi_2, phi_3}, orthogonal to the ground state,
/// so with zero control (the ground state only turns its phase) the infidelity is exactly 1.
#[test]
fn dataset_targets_are_unit_and_orthogonal_to_the_start() {
    let d = QuantumDipole::hig_paper();
    let data = d.dataset(64, 7).unwrap();
    let mut y = vec![0.0; 28];
    for s in 0..data.len {
        let b = data.batch(s, 1);
        assert!((norm(b.targets) - 1.0).abs() < 1e-12);
        assert_eq!(b.inputs, b.targets);
        d.forward(b.contexts, &vec![0.0; 384], &mut y).unwrap();
        let l = Loss::Infidelity.value(&y, b.targets).unwrap();
        assert!((l - 1.0).abs() < 1e-12, "sample {s}: {l}");
        // And a target is reached perfectly by itself.
        assert!(Loss::Infidelity.value(b.targets, b.targets).unwrap().abs() < 1e-12);
    }
}

/// Both losses' gradients against central differences.
#[test]
fn loss_gradients_match_finite_differences() {
    let y = random(28, -0.5, 0.5, 8);
    let t = random(28, -0.5, 0.5, 9);
    for loss in [Loss::SquaredError, Loss::Infidelity] {
        let mut g = vec![0.0; 28];
        let l0 = loss.value_and_gradient(&y, &t, &mut g).unwrap();
        assert_eq!(l0, loss.value(&y, &t).unwrap());
        let h = 1e-6;
        let mut yy = y.clone();
        let mut worst = 0.0f64;
        for k in 0..28 {
            yy[k] = y[k] + h;
            let up = loss.value(&yy, &t).unwrap();
            yy[k] = y[k] - h;
            let dn = loss.value(&yy, &t).unwrap();
            yy[k] = y[k];
            worst = worst.max((g[k] - (up - dn) / (2.0 * h)).abs());
        }
        let rel = worst / g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(rel < 1e-8, "{loss:?}: rel {rel:e}");
    }
    assert!(matches!(Loss::Infidelity.value(&[1.0; 3], &[1.0; 3]), Err(Error::ShapeMismatch { .. })));
}

/// The HIG right-hand side for the infidelity: `J^T g` (composed Jacobian, `g = d(L/b)/dy`)
/// equals finite differences of the mean batch loss in theta; a HIG step reports that loss.
#[test]
fn infidelity_gradient_through_network_and_physics_matches_finite_differences() {
    let d = QuantumDipole { steps: 48, ..QuantumDipole::hig_paper() };
    let data = d.dataset(4, 11).unwrap();
    let mut net = Mlp::new(&[28, 8, 48], Activation::Tanh, 12).unwrap();
    let (j, y) = composed_jacobian(&net, &d, data.all()).unwrap();
    let (rows, p) = (4 * 28, net.n_params());
    let mut g = vec![0.0; rows];
    let mut loss = 0.0;
    for s in 0..4 {
        let r = s * 28..(s + 1) * 28;
        loss += Loss::Infidelity.value_and_gradient(&y[r.clone()], &data.targets[r.clone()], &mut g[r]).unwrap();
    }
    g.iter_mut().for_each(|v| *v /= 4.0);
    loss /= 4.0;
    let jtg: Vec<f64> = (0..p).map(|c| (0..rows).map(|r| j[r * p + c] * g[r]).sum()).collect();
    let theta = net.params().to_vec();
    let h = 1e-6;
    let scale = jtg.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut worst = 0.0f64;
    for c in (0..p).step_by(5) {
        let mut t = theta.clone();
        t[c] += h;
        net.set_params(&t).unwrap();
        let up = evaluate_with_loss(&net, &d, Loss::Infidelity, &data).unwrap();
        t[c] -= 2.0 * h;
        net.set_params(&t).unwrap();
        let dn = evaluate_with_loss(&net, &d, Loss::Infidelity, &data).unwrap();
        worst = worst.max((jtg[c] - (up - dn) / (2.0 * h)).abs());
    }
    net.set_params(&theta).unwrap();
    assert!(worst / scale < 1e-6, "rel {:e}", worst / scale);

    let mut hig = HigTrainer::new(HigConfig::hig(0.5, 1e-5)).unwrap().with_loss(Loss::Infidelity);
    let info = hig.step(&mut net, &d, data.all()).unwrap();
    assert!((info.loss - loss).abs() < 1e-14, "{} vs {loss}", info.loss);
}

#[test]
fn bad_settings_are_typed_errors() {
    let d = QuantumDipole { dt: -0.1, ..QuantumDipole::hig_paper() };
    let mut y = vec![0.0; 28];
    let err = d.forward(&[0.0; 28], &[0.0; 384], &mut y).unwrap_err();
    assert!(matches!(err, Error::InvalidConfig { name: "dt", .. }), "{err}");
    let d = QuantumDipole::hig_paper();
    assert!(matches!(d.forward(&[0.0; 28], &[0.0; 10], &mut y), Err(Error::ShapeMismatch { .. })));
    assert!(matches!(d.eigenstate(0), Err(Error::ShapeMismatch { .. })));
    let mut u = vec![0.0; 384];
    u[3] = f64::NAN;
    assert!(matches!(d.forward(&[0.0; 28], &u, &mut y), Err(Error::NonFinite { .. })));
}
