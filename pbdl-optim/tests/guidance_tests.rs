//! Guidance by repulsion: the candle step against a plain `f64` transcription of the official
//! simulator's pair loops, the BPTT gradient against finite differences, and tiny training runs.

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed::rand_uniform;
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{gradients, GradientMode};
use pbdl_optim::guidance::{train, DenseController, Guidance, GuidanceConfig};

mod common;

/// One explicit Euler step of one sample, written as the official simulator loops: for each
/// object `i`, the pair force computed from `i`'s point of view is added to the *other* object.
fn step_ref(p: &Guidance, s: &[f64], u: &[f64]) -> Vec<f64> {
    let (nd, n) = (p.drivers, p.objects());
    let pos = |k: usize| [s[4 * k], s[4 * k + 1]];
    let vel = |k: usize| [s[4 * k + 2], s[4 * k + 3]];
    let dist = |r: [f64; 2]| p.epsilon + (r[0] * r[0] + r[1] * r[1]).sqrt();
    let mut acc = vec![[0.0f64; 2]; n];
    // Evading: relative = x_d - x_e, force on e = k_ev * (-1/d^2) * relative.
    for d in 0..nd {
        for e in nd..n {
            let r = [pos(d)[0] - pos(e)[0], pos(d)[1] - pos(e)[1]];
            let w = -p.evade / dist(r).powi(2);
            acc[e][0] += w * r[0];
            acc[e][1] += w * r[1];
        }
    }
    // Spreading: for driver i, relative = x_j - x_i, force on j = k_sp r / d^2.
    for i in 0..nd {
        for j in (0..nd).filter(|&j| j != i) {
            let r = [pos(j)[0] - pos(i)[0], pos(j)[1] - pos(i)[1]];
            let w = p.spreading / dist(r).powi(2);
            acc[j][0] += w * r[0];
            acc[j][1] += w * r[1];
        }
    }
    // Flocking: for evader i, relative = x_i - x_j, force on j = k_fl ((r_fl/d - 1)/d) relative.
    for i in nd..n {
        for j in (nd..n).filter(|&j| j != i) {
            let r = [pos(i)[0] - pos(j)[0], pos(i)[1] - pos(j)[1]];
            let d = dist(r);
            let w = p.flocking * (p.flock_distance / d - 1.0) / d;
            acc[j][0] += w * r[0];
            acc[j][1] += w * r[1];
        }
    }
    let centre = (nd..n).fold([0.0, 0.0], |c, e| [c[0] + pos(e)[0], c[1] + pos(e)[1]]);
    for (d, a) in acc.iter_mut().enumerate().take(nd) {
        let r = [pos(d)[0] - centre[0], pos(d)[1] - centre[1]];
        let perp = [-r[1], r[0]];
        let (cr, ct) = (u[2 * d], u[2 * d + 1]);
        a[0] += cr * r[0] + ct * perp[0] - p.driver_friction * vel(d)[0];
        a[1] += cr * r[1] + ct * perp[1] - p.driver_friction * vel(d)[1];
    }
    for (e, a) in acc.iter_mut().enumerate().skip(nd) {
        a[0] -= p.evader_friction * vel(e)[0];
        a[1] -= p.evader_friction * vel(e)[1];
    }
    let mut out = Vec::new();
    for (k, a) in acc.iter().enumerate() {
        let (x, v) = (pos(k), vel(k));
        out.extend([x[0] + p.dt * v[0], x[1] + p.dt * v[1], v[0] + p.dt * a[0], v[1] + p.dt * a[1]]);
    }
    out.extend_from_slice(u);
    out
}

/// Start states with random velocities too, so that every term of the step is exercised.
fn moving_states(p: &Guidance, n: usize) -> Tensor {
    let s = p.initial_states(n, 7).unwrap();
    let noise = rand_uniform((n, p.state_dim()), -1.0, 1.0, DType::F64, &Device::Cpu, 11).unwrap();
    (s + noise).unwrap()
}

#[test]
fn step_matches_scalar_equations() {
    for (nd, ne) in [(2, 4), (1, 1), (3, 5)] {
        let p = Guidance::new(nd, ne);
        let st = p.stepper().unwrap();
        let s = moving_states(&p, 5);
        let u = rand_uniform((5, p.control_dim()), -2.0, 2.0, DType::F64, &Device::Cpu, 3).unwrap();
        let next = st.step(&s, &u).unwrap().to_vec2::<f64>().unwrap();
        let (sv, uv) = (s.to_vec2::<f64>().unwrap(), u.to_vec2::<f64>().unwrap());
        let mut worst = 0.0f64;
        for b in 0..5 {
            let r = step_ref(&p, &sv[b], &uv[b]);
            assert_eq!(r.len(), next[b].len());
            for (a, e) in next[b].iter().zip(&r) {
                worst = worst.max((a - e).abs() / (1.0 + e.abs()));
            }
        }
        println!("{nd} drivers, {ne} evaders: max rel. deviation {worst:.2e}");
        assert!(worst <= 1e-13, "{nd}/{ne}: {worst}");
    }
}

#[test]
fn start_states_follow_the_paper() {
    let p = Guidance::default();
    let s = p.initial_states(200, 1).unwrap().to_vec2::<f64>().unwrap();
    for row in &s {
        for d in 0..2 {
            let r = (row[4 * d].powi(2) + row[4 * d + 1].powi(2)).sqrt();
            assert!((3.0..=4.0).contains(&r), "driver radius {r}");
        }
        let c = (2..6).fold([0.0, 0.0], |c, e| [c[0] + row[4 * e] / 4.0, c[1] + row[4 * e + 1] / 4.0]);
        let rc = (c[0] * c[0] + c[1] * c[1]).sqrt();
        // The mean of four offsets in [-0.5, 0.5] moves the centre by at most 0.5 per coordinate.
        assert!((1.0 - 0.71..=2.0 + 0.71).contains(&rc), "evader centre radius {rc}");
        assert!(row.iter().skip(2).step_by(4).take(6).all(|v| *v == 0.0), "velocities start at zero");
    }
}

#[test]
fn bad_settings_are_typed_errors() {
    let err = Guidance::new(0, 4).stepper().unwrap_err().to_string();
    assert!(err.contains("at least one driver"), "{err}");
    let p = Guidance { epsilon: 0.0, ..Default::default() };
    assert!(p.stepper().unwrap_err().to_string().contains("softening"));
    let mut cfg = GuidanceConfig::new(0.1, GradientMode::F, 1);
    cfg.batch = 0;
    assert!(train(&cfg).unwrap_err().to_string().contains("batch"));
}

/// Regular BPTT (mode F) through 6 steps, control cost included, against central differences.
#[test]
fn mode_f_gradient_matches_finite_differences() {
    let p = Guidance { steps: 6, ..Default::default() };
    let st = p.stepper().unwrap();
    let net = DenseController::new(p.phys_dim(), 8, p.control_dim(), 5).unwrap();
    let s0 = p.initial_states(3, 2).unwrap();
    let rc = 0.1;
    let pd = p.phys_dim();
    let fwd = |s: &Tensor| net.forward(&s.narrow(1, 0, pd)?);
    let phys = |s: &Tensor, u: &Tensor| st.step(s, u);
    let loss = |t: &[Tensor]| st.loss(t, rc);
    let out = gradients(GradientMode::F, net.vars(), &s0, p.steps, &fwd, &phys, &loss, &ClipConfig::None).unwrap();
    let rollout_loss = || -> f64 {
        let mut traj = vec![s0.clone()];
        for _ in 0..p.steps {
            let s = traj.last().unwrap();
            let next = st.step(s, &fwd(s).unwrap()).unwrap();
            traj.push(next);
        }
        st.loss(&traj, rc).unwrap().to_scalar::<f64>().unwrap()
    };
    let entries = [(0, 3), (0, 50), (1, 2), (2, 7), (4, 5), (5, 1)];
    let worst = common::check_against_central_differences(net.vars(), &out.grads, &entries, rollout_loss);
    println!("mode F vs central FD: worst relative error {worst:.2e}");
}

#[test]
fn tiny_training_runs_in_modes_f_p_c() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::C] {
        let mut cfg = GuidanceConfig::new(0.1, mode, 3);
        cfg.physics.steps = 8;
        cfg.width = 8;
        cfg.train = 16;
        cfg.test = 16;
        cfg.eval_every = 1;
        let run = train(&cfg).unwrap();
        common::check_tiny_run(&run, mode, |l| l.is_finite() && l >= 0.0);
    }
}

/// A shortened version of the bench run (2 epochs, rc 0.01), printing the final test losses.
#[test]
#[ignore = "training run: 3 modes x 64 Adam steps of 60-step rollouts; about a minute or two on 2 cores"]
fn short_training_prints_mode_losses() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::C] {
        let cfg = GuidanceConfig::new(0.01, mode, 64);
        let run = train(&cfg).unwrap();
        common::print_run(mode, &run, 64, 4, 1);
    }
}

/// The official runs' value-clipping variant (clip 1.0) for F and C at the two weights where
/// unclipped F beat C; prints the final test losses.
#[test]
#[ignore = "training run: 4 runs of 320 Adam steps; about 3-5 min on 2 cores"]
fn value_clipped_modes_print_losses() {
    for rc in [0.01, 0.001] {
        for mode in [GradientMode::F, GradientMode::C] {
            let mut cfg = GuidanceConfig::new(rc, mode, 320);
            cfg.clip = ClipConfig::Value { max_value: 1.0 };
            cfg.eval_every = 320;
            let run = train(&cfg).unwrap();
            println!("rc {rc} {mode:?} value-clip 1: test loss {:.4} -> {:.4}", run.test_loss[0], run.final_loss());
        }
    }
}
