//! Cart-pole physics against a plain `f64` transcription of the equations, its BPTT gradient
//! against finite differences, and a tiny training run in every mode.

use candle_core::{Device, Tensor};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{gradients, GradientMode};
use pbdl_optim::cartpole::{train, CartPole, CartPoleConfig, Controller};

mod common;

/// The equations of the module docs, one sample, written out in scalars.
fn step_ref(p: &CartPole, s: &[f64], f: f64) -> Vec<f64> {
    let nc = p.poles;
    let (m, big_m, l, g, dt) = (p.pole_mass, p.total_mass, p.half_length, p.gravity, p.dt);
    let (x, xd) = (s[0], s[1 + nc]);
    let mut thdd = vec![0.0; nc];
    let mut sum = 0.0;
    for i in 0..nc {
        let (th, thd) = (s[1 + i], s[2 + nc + i]);
        let a = (f + m * l * th.sin() * thd * thd) / big_m;
        thdd[i] = (g * th.sin() - th.cos() * a) / (l * (4.0 / 3.0 - m * th.cos() * th.cos() / big_m));
        sum += th.sin() * thd * thd - thdd[i] * th.cos();
    }
    let xdd = (f + m * l * sum) / big_m;
    let xd_new = xd + dt * xdd;
    let mut out = vec![x + dt * xd_new];
    let thd_new: Vec<f64> = (0..nc).map(|i| s[2 + nc + i] + dt * thdd[i]).collect();
    out.extend((0..nc).map(|i| s[1 + i] + dt * thd_new[i]));
    out.push(xd_new);
    out.extend(thd_new);
    out
}

#[test]
fn step_matches_scalar_equations() {
    for poles in 1..=4 {
        let p = CartPole::new(poles);
        let s = p.initial_states(5, 3).unwrap();
        let f = Tensor::new(&[[0.5f64], [-2.0], [0.0], [3.0], [-0.1]], &Device::Cpu).unwrap();
        let next = p.step(&s, &f).unwrap().to_vec2::<f64>().unwrap();
        let (sv, fv) = (s.to_vec2::<f64>().unwrap(), f.to_vec2::<f64>().unwrap());
        for b in 0..5 {
            let r = step_ref(&p, &sv[b], fv[b][0]);
            for (a, e) in next[b].iter().zip(&r) {
                assert!((a - e).abs() <= 1e-13 * (1.0 + e.abs()), "poles {poles}: {a} vs {e}");
            }
        }
    }
}

#[test]
fn start_states_hang_down_and_loss_is_near_two() {
    let p = CartPole::new(3);
    let s = p.initial_states(64, 1).unwrap();
    let loss = p.loss(&s).unwrap().to_scalar::<f64>().unwrap();
    // cos(pi +- pi/6) is in [-1, -0.866].
    assert!((1.866..=2.0).contains(&loss), "{loss}");
}

/// Regular BPTT (mode F) through 20 steps against central differences of the rollout loss.
#[test]
fn mode_f_gradient_matches_finite_differences() {
    let mut p = CartPole::new(2);
    p.steps = 20;
    let net = Controller::with_zero_last_layer(p.state_dim(), 6, 1, 5).unwrap();
    // Give the zero-initialised last layer values so that every parameter matters.
    let w = Tensor::new(&[[0.7f64], [-0.4], [1.1], [0.3], [-0.9], [0.5]], &Device::Cpu).unwrap();
    net.vars()[4].set(&w).unwrap();
    let s0 = p.initial_states(4, 2).unwrap();
    let fwd = |s: &Tensor| net.forward(s);
    let phys = |s: &Tensor, u: &Tensor| p.step(s, u);
    let loss = |t: &[Tensor]| p.loss(t.last().unwrap());
    let out = gradients(GradientMode::F, net.vars(), &s0, p.steps, &fwd, &phys, &loss, &ClipConfig::None).unwrap();
    let rollout_loss = || -> f64 {
        let mut s = s0.clone();
        for _ in 0..p.steps {
            s = p.step(&s, &net.forward(&s).unwrap()).unwrap();
        }
        p.loss(&s).unwrap().to_scalar::<f64>().unwrap()
    };
    let entries = [(0, 3), (2, 7), (4, 2), (5, 0)];
    common::check_against_central_differences(net.vars(), &out.grads, &entries, rollout_loss);
}

#[test]
fn tiny_training_runs_in_every_mode() {
    for mode in [GradientMode::F, GradientMode::P, GradientMode::S, GradientMode::C] {
        let mut cfg = CartPoleConfig::new(2, mode, 3);
        cfg.physics.steps = 10;
        cfg.width = 8;
        cfg.train = 16;
        cfg.test = 16;
        cfg.eval_every = 1;
        let run = train(&cfg).unwrap();
        common::check_tiny_run(&run, mode, |l| l.is_finite() && (0.0..=2.0).contains(&l));
    }
}
