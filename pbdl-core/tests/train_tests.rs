//! Tests of `pbdl_core::train`: optimisers on small problems with known minima, schedule values
//! at known steps, clipping invariants, log round trips and the divergence guard.

use candle_core::{backprop::GradStore, DType, Device, Tensor, Var};
use candle_nn::Optimizer;
use pbdl_core::train::*;
use pbdl_core::{seed, Error};

fn v1(t: &Tensor) -> Vec<f64> {
    t.flatten_all().unwrap().to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
}

/// A least-squares problem `min |A x - b|^2 / n` with a known exact solution `x_star`.
struct LeastSquares {
    a: Tensor,
    b: Tensor,
    x_star: Vec<f64>,
}

fn least_squares() -> LeastSquares {
    let dev = Device::Cpu;
    let a = seed::randn((20, 3), 0.0, 1.0, DType::F64, &dev, 1).unwrap();
    let x_star = vec![1.5, -2.0, 0.5];
    let b = a.matmul(&Tensor::new(x_star.as_slice(), &dev).unwrap().reshape((3, 1)).unwrap()).unwrap();
    LeastSquares { a, b, x_star }
}

impl LeastSquares {
    fn loss(&self, x: &Var) -> Tensor {
        self.a
            .matmul(&x.as_tensor().reshape((3, 1)).unwrap())
            .unwrap()
            .sub(&self.b)
            .unwrap()
            .sqr()
            .unwrap()
            .mean_all()
            .unwrap()
    }

    /// Runs `steps` optimiser steps from x = 0 and returns the max error to `x_star`.
    fn solve(&self, cfg: OptimizerConfig, steps: usize) -> f64 {
        let x = Var::zeros(3, DType::F64, &Device::Cpu).unwrap();
        let mut opt = cfg.build(vec![x.clone()]).unwrap();
        for _ in 0..steps {
            opt.backward_step(&self.loss(&x)).unwrap();
        }
        v1(x.as_tensor()).iter().zip(&self.x_star).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
    }
}

// ---------------------------------------------------------------- optimisers

#[test]
fn adam_solves_least_squares() {
    let p = least_squares();
    let err = p.solve(OptimizerConfig::Adam(AdamConfig { lr: 0.05, ..Default::default() }), 3000);
    assert!(err < 1e-6, "max error {err:e}");
}

#[test]
fn adamw_solves_least_squares_without_decay_and_decays_unused_weights() {
    let p = least_squares();
    let cfg = OptimizerConfig::AdamW(AdamWConfig { lr: 0.05, weight_decay: 0.0, ..Default::default() });
    let err = p.solve(cfg, 3000);
    assert!(err < 1e-6, "max error {err:e}");

    // With a zero gradient the update is the decoupled decay alone: theta *= (1 - lr * wd).
    let w = Var::new(&[2.0f64, -4.0], &Device::Cpu).unwrap();
    let mut opt = OptimizerConfig::AdamW(AdamWConfig { lr: 0.1, weight_decay: 0.5, ..Default::default() })
        .build(vec![w.clone()])
        .unwrap();
    for _ in 0..3 {
        // (`w * 0.0` would be an affine op with factor 0, which candle drops from the graph.)
        let zero_grad_loss = w.as_tensor().mul(&w.zeros_like().unwrap()).unwrap().sum_all().unwrap();
        opt.backward_step(&zero_grad_loss).unwrap();
    }
    let f = 0.95f64.powi(3);
    let got = v1(w.as_tensor());
    assert!((got[0] - 2.0 * f).abs() < 1e-15 && (got[1] + 4.0 * f).abs() < 1e-15, "{got:?}");
}

#[test]
fn sgd_with_and_without_momentum_solves_least_squares() {
    let p = least_squares();
    let plain = p.solve(OptimizerConfig::Sgd(SgdConfig { lr: 0.1, ..Default::default() }), 2000);
    assert!(plain < 1e-6, "plain SGD: {plain:e}");
    for nesterov in [false, true] {
        let cfg = OptimizerConfig::Sgd(SgdConfig { lr: 0.05, momentum: 0.9, nesterov, ..Default::default() });
        let err = p.solve(cfg, 1000);
        assert!(err < 1e-8, "momentum (nesterov {nesterov}): {err:e}");
    }
}

#[test]
fn momentum_beats_plain_sgd_on_an_ill_conditioned_quadratic() {
    // f = (x0^2 + 100 x1^2) / 2, same learning rate and step count.
    let run = |momentum: f64| {
        let x = Var::new(&[1.0f64, 1.0], &Device::Cpu).unwrap();
        let cfg = SgdConfig { lr: 0.009, momentum, ..Default::default() };
        let mut opt = Sgd::with_config(vec![x.clone()], cfg).unwrap();
        let scale = Tensor::new(&[0.5f64, 50.0], &Device::Cpu).unwrap();
        for _ in 0..200 {
            opt.backward_step(&x.as_tensor().sqr().unwrap().mul(&scale).unwrap().sum_all().unwrap()).unwrap();
        }
        v1(x.as_tensor()).iter().map(|v| v.abs()).fold(0.0, f64::max)
    };
    let (plain, heavy) = (run(0.0), run(0.9));
    assert!(heavy < 1e-4 && plain > 0.1, "plain {plain:e}, momentum {heavy:e}");
}

#[test]
fn learning_rate_can_be_set_each_step_through_the_optimizer_trait() {
    let x = Var::new(&[1.0f64], &Device::Cpu).unwrap();
    for cfg in [OptimizerConfig::default(), OptimizerConfig::Sgd(SgdConfig::default())] {
        let mut opt = cfg.build(vec![x.clone()]).unwrap();
        assert_eq!(opt.learning_rate(), cfg.lr());
        opt.set_learning_rate(0.0);
        let before = v1(x.as_tensor());
        opt.backward_step(&x.as_tensor().sqr().unwrap().sum_all().unwrap()).unwrap();
        assert_eq!(v1(x.as_tensor()), before, "lr 0 must not move the parameters");
    }
    // Also through the candle-nn constructor.
    let opt =
        <Optim as Optimizer>::new(vec![x], OptimizerConfig::Sgd(SgdConfig { lr: 0.3, ..Default::default() })).unwrap();
    assert_eq!(opt.learning_rate(), 0.3);
}

// ---------------------------------------------------------------- schedules

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-15 * b.abs().max(1.0)
}

#[test]
fn constant_and_step_decay_values() {
    let c = LrScheduler::new(ScheduleConfig::Constant, 0.01).unwrap();
    assert!([0, 1, 1_000_000].iter().all(|&s| c.lr(s) == 0.01));
    let s = LrScheduler::new(ScheduleConfig::StepDecay { step_size: 10, gamma: 0.5 }, 0.8).unwrap();
    for (step, lr) in [(0, 0.8), (9, 0.8), (10, 0.4), (19, 0.4), (20, 0.2), (35, 0.1)] {
        assert!(close(s.lr(step), lr), "step {step}: {} != {lr}", s.lr(step));
    }
}

#[test]
fn cosine_is_half_at_half_period_and_warms_up_linearly() {
    let s = LrScheduler::new(ScheduleConfig::Cosine { total_steps: 100, warmup_steps: 0, min_lr: 0.0 }, 2.0).unwrap();
    assert!(close(s.lr(0), 2.0));
    assert!(close(s.lr(50), 1.0), "{}", s.lr(50));
    assert!(close(s.lr(25), 1.0 + 2f64.sqrt() / 2.0), "{}", s.lr(25)); // (1 + cos(pi/4)) / 2 * 2
    assert_eq!(s.lr(100), 0.0);
    assert_eq!(s.lr(10_000), 0.0);
    assert!((1..100).all(|t| s.lr(t) < s.lr(t - 1)), "monotone decay");

    let w = LrScheduler::new(ScheduleConfig::Cosine { total_steps: 110, warmup_steps: 10, min_lr: 0.5 }, 2.0).unwrap();
    for step in 0..10 {
        assert!(close(w.lr(step), 2.0 * (step + 1) as f64 / 10.0), "warmup step {step}");
    }
    assert!(close(w.lr(10), 2.0));
    assert!(close(w.lr(60), 1.25), "{}", w.lr(60)); // half way between base and min_lr
    assert_eq!(w.lr(110), 0.5);
}

#[test]
fn plateau_reduces_after_patience() {
    let cfg = ScheduleConfig::ReduceOnPlateau(PlateauConfig {
        patience: 2,
        factor: 0.5,
        threshold: 0.01,
        min_lr: 0.2,
        cooldown: 0,
    });
    let mut s = LrScheduler::new(cfg, 1.0).unwrap();
    assert!(!s.observe(1.0)); // best = 1
    assert!(!s.observe(0.9)); // improved: best = 0.9
    assert!(!s.observe(0.895)); // not by 1 %: bad 1
    assert!(!s.observe(0.9)); // bad 2 = patience: still tolerated
    assert_eq!(s.lr(123), 1.0);
    assert!(s.observe(0.9)); // bad 3 > patience: reduce
    assert_eq!(s.lr(0), 0.5);
    assert!(!s.observe(0.5)); // improvement resets the count
    for _ in 0..2 {
        assert!(!s.observe(0.6));
    }
    assert!(s.observe(0.6));
    assert_eq!(s.lr(0), 0.25);
    for _ in 0..3 {
        s.observe(f64::NAN); // NaN is never an improvement
    }
    assert_eq!(s.lr(0), 0.2, "clamped at min_lr");
    for _ in 0..10 {
        assert!(!s.observe(1.0), "no reduction below min_lr");
    }
    assert_eq!(s.lr(0), 0.2);
}

#[test]
fn plateau_cooldown_delays_counting() {
    let cfg =
        ScheduleConfig::ReduceOnPlateau(PlateauConfig { patience: 0, factor: 0.1, cooldown: 2, ..Default::default() });
    let mut s = LrScheduler::new(cfg, 1.0).unwrap();
    s.observe(1.0);
    assert!(s.observe(1.0)); // patience 0: first bad one reduces
    assert!(!s.observe(1.0)); // cooldown 1
    assert!(!s.observe(1.0)); // cooldown 2
    assert!(s.observe(1.0));
    assert!(close(s.lr(0), 0.01));
}

#[test]
fn scheduler_drives_the_optimizer() {
    let x = Var::new(&[1.0f64], &Device::Cpu).unwrap();
    let cfg = OptimizerConfig::Sgd(SgdConfig { lr: 0.4, ..Default::default() });
    let mut opt = cfg.build(vec![x]).unwrap();
    let s = LrScheduler::new(ScheduleConfig::StepDecay { step_size: 2, gamma: 0.5 }, cfg.lr()).unwrap();
    let lrs: Vec<f64> = (0..5)
        .map(|step| {
            s.apply(&mut opt, step);
            opt.learning_rate()
        })
        .collect();
    assert_eq!(lrs, [0.4, 0.4, 0.2, 0.2, 0.1]);
}

// ---------------------------------------------------------------- clipping

/// Two vars and their gradients from a linear loss `sum(ca * a) + sum(cb * b)`: grad = (ca, cb).
fn linear_grads(ca: &[f64], cb: &[f64]) -> (Vec<Var>, GradStore) {
    let dev = Device::Cpu;
    let a = Var::zeros(ca.len(), DType::F64, &dev).unwrap();
    let b = Var::zeros(cb.len(), DType::F64, &dev).unwrap();
    let la = a.as_tensor().mul(&Tensor::new(ca, &dev).unwrap()).unwrap().sum_all().unwrap();
    let lb = b.as_tensor().mul(&Tensor::new(cb, &dev).unwrap()).unwrap().sum_all().unwrap();
    let grads = (la + lb).unwrap().backward().unwrap();
    (vec![a, b], grads)
}

fn grads_of(vars: &[Var], grads: &GradStore) -> Vec<f64> {
    vars.iter().flat_map(|v| v1(grads.get(v.as_tensor()).unwrap())).collect()
}

#[test]
fn global_norm_clip_gives_max_norm_and_keeps_direction() {
    let (ca, cb) = ([3.0, -1.0, 2.5], [0.5, -7.0]);
    let (vars, mut grads) = linear_grads(&ca, &cb);
    let before = grads_of(&vars, &grads);
    let norm0 = before.iter().map(|g| g * g).sum::<f64>().sqrt();
    let reported = clip_grad_norm(&mut grads, &vars, 2.0).unwrap();
    assert!((reported - norm0).abs() < 1e-14, "returns the pre-clip norm");
    let after = grads_of(&vars, &grads);
    let norm1 = grad_norm(&grads, &vars).unwrap();
    assert!((norm1 - 2.0).abs() < 1e-14, "clipped norm {norm1}");
    // Same direction: after = before * (2 / norm0), entry by entry.
    for (b, a) in before.iter().zip(&after) {
        assert!((a - b * 2.0 / norm0).abs() < 1e-15, "{a} vs {b}");
    }

    // Below the bound nothing changes.
    let (vars, mut grads) = linear_grads(&ca, &cb);
    let n = clip_grad_norm(&mut grads, &vars, 100.0).unwrap();
    assert!((n - norm0).abs() < 1e-14);
    assert_eq!(grads_of(&vars, &grads), before);
}

#[test]
fn value_clip_bounds_every_entry_and_keeps_small_ones() {
    let (vars, mut grads) = linear_grads(&[3.0, -1.0, 2.5], &[0.5, -7.0]);
    clip_grad_value(&mut grads, &vars, 2.0).unwrap();
    assert_eq!(grads_of(&vars, &grads), [2.0, -1.0, 2.0, 0.5, -2.0]);
    let (vars, mut grads) = linear_grads(&[3.0], &[-4.0]);
    let norm = ClipConfig::Value { max_value: 1.0 }.apply(&mut grads, &vars).unwrap();
    assert_eq!(norm, 5.0, "ClipConfig::apply reports the norm before clipping");
    assert_eq!(grads_of(&vars, &grads), [1.0, -1.0]);
}

#[test]
fn clipping_skips_vars_without_gradient_and_leaves_non_finite_norms_alone() {
    let (mut vars, mut grads) = linear_grads(&[3.0], &[4.0]);
    vars.push(Var::zeros(2, DType::F64, &Device::Cpu).unwrap()); // unused: no gradient
    assert_eq!(clip_grad_norm(&mut grads, &vars, 1.0).unwrap(), 5.0);
    assert!(grads.get(vars[2].as_tensor()).is_none());

    let (vars, mut grads) = linear_grads(&[f64::INFINITY, 1.0], &[2.0]);
    let n = clip_grad_norm(&mut grads, &vars, 1.0).unwrap();
    assert!(n.is_infinite());
    assert_eq!(grads_of(&vars, &grads)[1..], [1.0, 2.0], "left for the guard to stop on");
    assert!(clip_grad_norm(&mut grads, &vars, 0.0).is_err());
    assert!(clip_grad_value(&mut grads, &vars, f64::NAN).is_err());
}

#[test]
fn grad_norm_does_not_overflow_where_the_norm_is_finite() {
    // The squares overflow f64 (1e400), the norm sqrt(2) 1e200 does not.
    let (vars, grads) = linear_grads(&[1e200], &[-1e200]);
    let n = grad_norm(&grads, &vars).unwrap();
    assert!((n / (2f64.sqrt() * 1e200) - 1.0).abs() < 1e-15, "{n:e}");
    let (vars, grads) = linear_grads(&[f64::NAN], &[1.0]);
    assert!(grad_norm(&grads, &vars).unwrap().is_nan());
    let (vars, grads) = linear_grads(&[f64::NEG_INFINITY], &[1e300]);
    assert_eq!(grad_norm(&grads, &vars).unwrap(), f64::INFINITY);
}

#[test]
fn clip_config_serde() {
    let c: ClipConfig = serde_json::from_str(r#"{"kind":"norm","max_norm":1.5}"#).unwrap();
    assert_eq!(c, ClipConfig::Norm { max_norm: 1.5 });
    assert_eq!(serde_json::from_str::<ClipConfig>(r#"{"kind":"none"}"#).unwrap(), ClipConfig::None);
}

// ---------------------------------------------------------------- logs

/// Rows with a NaN, infinities, awkward floats and a column that appears later.
fn sample_log(log: &mut ScalarLog) {
    log.log(0, &[("loss", 1.5), ("lr", 1e-3)]).unwrap();
    log.log(1, &[("loss", 0.1 + 0.2), ("lr", 1e-7)]).unwrap();
    log.log(2, &[("loss", f64::NAN), ("lr", 2.5e300)]).unwrap();
    log.log(3, &[("lr", -0.0), ("val_loss", f64::INFINITY)]).unwrap();
    log.log(10, &[("loss", f64::MIN_POSITIVE), ("val_loss", f64::NEG_INFINITY), ("lr", 1.0)]).unwrap();
}

fn assert_same(a: &ScalarLog, b: &ScalarLog) {
    assert_eq!(a.columns(), b.columns());
    assert_eq!(a.len(), b.len());
    for (ra, rb) in a.rows().iter().zip(b.rows()) {
        assert_eq!(ra.step, rb.step);
        for i in 0..a.columns().len() {
            match (ra.get(i), rb.get(i)) {
                (Some(x), Some(y)) => assert!(x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()), "{x} vs {y}"),
                (x, y) => assert_eq!(x, y, "step {} column {}", ra.step, a.columns()[i]),
            }
        }
    }
}

#[test]
fn logs_round_trip_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    let mut mem = ScalarLog::new();
    sample_log(&mut mem);
    assert_eq!(mem.columns(), ["loss", "lr", "val_loss"]);
    for name in ["log.csv", "log.jsonl", "log.json"] {
        // Written through, row by row.
        let path = dir.path().join(name);
        let mut log = ScalarLog::open(&path).unwrap();
        sample_log(&mut log);
        assert_same(&ScalarLog::read(&path).unwrap(), &mem);
        // Written at once.
        let saved = dir.path().join(format!("saved_{name}"));
        mem.save(&saved).unwrap();
        assert_same(&ScalarLog::read(&saved).unwrap(), &mem);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), std::fs::read_to_string(&saved).unwrap(), "{name}");
    }
    assert_eq!(mem.column("val_loss"), [(3, f64::INFINITY), (10, f64::NEG_INFINITY)]);
    assert_eq!(mem.last("lr"), Some(1.0));
    assert!(mem.column("nope").is_empty());
}

#[test]
fn log_files_have_the_documented_layout() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("a.csv");
    let jsonl = dir.path().join("a.jsonl");
    for p in [&csv, &jsonl] {
        let mut log = ScalarLog::open(p).unwrap();
        log.log(0, &[("loss", 2.0)]).unwrap();
        log.log(1, &[("loss", f64::NAN), ("lr", 0.5)]).unwrap();
    }
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), "step,loss,lr\n0,2.0,\n1,NaN,0.5\n");
    assert_eq!(
        std::fs::read_to_string(&jsonl).unwrap(),
        "{\"step\":0,\"loss\":2.0}\n{\"step\":1,\"loss\":\"NaN\",\"lr\":0.5}\n"
    );
}

#[test]
fn reopening_a_log_keeps_earlier_rows() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["run.csv", "run.jsonl", "run.json"] {
        let path = dir.path().join(name);
        {
            let mut log = ScalarLog::open(&path).unwrap();
            log.log(0, &[("loss", 3.0)]).unwrap();
            log.log(1, &[("loss", 2.0)]).unwrap();
        }
        // A resumed run appends, also with a new column (CSV rewrites its header).
        let mut log = ScalarLog::open(&path).unwrap();
        assert_eq!(log.len(), 2, "{name}");
        log.log(2, &[("loss", 1.0), ("lr", 0.1)]).unwrap();
        let back = ScalarLog::read(&path).unwrap();
        assert_eq!(back.column("loss"), [(0, 3.0), (1, 2.0), (2, 1.0)], "{name}");
        assert_eq!(back.column("lr"), [(2, 0.1)], "{name}");
        assert!(!dir.path().join(format!("{name}.tmp")).exists(), "temporary file left behind");
    }
}

#[test]
fn save_never_replaces_a_different_log() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.jsonl");
    let mut log = ScalarLog::new();
    log.log(0, &[("loss", 1.0)]).unwrap();
    log.save(&path).unwrap();
    log.log(1, &[("loss", 0.5), ("lr", 0.1)]).unwrap();
    log.save(&path).unwrap(); // the file's rows are a prefix of the log: fine
    assert_eq!(ScalarLog::read(&path).unwrap().len(), 2);

    let mut other = ScalarLog::new();
    other.log(0, &[("loss", 9.0)]).unwrap();
    let e = other.save(&path).unwrap_err();
    assert!(matches!(e, Error::Format { .. }) && e.to_string().contains("ScalarLog::open"), "{e}");
    assert_eq!(ScalarLog::read(&path).unwrap().len(), 2, "the earlier file is untouched");
}

#[test]
fn malformed_log_is_a_format_error_naming_the_record() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.csv");
    std::fs::write(&path, "step,loss\n0,1.0\n1,oops\n").unwrap();
    let e = ScalarLog::open(&path).unwrap_err();
    assert!(matches!(e, Error::Format { .. }) && e.to_string().contains("record 3"), "{e}");
    // The bad file is left as it was.
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "step,loss\n0,1.0\n1,oops\n");
    let path = dir.path().join("bad.jsonl");
    std::fs::write(&path, "{\"step\":0,\"loss\":1}\n{\"loss\":2}\n").unwrap();
    let e = ScalarLog::read(&path).unwrap_err();
    assert!(e.to_string().contains("record 2") && e.to_string().contains("step"), "{e}");
}

// ---------------------------------------------------------------- guard and train_step

#[test]
fn guard_reports_the_first_non_finite_step() {
    let mut guard = NanGuard::new().with_checkpoint("runs/a/checkpoints");
    let losses = [1.0, 0.5, 0.25, f64::NAN, 0.1];
    let mut stopped = None;
    for (step, &loss) in losses.iter().enumerate() {
        if let Err(e) = guard.check(step as u64, loss, Some(1.0)) {
            stopped = Some(e);
            break;
        }
    }
    let e = stopped.expect("must stop");
    match &e {
        Error::Diverged { step, quantity, value, .. } => {
            assert_eq!((*step, quantity.as_str()), (3, "loss"));
            assert!(value.is_nan());
        }
        other => panic!("{other:?}"),
    }
    let msg = e.to_string();
    for needle in [
        "step 3",
        "last good checkpoint is kept",
        "runs/a/checkpoints",
        "pbdl_core::io::checkpoint",
        "last finite step was 2",
    ] {
        assert!(msg.contains(needle), "`{needle}` missing in: {msg}");
    }
    assert_eq!(guard.last_good_step(), Some(2));

    let e = guard.check(7, 0.1, Some(f64::INFINITY)).unwrap_err();
    assert!(matches!(e, Error::Diverged { step: 7, ref quantity, .. } if quantity == "gradient norm"), "{e}");
}

#[test]
fn diverging_sgd_is_stopped_at_the_predicted_step_with_parameters_untouched() {
    // f = x^2 with lr 1.5: x <- x - 3x = -2x, so x_t = (-2)^t and the loss 4^t first
    // overflows f64 at t = 512 (4^512 = 2^1024).
    let x = Var::new(&[1.0f64], &Device::Cpu).unwrap();
    let vars = vec![x.clone()];
    let mut opt = OptimizerConfig::Sgd(SgdConfig { lr: 1.5, ..Default::default() }).build(vars.clone()).unwrap();
    let mut guard = NanGuard::new();
    let mut log = ScalarLog::new();
    let progress = Progress::hidden(1000);
    let mut result = Ok(());
    for step in 0..1000u64 {
        let loss = x.as_tensor().sqr().unwrap().sum_all().unwrap();
        match train_step(step, &loss, &mut opt, &vars, &ClipConfig::None, &mut guard) {
            Ok(info) => {
                log.log(step, &[("loss", info.loss), ("grad_norm", info.grad_norm)]).unwrap();
                progress.update(step, info.loss);
            }
            Err(e) => {
                result = Err(e);
                break;
            }
        }
    }
    match result {
        Err(Error::Diverged { step, quantity, value, .. }) => {
            assert_eq!((step, quantity.as_str()), (512, "loss"));
            assert_eq!(value, f64::INFINITY);
        }
        other => panic!("expected Diverged, got {other:?}"),
    }
    assert_eq!(v1(x.as_tensor()), [2f64.powi(512)], "the bad step did not update the parameters");
    assert_eq!(log.len(), 512);
    assert_eq!(log.last("loss"), Some(4f64.powi(511)));
}

#[test]
fn infinite_gradient_with_finite_loss_is_caught() {
    // sqrt at 0: loss 0, gradient 1 / (2 sqrt(0)) = inf.
    let x = Var::new(&[0.0f64, 1.0], &Device::Cpu).unwrap();
    let vars = vec![x.clone()];
    let mut opt = OptimizerConfig::default().build(vars.clone()).unwrap();
    let loss = x.as_tensor().sqrt().unwrap().sum_all().unwrap();
    let e =
        train_step(4, &loss, &mut opt, &vars, &ClipConfig::Norm { max_norm: 1.0 }, &mut NanGuard::new()).unwrap_err();
    assert!(matches!(e, Error::Diverged { step: 4, ref quantity, .. } if quantity == "gradient norm"), "{e}");
    assert_eq!(v1(x.as_tensor()), [0.0, 1.0]);
}

/// A `run_custom_with_state` trainer: its own Adam over the `VarMap`'s variables and its own
/// state (an EMA of the weights that the loss pulls towards), a fresh random batch per update
/// drawn from (seed, step), a learning-rate drop at step 10, checkpoints every 5 updates in
/// `dir`. `restore`: put the checkpoint's optimiser state and EMA back before training (`false`:
/// the broken resume that restarts them). `fail_at`: the update after which the hook stops the
/// run with an error.
fn custom_run(dir: &std::path::Path, steps: u64, restore: bool, fail_at: Option<u64>) -> pbdl_core::Result<LoopReport> {
    use pbdl_core::io::CheckpointMeta;
    let dev = Device::Cpu;
    let varmap = candle_nn::VarMap::new();
    let w = varmap.get((4, 1), "w", candle_nn::Init::Const(0.0), DType::F64, &dev)?;
    let b = varmap.get(1, "b", candle_nn::Init::Const(0.0), DType::F64, &dev)?;
    let cfg = LoopConfig { steps, checkpoint_every: 5, dir: Some(dir.into()), progress: false, ..Default::default() };
    let run = TrainLoop::resume(&varmap, cfg)?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.05, ..Default::default() });
    let mut opt = adam.build(sorted_vars(&varmap).into_iter().map(|(_, v)| v).collect())?;
    let mut ema = w.zeros_like()?;
    if let (Some(ck), true) = (run.resumed(), restore) {
        assert!(ck.restore_optimizer(&mut opt, &varmap)?, "the checkpoint holds the Adam state");
        ema = ck.extra_tensor("ema")?.clone();
    }
    let (opt, ema) = (std::cell::RefCell::new(opt), std::cell::RefCell::new(ema));
    let a_true = Tensor::new(&[[1.0f64], [-2.0], [0.5], [3.0]], &dev)?;
    run.after_step(|step, _: &StepInfo| {
        if Some(step) == fail_at {
            Err(Error::invalid("custom_run", "step", "stopped by the test"))
        } else {
            Ok(())
        }
    })
    .run_custom_with_state::<Error>(
        |step| if step < 10 { 0.05 } else { 0.02 },
        CheckpointMeta::at,
        |_| {
            let mut state = state::optimizer_state_tensors(&opt.borrow(), &varmap)?;
            state.push(("ema".into(), ema.borrow().clone()));
            Ok(state)
        },
        |step, lr| {
            let x = seed::randn((16, 4), 0.0, 1.0, DType::F64, &dev, 7 ^ step.wrapping_mul(0x9E37_79B9_7F4A_7C15))?;
            let y = x.matmul(&a_true)?;
            let fit = (x.matmul(&w)?.broadcast_add(&b)? - y)?.sqr()?.mean_all()?;
            let pull = ((&w - &*ema.borrow())?.sqr()?.sum_all()? * 0.5)?;
            let loss = (&fit + &pull)?;
            let mut opt = opt.borrow_mut();
            opt.set_learning_rate(lr);
            opt.backward_step(&loss)?;
            let next = ((&*ema.borrow() * 0.9)? + (&w * 0.1)?)?;
            // Detached: the EMA is a constant of the next loss, not a path to earlier weights.
            *ema.borrow_mut() = next.detach();
            Ok(Update::loss(loss.to_scalar::<f64>()?).with("pull", pull.to_scalar::<f64>()?))
        },
    )
}

/// `run_custom_with_state` resumes exactly: a run stopped after 12 updates (its last
/// checkpoint at 12), resumed in a fresh call that fails after update 17 (rows 15..=17 logged
/// past the step-15 checkpoint) and resumed again, ends with the `loss.csv` (loss and the
/// extra column, bit for bit) and the checkpoints (weights, Adam moments and count, EMA) of
/// the uninterrupted run. Restarting the method's state instead is caught.
#[test]
fn run_custom_with_state_resumes_exactly_after_a_stop_and_an_error() {
    use pbdl_core::train::crash::Fingerprint;
    let root = tempfile::tempdir().unwrap();
    let (full_dir, cut_dir, cold_dir) = (root.path().join("full"), root.path().join("cut"), root.path().join("cold"));
    let full = custom_run(&full_dir, 20, true, None).unwrap();
    assert_eq!(full.losses.len(), 20);

    assert_eq!(custom_run(&cut_dir, 12, true, None).unwrap().losses.len(), 12);
    let e = custom_run(&cut_dir, 20, true, Some(17)).unwrap_err();
    assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
    let last = custom_run(&cut_dir, 20, true, None).unwrap();
    assert_eq!(last.resumed_from, 15);
    assert!(!last.optimizer_restored, "run_custom restores nothing itself");
    assert_eq!(last.losses, full.losses[15..], "the resumed losses are the uninterrupted run's, bit for bit");

    let expected = Fingerprint::of_run_dir(&full_dir).unwrap();
    for key in
        ["step-20/ema", "step-20/w", "step-20/__optim__/adamw/m/w", "step-20/__optim__/adamw/steps", "loss.csv/pull"]
    {
        assert!(expected.entries.contains_key(key), "{key} is compared");
    }
    let without_12 = |dir: &std::path::Path| {
        let mut f = Fingerprint::of_run_dir(dir).unwrap();
        assert!(f.entries.remove("step-12/step").is_some(), "the stopped call checkpointed its last update");
        f.entries.retain(|k, _| !k.starts_with("step-12/"));
        f
    };
    assert_eq!(without_12(&cut_dir).diff(&expected), None);

    // The same interruption, resumed without the method's state (Adam moments and EMA restart).
    custom_run(&cold_dir, 12, true, None).unwrap();
    let cold = custom_run(&cold_dir, 20, false, None).unwrap();
    assert_eq!(cold.losses.len(), 8);
    assert!(cold.losses.iter().zip(&full.losses[12..]).all(|(c, f)| c != f), "the EMA pull restarted at 0");
    assert!(without_12(&cold_dir).diff(&expected).is_some());

    // State names must not shadow a variable.
    let varmap = candle_nn::VarMap::new();
    varmap.get(1, "w", candle_nn::Init::Const(0.0), DType::F64, &Device::Cpu).unwrap();
    let clash = vec![("w".to_string(), Tensor::new(&[1.0f64], &Device::Cpu).unwrap())];
    let meta = pbdl_core::io::CheckpointMeta::at(1);
    let e = state::save_state_checkpoint(root.path().join("clash"), &varmap, clash, &meta).unwrap_err();
    assert!(e.to_string().contains("also a variable"), "{e}");
}
