//! Pins the stabilized-BPTT schedule loop (`bptt::train`, the cart-pole candle and adjoint
//! paths) to exact `f64` bits: the evaluation steps, every test loss and the mean sign
//! agreement of short runs. The values were recorded on the c5f1131-equivalent code (the loop
//! before it ran on `pbdl_core::train::TrainLoop`); a port of the loop must reproduce them.
//! Run with `--nocapture` to print the bits.

use candle_core::{Device, Tensor, Var};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{train, BpttRun, GradientMode, Rollout, TrainSchedule};
use pbdl_optim::cartpole::{self, adjoint, CartPoleConfig};

/// `(steps, test-loss bits, agreement bits)` of a run, printed for recording.
fn fingerprint(what: &str, run: &BpttRun) -> (Vec<usize>, Vec<u64>, Option<u64>) {
    let bits: Vec<u64> = run.test_loss.iter().map(|l| l.to_bits()).collect();
    let agreement = run.agreement.map(f64::to_bits);
    println!("{what}: steps {:?}, test loss {:?}", run.steps, run.test_loss);
    let hex: Vec<String> = bits.iter().map(|b| format!("{b:#018x}")).collect();
    println!("{what}: bits [{}], agreement {:?}", hex.join(", "), agreement.map(|a| format!("{a:#018x}")));
    assert!(run.seconds >= 0.0 && run.seconds.is_finite());
    (run.steps.clone(), bits, agreement)
}

/// Two scalar systems `s' = a s + u`, `u = w s` (per component), loss `sum s_N^2`, trained on
/// 5 episodes in batches of 2 (cycled: 2 batches), 7 Adam steps evaluated at 0, 3, 6, 7.
fn linear_toy(mode: GradientMode, clip: ClipConfig) -> BpttRun {
    let dev = Device::Cpu;
    let w = Var::new(&[-1.5f64, 0.2], &dev).unwrap();
    let a = Tensor::new(&[0.9f64, 0.5], &dev).unwrap();
    let train_eps = Tensor::new(&[[1.0f64, 0.8], [-0.5, 0.3], [0.7, -1.1], [0.2, 0.4], [-0.9, -0.6]], &dev).unwrap();
    let test_eps = Tensor::new(&[[0.6f64, -0.2], [-1.0, 0.9], [0.3, 0.5]], &dev).unwrap();
    let net = |s: &Tensor| s.broadcast_mul(w.as_tensor());
    let physics = |s: &Tensor, u: &Tensor| s.broadcast_mul(&a)? + u;
    let loss = |traj: &[Tensor]| traj.last().unwrap().sqr()?.sum_all();
    let rollout = Rollout { steps: 4, net: &net, physics: &physics, loss: &loss };
    let schedule = TrainSchedule { mode, clip, lr: 0.05, batch: 2, iterations: 7, eval_every: 3 };
    let evaluate = || {
        let mut s = test_eps.clone();
        for _ in 0..4 {
            s = physics(&s, &net(&s)?)?;
        }
        Ok(s.sqr()?.sum_all()?.to_scalar::<f64>()?)
    };
    train(std::slice::from_ref(&w), &train_eps, &rollout, &schedule, evaluate).unwrap()
}

/// A small cart-pole configuration: 2 poles, 100-step episodes, width 8, 16 + 16 episodes in
/// batches of 4, 5 Adam steps evaluated every 2 (and after the last).
fn small_cartpole(mode: GradientMode, clip: ClipConfig) -> CartPoleConfig {
    let mut cfg = CartPoleConfig::new(2, mode, 5);
    cfg.physics.steps = 100;
    cfg.width = 8;
    cfg.train = 16;
    cfg.test = 16;
    cfg.batch = 4;
    cfg.lr = 1e-2;
    cfg.clip = clip;
    cfg.eval_every = 2;
    cfg
}

/// Test-loss bits of [`small_cartpole`] in mode C (both paths).
const CARTPOLE_C: [u64; 4] = [0x3fff6d97e8fdf73c, 0x3fff692659860ecc, 0x3fff638c01f58dc0, 0x3fff608b610f6c5f];

#[test]
fn linear_toy_runs_are_bit_identical() {
    let c = fingerprint("toy C", &linear_toy(GradientMode::C, ClipConfig::None));
    let f = fingerprint("toy F norm-clip", &linear_toy(GradientMode::F, ClipConfig::Norm { max_norm: 0.5 }));
    // Recorded on c5f1131-equivalent code.
    assert_eq!(c.0, [0, 3, 6, 7]);
    assert_eq!(c.1, [0x3fb677e9fe585778, 0x3fa1817eb861bc64, 0x3f9a5a68b89b46e6, 0x3f99af96abccb603]);
    assert_eq!(c.2, Some(0x3fe0000000000000), "component 0 disagrees, component 1 agrees: 0.5");
    assert_eq!(f.0, [0, 3, 6, 7]);
    assert_eq!(f.1, [0x3fb677e9fe585778, 0x3f8b10245cc50222, 0x3f60807f931d6f2a, 0x3f5248484fa3396e]);
    assert_eq!(f.2, None);
}

#[test]
fn cartpole_candle_runs_are_bit_identical() {
    let c = fingerprint("candle C", &cartpole::train(&small_cartpole(GradientMode::C, ClipConfig::None)).unwrap());
    let p = fingerprint(
        "candle P value-clip",
        &cartpole::train(&small_cartpole(GradientMode::P, ClipConfig::Value { max_value: 1.0 })).unwrap(),
    );
    // Recorded on c5f1131-equivalent code.
    assert_eq!(c.0, [0, 2, 4, 5]);
    assert_eq!(c.1, CARTPOLE_C);
    assert_eq!(c.2, Some(0x3ff0000000000000));
    assert_eq!(p.0, [0, 2, 4, 5]);
    assert_eq!(p.1, CARTPOLE_C, "mode P with value clipping at 1 took the same steps as C here");
    assert_eq!(p.2, None);
}

#[test]
fn cartpole_adjoint_runs_are_bit_identical() {
    let c = fingerprint("adjoint C", &adjoint::train(&small_cartpole(GradientMode::C, ClipConfig::None)).unwrap());
    let f = fingerprint(
        "adjoint F norm-clip",
        &adjoint::train(&small_cartpole(GradientMode::F, ClipConfig::Norm { max_norm: 1.0 })).unwrap(),
    );
    // Recorded on c5f1131-equivalent code: the adjoint path repeats the candle path's bits.
    assert_eq!(c.0, [0, 2, 4, 5]);
    assert_eq!(c.1, CARTPOLE_C);
    assert_eq!(c.2, Some(0x3ff0000000000000));
    assert_eq!(f.0, [0, 2, 4, 5]);
    assert_eq!(f.1, [0x3fff6d97e8fdf73c, 0x3fff6925f6166a6e, 0x3fff638a70369fa8, 0x3fff60883e0c2f7a]);
    assert_eq!(f.2, None);
    // The adjoint path's progress callback sees every evaluation, in order.
    let mut seen = Vec::new();
    let run =
        adjoint::train_with(&small_cartpole(GradientMode::C, ClipConfig::None), &mut |s, l| seen.push((s, l))).unwrap();
    assert_eq!(seen, run.steps.iter().copied().zip(run.test_loss.iter().copied()).collect::<Vec<_>>());
}
