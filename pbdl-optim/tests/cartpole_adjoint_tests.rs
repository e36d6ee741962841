//! The hand-written adjoint cart-pole path (`cartpole::adjoint`) against the candle path:
//! gradients of every mode, clipping, Adam and whole short training runs; its adjoint against
//! central differences.

use candle_core::{DType, Device, Tensor};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{gradients, GradientMode};
use pbdl_optim::cartpole::adjoint::{self, AdjointBptt, AdjointController};
use pbdl_optim::cartpole::{train, CartPole, CartPoleConfig, Controller};

const MODES: [GradientMode; 4] = [GradientMode::F, GradientMode::P, GradientMode::S, GradientMode::C];

/// A controller with every weight and bias random (Glorot weights, uniform biases).
fn random_controller(inputs: usize, width: usize, seed: u64) -> Controller {
    let net = Controller::new(inputs, width, 1, seed).unwrap();
    for (k, v) in net.vars().iter().enumerate().filter(|(k, _)| k % 2 == 1) {
        let shape = v.as_tensor().shape().clone();
        v.set(&pbdl_core::seed::rand_uniform(shape, -0.3, 0.3, DType::F64, &Device::Cpu, seed + k as u64).unwrap())
            .unwrap();
    }
    net
}

/// Random states `[n, d]`: every component uniform in `[-2, 2]`.
fn random_states(p: &CartPole, n: usize, seed: u64) -> Tensor {
    pbdl_core::seed::rand_uniform((n, p.state_dim()), -2.0, 2.0, DType::F64, &Device::Cpu, seed).unwrap()
}

/// The candle path's gradient in the flat layout of `AdjointController::params`.
fn candle_grads(
    p: &CartPole,
    net: &Controller,
    s0: &Tensor,
    mode: GradientMode,
    clip: &ClipConfig,
) -> (Vec<f64>, f64, f64, Option<f64>) {
    let fwd = |s: &Tensor| net.forward(s);
    let phys = |s: &Tensor, u: &Tensor| p.step(s, u);
    let loss = |t: &[Tensor]| p.loss(t.last().unwrap());
    let out = gradients(mode, net.vars(), s0, p.steps, &fwd, &phys, &loss, clip).unwrap();
    let mut flat = Vec::new();
    for v in net.vars() {
        flat.extend(out.grads.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap());
    }
    (flat, out.loss, out.norm_before_clip, out.agreement)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Largest entry difference relative to the largest entry of `b`.
fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let d = a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    d / max_abs(b).max(f64::MIN_POSITIVE)
}

fn compare(p: &CartPole, width: usize, batch: usize, seed: u64, clip: &ClipConfig) -> f64 {
    let net = random_controller(p.state_dim(), width, seed);
    let s0 = random_states(p, batch, seed + 100);
    let adjoint_net = AdjointController::from_dense(&net).unwrap();
    let s0v = s0.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let mut bptt = AdjointBptt::new(p, width, batch);
    let mut worst = 0.0f64;
    for mode in MODES {
        let (g, loss, norm, agree) = candle_grads(p, &net, &s0, mode, clip);
        let info = bptt.gradients(&adjoint_net, &s0v, mode, clip).unwrap();
        let r = rel_diff(bptt.grad(), &g);
        let ctx = format!("poles {}, {mode:?}, {clip:?}", p.poles);
        assert!(max_abs(&g) > 0.0, "{ctx}: zero gradient tests nothing");
        assert!(r <= 1e-10, "{ctx}: gradient differs by {r:e} (relative)");
        assert!((info.loss - loss).abs() <= 1e-13, "{ctx}: loss {} vs {loss}", info.loss);
        assert!(
            (info.norm_before_clip - norm).abs() <= 1e-10 * norm,
            "{ctx}: norm {} vs {norm}",
            info.norm_before_clip
        );
        assert_eq!(info.agreement, agree, "{ctx}");
        worst = worst.max(r);
    }
    worst
}

#[test]
fn gradients_of_every_mode_match_candle_for_1_to_4_poles() {
    for poles in 1..=4 {
        let mut p = CartPole::new(poles);
        p.steps = 40;
        let worst = compare(&p, 24, 3, 10 + poles as u64, &ClipConfig::None);
        println!("poles {poles}: worst relative gradient difference {worst:.2e}");
    }
}

#[test]
fn gradients_match_candle_at_paper_size_with_clipping() {
    // The paper's sizes (width 100, b = 8, 100 steps) with both clipping kinds.
    let p = CartPole::new(3);
    for clip in [ClipConfig::Value { max_value: 1e-3 }, ClipConfig::Norm { max_norm: 1e-3 }] {
        let worst = compare(&p, 100, 8, 7, &clip);
        println!("{clip:?}: worst relative gradient difference {worst:.2e}");
    }
}

/// Mode F against central differences of the adjoint path's rollout loss.
#[test]
fn mode_f_gradient_matches_finite_differences() {
    let mut p = CartPole::new(3);
    p.steps = 30;
    let width = 12;
    let mut net = AdjointController::from_dense(&random_controller(p.state_dim(), width, 3)).unwrap();
    let s0 = random_states(&p, 4, 4).flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let mut bptt = AdjointBptt::new(&p, width, 4);
    bptt.gradients(&net, &s0, GradientMode::F, &ClipConfig::None).unwrap();
    let g = bptt.grad().to_vec();
    let o = net.offsets();
    // Entries in every block: w0, b0, w1, b1, w2, b2.
    for idx in [o[0] + 5, o[1] + 2, o[2] + 17, o[3] + 9, o[4] + 3, o[5]] {
        let base = net.params()[idx];
        let h = 1e-6;
        let mut at = |v: f64| {
            net.params_mut()[idx] = v;
            adjoint::evaluate(&p, &net, &s0).unwrap()
        };
        let fd = (at(base + h) - at(base - h)) / (2.0 * h);
        at(base);
        assert!((g[idx] - fd).abs() <= 1e-6 * (1e-3 + fd.abs()), "param {idx}: {} vs fd {fd}", g[idx]);
    }
}

/// The adjoint of one physics step against central differences, all inputs and the force.
#[test]
fn step_adjoint_matches_finite_differences() {
    for poles in 1..=4 {
        let p = CartPole::new(poles);
        let d = p.state_dim();
        let s = random_states(&p, 1, 20 + poles as u64).flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let w = random_states(&p, 1, 40 + poles as u64).flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let f = 0.7;
        let mut a_in = vec![0.0; d];
        let af = adjoint::step_adjoint(&p, &s, f, &w, &mut a_in);
        let obj = |s: &[f64], f: f64| {
            let mut out = vec![0.0; d];
            adjoint::step(&p, s, f, &mut out);
            out.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>()
        };
        let h = 1e-6;
        for k in 0..=d {
            let fd = if k < d {
                let (mut sp, mut sm) = (s.clone(), s.clone());
                sp[k] += h;
                sm[k] -= h;
                (obj(&sp, f) - obj(&sm, f)) / (2.0 * h)
            } else {
                (obj(&s, f + h) - obj(&s, f - h)) / (2.0 * h)
            };
            let a = if k < d { a_in[k] } else { af };
            assert!((a - fd).abs() <= 1e-8 * (1.0 + fd.abs()), "poles {poles}, input {k}: {a} vs fd {fd}");
        }
    }
}

/// Five Adam steps of both paths from the same start: the same test-loss curve.
#[test]
fn short_training_runs_match_candle() {
    for (mode, clip) in [
        (GradientMode::F, ClipConfig::None),
        (GradientMode::P, ClipConfig::Value { max_value: 1.0 }),
        (GradientMode::C, ClipConfig::Norm { max_norm: 1.0 }),
    ] {
        let mut cfg = CartPoleConfig::new(2, mode, 5);
        cfg.clip = clip;
        cfg.test = 16;
        cfg.eval_every = 1;
        let slow = train(&cfg).unwrap();
        let quick = adjoint::train(&cfg).unwrap();
        assert_eq!(slow.steps, quick.steps);
        let diff = slow.test_loss.iter().zip(&quick.test_loss).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        println!("{mode:?} {clip:?}: losses {:?}, max difference {diff:.1e}", quick.test_loss);
        assert!(diff <= 1e-9, "{mode:?}: {:?} vs {:?}", slow.test_loss, quick.test_loss);
        // Training moved the loss, so the comparison saw the updates.
        assert!((quick.test_loss[5] - quick.test_loss[0]).abs() > 1e-6, "{:?}", quick.test_loss);
        match (slow.agreement, quick.agreement) {
            (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-12, "agreement {a} vs {b}"),
            (a, b) => assert_eq!(a, b),
        }
    }
}

#[test]
fn bad_input_is_a_typed_error() {
    let p = CartPole::new(2);
    let net = AdjointController::with_zero_last_layer(p.state_dim(), 8, 0).unwrap();
    let mut bptt = AdjointBptt::new(&p, 8, 2);
    let err = bptt.gradients(&net, &[0.0; 5], GradientMode::F, &ClipConfig::None).unwrap_err();
    assert!(err.to_string().contains("s0 length"), "{err}");
    let err = bptt.gradients(&net, &[0.0; 12], GradientMode::F, &ClipConfig::Norm { max_norm: -1.0 }).unwrap_err();
    assert!(err.to_string().contains("max_norm"), "{err}");
    let wide = AdjointController::with_zero_last_layer(p.state_dim(), 9, 0).unwrap();
    let err = bptt.gradients(&wide, &[0.0; 12], GradientMode::F, &ClipConfig::None).unwrap_err();
    assert!(err.to_string().contains("width"), "{err}");
}
