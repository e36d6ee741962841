//! Quantum control: the Crank-Nicolson custom op against the scalar CN equations, the analytic
//! phase of an eigenstate and unitarity; its adjoint and a BPTT rollout against finite
//! differences; tiny training runs.

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed::rand_uniform;
use pbdl_core::{check_grad, GradCheckOptions};
use pbdl_optim::bptt::{gradients, GradientMode};
use pbdl_optim::quantum_control::{cn_step, train, ConvController, QuantumControl, QuantumControlConfig};

mod common;

fn small() -> QuantumControl {
    QuantumControl { points: 12, length: 2.0, dt: 0.0625, steps: 4, target: 3 }
}

/// `A y - B psi` for one sample, written out from the equations in scalars.
fn cn_residual(p: &QuantumControl, psi: &[f64], y: &[f64], u: f64) -> f64 {
    let (n, dx, h) = (p.points, p.dx(), 0.5 * p.dt);
    // H v at point j, complex v as interleaved pairs.
    let hv = |v: &[f64], j: usize| -> (f64, f64) {
        let get =
            |k: isize| if k < 0 || k as usize >= n { (0.0, 0.0) } else { (v[2 * k as usize], v[2 * k as usize + 1]) };
        let (l, c, r) = (get(j as isize - 1), get(j as isize), get(j as isize + 1));
        let x = (j + 1) as f64 * dx;
        let lap = |a: f64, b: f64, cc: f64| (a - 2.0 * b + cc) / (dx * dx);
        (-lap(l.0, c.0, r.0) + u * x * c.0, -lap(l.1, c.1, r.1) + u * x * c.1)
    };
    let mut worst = 0.0f64;
    for j in 0..n {
        let (hy, hp) = (hv(y, j), hv(psi, j));
        // (I + i h H) y = (y_r - h (Hy)_i, y_i + h (Hy)_r); (I - i h H) psi likewise with signs flipped.
        let lhs = (y[2 * j] - h * hy.1, y[2 * j + 1] + h * hy.0);
        let rhs = (psi[2 * j] + h * hp.1, psi[2 * j + 1] - h * hp.0);
        worst = worst.max((lhs.0 - rhs.0).abs()).max((lhs.1 - rhs.1).abs());
    }
    worst
}

#[test]
fn step_solves_the_crank_nicolson_equations() {
    let p = QuantumControl::paper(3);
    let psi = p.initial_states(4, 1).unwrap();
    let u = Tensor::new(&[[0.0f64], [3.0], [-7.5], [20.0]], &Device::Cpu).unwrap();
    let y = p.step(&psi, &u).unwrap().to_vec2::<f64>().unwrap();
    let (pv, uv) = (psi.to_vec2::<f64>().unwrap(), u.to_vec2::<f64>().unwrap());
    let mut worst = 0.0f64;
    for b in 0..4 {
        worst = worst.max(cn_residual(&p, &pv[b], &y[b], uv[b][0]));
        // Unitary: the norm is kept.
        let (n0, n1): (f64, f64) = (pv[b].iter().map(|v| v * v).sum(), y[b].iter().map(|v| v * v).sum());
        assert!((n0 - 1.0).abs() < 1e-13 && (n1 - 1.0).abs() < 1e-13, "norms {n0} -> {n1}");
    }
    println!("CN residual max {worst:.2e}");
    assert!(worst < 1e-12, "{worst}");
}

/// At `u = 0` an eigenstate only turns its phase by `-2 atan(dt/2 lambda_m)`.
#[test]
fn eigenstate_turns_by_the_analytic_phase() {
    let p = QuantumControl::paper(4);
    for m in [1, 3, 5] {
        let phi = Tensor::from_vec(p.eigenstate(m).unwrap(), (1, p.state_dim()), &Device::Cpu).unwrap();
        let y = p.step(&phi, &Tensor::zeros((1, 1), DType::F64, &Device::Cpu).unwrap()).unwrap();
        let (yv, pv) = (y.to_vec2::<f64>().unwrap()[0].clone(), phi.to_vec2::<f64>().unwrap()[0].clone());
        let theta = -2.0 * (0.5 * p.dt * p.eigenvalue(m)).atan();
        let worst = (0..p.points)
            .map(|j| {
                let (c, s) = (theta.cos() * pv[2 * j], theta.sin() * pv[2 * j]);
                (yv[2 * j] - c).abs().max((yv[2 * j + 1] - s).abs())
            })
            .fold(0.0f64, f64::max);
        assert!(worst < 1e-14, "m = {m}: {worst}");
    }
}

#[test]
fn loss_of_orthogonal_states_is_one_per_step() {
    let p = QuantumControl::paper(3);
    let psi = p.initial_states(5, 2).unwrap();
    let target = p.target_tensor().unwrap();
    // Mixes of eigenstates 1 and 2 are orthogonal to 3: each step adds 1.
    let l = p.loss(&[psi.clone(), psi.clone(), psi.clone()], &target).unwrap().to_scalar::<f64>().unwrap();
    assert!((l - 2.0).abs() < 1e-13, "{l}");
    // ... and the target itself adds 0.
    let t = target.reshape((1, p.state_dim())).unwrap();
    let l = p.loss(&[t.clone(), t], &target).unwrap().to_scalar::<f64>().unwrap();
    assert!(l.abs() < 1e-13, "{l}");
}

#[test]
fn cn_adjoint_matches_finite_differences() {
    let p = small();
    let psi = p.initial_states(3, 4).unwrap();
    let u = rand_uniform((3, 1), -5.0, 5.0, DType::F64, &Device::Cpu, 9).unwrap();
    let (n, dx, dt) = (p.points, p.dx(), p.dt);
    let r = check_grad(|xs| cn_step(&xs[0], &xs[1], n, dx, dt), &[psi, u], &GradCheckOptions::default()).unwrap();
    println!("cn_step adjoint vs FD: {r:?}");
    r.ensure(1e-7).unwrap();
}

#[test]
fn bad_inputs_are_typed_errors() {
    let p = small();
    let psi = p.initial_states(2, 0).unwrap();
    let err = p.step(&psi, &Tensor::zeros((3, 1), DType::F64, &Device::Cpu).unwrap()).unwrap_err().to_string();
    assert!(err.contains("u must be [batch, 1]"), "{err}");
    let err = p.step(&psi.narrow(1, 0, 6).unwrap(), &Tensor::zeros((2, 1), DType::F64, &Device::Cpu).unwrap());
    assert!(err.unwrap_err().to_string().contains("psi must be"));
    let mut bad = small();
    bad.target = 0;
    assert!(bad.validate().unwrap_err().to_string().contains("target"));
    bad = small();
    bad.points = 4;
    assert!(bad.initial_states(1, 0).unwrap_err().to_string().contains("points"));
}

/// Regular BPTT (mode F) through 4 steps of network + CN step, against central differences.
#[test]
fn mode_f_gradient_matches_finite_differences() {
    let p = small();
    let net = ConvController::new(p.points, 4, 3).unwrap();
    let s0 = p.initial_states(3, 5).unwrap();
    let target = p.target_tensor().unwrap();
    let fwd = |s: &Tensor| net.forward(s);
    let phys = |s: &Tensor, u: &Tensor| p.step(s, u);
    let loss = |t: &[Tensor]| p.loss(t, &target);
    let clip = pbdl_core::train::ClipConfig::None;
    let out = gradients(GradientMode::F, net.vars(), &s0, p.steps, &fwd, &phys, &loss, &clip).unwrap();
    let rollout_loss = || -> f64 {
        let mut traj = vec![s0.clone()];
        for _ in 0..p.steps {
            let s = traj.last().unwrap();
            let next = p.step(s, &net.forward(s).unwrap()).unwrap();
            traj.push(next);
        }
        p.loss(&traj, &target).unwrap().to_scalar::<f64>().unwrap()
    };
    let entries = [(0, 0), (0, 17), (1, 2), (2, 11), (3, 0), (4, 3), (5, 0)];
    let worst = common::check_against_central_differences(net.vars(), &out.grads, &entries, rollout_loss);
    println!("mode F vs central FD: worst relative error {worst:.2e}");
}

#[test]
fn tiny_training_runs_in_modes_f_p_c() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::C] {
        let mut cfg = QuantumControlConfig::new(3, mode, 3);
        cfg.physics = small();
        cfg.width = 4;
        cfg.train = 16;
        cfg.test = 16;
        cfg.eval_every = 1;
        let run = train(&cfg).unwrap();
        let n = cfg.physics.steps as f64;
        common::check_tiny_run(&run, mode, |l| (0.0..=n).contains(&l));
    }
}

/// A shortened version of the bench run (target 3, 32 Adam steps = 1 epoch), printing losses.
#[test]
#[ignore = "training run: 3 modes x 32 Adam steps of 128-step rollouts; a minute or two on 2 cores"]
fn short_training_prints_mode_losses() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::C] {
        let cfg = QuantumControlConfig::new(3, mode, 32);
        let run = train(&cfg).unwrap();
        common::print_run(mode, &run, 32, 3, 0);
    }
}

/// The official runs' value-clipping variant (clip 1.0) for F and C on target 4, where
/// unclipped F beat C; prints the final test losses.
#[test]
#[ignore = "training run: 2 runs of 320 Adam steps of 128-step rollouts; about 3-6 min on 2 cores"]
fn value_clipped_modes_print_losses() {
    for mode in [GradientMode::F, GradientMode::C] {
        let mut cfg = QuantumControlConfig::new(4, mode, 320);
        cfg.clip = pbdl_core::train::ClipConfig::Value { max_value: 1.0 };
        cfg.eval_every = 320;
        let run = train(&cfg).unwrap();
        println!("target 4 {mode:?} value-clip 1: test loss {:.3} -> {:.3}", run.test_loss[0], run.final_loss());
    }
}
