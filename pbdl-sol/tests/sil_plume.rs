//! Solver-in-the-Loop on the buoyancy-driven flow (a plume in a closed box, state `u, v,
//! density`): the SOL-m gradient against finite differences through buoyancy, density
//! transport, inflow and the masked pressure solve; exact mass of the density transfer; typed
//! errors; a short training (default suite, tiny grids); and the held-out-buoyancy acceptance
//! run (`cargo test --release -p pbdl-sol --test sil_plume -- --ignored --nocapture`).

use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::seed;
use pbdl_grid::{Grid, Obstacle};
use pbdl_sol::sil::*;
use pbdl_sol::Error;
use std::time::Instant;

/// A tiny plume: 8 x 12 source cells of size 2, reference 2x finer, one sub-step per frame.
fn tiny() -> PlumeConfig {
    PlumeConfig {
        coarse: [8, 12],
        factor: 2,
        extent: [16.0, 24.0],
        inflow_lo: [6.0, 2.0],
        inflow_hi: [10.0, 4.0],
        obstacle: Some(Obstacle::Box { lo: [4.0, 12.0], hi: [8.0, 14.0] }),
        reference_substeps: 1,
        ..Default::default()
    }
}

fn scalar(t: &Tensor) -> f64 {
    t.to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
}

/// Relative error in the max norm over the probes.
fn rel_error(pairs: &[(f64, f64)]) -> f64 {
    let scale = pairs.iter().fold(0f64, |m, (a, b)| m.max(a.abs()).max(b.abs()));
    pairs.iter().fold(0f64, |m, (a, b)| m.max((a - b).abs())) / scale
}

/// The SOL-16 loss gradient with respect to network variables (two entries each) and to the
/// initial state (velocity and density entries) agrees with central differences in f64, through
/// 16 coarse steps of conservative density transport with inflow, MacCormack advection, the
/// buoyancy force and the masked pressure solve around the obstacle. Bar: 1e-4 relative (set
/// before measuring).
#[test]
fn sol16_gradient_matches_finite_differences() {
    const BAR: f64 = 1e-4;
    let t0 = Instant::now();
    let plume = tiny();
    let src = plume.source(0.05).unwrap();
    let ops = src.fluid.operators().to_vec();
    assert!(ops.iter().any(|o| o.contains("conservative")), "{ops:?}");
    assert!(ops.contains(&"buoyancy") && ops.contains(&"pressure.masked_cholesky"), "{ops:?}");
    // A developed state: 8 source steps from rest, then noise on every channel.
    let rest = Tensor::zeros((1, 3, 12, 8), DType::F64, &Device::Cpu).unwrap();
    let base = rollout(&src, &rest, 8, None).unwrap().pop().unwrap();
    let noise = |s| seed::randn((1, 3, 12, 8), 0.0, 0.05, DType::F64, &Device::Cpu, s).unwrap();
    let s0 = (&base + noise(1)).unwrap();
    let targets = rollout(&src, &(&base + noise(2)).unwrap(), 16, None).unwrap();
    let norm = Normalisation { sigma: [0.3, 0.3], re_mean: 0.05, re_std: 0.03 };
    let net = Corrector::with_scalars(
        CorrectorConfig { width: 4, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: false },
        norm,
        &[0.5],
        DType::F64,
        3,
    )
    .unwrap();
    assert_eq!(
        net.parameters(),
        CorrectorConfig { width: 4, blocks: 1, kernel: 3, ..Default::default() }.parameter_count_with_scalars(1)
    );
    let start = Var::from_tensor(&s0).unwrap();
    let loss_of = |s: &Tensor| scalar(&unrolled_loss(&net, &src, s, &targets).unwrap());
    let loss = unrolled_loss(&net, &src, start.as_tensor(), &targets).unwrap();
    let grads = loss.backward().unwrap();
    let eps = 1e-6;
    let data = net.varmap().data().lock().unwrap().clone();
    let mut names: Vec<_> = data.keys().cloned().collect();
    names.sort();
    let mut rng_i = 0usize;
    let mut weight_pairs = Vec::new();
    for name in &names {
        let var = &data[name];
        let g = grads.get(var.as_tensor()).unwrap_or_else(|| panic!("no gradient for {name}"));
        let g = g.flatten_all().unwrap().to_vec1::<f64>().unwrap();
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
    let g0 = grads.get(start.as_tensor()).expect("no gradient for the initial state");
    let g0 = g0.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let flat = s0.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let n = 12 * 8;
    let (mut vel_pairs, mut rho_pairs) = (Vec::new(), Vec::new());
    for i in (0..flat.len()).step_by(7) {
        let at = |d: f64| {
            let mut x = flat.clone();
            x[i] += d;
            loss_of(&Tensor::from_vec(x, s0.dims(), &Device::Cpu).unwrap())
        };
        let pair = (g0[i], (at(eps) - at(-eps)) / (2.0 * eps));
        if i >= 2 * n {
            rho_pairs.push(pair)
        } else {
            vel_pairs.push(pair)
        }
    }
    let (ew, ev, er) = (rel_error(&weight_pairs), rel_error(&vel_pairs), rel_error(&rho_pairs));
    eprintln!(
        "plume SOL-16 gradient: loss {:.4e}; rel err {} weight probes {ew:.2e}, {} velocity probes {ev:.2e}, \
         {} density probes {er:.2e} ({:.1} s)",
        scalar(&loss),
        weight_pairs.len(),
        vel_pairs.len(),
        rho_pairs.len(),
        t0.elapsed().as_secs_f64()
    );
    assert!(ew < BAR, "weights: {ew} {weight_pairs:?}");
    assert!(ev < BAR, "velocity: {ev} {vel_pairs:?}");
    assert!(er < BAR, "density: {er} {rho_pairs:?}");
    // The density's gradient is not trivially zero (it reaches the loss through the buoyancy
    // force and its own channel).
    assert!(rho_pairs.iter().filter(|(g, _)| g.abs() > 1e-8).count() >= rho_pairs.len() / 2, "{rho_pairs:?}");
}

/// The cell average keeps `sum rho dx dy` exactly, and the whole chain does too: in the closed
/// box with conservative transport the downsampled reference frames hold exactly the mass the
/// inflow put in, `t dt rate (inflow area)`, as does the source trajectory.
#[test]
fn density_downsampling_conserves_mass() {
    let (fine, coarse) = (Grid::new(24, 36, 16.0, 24.0).unwrap(), Grid::new(8, 12, 16.0, 24.0).unwrap());
    assert_eq!(downsample_factor(&fine, &coarse).unwrap(), 3);
    let rho = seed::randn((2, 1, 36, 24), 1.0, 1.0, DType::F64, &Device::Cpu, 4).unwrap();
    let c = downsample_cells(&rho, 3).unwrap();
    assert_eq!(c.dims(), &[2, 1, 12, 8]);
    let mass = |t: &Tensor, g: &Grid| scalar(&t.sum_all().unwrap()) * g.dx() * g.dy();
    let (mf, mc) = (mass(&rho, &fine), mass(&c, &coarse));
    assert!((mf - mc).abs() <= 1e-12 * mf.abs(), "fine {mf} coarse {mc}");
    // Cell (J = 1, I = 2) is the mean of fine rows 3..6, columns 6..9 (first batch item).
    let want =
        scalar(&rho.narrow(0, 0, 1).unwrap().narrow(2, 3, 3).unwrap().narrow(3, 6, 3).unwrap().mean_all().unwrap());
    let got = scalar(
        &c.narrow(0, 0, 1)
            .unwrap()
            .narrow(2, 1, 1)
            .unwrap()
            .narrow(3, 2, 1)
            .unwrap()
            .squeeze(0)
            .unwrap()
            .squeeze(0)
            .unwrap()
            .squeeze(0)
            .unwrap()
            .squeeze(0)
            .unwrap(),
    );
    assert!((got - want).abs() < 1e-14);
    assert!(matches!(downsample_cells(&rho, 5), Err(Error::Shape { .. })));
    // The whole chain.
    let plume = tiny();
    let g = plume.coarse_grid().unwrap();
    let r = reference_run(&plume, 0.05, 0, 12, DType::F64).unwrap();
    let traj = source_trajectory(&plume, &r).unwrap();
    let area = (plume.inflow_hi[0] - plume.inflow_lo[0]) * (plume.inflow_hi[1] - plume.inflow_lo[1]);
    for t in 0..12 {
        let want = t as f64 * plume.dt * plume.rate * area;
        for (what, x) in [("reference", &r.frames), ("source", &traj)] {
            let m = mass(&x.narrow(0, t, 1).unwrap().narrow(1, 2, 1).unwrap(), &g);
            assert!((m - want).abs() <= 1e-10 * want.max(1.0), "{what} frame {t}: mass {m} vs {want}");
        }
    }
}

/// Bad plume settings and parameters are typed errors naming the setting.
#[test]
fn bad_plume_configs_are_typed_errors() {
    let invalid = |r: Result<(), Error>, field: &str| match r {
        Err(Error::InvalidConfig { field: f, .. }) => assert!(f.contains(field), "{f} vs {field}"),
        other => panic!("expected InvalidConfig({field}), got {other:?}"),
    };
    let d = PlumeConfig::default;
    assert!(d().validate().is_ok() && tiny().validate().is_ok());
    invalid(PlumeConfig { coarse: [2, 48], ..d() }.validate(), "coarse");
    invalid(PlumeConfig { factor: 1, ..d() }.validate(), "factor");
    invalid(PlumeConfig { reference_substeps: 0, ..d() }.validate(), "reference_substeps");
    invalid(PlumeConfig { extent: [0.0, 96.0], ..d() }.validate(), "extent");
    invalid(PlumeConfig { dt: f64::NAN, ..d() }.validate(), "dt");
    invalid(PlumeConfig { rate: 0.0, ..d() }.validate(), "rate");
    invalid(PlumeConfig { nu: -0.1, ..d() }.validate(), "nu");
    invalid(PlumeConfig { inflow_hi: [70.0, 12.0], ..d() }.validate(), "inflow");
    invalid(PlumeConfig { inflow_lo: [40.0, 4.0], inflow_hi: [24.0, 12.0], ..d() }.validate(), "inflow");
    // Inside the box but between cell centres (x in [24.2, 25.8], centres at 25 +- 2k... none).
    invalid(PlumeConfig { inflow_lo: [24.2, 4.2], inflow_hi: [24.8, 4.8], ..d() }.validate(), "inflow");
    invalid(
        PlumeConfig { obstacle: Some(Obstacle::Box { lo: [16.0, 40.0], hi: [80.0, 48.0] }), ..d() }.validate(),
        "obstacle",
    );
    invalid(
        PlumeConfig { obstacle: Some(Obstacle::Cylinder { center: [32.0, 8.0], radius: 3.0 }), ..d() }.validate(),
        "obstacle",
    );
    invalid(PlumeConfig { advection: pbdl_grid::fluid::Advection::Conservative, ..d() }.validate(), "advection");
    invalid(
        PlumeConfig { density_advection: pbdl_grid::fluid::Advection::CentralRk4, ..d() }.validate(),
        "density_advection",
    );
    invalid(d().check_buoyancy(0.0), "buoyancy");
    invalid(d().check_buoyancy(f64::INFINITY), "buoyancy");
    invalid(tiny().source(-1.0).map(|_| ()), "buoyancy");
    let data = DataConfig { train_re: vec![0.05], test_re: vec![-0.1], warmup: 0, train_frames: 3, test_frames: 3 };
    invalid(generate(&tiny(), &data, DType::F32).map(|_| ()), "test_re");
    // A velocity-only state does not fit the plume's source solver; a 3-channel one not the
    // wake's corrector.
    let src = tiny().source(0.05).unwrap();
    assert_eq!(src.channels(), 3);
    assert!(matches!(
        src.step(&Tensor::zeros((1, 2, 12, 8), DType::F32, &Device::Cpu).unwrap()),
        Err(Error::Shape { .. })
    ));
    let norm = Normalisation { sigma: [1.0, 1.0], re_mean: 0.0, re_std: 1.0 };
    let wake_net =
        Corrector::new(CorrectorConfig { width: 4, blocks: 1, kernel: 3, ..Default::default() }, norm, DType::F32, 0)
            .unwrap();
    assert!(matches!(
        wake_net.correction(&Tensor::zeros((1, 3, 12, 8), DType::F32, &Device::Cpu).unwrap(), 0.05),
        Err(Error::Shape { .. })
    ));
    invalid(
        Corrector::with_scalars(CorrectorConfig::default(), norm, &[0.0], DType::F32, 0).map(|_| ()),
        "scalar_sigma",
    );
}

/// The density correction moves density without creating any: its domain sum is zero, so a
/// corrected step keeps the source step's mass.
#[test]
fn density_correction_has_zero_mean() {
    let norm = Normalisation { sigma: [0.5, 0.5], re_mean: 0.05, re_std: 0.03 };
    let net = Corrector::with_scalars(
        CorrectorConfig { width: 4, blocks: 1, kernel: 3, ..Default::default() },
        norm,
        &[0.7],
        DType::F64,
        1,
    )
    .unwrap();
    let x = seed::randn((2, 3, 12, 8), 0.0, 1.0, DType::F64, &Device::Cpu, 9).unwrap();
    let c = net.correction(&x, 0.04).unwrap();
    assert_eq!(c.dims(), &[2, 3, 12, 8]);
    for b in 0..2 {
        let rho = scalar(&c.narrow(0, b, 1).unwrap().narrow(1, 2, 1).unwrap().sum_all().unwrap());
        let vel = scalar(&c.narrow(0, b, 1).unwrap().narrow(1, 0, 2).unwrap().abs().unwrap().sum_all().unwrap());
        assert!(rho.abs() < 1e-12 && vel > 1e-3, "density sum {rho}, velocity |sum| {vel}");
    }
}

/// A short SOL-2 training on a tiny plume learns something: the corrected 8-step rollouts from
/// the first frame of the training simulations are closer to the reference in velocity than the
/// uncorrected source (bar: velocity MAE below the source's, set before measuring).
#[test]
fn short_sol2_training_beats_the_source_on_training_data() {
    let plume = tiny();
    let data_cfg =
        DataConfig { train_re: vec![0.03, 0.1], test_re: vec![], warmup: 10, train_frames: 30, test_frames: 0 };
    let data = generate(&plume, &data_cfg, DType::F32).unwrap();
    assert_eq!(data.train[0].frames.dims(), &[30, 3, 12, 8]);
    let cfg = TrainConfig {
        corrector: CorrectorConfig { width: 8, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: true },
        lr: 1e-3,
        batch: 4,
        progress: false,
        ..TrainConfig::new(Variant::Sol { m: 2 }, 1000, 1)
    };
    let trained = train(&data, &cfg).unwrap();
    assert_eq!(trained.corrector.channels(), 3);
    let src = evaluate(&plume, &data.train, 8, None).unwrap();
    let cor = evaluate(&plume, &data.train, 8, Some(&trained.corrector)).unwrap();
    eprintln!(
        "tiny plume SOL-2: velocity MAE source {:.5} corrected {:.5}; density MAE source {:.5} corrected {:.5}; {:.1} s training",
        src.mean_over(0, 8),
        cor.mean_over(0, 8),
        src.scalar_mean_over(0, 8),
        cor.scalar_mean_over(0, 8),
        trained.seconds
    );
    assert!(trained.losses.iter().all(|l| l.is_finite()));
    assert_eq!(src.scalar_mae_per_step.len(), 8);
    assert!(
        cor.mean_over(0, 8) < src.mean_over(0, 8),
        "corrected {} vs source {}",
        cor.mean_over(0, 8),
        src.mean_over(0, 8)
    );
}

/// A run directory of a plume training reads back as a 3-channel corrector with the same
/// output, and a wake set's scene does not change (the wake stays the default type).
#[test]
fn plume_run_directory_round_trips() {
    let plume = tiny();
    let data_cfg = DataConfig { train_re: vec![0.05], test_re: vec![], warmup: 4, train_frames: 5, test_frames: 0 };
    let data: ReferenceSet<PlumeConfig> = generate(&plume, &data_cfg, DType::F32).unwrap();
    let cfg = TrainConfig {
        corrector: CorrectorConfig { width: 4, blocks: 1, kernel: 3, ..Default::default() },
        progress: false,
        checkpoint_every: 2,
        ..TrainConfig::new(Variant::Sol { m: 2 }, 3, 0)
    };
    let dir = tempfile::tempdir().unwrap();
    let trained = train_resumable(&data, &cfg, dir.path()).unwrap();
    let (loaded, step) = load_trained(dir.path()).unwrap();
    assert_eq!((step, loaded.channels()), (3, 3));
    assert_eq!(loaded.scalar_sigma(), trained.corrector.scalar_sigma());
    let x = data.train[0].frames.narrow(0, 1, 1).unwrap();
    let d = (loaded.apply(&x, 0.05).unwrap() - trained.corrector.apply(&x, 0.05).unwrap()).unwrap();
    assert_eq!(scalar(&d.abs().unwrap().max_all().unwrap()), 0.0);
    // Resuming with the data of another scene parameter is refused.
    let mut other = data.clone();
    other.train[0].re = 0.06;
    assert!(matches!(train_resumable(&other, &cfg, dir.path()), Err(Error::ResumeMismatch { .. })));
}

/// Held-out buoyancy factors: the corrected source against the uncorrected one, and SOL-8
/// against NON and PRE at long horizons, on the default plume (`nu = 1`, 32 x 48 source, 128 x 192
/// reference, [`PlumeConfig::data`]: training buoyancy 0.01 .. 0.08, held out 0.0141, 0.0283,
/// 0.0566). Bars (set before the first measurement, never loosened):
/// * SOL-8's velocity MAE over the 128 held-out steps is below the source's;
/// * SOL-8's velocity MAE over steps 65..128 is below NON's and PRE's.
///
/// The density MAE is reported (no bar). Settings as the wake's acceptance run: the network
/// of width 16 with 2 residual blocks of 5x5 convs, output conv started at zero, Adam 1e-3,
/// batch 2, 2000 updates, seed 0 (`SIL_SEED=<n>` for another).
///
/// Run 1 (2026-11-27, inviscid plume `nu = 0`, otherwise this test), 596 s: velocity MAE
/// steps 1-32 / 1-128 / 65-128: source 0.0030 / 0.0745 / 0.1341, PRE 0.0113 / 0.1590 / 0.2738,
/// NON 0.1167 / 0.7309 / 1.1251, SOL-8 0.0081 / 0.1098 / 0.1902 (density MAE 1-128: source
/// 0.1352, PRE 0.3362, NON 1.7003, SOL-8 0.2142). SOL-8 beat NON and PRE but missed the
/// source bar: inviscid, the source's own error reaches 23-43% of the mean speed by frame 64
/// (the reference and source plumes part ways). Run 2, this test: the laminar plume
/// (`PlumeConfig::default()`, now `nu = 1`); same bars, same training. Run 2 (2026-11-27),
/// 472 s: velocity MAE 1-32 / 1-128 / 65-128: source 0.0008 / 0.0146 / 0.0253, PRE 0.0016 /
/// 0.0281 / 0.0498, NON 0.0517 / 0.4872 / 0.7997, SOL-8 0.0018 / 0.0178 / 0.0309 (density
/// MAE 1-128: source 0.0954, PRE 0.3685, NON 2.3443, SOL-8 0.1006): SOL-8 beat NON and PRE
/// again and missed the source bar again (0.0178 vs 0.0146), already twice the source's error
/// over steps 1-32, where the plume is still small and most of the box at rest.
#[test]
#[ignore]
fn acceptance_held_out_buoyancy() {
    let t_all = Instant::now();
    let plume = PlumeConfig::default();
    let data_cfg = PlumeConfig::data();
    let t = Instant::now();
    let data = generate(&plume, &data_cfg, DType::F32).unwrap();
    eprintln!(
        "data: source {:?}, reference x{} ({} substeps), train buoyancy {:?}, held-out {:?}: {:.0} s",
        plume.coarse,
        plume.factor,
        plume.reference_substeps,
        data_cfg.train_re,
        data_cfg.test_re,
        t.elapsed().as_secs_f64()
    );
    let steps = 128;
    let source = evaluate(&plume, &data.test, steps, None).unwrap();
    let net = CorrectorConfig { width: 16, blocks: 2, kernel: 5, negative_slope: 0.3, zero_output: true };
    let seed = std::env::var("SIL_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(0u64);
    let mut rows = vec![("source".to_string(), source, 0.0)];
    for variant in [Variant::Pre, Variant::Non, Variant::Sol { m: 8 }] {
        let cfg = TrainConfig { corrector: net, batch: 2, lr: 1e-3, ..TrainConfig::new(variant, 2000, seed) };
        let trained = train(&data, &cfg).unwrap();
        let n = trained.losses.len();
        let last = trained.losses[n - 100..].iter().sum::<f64>() / 100.0;
        let ev = evaluate(&plume, &data.test, steps, Some(&trained.corrector)).unwrap();
        eprintln!(
            "{}: trained {:.0} s, final loss (mean of last 100) {last:.4e}, per-buoyancy velocity MAE {:?}",
            variant.name(),
            trained.seconds,
            ev.per_sim
        );
        rows.push((variant.name(), ev, trained.seconds));
    }
    eprintln!(
        "| method (seed {seed}) | velocity MAE 1-32 | 1-128 | 65-128 | density MAE 1-32 | 1-128 | 65-128 | train s |"
    );
    eprintln!("|---|---|---|---|---|---|---|---|");
    for (name, ev, secs) in &rows {
        eprintln!(
            "| {name} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {secs:.0} |",
            ev.mean_over(0, 32),
            ev.mean_over(0, steps),
            ev.mean_over(64, steps),
            ev.scalar_mean_over(0, 32),
            ev.scalar_mean_over(0, steps),
            ev.scalar_mean_over(64, steps),
        );
    }
    let get = |name: &str| rows.iter().find(|r| r.0 == name).unwrap().1.clone();
    let (src, non, pre, sol) = (get("source"), get("NON"), get("PRE"), get("SOL-8"));
    let mut missed = Vec::new();
    for (what, measured, bar) in [
        ("SOL-8 velocity MAE over 128 held-out steps < source", sol.mean_over(0, steps), src.mean_over(0, steps)),
        ("SOL-8 velocity MAE steps 65-128 < NON", sol.mean_over(64, steps), non.mean_over(64, steps)),
        ("SOL-8 velocity MAE steps 65-128 < PRE", sol.mean_over(64, steps), pre.mean_over(64, steps)),
    ] {
        let met = measured < bar;
        eprintln!("ACCEPTANCE: measured={measured:.5} bar={bar:.5} ({what}){}", if met { "" } else { " NOT MET" });
        if !met {
            missed.push(format!("{what}: {measured:.5} vs {bar:.5}"));
        }
    }
    eprintln!("total {:.0} s", t_all.elapsed().as_secs_f64());
    assert!(missed.is_empty(), "bars missed: {missed:?}");
}
