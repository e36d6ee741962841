//! Exact Jacobians of the physics and of the composed network + physics against central
//! finite differences in f64.

use pbdl_optim::hig::composed_jacobian;
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Oscillators, Physics, Poisson8};
use rand::Rng;

/// Max |J - J_fd| / max |J| for the control Jacobian of `physics` at (x, u).
fn physics_fd_error(physics: &dyn Physics, x: &[f64], u: &[f64]) -> f64 {
    let (ny, nu) = (physics.output_dim(), physics.control_dim());
    let mut y = vec![0.0; ny];
    let mut jac = vec![0.0; ny * nu];
    physics.jacobian(x, u, &mut y, &mut jac).unwrap();
    let mut y_check = vec![0.0; ny];
    physics.forward(x, u, &mut y_check).unwrap();
    assert_eq!(y, y_check, "jacobian() and forward() must give the same outcome");
    let h = 1e-6;
    let (mut up, mut dn) = (vec![0.0; ny], vec![0.0; ny]);
    let mut worst = 0.0f64;
    let mut uu = u.to_vec();
    for k in 0..nu {
        uu[k] = u[k] + h;
        physics.forward(x, &uu, &mut up).unwrap();
        uu[k] = u[k] - h;
        physics.forward(x, &uu, &mut dn).unwrap();
        uu[k] = u[k];
        for i in 0..ny {
            worst = worst.max((jac[i * nu + k] - (up[i] - dn[i]) / (2.0 * h)).abs());
        }
    }
    worst / jac.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

fn random(n: usize, lo: f64, hi: f64, seed: u64) -> Vec<f64> {
    let mut rng = pbdl_core::seed::rng(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

#[test]
fn linear_chain_jacobian_matches_finite_differences() {
    let p = Oscillators::linear_chain();
    let err = physics_fd_error(&p, &random(4, 0.0, 1.0, 1), &random(24, -0.5, 0.5, 2));
    assert!(err < 1e-6, "rel {err:e}");
}

#[test]
fn nonlinear_oscillators_jacobian_matches_finite_differences() {
    let p = Oscillators::nonlinear();
    let err = physics_fd_error(&p, &random(4, 0.0, 1.0, 3), &random(96, -0.3, 0.3, 4));
    assert!(err < 1e-6, "rel {err:e}");
}

#[test]
fn poisson_jacobian_matches_finite_differences() {
    let err = physics_fd_error(&Poisson8, &[], &random(64, -1.0, 1.0, 5));
    assert!(err < 1e-6, "rel {err:e}");
}

/// The linear chain's RK4 agrees with the exact solution of the linear ODE to RK4 accuracy:
/// halving dt (same control held over two half steps) shrinks the difference ~16x.
#[test]
fn linear_chain_rk4_is_fourth_order() {
    let x0 = [0.3, 0.7, 0.1, 0.5];
    let coarse = |dt: f64, steps: usize| {
        let mut p = Oscillators::linear_chain();
        p.dt = dt;
        p.steps = steps;
        let mut y = vec![0.0; 4];
        p.forward(&x0, &vec![0.0; steps], &mut y).unwrap();
        y
    };
    let y1 = coarse(0.5, 24);
    let y2 = coarse(0.25, 48);
    let y4 = coarse(0.125, 96);
    let d1: f64 = y1.iter().zip(&y2).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let d2: f64 = y2.iter().zip(&y4).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let order = (d1 / d2).log2();
    assert!((order - 4.0).abs() < 0.3, "observed order {order}");
}

/// The composed Jacobian (exact network rows times physics) against finite differences of the
/// whole map theta -> y, for tanh and ReLU networks on the nonlinear oscillators.
#[test]
fn composed_jacobian_matches_finite_differences() {
    let physics = Oscillators::nonlinear();
    let data = Dataset::return_to_start(2, 4, 9);
    for act in [Activation::Tanh, Activation::Relu] {
        let mut net = Mlp::new(&[4, 8, 8, 96], act, 10).unwrap();
        // Small weights keep the controls moderate.
        net.params_mut().iter_mut().for_each(|p| *p *= 0.3);
        let (j, _) = composed_jacobian(&net, &physics, data.all()).unwrap();
        let p = net.n_params();
        let rows = 2 * 4;
        let theta = net.params().to_vec();
        let h = 1e-6;
        let mut worst = 0.0f64;
        let scale = j.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for c in (0..p).step_by(7) {
            let mut t = theta.clone();
            t[c] += h;
            net.set_params(&t).unwrap();
            let (_, up) = composed_jacobian(&net, &physics, data.all()).unwrap();
            t[c] -= 2.0 * h;
            net.set_params(&t).unwrap();
            let (_, dn) = composed_jacobian(&net, &physics, data.all()).unwrap();
            for r in 0..rows {
                worst = worst.max((j[r * p + c] - (up[r] - dn[r]) / (2.0 * h)).abs());
            }
        }
        net.set_params(&theta).unwrap();
        assert!(worst / scale < 1e-6, "{act:?}: rel {:e}", worst / scale);
    }
}
