//! Solver-in-the-Loop: network size, transfer operator, typed errors, the SOL-m gradient
//! against finite differences (default suite), and the held-out-Re acceptance run
//! (`cargo test --release -p pbdl-sol --test sil -- --ignored --nocapture`).

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::seed;
use pbdl_grid::{Boundaries, Grid, MacField};
use pbdl_sol::sil::*;
use pbdl_sol::Error;
use std::time::Instant;

/// The paper's network: 260,354 parameters, counted from the built variables.
#[test]
fn paper_network_has_260354_parameters() {
    let norm = Normalisation { sigma: [1.0, 1.0], re_mean: 0.0, re_std: 1.0 };
    let net = Corrector::new(CorrectorConfig::default(), norm, DType::F32, 0).unwrap();
    assert_eq!(net.parameters(), 260_354);
    assert_eq!(CorrectorConfig::default().parameter_count(), 260_354);
    let x = Tensor::zeros((2, 2, 32, 64), DType::F32, &Device::Cpu).unwrap();
    assert_eq!(net.correction(&x, 100.0).unwrap().dims(), &[2, 2, 32, 64]);
    // zero_output: same count, and a zero correction at the start.
    let zero = CorrectorConfig { zero_output: true, ..Default::default() };
    let net = Corrector::new(zero, norm, DType::F32, 0).unwrap();
    assert_eq!(net.parameters(), 260_354);
    let x = seed::randn((1, 2, 32, 64), 0.0, 1.0, DType::F32, &Device::Cpu, 1).unwrap();
    let c = net.correction(&x, 100.0).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    assert_eq!(c, 0.0);
}

/// The MAC face average keeps the flux through every coarse face: a discretely
/// divergence-free fine field is divergence-free on the coarse grid; and each coarse face is
/// the mean of the fine faces it covers.
#[test]
fn face_average_keeps_fluxes() {
    let (fine, coarse) = (Grid::new(24, 12, 2.0, 1.0).unwrap(), Grid::new(6, 3, 2.0, 1.0).unwrap());
    assert_eq!(downsample_factor(&fine, &coarse).unwrap(), 4);
    let bc = Boundaries::periodic();
    let u = seed::randn((1, 2, 12, 24), 0.0, 1.0, DType::F64, &Device::Cpu, 5).unwrap();
    let solver = pbdl_grid::PressureSolver::new(fine, &bc).unwrap();
    let u = pbdl_grid::pressure::make_incompressible(&MacField::new(u, fine, bc).unwrap(), &solver).unwrap();
    let max = |t: &Tensor| t.abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
    assert!(max(pbdl_grid::fd::divergence(&u).unwrap().values()) < 1e-10);
    let c = downsample_mac(u.values(), 4).unwrap();
    let cdiv = pbdl_grid::fd::divergence(&MacField::new(c.clone(), coarse, bc).unwrap()).unwrap();
    let d = max(cdiv.values());
    assert!(d < 1e-10 * max(&c).max(1.0), "coarse divergence {d}");
    // Face (J = 1, I = 2) of u: fine column 4*3-1 = 11, rows 4..8.
    let fu = u.values().narrow(1, 0, 1).unwrap().narrow(2, 4, 4).unwrap().narrow(3, 11, 1).unwrap();
    let want = fu.mean_all().unwrap().to_scalar::<f64>().unwrap();
    let got = c.narrow(1, 0, 1).unwrap().narrow(2, 1, 1).unwrap().narrow(3, 2, 1).unwrap();
    assert!((got.flatten_all().unwrap().to_vec1::<f64>().unwrap()[0] - want).abs() < 1e-14);
}

/// Bad settings are typed errors naming the setting.
#[test]
fn bad_configs_are_typed_errors() {
    let invalid = |r: Result<(), Error>, field: &str| match r {
        Err(Error::InvalidConfig { field: f, .. }) => assert!(f.contains(field), "{f} vs {field}"),
        other => panic!("expected InvalidConfig({field}), got {other:?}"),
    };
    let g = |nx, ny, lx| Grid::new(nx, ny, lx, 1.0).unwrap();
    invalid(downsample_factor(&g(30, 15, 2.0), &g(8, 4, 2.0)).map(|_| ()), "grid"); // 30 / 8
    invalid(downsample_factor(&g(32, 16, 2.0), &g(8, 8, 2.0)).map(|_| ()), "grid"); // 4 vs 2
    invalid(downsample_factor(&g(32, 16, 2.0), &g(8, 4, 3.0)).map(|_| ()), "grid"); // extents
    assert!(matches!(
        downsample_mac(&Tensor::zeros((1, 2, 10, 12), DType::F32, &Device::Cpu).unwrap(), 4),
        Err(Error::Shape { .. })
    ));
    invalid(WakeConfig { factor: 1, ..Default::default() }.validate(), "factor");
    invalid(WakeConfig { reference_substeps: 0, ..Default::default() }.validate(), "reference_substeps");
    invalid(WakeConfig { center: [5.0, 50.0], ..Default::default() }.validate(), "center");
    invalid(WakeConfig::default().viscosity(0.0).map(|_| ()), "re");
    invalid(DataConfig { train_re: vec![], ..Default::default() }.validate(), "train_re");
    // A tiny data set to validate training configs against.
    let wake = WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, ..Default::default() };
    let data = generate(
        &wake,
        &DataConfig { train_re: vec![200.0], test_re: vec![], warmup: 0, train_frames: 4, test_frames: 0 },
        DType::F32,
    )
    .unwrap();
    invalid(TrainConfig::new(Variant::Sol { m: 0 }, 1, 0).validate(&data), "variant.m");
    invalid(TrainConfig::new(Variant::Sol { m: 4 }, 1, 0).validate(&data), "variant.m"); // 4 frames < m + 1
    invalid(TrainConfig { batch: 0, ..TrainConfig::new(Variant::Non, 1, 0) }.validate(&data), "batch");
    invalid(TrainConfig { lr: -1.0, ..TrainConfig::new(Variant::Non, 1, 0) }.validate(&data), "lr");
    // Frames on another grid than the source solver's.
    let mut wrong = data.clone();
    wrong.train[0].frames = Tensor::zeros((4, 2, 8, 12), DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(TrainConfig::new(Variant::Non, 1, 0).validate(&wrong), Err(Error::Shape { .. })));
    let src = wake.source(200.0).unwrap();
    assert!(matches!(
        src.step(&Tensor::zeros((1, 2, 8, 12), DType::F32, &Device::Cpu).unwrap()),
        Err(Error::Shape { .. })
    ));
}

/// Relative error in the max norm over the probes, as pbdl_core::grad_check reports it.
fn rel_error(pairs: &[(f64, f64)]) -> f64 {
    let scale = pairs.iter().fold(0f64, |m, (a, b)| m.max(a.abs()).max(b.abs()));
    pairs.iter().fold(0f64, |m, (a, b)| m.max((a - b).abs())) / scale
}

/// The SOL-32 loss gradient with respect to every network variable (two entries each) and to
/// the initial state agrees with central differences in f64 to 1e-4, through 32 coarse steps
/// of MacCormack advection, implicit viscosity and the masked pressure solve around the
/// cylinder. Bar: 1e-4 relative (set before measuring).
#[test]
fn sol32_gradient_matches_finite_differences() {
    const BAR: f64 = 1e-4;
    let t0 = Instant::now();
    let wake = WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, ..Default::default() };
    let src = wake.source(200.0).unwrap();
    assert!(src.fluid.operators().contains(&"pressure.masked_cholesky"), "{:?}", src.fluid.operators());
    let grid = wake.coarse_grid().unwrap();
    let base = wake.initial_state(&src.fluid, grid, DType::F64).unwrap().velocity.into_values();
    let noise = |s| seed::randn((1, 2, 8, 16), 0.0, 0.1, DType::F64, &Device::Cpu, s).unwrap();
    let s0 = (&base + noise(1)).unwrap();
    let targets = rollout(&src, &(&base + noise(2)).unwrap(), 32, None).unwrap();
    let norm = Normalisation { sigma: [0.5, 0.2], re_mean: 300.0, re_std: 200.0 };
    let net = Corrector::new(
        CorrectorConfig { width: 4, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: false },
        norm,
        DType::F64,
        3,
    )
    .unwrap();
    let start = Var::from_tensor(&s0).unwrap();
    let loss_of = |s: &Tensor| unrolled_loss(&net, &src, s, &targets).unwrap().to_scalar::<f64>().unwrap();
    let loss = unrolled_loss(&net, &src, start.as_tensor(), &targets).unwrap();
    let grads = loss.backward().unwrap();
    let eps = 1e-6;
    // Network weights.
    let data = net.varmap().data().lock().unwrap().clone();
    let mut names: Vec<_> = data.keys().cloned().collect();
    names.sort();
    let mut rng_i = 0usize;
    let mut weight_pairs = Vec::new();
    for name in &names {
        let var = &data[name];
        let g = grads
            .get(var.as_tensor())
            .unwrap_or_else(|| panic!("no gradient for {name}"))
            .flatten_all()
            .unwrap()
            .to_vec1::<f64>()
            .unwrap();
        let orig = var.as_tensor().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        for _ in 0..2 {
            rng_i = (rng_i * 7919 + 104_729) % 1_000_003;
            let i = rng_i % orig.len();
            let eval = |d: f64| {
                let mut w = orig.clone();
                w[i] += d;
                var.set(&Tensor::from_vec(w, var.dims(), &Device::Cpu).unwrap()).unwrap();
                loss_of(&s0)
            };
            let fd = (eval(eps) - eval(-eps)) / (2.0 * eps);
            var.set(&Tensor::from_vec(orig.clone(), var.dims(), &Device::Cpu).unwrap()).unwrap();
            weight_pairs.push((g[i], fd));
        }
    }
    // Initial state: 24 faces (every 11th).
    let g0 = grads
        .get(start.as_tensor())
        .expect("no gradient for the initial state")
        .flatten_all()
        .unwrap()
        .to_vec1::<f64>()
        .unwrap();
    let flat = s0.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let mut state_pairs = Vec::new();
    for i in (0..flat.len()).step_by(11) {
        let at = |d: f64| {
            let mut x = flat.clone();
            x[i] += d;
            loss_of(&Tensor::from_vec(x, s0.dims(), &Device::Cpu).unwrap())
        };
        state_pairs.push((g0[i], (at(eps) - at(-eps)) / (2.0 * eps)));
    }
    let (ew, es) = (rel_error(&weight_pairs), rel_error(&state_pairs));
    eprintln!(
        "SOL-32 gradient: loss {:.4e}, {} weight probes rel err {ew:.2e}, {} state probes rel err {es:.2e} ({:.1} s)",
        loss.to_scalar::<f64>().unwrap(),
        weight_pairs.len(),
        state_pairs.len(),
        t0.elapsed().as_secs_f64()
    );
    assert!(ew < BAR, "weights: {ew} {weight_pairs:?}");
    assert!(es < BAR, "state: {es} {state_pairs:?}");
    assert!(weight_pairs.iter().any(|(g, _)| g.abs() > 0.0) && state_pairs.iter().any(|(g, _)| g.abs() > 0.0));
}

/// A short SOL-2 training on a tiny wake learns something: the corrected 8-step rollout from
/// the first training frame is closer to the reference than the uncorrected source (bar: MAE
/// below the source's, set before measuring; a first run with 300 updates missed it, MAE
/// 0.0127 vs 0.0068, the network's initial output still dominating: 1500 updates, same bar).
#[test]
fn short_sol2_training_beats_the_source_on_training_data() {
    let wake = WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() };
    let data_cfg =
        DataConfig { train_re: vec![200.0, 800.0], test_re: vec![], warmup: 20, train_frames: 30, test_frames: 0 };
    let data = generate(&wake, &data_cfg, DType::F32).unwrap();
    let cfg = TrainConfig {
        corrector: CorrectorConfig { width: 8, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: false },
        lr: 1e-3,
        batch: 4,
        progress: false,
        ..TrainConfig::new(Variant::Sol { m: 2 }, 1500, 1)
    };
    let trained = train(&data, &cfg).unwrap();
    let src = evaluate(&wake, &data.train, 8, None).unwrap().mean_over(0, 8);
    let cor = evaluate(&wake, &data.train, 8, Some(&trained.corrector)).unwrap().mean_over(0, 8);
    eprintln!("tiny SOL-2: source MAE {src:.5}, corrected {cor:.5}, {:.1} s training", trained.seconds);
    assert!(trained.losses.iter().all(|l| l.is_finite()));
    assert!(cor < src, "corrected {cor} vs source {src}");
}

/// NON learns from the uncorrected source trajectory, PRE from one source step of the
/// downsampled reference: the data set carries the trajectory (`s^src_0 = T r_0`, then
/// uncorrected source steps), NON's first input is `P_s(T r_0)` (the same as PRE's first input)
/// and later inputs are `P_s(s^src_t)`, which drift from PRE's `P_s(T r_t)`; a short training
/// of each from the same seed gives different networks.
#[test]
fn non_learns_from_the_uncorrected_source_trajectory() {
    let wake = WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() };
    let data_cfg =
        DataConfig { train_re: vec![200.0, 800.0], test_re: vec![300.0], warmup: 20, train_frames: 12, test_frames: 3 };
    let data = generate(&wake, &data_cfg, DType::F32).unwrap();
    assert!(data.test.iter().all(|r| r.source.is_none()));
    let max = |t: &Tensor| t.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    let non = training_inputs(&data, Variant::Non).unwrap().unwrap();
    let pre = training_inputs(&data, Variant::Pre).unwrap().unwrap();
    for (k, r) in data.train.iter().enumerate() {
        let traj = r.source.as_ref().expect("generate fills the training trajectories");
        assert_eq!(traj.dims(), r.frames.dims());
        // s^src_0 = T r_0, s^src_{t+1} = P_s(s^src_t) (a fresh rollout, no correction).
        let r0 = r.frames.narrow(0, 0, 1).unwrap();
        assert_eq!(max(&(traj.narrow(0, 0, 1).unwrap() - &r0).unwrap()), 0.0);
        let src = wake.source(r.re).unwrap();
        let roll = rollout(&src, &r0, r.len() - 1, None).unwrap();
        let roll = Tensor::cat(&roll, 0).unwrap();
        assert_eq!(max(&(traj.narrow(0, 1, r.len() - 1).unwrap() - &roll).unwrap()), 0.0);
        // NON's inputs are the source trajectory after one step: the first is P_s(T r_0).
        assert_eq!(non[k].dims(), &[r.len() - 1, 2, 8, 16]);
        assert_eq!(max(&(&non[k] - &roll).unwrap()), 0.0);
        let p_r0 = src.step(&r0).unwrap();
        assert_eq!(max(&(non[k].narrow(0, 0, 1).unwrap() - &p_r0).unwrap()), 0.0);
        assert_eq!(max(&(pre[k].narrow(0, 0, 1).unwrap() - &p_r0).unwrap()), 0.0);
        // PRE's input t is P_s(T r_t); NON's drifts away from it.
        let p_rt = src.step(&r.frames.narrow(0, 0, r.len() - 1).unwrap()).unwrap();
        assert_eq!(max(&(&pre[k] - &p_rt).unwrap()), 0.0);
        let last = r.len() - 2;
        let drift = max(&(non[k].narrow(0, last, 1).unwrap() - pre[k].narrow(0, last, 1).unwrap()).unwrap());
        eprintln!("Re {}: NON vs PRE input {last}, max |diff| {drift:.3e}", r.re);
        assert!(drift > 1e-4, "Re {}: NON's input {last} equals PRE's ({drift})", r.re);
    }
    // Same seed, same batches: the trained networks differ.
    let cfg = |v| TrainConfig {
        corrector: CorrectorConfig { width: 4, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: false },
        lr: 1e-3,
        batch: 2,
        progress: false,
        ..TrainConfig::new(v, 20, 3)
    };
    let (tn, tp) = (train(&data, &cfg(Variant::Non)).unwrap(), train(&data, &cfg(Variant::Pre)).unwrap());
    assert_ne!(tn.losses, tp.losses);
    let x = data.test[0].frames.narrow(0, 0, 1).unwrap();
    let d = max(&(tn.corrector.apply(&x, 300.0).unwrap() - tp.corrector.apply(&x, 300.0).unwrap()).unwrap());
    assert!(d > 0.0, "NON and PRE trained the same network");
    // NON without the trajectories is a typed error.
    let mut bare = data.clone();
    bare.train[1].source = None;
    match cfg(Variant::Non).validate(&bare) {
        Err(Error::InvalidConfig { field, .. }) => assert!(field.contains("source"), "{field}"),
        other => panic!("expected InvalidConfig(data.train.source), got {other:?}"),
    }
    assert!(cfg(Variant::Pre).validate(&bare).is_ok());
}

/// Held-out Reynolds numbers: the corrected source against the uncorrected one, and SOL-m
/// against NON and PRE at long horizons. Bars (set before the first measurement, never
/// loosened):
/// * SOL-8's MAE over the 128-step rollouts is below the source's;
/// * SOL-8's MAE over steps 65..128 is below NON's and PRE's.
///
/// Since 2026-11-27 the same three bars apply to every SOL-m in the run (`SIL_VARIANTS`,
/// e.g. `pre,non,sol2,sol16` for the m = 2 and 16), stated before those were run.
///
/// Affordable settings for a 2-core machine (deviations from the paper, see the report):
/// a smaller network (width 16, 2 residual blocks, 5x5), Adam lr 1e-3, batch 2, seed 0
/// (`SIL_SEED=<n>` for another),
/// 200 training frames per Re after 100 warm-up frames.
///
/// Run 1 (paper initialisation, 1000 updates, PRE / NON / SOL-2 / SOL-4 / SOL-8), 868 s: MAE
/// 1-128 source 0.0318, PRE 0.0678, NON 0.0678, SOL-2 0.1031, SOL-4 0.0527, SOL-8 0.0400;
/// MAE 65-128 source 0.0478, PRE = NON 0.1010, SOL-8 0.0600: SOL-8 beat NON and PRE but
/// missed the source bar (every corrected variant was worse than the source). Run 2, this
/// test: the output conv starts at zero (`zero_output`, the corrected solver starts as the
/// source), 2000 updates, PRE / NON / SOL-4 / SOL-8; same bars.
///
/// Since then NON follows the paper (inputs from the uncorrected source trajectory from
/// `T r_0`, not from `T r_t`), so PRE and NON no longer coincide; settings and bars unchanged.
#[test]
#[ignore]
fn acceptance_held_out_re() {
    let t_all = Instant::now();
    let wake = WakeConfig::default();
    let data_cfg = DataConfig { warmup: 100, train_frames: 200, test_frames: 129, ..Default::default() };
    let t = Instant::now();
    let data = generate(&wake, &data_cfg, DType::F32).unwrap();
    eprintln!(
        "data: source {:?}, reference x{} ({} substeps), train Re {:?}, held-out Re {:?}: {:.0} s",
        wake.coarse,
        wake.factor,
        wake.reference_substeps,
        data_cfg.train_re,
        data_cfg.test_re,
        t.elapsed().as_secs_f64()
    );
    let steps = 128;
    let source = evaluate(&wake, &data.test, steps, None).unwrap();
    let net = CorrectorConfig { width: 16, blocks: 2, kernel: 5, negative_slope: 0.3, zero_output: true };
    // Seed of the weights and batches: `SIL_SEED` (default 0).
    let seed = std::env::var("SIL_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(0u64);
    let mut rows = vec![("source".to_string(), source.clone(), 0.0, f64::NAN)];
    // Variants: `SIL_VARIANTS` (comma list of pre, non, sol<m>; default pre,non,sol4,sol8).
    // PRE and NON must be in the list: every SOL-m row is checked against them.
    let variants = std::env::var("SIL_VARIANTS").unwrap_or_else(|_| "pre,non,sol4,sol8".into());
    let variants: Vec<Variant> = variants
        .split(',')
        .map(|v| match v.trim() {
            "pre" => Variant::Pre,
            "non" => Variant::Non,
            s => Variant::Sol {
                m: s.strip_prefix("sol").and_then(|m| m.parse().ok()).expect("SIL_VARIANTS: pre, non or sol<m>"),
            },
        })
        .collect();
    assert!(variants.contains(&Variant::Pre) && variants.contains(&Variant::Non), "SIL_VARIANTS needs pre and non");
    for variant in variants {
        let cfg = TrainConfig { corrector: net, batch: 2, lr: 1e-3, ..TrainConfig::new(variant, 2000, seed) };
        let trained = train(&data, &cfg).unwrap();
        let n = trained.losses.len();
        let last = trained.losses[n - 100..].iter().sum::<f64>() / 100.0;
        let ev = evaluate(&wake, &data.test, steps, Some(&trained.corrector)).unwrap();
        eprintln!(
            "{}: trained {:.0} s, final loss (mean of last 100) {last:.4e}, per-Re MAE {:?}",
            variant.name(),
            trained.seconds,
            ev.per_sim
        );
        rows.push((variant.name(), ev, trained.seconds, last));
    }
    eprintln!("| method (seed {seed}) | MAE steps 1-32 | MAE 1-128 | MAE 65-128 | train s |");
    eprintln!("|---|---|---|---|---|");
    for (name, ev, secs, _) in &rows {
        eprintln!(
            "| {name} | {:.4} | {:.4} | {:.4} | {secs:.0} |",
            ev.mean_over(0, 32),
            ev.mean_over(0, steps),
            ev.mean_over(64, steps)
        );
    }
    let get = |name: &str| rows.iter().find(|r| r.0 == name).unwrap().1.clone();
    let (src, non, pre) = (get("source"), get("NON"), get("PRE"));
    let src_all = src.mean_over(0, steps);
    let (non_long, pre_long) = (non.mean_over(64, steps), pre.mean_over(64, steps));
    // Every SOL-m row of the run against the three bars (the default run: SOL-4 and SOL-8).
    let mut missed = Vec::new();
    for (name, ev, _, _) in rows.iter().filter(|r| r.0.starts_with("SOL-")) {
        let (all, long) = (ev.mean_over(0, steps), ev.mean_over(64, steps));
        for (what, measured, bar) in [
            ("MAE over 128 held-out steps < source", all, src_all),
            ("MAE steps 65-128 < NON", long, non_long),
            ("MAE steps 65-128 < PRE", long, pre_long),
        ] {
            let met = measured < bar;
            eprintln!(
                "ACCEPTANCE: measured={measured:.5} bar={bar:.5} ({name} {what}){}",
                if met { "" } else { " NOT MET" }
            );
            if !met {
                missed.push(format!("{name} {what}: {measured:.5} vs {bar:.5}"));
            }
        }
    }
    eprintln!("total {:.0} s", t_all.elapsed().as_secs_f64());
    assert!(missed.is_empty(), "bars missed: {missed:?}");
}
