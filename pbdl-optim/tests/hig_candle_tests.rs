//! HIG through the candle adapter: Jacobians against the hand-written Mlp and against finite
//! differences, one step against the explicit half-inverse, training, typed errors, timing.

use candle_core::{DType, Device, Tensor, Var};
use faer::{Mat, MatRef};
use pbdl_core::conv::{conv1d, Conv1dParams};
use pbdl_optim::hig::{
    composed_jacobian, evaluate, from_mlp, AdamTrainer, CandleModel, HigConfig, HigTrainer, JacobianMode,
    JacobianModel, MlpForward,
};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Batch, Dataset, Oscillators, Physics, Rk4Rollout};
use pbdl_optim::Error;
use std::time::Instant;

/// `max |a - b| / max |b|`.
fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let num = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    num / b.iter().map(|y| y.abs()).fold(0.0, f64::max)
}

/// The Mlp's weights as candle `Var`s through the library's [`from_mlp`]; the activation
/// argument is checked against the net's own.
fn mlp_as_candle(net: &Mlp, act: Activation) -> CandleModel<MlpForward> {
    assert_eq!(net.activation(), act);
    from_mlp(net).unwrap()
}

/// A non-MLP model: the 4 inputs as one channel, a circular conv1d (3 channels, kernel 3, from
/// `pbdl_core::conv`), tanh, flattened to 12 features, then a dense layer to 24 controls.
fn conv_model(seed: u64) -> CandleModel<impl Fn(&Tensor) -> candle_core::Result<Tensor>> {
    let dev = Device::Cpu;
    let randn = |shape: &[usize], std: f64, s: u64| {
        Var::from_tensor(&pbdl_core::seed::randn(shape, 0.0, std, DType::F64, &dev, seed * 10 + s).unwrap()).unwrap()
    };
    let (wc, bc) = (randn(&[3, 1, 3], 0.6, 1), randn(&[3], 0.1, 2));
    let (wd, bd) = (randn(&[24, 12], 0.3, 3), randn(&[24], 0.1, 4));
    let vars = vec![wc.clone(), bc.clone(), wd.clone(), bd.clone()];
    let params = Conv1dParams::default().padding(1).circular();
    let forward = move |x: &Tensor| {
        let b = x.dim(0)?;
        let h = conv1d(&x.reshape((b, 1, 4))?, &wc, Some(&bc), &params)?.tanh()?;
        h.reshape((b, 12))?.matmul(&wd.t()?)?.broadcast_add(&bd)
    };
    CandleModel::new(vars, 4, 24, forward).unwrap()
}

/// (a) The Mlp rebuilt from candle Vars with the same weights gives the Mlp's composed
/// Jacobian and outcomes, for tanh (linear chain) and ReLU (nonlinear oscillators).
#[test]
fn adapter_jacobian_equals_mlp_jacobian() {
    let cases: [(Rk4Rollout<Oscillators>, Vec<usize>, Activation); 2] = [
        (Oscillators::linear_chain(), vec![4, 20, 20, 20, 24], Activation::Tanh),
        (Oscillators::nonlinear(), vec![4, 20, 20, 20, 96], Activation::Relu),
    ];
    for (physics, sizes, act) in cases {
        let data = Dataset::return_to_start(6, 4, 3);
        let net = Mlp::new(&sizes, act, 5).unwrap();
        let (j_mlp, y_mlp) = composed_jacobian(&net, &physics, data.all()).unwrap();
        for mode in [JacobianMode::Batch, JacobianMode::PerSample] {
            let adapter = mlp_as_candle(&net, act).with_mode(mode);
            assert_eq!(JacobianModel::n_params(&adapter), net.n_params());
            let (j_cnd, y_cnd) = composed_jacobian(&adapter, &physics, data.all()).unwrap();
            let (ej, ey) = (max_rel(&j_cnd, &j_mlp), max_rel(&y_cnd, &y_mlp));
            println!("{act:?}, {mode:?}: J {}x{} max rel diff {ej:e}, y {ey:e}", y_mlp.len(), net.n_params());
            assert!(ej <= 1e-12 && ey <= 1e-12, "{act:?}, {mode:?}: J diff {ej:e}, y diff {ey:e}");
        }
    }
}

/// Outcomes `y` of the batch for the model's current parameters.
fn outcomes<M: JacobianModel>(net: &M, physics: &dyn Physics, batch: Batch<'_>) -> Vec<f64> {
    let mut cache = M::Cache::default();
    net.forward(batch.inputs, batch.len, &mut cache).unwrap();
    let (nu, ny, nx) = (physics.control_dim(), physics.output_dim(), physics.context_dim());
    let u = net.output(&cache);
    let mut y = vec![0.0; batch.len * ny];
    for s in 0..batch.len {
        physics
            .forward(&batch.contexts[s * nx..(s + 1) * nx], &u[s * nu..(s + 1) * nu], &mut y[s * ny..(s + 1) * ny])
            .unwrap();
    }
    y
}

/// (b) The composed Jacobian of a conv + dense candle model against central differences of
/// the outcomes, parameter by parameter (rows from the batch graph and from per-sample graphs).
#[test]
fn adapter_jacobian_of_conv_model_matches_finite_differences() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(5, 4, 7);
    let mut net = conv_model(1);
    let p = net.n_params();
    let (j, _) = composed_jacobian(&net, &physics, data.all()).unwrap();
    let net_ps = conv_model(1).with_mode(JacobianMode::PerSample);
    let (j_ps, _) = composed_jacobian(&net_ps, &physics, data.all()).unwrap();
    let rows = j.len() / p;
    let mut theta = vec![0.0; p];
    net.read_params(&mut theta).unwrap();
    let h = 1e-5;
    let mut fd = vec![0.0; rows * p];
    for c in 0..p {
        let mut t = theta.clone();
        t[c] = theta[c] + h;
        net.write_params(&t).unwrap();
        let up = outcomes(&net, &physics, data.all());
        t[c] = theta[c] - h;
        net.write_params(&t).unwrap();
        let dn = outcomes(&net, &physics, data.all());
        for r in 0..rows {
            fd[r * p + c] = (up[r] - dn[r]) / (2.0 * h);
        }
    }
    net.write_params(&theta).unwrap();
    let abs = j.iter().zip(&fd).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let rel = max_rel(&j, &fd);
    println!("conv model: J {rows}x{p}, max |J - J_fd| = {abs:e}, relative to max |J_fd|: {rel:e}");
    let abs_ps = j_ps.iter().zip(&fd).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    println!("  per-sample graphs: max |J - J_fd| = {abs_ps:e}");
    assert!(abs <= 1e-6 && abs_ps <= 1e-6, "max abs diff {abs:e} (batch), {abs_ps:e} (per sample)");
    // The columns of the conv layer must be nonzero (the rows really go through the conv).
    assert!(j.chunks(p).any(|row| row[..12].iter().any(|v| v.abs() > 1e-3)));
}

/// (c) One HIG step through the adapter moves the parameters by exactly
/// `-eta V diag(s^-1/2, truncated) U^T g`, with `V`, `U`, `s` from faer's allocating thin SVD.
#[test]
fn adapter_hig_step_equals_explicit_half_inverse() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(8, 4, 9);
    let mut net = conv_model(2);
    let p = net.n_params();
    let (eta, tau) = (0.7, 1e-6);
    let (jac, y) = composed_jacobian(&net, &physics, data.all()).unwrap();
    let rows = y.len();
    let g: Vec<f64> = y.iter().zip(&data.targets).map(|(a, t)| 2.0 * (a - t) / data.len as f64).collect();
    let j = MatRef::from_row_major_slice(&jac, rows, p);
    let svd = j.thin_svd().unwrap();
    let s = svd.S().column_vector();
    let k = rows.min(p);
    let s_max = (0..k).map(|i| s[i]).fold(0.0, f64::max);
    let h = Mat::from_fn(p, rows, |a, b| {
        (0..k).filter(|&i| s[i] > tau * s_max).map(|i| svd.V()[(a, i)] * s[i].powf(-0.5) * svd.U()[(b, i)]).sum::<f64>()
    });
    let delta: Vec<f64> = (0..p).map(|a| (0..rows).map(|b| h[(a, b)] * g[b]).sum()).collect();
    let mut before = vec![0.0; p];
    net.read_params(&mut before).unwrap();
    let mut hig = HigTrainer::new(HigConfig::hig(eta, tau)).unwrap();
    let info = hig.step(&mut net, &physics, data.all()).unwrap();
    let mut after = vec![0.0; p];
    net.read_params(&mut after).unwrap();
    let ours: Vec<f64> = before.iter().zip(&after).map(|(b, a)| (b - a) / eta).collect();
    let num = ours.iter().zip(&delta).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
    let err = num / delta.iter().map(|d| d * d).sum::<f64>().sqrt();
    println!("HIG step through the adapter: rank {} of {rows}, relative difference {err:e}", info.solve.unwrap().rank);
    assert!(err <= 1e-10, "relative difference {err:e}");
}

/// (d) A short HIG run of the conv + dense candle model (324 parameters) on the linear chain:
/// 8 steps of b = 32 must cut the test loss 10x, the criterion of the 1,444-parameter Mlp's doc
/// example and the bar this test was written with. It is NOT met: 0.917 -> 0.149, 6.1x (an
/// earlier version of this test then asserted only `after < before`, a bar loosened after the
/// miss; the audit of issue 25 restored the first one). The adapter's correctness is shown by
/// the exact-step tests above; this is a training-speed claim that the conv model misses.
#[test]
#[ignore = "NOT met: 6.1x loss cut in 8 HIG steps, bar 10x (fails by design; README says not met)"]
fn adapter_hig_training_reduces_the_loss() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(256, 4, 0);
    let mut net = conv_model(3);
    let before = evaluate(&net, &physics, &data).unwrap();
    let mut hig = HigTrainer::new(HigConfig::hig(1.0, 1e-10)).unwrap();
    let t = Instant::now();
    let mut losses = Vec::new();
    for step in 0..8 {
        losses.push(hig.step(&mut net, &physics, data.batch(32 * step, 32)).unwrap().loss);
    }
    let after = evaluate(&net, &physics, &data).unwrap();
    let losses: Vec<String> = losses.iter().map(|l| format!("{l:.3e}")).collect();
    println!(
        "conv model, linear chain, 8 HIG steps (b = 32) in {:.2} s: loss {before:.4e} -> {after:.4e}; batch losses {}",
        t.elapsed().as_secs_f64(),
        losses.join(" ")
    );
    println!("ACCEPTANCE: hig_adapter_conv measured={:.1}x loss cut bar=>= 10x", before / after);
    assert!(after * 10.0 <= before, "{before:e} -> {after:e}: {:.1}x, bar 10x", before / after);
}

/// HIG through the adapter follows HIG through the Mlp it was built from, step after step.
#[test]
fn adapter_hig_run_follows_mlp_hig_run() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(128, 4, 2);
    let mut net = Mlp::new(&[4, 20, 20, 20, 24], Activation::Tanh, 3).unwrap();
    let mut adapter = mlp_as_candle(&net, Activation::Tanh);
    let (mut a, mut b) =
        (HigTrainer::new(HigConfig::hig(1.0, 1e-10)).unwrap(), HigTrainer::new(HigConfig::hig(1.0, 1e-10)).unwrap());
    let mut worst = 0.0f64;
    for step in 0..4 {
        let batch = data.batch(32 * step, 32);
        let la = a.step(&mut net, &physics, batch).unwrap().loss;
        let lb = b.step(&mut adapter, &physics, batch).unwrap().loss;
        worst = worst.max((la - lb).abs() / la);
    }
    let mut theta = vec![0.0; net.n_params()];
    adapter.read_params(&mut theta).unwrap();
    let err = max_rel(&theta, net.params());
    println!("4 HIG steps, Mlp vs its candle copy: loss rel diff {worst:e}, parameter max rel diff {err:e}");
    assert!(worst <= 1e-9 && err <= 1e-9, "loss {worst:e}, parameters {err:e}");
}

/// Adam through the adapter (its one-pass `gradient`) follows Adam through the Mlp.
#[test]
fn adapter_adam_steps_equal_mlp_adam_steps() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(32, 4, 4);
    let mut net = Mlp::new(&[4, 16, 16, 24], Activation::Tanh, 6).unwrap();
    let mut adapter = mlp_as_candle(&net, Activation::Tanh);
    let mut a = AdamTrainer::new(&net, 1e-2).unwrap();
    let mut b = AdamTrainer::new(&adapter, 1e-2).unwrap();
    for step in 0..3 {
        let batch = data.batch(8 * step, 8);
        let la = a.step(&mut net, &physics, batch).unwrap().loss;
        let lb = b.step(&mut adapter, &physics, batch).unwrap().loss;
        assert!((la - lb).abs() <= 1e-12 * la, "step {step}: loss {la} vs {lb}");
    }
    let mut theta = vec![0.0; net.n_params()];
    adapter.read_params(&mut theta).unwrap();
    let err = max_rel(&theta, net.params());
    assert!(err <= 1e-12, "parameters differ by {err:e}");
}

/// `f32` Vars: parameters round-trip through the flat `f64` vector, and the Jacobian agrees
/// with the same weights in `f64` to `f32` precision.
#[test]
fn adapter_accepts_f32_vars() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(4, 4, 8);
    let dev = Device::Cpu;
    let model = |dtype: DType| {
        let w = Var::from_tensor(
            &pbdl_core::seed::randn((24, 4), 0.0, 0.5, DType::F32, &dev, 3).unwrap().to_dtype(dtype).unwrap(),
        )
        .unwrap();
        let b = Var::from_tensor(
            &pbdl_core::seed::randn(24, 0.0, 0.1, DType::F32, &dev, 4).unwrap().to_dtype(dtype).unwrap(),
        )
        .unwrap();
        let (wc, bc) = (w.clone(), b.clone());
        let forward = move |x: &Tensor| x.to_dtype(dtype)?.matmul(&wc.t()?)?.tanh()?.broadcast_add(&bc);
        CandleModel::new(vec![w, b], 4, 24, forward).unwrap()
    };
    let (mut m32, m64) = (model(DType::F32), model(DType::F64));
    let (j32, _) = composed_jacobian(&m32, &physics, data.all()).unwrap();
    let (j64, _) = composed_jacobian(&m64, &physics, data.all()).unwrap();
    let err = max_rel(&j32, &j64);
    println!("f32 vs f64 Vars: J max rel diff {err:e}");
    assert!(err <= 1e-5, "{err:e}");
    let theta: Vec<f64> = (0..m32.n_params()).map(|i| i as f64 * 0.25 - 3.0).collect(); // exact in f32
    m32.write_params(&theta).unwrap();
    let mut back = vec![0.0; theta.len()];
    m32.read_params(&mut back).unwrap();
    assert_eq!(back, theta);
}

#[test]
fn adapter_bad_input_is_a_typed_error() {
    let physics = Oscillators::linear_chain();
    let data = Dataset::return_to_start(4, 4, 1);
    let id = |x: &Tensor| Ok(x.clone());
    // No Vars.
    let e = CandleModel::new(Vec::new(), 4, 24, id).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }) && e.to_string().contains("at least one Var"), "{e}");
    // An integer Var.
    let int = Var::from_slice(&[1u32, 2], 2, &Device::Cpu).unwrap();
    let e = CandleModel::new(vec![int], 4, 24, id).unwrap_err();
    assert!(e.to_string().contains("floating point"), "{e}");

    let w = Var::from_tensor(&pbdl_core::seed::randn((24, 4), 0.0, 1.0, DType::F64, &Device::Cpu, 1).unwrap()).unwrap();
    // The closure's output is not [b, out_dim]: declared 24 wide, but it returns 23 columns.
    let wc = w.clone();
    let narrow =
        CandleModel::new(vec![w.clone()], 4, 24, move |x: &Tensor| x.matmul(&wc.t()?)?.narrow(1, 0, 23)).unwrap();
    let e = composed_jacobian(&narrow, &physics, data.all()).unwrap_err();
    assert!(e.to_string().contains("CandleModel forward output shape") && e.to_string().contains("[4, 24]"), "{e}");
    // Declared (and returned) 20 wide, but the physics takes 24 controls.
    let w20 =
        Var::from_tensor(&pbdl_core::seed::randn((20, 4), 0.0, 1.0, DType::F64, &Device::Cpu, 2).unwrap()).unwrap();
    let wc = w20.clone();
    let mut short = CandleModel::new(vec![w20], 4, 20, move |x: &Tensor| x.matmul(&wc.t()?)).unwrap();
    let e = HigTrainer::new(HigConfig::default()).unwrap().step(&mut short, &physics, data.all()).unwrap_err();
    assert!(e.to_string().contains("physics control length") && e.to_string().contains("expected 24, got 20"), "{e}");
    // NaN derivative with a finite output: d sqrt(|z|)/dz at z = 0 is inf * sign(0) = NaN.
    let wc = w.clone();
    let mut nan = CandleModel::new(vec![w.clone()], 4, 24, move |x: &Tensor| {
        let z = x.matmul(&wc.t()?)?;
        (z.clone() - z.detach())?.abs()?.sqrt()
    })
    .unwrap();
    let e = composed_jacobian(&nan, &physics, data.all()).unwrap_err();
    assert!(matches!(e, Error::NonFinite { .. }) && e.to_string().contains("CandleModel Jacobian"), "{e}");
    let e = HigTrainer::new(HigConfig::default()).unwrap().step(&mut nan, &physics, data.all()).unwrap_err();
    assert!(matches!(e, Error::NonFinite { .. }), "{e}");
    // Wrong parameter vector length.
    let e = nan.write_params(&[0.0; 3]).unwrap_err();
    assert!(e.to_string().contains("expected 96, got 3"), "{e}");
}

/// Cost of the adapter's Jacobian (one candle backward pass per row) against the hand-written
/// Mlp's, on the nonlinear oscillators (J 512 x 2956 at b = 128; also b = 32 and 512 to show
/// how the batch-graph mode grows with b). Prints medians side by side.
#[test]
#[ignore = "timing: 30-80 s on the 2-core machine; run with RAYON_NUM_THREADS=2 ... --ignored --nocapture"]
fn adapter_jacobian_cost_vs_mlp() {
    let physics = Oscillators::nonlinear();
    let net = Mlp::new(&[4, 20, 20, 20, 96], Activation::Relu, 2).unwrap();
    let adapter = mlp_as_candle(&net, Activation::Relu);
    let adapter_ps = mlp_as_candle(&net, Activation::Relu).with_mode(JacobianMode::PerSample);
    let median = |f: &dyn Fn() -> Vec<f64>, n: usize| {
        let mut t: Vec<f64> = (0..n)
            .map(|_| {
                let s = Instant::now();
                std::hint::black_box(f());
                s.elapsed().as_secs_f64()
            })
            .collect();
        t.sort_by(f64::total_cmp);
        t[n / 2]
    };
    // Without RAYON_NUM_THREADS candle 0.11 reads /proc/cpuinfo on every CPU matmul (slow).
    let env = std::env::var("RAYON_NUM_THREADS").ok();
    println!("rayon threads {}, RAYON_NUM_THREADS = {env:?}", rayon::current_num_threads());
    for b in [32, 128, 512] {
        let data = Dataset::return_to_start(b, 4, 1);
        let (j_mlp, _) = composed_jacobian(&net, &physics, data.all()).unwrap();
        let (j_cnd, _) = composed_jacobian(&adapter, &physics, data.all()).unwrap();
        let (j_ps, _) = composed_jacobian(&adapter_ps, &physics, data.all()).unwrap();
        let err = max_rel(&j_cnd, &j_mlp).max(max_rel(&j_ps, &j_mlp));
        let reps = if b > 128 { 3 } else { 5 };
        let t_mlp = median(&|| composed_jacobian(&net, &physics, data.all()).unwrap().0, 2 * reps + 1);
        let t_cnd = median(&|| composed_jacobian(&adapter, &physics, data.all()).unwrap().0, reps);
        let t_ps = median(&|| composed_jacobian(&adapter_ps, &physics, data.all()).unwrap().0, reps);
        println!(
            "composed Jacobian {}x2956 (b = {b}), medians: Mlp {:.1} ms | CandleModel batch graph {:.1} ms (x{:.1}) | \
             CandleModel per-sample graphs {:.1} ms (x{:.1}); max rel diff to Mlp {err:e}",
            4 * b,
            t_mlp * 1e3,
            t_cnd * 1e3,
            t_cnd / t_mlp,
            t_ps * 1e3,
            t_ps / t_mlp
        );
        assert!(err <= 1e-12, "b = {b}: {err:e}");
    }
}
