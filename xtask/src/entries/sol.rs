//! pbdl-sol's entries: PDE control of forced Burgers (Holl et al. 2020) on held-out scenes, and
//! Solver-in-the-Loop (Um et al. 2020) on a cylinder wake at a held-out Reynolds number.

use crate::bench_schema::BenchRow;
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::viz::{line_plot, rollout_to_gif, ColorRange, FieldStyle, GifStyle, PlotStyle, Series};
use pbdl_sol::control::{
    optimize_forces, pretrain_supervised, scene, train_end_to_end, BurgersControlConfig, ControlScore, Controller,
    ConvNetConfig, DirectOptimConfig, ForcedBurgers, TrainConfig,
};
use pbdl_sol::sil;
use std::time::Instant;

/// This crate's entries.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "sol",
        tour: vec![
            Entry {
                name: "burgers_control",
                about: "PDE control of forced 1D Burgers (128 cells, 32 steps): a short supervised + end-to-end training through the solver, then held-out scenes against the iterative optimiser at equal wall-clock and no control (PNG).",
                run: tour_burgers_control,
            },
            Entry {
                name: "smoke_control",
                about: "2D smoke shape transitions (Holl et al. 2020) on a 32x32 closed box, 16 steps: forces found by the direct optimiser through pbdl-grid's solver move and reshape a density blob into a target shape on held-out scenes (GIF: uncontrolled | controlled | target); the learned controller's claim is its acceptance test.",
                run: tour_smoke_control,
            },
            Entry {
                name: "solver_in_the_loop",
                about: "Solver-in-the-Loop on a small cylinder wake: a plumbing-sized SOL-4 training through the coarse solver, then a corrected rollout at a held-out Reynolds number against the source and the reference (GIF, MAE table).",
                run: tour_solver_in_the_loop,
            },
        ],
        bench: vec![Entry {
            name: "sil_time_vs_error",
            about: "Solver-in-the-Loop time against error on held-out Re: source 1x, SOL-8-corrected 1x (the acceptance test's corrector, trained once and cached), source 2x and 4x (dt 1), reference; velocity MAE vs the 4x reference over 128 steps and time per frame; says whether the corrected coarse solver is cheaper than the fine one at equal error.",
            run: bench_sil_time_vs_error,
        }],
        stress: vec![Entry {
            name: "sil_long_rollout",
            about: "A briefly trained Solver-in-the-Loop corrector rolled out 1000 steps (quick: 50) at a held-out Reynolds number: finite, and max |u| <= 5 x inflow every step.",
            run: stress_sil_long_rollout,
        }],
    }
}

/// One held-out scene's profile as a plot series.
fn profile(name: &str, t: &Tensor, scene: usize) -> TaskResult<Series> {
    let y: Vec<f64> = t.get(scene)?.flatten_all()?.to_dtype(DType::F64)?.to_vec1()?;
    let n = y.len();
    Ok(Series::new(name, (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect(), y))
}

fn tour_burgers_control(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let dev = Device::Cpu;
    let problem = BurgersControlConfig::default();
    let physics = ForcedBurgers::new(&problem)?;
    // The tour shows the pipeline at a few percent of the acceptance run's training
    // (pbdl-sol/tests/control.rs: 1000 scenes, 3000 + 1000 iterations).
    let (n_train, sup_its, e2e_its) = if ctx.quick { (16, 20, 2) } else { (128, 300, 30) };
    let train = scene::generate(&problem, 1, 0..n_train, DType::F32, &dev)?;
    let test = scene::generate(&problem, 2, 0..16, DType::F32, &dev)?;
    let ctrl = Controller::new(&problem, &ConvNetConfig::default(), DType::F32, &dev, 0)?;
    let t0 = Instant::now();
    pretrain_supervised(
        &ctrl,
        &train,
        &TrainConfig { iterations: sup_its, batch: 16, lr: 1e-3, ..Default::default() },
    )?;
    let e2e = TrainConfig { iterations: e2e_its, batch: 8, lr: 1e-4, clip_norm: 10.0, ..Default::default() };
    train_end_to_end(&ctrl, &train, &e2e)?;
    let train_seconds = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let r = ctrl.rollout(&test.initial, &test.target)?;
    let infer = t1.elapsed().as_secs_f64();
    let last = problem.steps;
    let ours = ControlScore::of(&r.forces, problem.dt, &r.states[last], &test.target, problem.target_weight)?;
    let opt = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { time_budget_s: infer, ..Default::default() },
    )?;
    let zero: Vec<Tensor> = (0..last).map(|_| test.initial.zeros_like()).collect::<candle_core::Result<_>>()?;
    let natural = physics.rollout(&test.initial, &zero)?;
    let none = ControlScore::of(&zero, problem.dt, &natural[last], &test.target, problem.target_weight)?;

    let path = ctx.out_dir.join("burgers_control.png");
    let series = [
        profile("initial u_0", &test.initial, 0)?,
        profile("target u*", &test.target, 0)?,
        profile("controlled u_T", &r.states[last], 0)?,
        profile("optimiser (same time) u_T", &opt.final_state, 0)?,
        profile("no control u_T", &natural[last], 0)?,
    ];
    let style = PlotStyle {
        title: "held-out Burgers scene 0".into(),
        x_label: "x".into(),
        y_label: "u".into(),
        ..Default::default()
    };
    line_plot(&path, &series, &style)?;

    let row = |item: &str, seconds: f64, s: &ControlScore, note: String| TourRow {
        item: format!("Burgers control, {item}"),
        seconds,
        error: Some(s.combined),
        error_kind: "effort + target error (16 held-out scenes)".into(),
        note,
    };
    let rows = vec![
        row("controller", infer, &ours, format!("trained {train_seconds:.0} s ({sup_its} + {e2e_its} its)")),
        row("optimiser, same time", opt.seconds, &opt.score, format!("{} Adam steps", opt.iterations)),
        row("no control", 0.0, &none, String::new()),
    ];
    let mut md = format!(
        "Forced 1D Burgers, {} cells, {} steps of dt {}: {n_train} training scenes, {sup_its} supervised + {e2e_its} \
         end-to-end iterations ({train_seconds:.0} s; the acceptance test trains 1000 scenes for 3000 + 1000), 16 held-out scenes.\n\n\
         | | effort | target error | combined | seconds |\n|---|---:|---:|---:|---:|\n",
        problem.cells, problem.steps, problem.dt
    );
    for (name, s, secs) in
        [("controller", &ours, infer), ("optimiser, same time", &opt.score, opt.seconds), ("no control", &none, 0.0)]
    {
        md.push_str(&format!("| {name} | {:.3} | {:.3} | {:.3} | {secs:.3} |\n", s.effort, s.target_error, s.combined));
    }
    md.push_str("\n![held-out scene](burgers_control.png)\n");
    Ok(TourOutcome { rows, files: vec![path], markdown: md })
}

/// Sizes of the Solver-in-the-Loop tour and stress entries: a wake scene, its reference data
/// (training Re and one held-out Re) and a short SOL-4 training.
struct SilSetup {
    wake: sil::WakeConfig,
    data: sil::DataConfig,
    train: sil::TrainConfig,
}

/// Plumbing sizes (the acceptance test, pbdl-sol/tests/sil.rs, uses the paper's 64 x 32 source at
/// 4x reference, six training Re and 2000 updates). Quick: a 16 x 8 source; full: 32 x 16.
fn sil_setup(quick: bool) -> SilSetup {
    let (wake, data, iterations, width) = if quick {
        let wake =
            sil::WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() };
        let data = sil::DataConfig {
            train_re: vec![200.0, 800.0],
            test_re: vec![400.0],
            warmup: 20,
            train_frames: 20,
            test_frames: 17,
        };
        (wake, data, 100, 8)
    } else {
        let wake = sil::WakeConfig { coarse: [32, 16], factor: 2, reference_substeps: 1, ..Default::default() };
        let data = sil::DataConfig {
            train_re: vec![200.0, 400.0, 800.0],
            test_re: vec![566.0],
            warmup: 60,
            train_frames: 80,
            test_frames: 65,
        };
        (wake, data, 1000, 16)
    };
    let train = sil::TrainConfig {
        // The output conv starts at zero: the corrected solver starts as the source.
        corrector: sil::CorrectorConfig { width, blocks: 2, kernel: 3, negative_slope: 0.3, zero_output: true },
        lr: 1e-3,
        batch: 2,
        progress: false,
        ..sil::TrainConfig::new(sil::Variant::Sol { m: 4 }, iterations, 0)
    };
    SilSetup { wake, data, train }
}

/// Vorticity `dv/dx - du/dy` at the interior cell corners of MAC velocities `[1, 2, ny, nx]`:
/// `(ny - 1) * (nx - 1)` values, row-major.
fn corner_vorticity(u: &Tensor, dx: f64, dy: f64) -> TaskResult<Vec<f64>> {
    let (ny, nx) = (u.dim(2)?, u.dim(3)?);
    let a: Vec<f64> = u.narrow(1, 0, 1)?.flatten_all()?.to_dtype(DType::F64)?.to_vec1()?;
    let b: Vec<f64> = u.narrow(1, 1, 1)?.flatten_all()?.to_dtype(DType::F64)?.to_vec1()?;
    let mut w = Vec::with_capacity((ny - 1) * (nx - 1));
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            w.push((b[j * nx + i + 1] - b[j * nx + i]) / dx - (a[(j + 1) * nx + i] - a[j * nx + i]) / dy);
        }
    }
    Ok(w)
}

fn tour_solver_in_the_loop(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let setup = sil_setup(ctx.quick);
    let (wake, data_cfg) = (&setup.wake, &setup.data);
    let t0 = Instant::now();
    let data = sil::generate(wake, data_cfg, DType::F32)?;
    let data_seconds = t0.elapsed().as_secs_f64();
    let trained = sil::train(&data, &setup.train)?;
    let its = setup.train.iterations;
    let last_loss = trained.losses.last().copied().unwrap_or(f64::NAN);

    let held = &data.test[0];
    let steps = held.len() - 1;
    let source = wake.source(held.re)?;
    let start = held.frames.narrow(0, 0, 1)?;
    let t1 = Instant::now();
    let plain = sil::rollout(&source, &start, steps, None)?;
    let plain_seconds = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let corrected = sil::rollout(&source, &start, steps, Some(&trained.corrector))?;
    let corrected_seconds = t2.elapsed().as_secs_f64();
    let mae_src = sil::mae_per_step(&plain, held, 0)?;
    let mae_cor = sil::mae_per_step(&corrected, held, 0)?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (src_mean, cor_mean) = (mean(&mae_src), mean(&mae_cor));

    // Three panels per frame (source | corrected | reference), vorticity, white separators.
    let grid = wake.coarse_grid()?;
    let (h, w) = (grid.ny - 1, grid.nx - 1);
    let width = 3 * w + 2;
    let mut frames = Vec::with_capacity(steps);
    let mut vmax = 0f64;
    for t in 0..steps {
        let reference = held.frames.narrow(0, t + 1, 1)?;
        let panels = [
            corner_vorticity(&plain[t], grid.dx(), grid.dy())?,
            corner_vorticity(&corrected[t], grid.dx(), grid.dy())?,
            corner_vorticity(&reference, grid.dx(), grid.dy())?,
        ];
        vmax = panels[2].iter().fold(vmax, |m, x| m.max(x.abs()));
        let mut f = Vec::with_capacity(h * width);
        for j in 0..h {
            for (k, p) in panels.iter().enumerate() {
                if k > 0 {
                    f.push(f64::NAN);
                }
                f.extend_from_slice(&p[j * w..(j + 1) * w]);
            }
        }
        frames.push(f);
    }
    let gif = ctx.out_dir.join("solver_in_the_loop.gif");
    let style = GifStyle {
        field: FieldStyle {
            range: ColorRange::Symmetric(if vmax > 0.0 { vmax } else { 1.0 }),
            nan_color: [255, 255, 255],
            upscale: Some(8),
            ..FieldStyle::diverging()
        },
        frame_delay_ms: 120,
        repeat: true,
    };
    rollout_to_gif(&gif, &frames, h, width, &style)?;

    let kind = format!("velocity MAE vs reference, {steps} steps, held-out Re {:.0}", held.re);
    let rows = vec![
        TourRow {
            item: "Solver-in-the-Loop, source solver".into(),
            seconds: plain_seconds,
            error: Some(src_mean),
            error_kind: kind.clone(),
            note: format!("{}x{} cells", wake.coarse[0], wake.coarse[1]),
        },
        TourRow {
            item: format!("Solver-in-the-Loop, {}-corrected", setup.train.variant.name()),
            seconds: corrected_seconds,
            error: Some(cor_mean),
            error_kind: kind,
            note: format!(
                "trained {:.1} s ({its} updates, {} parameters); plumbing-sized",
                trained.seconds,
                trained.corrector.parameters()
            ),
        },
    ];
    let mut md = format!(
        "Solver-in-the-Loop on a cylinder wake: a {}x{} source solver corrected after every step by a small \
         ResNet ({} parameters) trained with {} ({its} Adam updates, {:.1} s, last loss {last_loss:.3e}) on \
         reference runs at {}x the resolution for Re {:?} ({} frames each after {} warm-up frames; data {data_seconds:.1} s). \
         Rollout of {steps} steps from the first reference frame at the held-out Re {:.0}.\n\n\
         **Plumbing-sized**: far too little data and training for the ranking to mean anything; the held-out-Re \
         claims are checked by the acceptance test \
         (`cargo test --release -p pbdl-sol --test sil -- --ignored --nocapture`, pbdl-sol/tests/sil.rs).\n\n\
         | | MAE steps 1-{steps} | MAE step 1 | MAE step {steps} | rollout seconds |\n|---|---:|---:|---:|---:|\n",
        wake.coarse[0],
        wake.coarse[1],
        trained.corrector.parameters(),
        setup.train.variant.name(),
        trained.seconds,
        wake.factor,
        data_cfg.train_re,
        data_cfg.train_frames,
        data_cfg.warmup,
        held.re,
    );
    for (name, mae, secs) in [("source", &mae_src, plain_seconds), ("corrected", &mae_cor, corrected_seconds)] {
        md.push_str(&format!("| {name} | {:.5} | {:.5} | {:.5} | {secs:.3} |\n", mean(mae), mae[0], mae[steps - 1]));
    }
    md.push_str(
        "\nVorticity, left to right: source, corrected, reference (one colour scale).\n\n\
         ![source | corrected | reference](solver_in_the_loop.gif)\n",
    );
    Ok(TourOutcome { rows, files: vec![gif], markdown: md })
}

fn stress_sil_long_rollout(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    // Quick: the tiny tour setup as it is; full: the full tour's wake with a 50-update training.
    let mut setup = sil_setup(ctx.quick);
    if !ctx.quick {
        setup.train.iterations = 50;
    }
    let steps = if ctx.quick { 50 } else { 1000 };
    let data = sil::generate(&setup.wake, &setup.data, DType::F32)?;
    let trained = sil::train(&data, &setup.train)?;
    let held = &data.test[0];
    let source = setup.wake.source(held.re)?;
    let bound = 5.0 * setup.wake.inflow;
    let mut s = held.frames.narrow(0, 0, 1)?;
    let (mut first_nonfinite, mut first_unbounded, mut peak) = (None, None, 0f64);
    for t in 1..=steps as u64 {
        s = trained.corrector.apply(&source.step(&s)?, held.re)?.detach();
        let m = s.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        if !m.is_finite() {
            first_nonfinite = Some(t);
            first_unbounded.get_or_insert(t);
            break;
        }
        peak = peak.max(m);
        if m > bound && first_unbounded.is_none() {
            first_unbounded = Some(t);
        }
    }
    let what = format!(
        "{steps} corrected steps of a {}x{} source at held-out Re {:.0}, corrector trained {} updates ({:.1} s)",
        setup.wake.coarse[0], setup.wake.coarse[1], held.re, setup.train.iterations, trained.seconds
    );
    Ok(vec![
        StressCheck {
            invariant: "velocity finite".into(),
            passed: first_nonfinite.is_none(),
            first_broken_step: first_nonfinite,
            detail: what.clone(),
            measure: first_nonfinite.is_none().then_some(StressMeasure::StableSteps(steps as u64)),
        },
        StressCheck {
            invariant: format!("max |u| <= {bound} (5 x inflow)"),
            passed: first_unbounded.is_none(),
            first_broken_step: first_unbounded,
            detail: format!("{what}: peak max |u| {peak:.3}"),
            measure: first_unbounded.is_none().then_some(StressMeasure::StableSteps(steps as u64)),
        },
    ])
}

/// The settings of the time-against-error bench: the scene, the data, the SOL-8 training and
/// the held-out rollouts.
struct SilTimeVsError {
    wake: sil::WakeConfig,
    data: sil::DataConfig,
    train: sil::TrainConfig,
    steps: usize,
    /// Interleaved timing rounds of one frame per method.
    rounds: usize,
}

/// Full: the default wake (source 64 x 32, reference 4x, 2 sub-steps) and exactly the acceptance
/// test's data and SOL-8 training (pbdl-sol/tests/sil.rs, `acceptance_held_out_re`, seed 0: six
/// training Re, 200 frames after 100 warm-up frames, width-16 corrector with 2 blocks, 2000
/// updates, batch 2, Adam 1e-3), 128 steps on the five held-out Re. Quick: plumbing on a 16 x 8
/// wake (reference 4x).
fn sil_time_vs_error_setup(quick: bool) -> SilTimeVsError {
    let net = sil::CorrectorConfig { width: 16, blocks: 2, kernel: 5, negative_slope: 0.3, zero_output: true };
    let (wake, data, iterations, steps, rounds) = if quick {
        let wake =
            sil::WakeConfig { coarse: [16, 8], factor: 4, radius: 14.0, reference_substeps: 1, ..Default::default() };
        let data = sil::DataConfig {
            train_re: vec![200.0, 800.0],
            test_re: vec![400.0],
            warmup: 10,
            train_frames: 12,
            test_frames: 9,
        };
        (wake, data, 10, 8, 3)
    } else {
        let data = sil::DataConfig { warmup: 100, train_frames: 200, test_frames: 129, ..Default::default() };
        (sil::WakeConfig::default(), data, 2000, 128, 30)
    };
    let train = sil::TrainConfig {
        corrector: net,
        batch: 2,
        lr: 1e-3,
        progress: false,
        ..sil::TrainConfig::new(sil::Variant::Sol { m: 8 }, iterations, 0)
    };
    SilTimeVsError { wake, data, train, steps, rounds }
}

/// What a cached corrector was trained with (the weights are reused only when all of it matches).
#[derive(serde::Serialize, serde::Deserialize, PartialEq)]
struct CachedCorrector {
    wake: sil::WakeConfig,
    data: sil::DataConfig,
    train: sil::TrainConfig,
    norm: sil::Normalisation,
    seconds: f64,
}

/// The SOL-8 corrector of `setup`: loaded from `dir` when a run with the same settings saved it,
/// trained (and saved) otherwise. Returns it with the training seconds and whether it was cached.
fn sil_corrector(setup: &SilTimeVsError, dir: &std::path::Path) -> TaskResult<(sil::Corrector, f64, bool)> {
    let stem = dir.join(format!("sil_sol8_{}x{}_seed{}", setup.wake.coarse[0], setup.wake.coarse[1], setup.train.seed));
    let (weights, meta) = (stem.with_extension("safetensors"), stem.with_extension("json"));
    if let Ok(text) = std::fs::read_to_string(&meta) {
        if let Ok(c) = serde_json::from_str::<CachedCorrector>(&text) {
            if c.wake == setup.wake && c.data == setup.data && c.train == setup.train && weights.is_file() {
                let mut net = sil::Corrector::new(c.train.corrector, c.norm, DType::F32, c.train.seed)?;
                net.load(&weights)?;
                return Ok((net, c.seconds, true));
            }
        }
    }
    let t = Instant::now();
    let data = sil::generate(&setup.wake, &sil::DataConfig { test_re: vec![], ..setup.data.clone() }, DType::F32)?;
    eprintln!("sil_time_vs_error: training data {:.0} s", t.elapsed().as_secs_f64());
    let trained = sil::train(&data, &setup.train)?;
    eprintln!("sil_time_vs_error: SOL-8 trained {:.0} s", trained.seconds);
    trained.corrector.save(&weights)?;
    let c = CachedCorrector {
        wake: setup.wake.clone(),
        data: setup.data.clone(),
        train: setup.train.clone(),
        norm: *trained.corrector.normalisation(),
        seconds: trained.seconds,
    };
    std::fs::write(&meta, serde_json::to_string_pretty(&c)?)?;
    Ok((trained.corrector, trained.seconds, false))
}

/// One held-out reference run kept at two resolutions: `fine` holds the reference's own state at
/// the first recorded frame, `half` the frames face-averaged to 2x the source grid, `coarse` to
/// the source grid (the same `T r_t` as [`sil::reference_run`], averaged in two halvings).
struct HeldOut {
    fine0: Tensor,
    half: Tensor,
    coarse: sil::ReferenceSim,
}

fn held_out_run(wake: &sil::WakeConfig, re: f64, warmup: usize, frames: usize) -> TaskResult<HeldOut> {
    let fluid = wake.reference_stepper(re)?;
    let mut s = wake.initial_state(&fluid, wake.reference_grid()?, DType::F32)?;
    let (mut half, mut fine0) = (Vec::with_capacity(frames), None);
    for t in 0..warmup + frames {
        if t >= warmup {
            fine0.get_or_insert_with(|| s.velocity.values().clone());
            half.push(sil::downsample_mac(s.velocity.values(), wake.factor / 2)?);
        }
        for _ in 0..wake.reference_substeps {
            s = fluid.step(&s, None)?;
        }
    }
    let half = Tensor::cat(&half, 0)?;
    let coarse = sil::downsample_mac(&half, 2)?;
    let fine0 = fine0.ok_or("no frames recorded")?;
    Ok(HeldOut { fine0, half, coarse: sil::ReferenceSim { re, frames: coarse, source: None } })
}

/// Median of `v` (sorted copy).
fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Time against error for Solver-in-the-Loop on held-out Re.
///
/// Bar, written before measuring: **corrected 1x reaches MAE <= source 2x's at lower time per
/// step** (velocity MAE against the 4x reference face-averaged to the source grid, mean over the
/// held-out Re and the steps; time per frame of simulated time dt = 1, batch 1, median of
/// interleaved rounds).
///
/// Rows: the source solver at 1x (64 x 32), the SOL-8-corrected source at 1x, the source at 2x
/// (128 x 64) and 4x (256 x 128) with the source's time step (its states face-averaged to the
/// source grid), and the reference itself (256 x 128, 2 sub-steps per frame; no error: it is the
/// target). The 2x and 4x sources start from the reference's first frame at their resolution.
/// The corrector is the acceptance test's SOL-8 (same data, settings and seed), trained on the
/// first run and cached in `target/pbdl/bench/sol/` (delete the files there to retrain).
fn bench_sil_time_vs_error(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let setup = sil_time_vs_error_setup(ctx.quick);
    let wake = &setup.wake;
    let [nx, ny] = wake.coarse;
    let wake2 = sil::WakeConfig { coarse: [2 * nx, 2 * ny], factor: wake.factor / 2, ..wake.clone() };
    let wake4 = sil::WakeConfig { coarse: [wake.factor * nx, wake.factor * ny], factor: 2, ..wake.clone() };
    if wake.factor != 4 {
        return Err("the bench compares 1x, 2x and 4x grids: use a 4x reference".into());
    }
    let (corrector, train_seconds, cached) = sil_corrector(&setup, &ctx.out_dir)?;
    let steps = setup.steps;
    // name, size, MAE per held-out Re, seconds per frame per round
    let names = ["source_1x", "sol8_corrected_1x", "source_2x_dt1", "source_4x_dt1", "reference_4x"];
    let mut mae: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let mut rollout_wall = vec![0.0; names.len()];
    let t_ref = Instant::now();
    let mut res = Vec::new();
    for &re in &setup.data.test_re {
        let held = held_out_run(wake, re, setup.data.warmup, setup.data.test_frames)?;
        let (src1, src2, src4) = (wake.source(re)?, wake2.source(re)?, wake4.source(re)?);
        let reference = wake.reference_stepper(re)?;
        let start1 = held.coarse.frames.narrow(0, 0, 1)?;
        let start2 = held.half.narrow(0, 0, 1)?;
        let mean = |v: Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
        let timed = |f: &mut dyn FnMut() -> TaskResult<Vec<Tensor>>| -> TaskResult<(Vec<Tensor>, f64)> {
            let t = Instant::now();
            let s = f()?;
            Ok((s, t.elapsed().as_secs_f64() / steps as f64))
        };
        let (s1, w1) = timed(&mut || Ok(sil::rollout(&src1, &start1, steps, None)?))?;
        let (c1, wc) = timed(&mut || Ok(sil::rollout(&src1, &start1, steps, Some(&corrector))?))?;
        let (s2, w2) = timed(&mut || Ok(sil::rollout(&src2, &start2, steps, None)?))?;
        let (s4, w4) = timed(&mut || Ok(sil::rollout(&src4, &held.fine0, steps, None)?))?;
        let down = |states: &[Tensor], f: usize| -> TaskResult<Vec<Tensor>> {
            states.iter().map(|s| Ok(sil::downsample_mac(s, f)?)).collect()
        };
        let per_method = [s1, c1.clone(), down(&s2, 2)?, down(&s4, wake.factor)?];
        for (k, states) in per_method.iter().enumerate() {
            mae[k].push(mean(sil::mae_per_step(states, &held.coarse, 0)?));
        }
        for (k, w) in [w1, wc, w2, w4].into_iter().enumerate() {
            rollout_wall[k] += w / setup.data.test_re.len() as f64;
        }
        // Interleaved timing of one frame each, from the states halfway through the rollouts.
        let mid = steps / 2;
        let fine = fluid_state(&s4[mid], wake4.coarse_grid()?, wake.boundaries()?)?;
        for _ in 0..setup.rounds {
            let mut time = |k: usize, f: &mut dyn FnMut() -> TaskResult<()>| -> TaskResult<()> {
                let t = Instant::now();
                f()?;
                times[k].push(t.elapsed().as_secs_f64());
                Ok(())
            };
            time(0, &mut || {
                std::hint::black_box(src1.step(&per_method[0][mid])?);
                Ok(())
            })?;
            time(1, &mut || {
                std::hint::black_box(corrector.apply(&src1.step(&c1[mid])?, re)?.detach());
                Ok(())
            })?;
            time(2, &mut || {
                std::hint::black_box(src2.step(&s2[mid])?);
                Ok(())
            })?;
            time(3, &mut || {
                std::hint::black_box(src4.step(&s4[mid])?);
                Ok(())
            })?;
            time(4, &mut || {
                let mut s = fine.clone();
                for _ in 0..wake.reference_substeps {
                    s = reference.step(&s, None)?;
                }
                std::hint::black_box(s);
                Ok(())
            })?;
        }
        res.push(re);
        eprintln!(
            "sil_time_vs_error: Re {re:.1}: MAE source 1x {:.4}, corrected {:.4}, source 2x {:.4}, source 4x {:.4}",
            mae[0].last().unwrap_or(&f64::NAN),
            mae[1].last().unwrap_or(&f64::NAN),
            mae[2].last().unwrap_or(&f64::NAN),
            mae[3].last().unwrap_or(&f64::NAN)
        );
    }
    let eval_seconds = t_ref.elapsed().as_secs_f64();
    let avg = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let err: Vec<Option<f64>> = (0..names.len()).map(|k| (k < 4).then(|| avg(&mae[k]))).collect();
    let secs: Vec<f64> = times.iter().map(|t| median(t)).collect();
    let sizes = [
        format!("{nx}x{ny}"),
        format!("{nx}x{ny}"),
        format!("{}x{}", 2 * nx, 2 * ny),
        format!("{}x{}", 4 * nx, 4 * ny),
        format!("{}x{}", 4 * nx, 4 * ny),
    ];
    let error_kind = format!("velocity_mae_vs_4x_reference_{steps}_steps_{}_held_out_re", res.len());
    let rows: Vec<BenchRow> = (0..names.len())
        .map(|k| BenchRow {
            case: "sil_wake_held_out_re".into(),
            method: format!("pbdl_{}", names[k]),
            size: sizes[k].clone(),
            seconds: secs[k],
            unit: "frame".into(),
            error: err[k],
            error_kind: if err[k].is_some() { error_kind.clone() } else { String::new() },
            peer: false,
            threads: ctx.threads,
        })
        .collect();
    let (cor_mae, src2_mae) = (err[1].unwrap_or(f64::NAN), err[2].unwrap_or(f64::NAN));
    let met = cor_mae <= src2_mae && secs[1] < secs[2];
    let verdict = format!(
        "BAR (set before measuring): corrected 1x reaches MAE <= source 2x's at lower time per step: {} \
         (MAE {cor_mae:.4} vs {src2_mae:.4}; {:.2} ms vs {:.2} ms per frame, ratio {:.2})",
        if met { "MET" } else { "NOT MET" },
        1e3 * secs[1],
        1e3 * secs[2],
        secs[1] / secs[2]
    );
    let cheaper_than_fine: Vec<String> = (2..4)
        .map(|k| {
            let lower_err = cor_mae <= err[k].unwrap_or(f64::NAN);
            format!(
                "{}: corrected is {:.2}x its time per frame at {} error",
                names[k],
                secs[1] / secs[k],
                if lower_err { "equal or lower" } else { "higher" }
            )
        })
        .collect();
    let mut md = format!(
        "Solver-in-the-Loop, time against error on held-out Re {res:?} ({steps} steps from the first recorded frame, \
         {} warm-up frames). Corrector: SOL-8, {} parameters, {} updates ({}: {train_seconds:.0} s). Time per frame \
         (dt = 1), batch 1, median of {} interleaved rounds per Re on {} threads; evaluation {eval_seconds:.0} s.\n\n\
         | method | grid | MAE vs reference | ms per frame (median) | ms per frame (rollout wall) |\n|---|---|---:|---:|---:|\n",
        setup.data.warmup,
        corrector.parameters(),
        setup.train.iterations,
        if cached { "cached weights, trained" } else { "trained now" },
        setup.rounds,
        ctx.threads,
    );
    for k in 0..names.len() {
        md.push_str(&format!(
            "| {} | {} | {} | {:.2} | {} |\n",
            names[k],
            sizes[k],
            err[k].map_or("(target)".into(), |e| format!("{e:.4}")),
            1e3 * secs[k],
            if k < 4 { format!("{:.2}", 1e3 * rollout_wall[k]) } else { "-".into() }
        ));
    }
    md.push_str("\nPer held-out Re, MAE (source 1x / corrected 1x / source 2x / source 4x):\n\n");
    for (i, re) in res.iter().enumerate() {
        md.push_str(&format!(
            "* Re {re:.1}: {:.4} / {:.4} / {:.4} / {:.4}\n",
            mae[0][i], mae[1][i], mae[2][i], mae[3][i]
        ));
    }
    md.push_str(&format!("\n{verdict}\n\n{}\n", cheaper_than_fine.join("\n\n")));
    std::fs::write(ctx.out_dir.join("sil_time_vs_error.md"), &md)?;
    eprintln!("{md}");
    Ok(rows)
}

/// A fine MAC state as the reference solver's input.
/// Held-out smoke shape transitions driven by the direct optimiser's forces: a GIF of the
/// uncontrolled (at rest) density, the controlled density and the target, side by side.
fn tour_smoke_control(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    use pbdl_sol::smoke_control::{self as smoke, SmokeControlConfig};
    let problem = if ctx.quick {
        SmokeControlConfig { cells: 8, steps: 2, loss_levels: 2, ..Default::default() }
    } else {
        SmokeControlConfig::default()
    };
    let (scenes_n, updates) = if ctx.quick { (1, 3) } else { (2, 60) };
    let scenes = smoke::scene::generate(&problem, 2, 0..scenes_n, DType::F32, &Device::Cpu)?;
    let cfg = smoke::DirectOptimConfig { max_iterations: updates, time_budget_s: 600.0, ..Default::default() };
    let opt = smoke::optimize_forces(&problem, &scenes.initial, &scenes.target, &cfg)?;
    let rest: Vec<Tensor> =
        (0..problem.steps).map(|_| opt.forces[0].zeros_like()).collect::<candle_core::Result<_>>()?;
    let uncontrolled =
        smoke::SmokeScore::of(&rest, &scenes.initial, &scenes.target, problem.loss_levels, problem.effort_weight)?;

    // One row of three panels per scene (uncontrolled | controlled | target), NaN separators.
    let n = problem.cells;
    let width = 3 * n + 2;
    let to_vec = |t: &Tensor| -> TaskResult<Vec<f64>> { Ok(t.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?) };
    let (initial, target) = (to_vec(&scenes.initial)?, to_vec(&scenes.target)?);
    let mut frames = Vec::with_capacity(problem.steps + 1);
    let mut vmax = 0f64;
    for state in &opt.states {
        let controlled = to_vec(&state.density)?;
        let mut f = Vec::with_capacity(scenes_n * (n + 1) * width);
        for k in 0..scenes_n {
            if k > 0 {
                f.extend(std::iter::repeat_n(f64::NAN, width));
            }
            // Row 0 (y = 0) is drawn at the bottom; scene 0 is the bottom row of panels.
            for j in 0..n {
                let row = |v: &[f64]| v[k * n * n + j * n..k * n * n + (j + 1) * n].to_vec();
                for (p, panel) in [row(&initial), row(&controlled), row(&target)].into_iter().enumerate() {
                    if p > 0 {
                        f.push(f64::NAN);
                    }
                    vmax = panel.iter().fold(vmax, |m, x| m.max(*x));
                    f.extend(panel);
                }
            }
        }
        frames.push(f);
    }
    let height = scenes_n * (n + 1) - 1;
    let gif = ctx.out_dir.join("smoke_control.gif");
    let style = GifStyle {
        field: FieldStyle {
            range: ColorRange::Fixed(0.0, if vmax > 0.0 { vmax } else { 1.0 }),
            nan_color: [255, 255, 255],
            upscale: Some(8),
            ..FieldStyle::default()
        },
        frame_delay_ms: 200,
        repeat: true,
    };
    rollout_to_gif(&gif, &frames, height, width, &style)?;

    let kind = format!("final-density error ||rho_T - rho*||^2, mean of {scenes_n} held-out scenes");
    let rows = vec![
        TourRow {
            item: "smoke shape transition, no control".into(),
            seconds: 0.0,
            error: Some(uncontrolled.target_error),
            error_kind: kind.clone(),
            note: format!("{n}x{n} closed box, {} steps", problem.steps),
        },
        TourRow {
            item: "smoke shape transition, direct optimiser".into(),
            seconds: opt.seconds,
            error: Some(opt.score.target_error),
            error_kind: kind,
            note: format!("{} Adam updates on the {} force fields, through the solver", opt.iterations, problem.steps),
        },
    ];
    let md = format!(
        "2D smoke shape transitions (Holl et al. 2020): a density blob at rest in a {n}x{n} closed box must take \
         the target's shape and place after {} steps; each step adds a force field to the velocity, self-advects, \
         projects (pbdl-grid) and advects the density conservatively. Here the forces of {scenes_n} held-out \
         scenes are found by the direct optimiser ({} Adam updates through the solver, {:.1} s): final-density \
         error {:.2} vs {:.2} without control, effort {:.1}.\n\n\
         The learned controller (observation predictors + force estimator, trained end to end) is checked by \
         the acceptance test (`cargo test --release -p pbdl-sol --test smoke_control -- --ignored --nocapture`): \
         see the README's pbdl-sol section.\n\n\
         Density, left to right: uncontrolled (at rest), controlled, target; one row per scene.\n\n\
         ![uncontrolled | controlled | target](smoke_control.gif)\n",
        problem.steps, opt.iterations, opt.seconds, opt.score.target_error, uncontrolled.target_error, opt.score.effort,
    );
    Ok(TourOutcome { rows, files: vec![gif], markdown: md })
}

fn fluid_state(values: &Tensor, grid: pbdl_grid::Grid, bc: pbdl_grid::Boundaries) -> TaskResult<pbdl_grid::FluidState> {
    Ok(pbdl_grid::FluidState { velocity: pbdl_grid::MacField::new(values.clone(), grid, bc)?, density: None })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quick tour runs end to end, writes its plot, and the controller's numbers are finite
    /// (the quick training is far too short for its ranking to mean anything).
    #[test]
    fn quick_burgers_control_tour_writes_its_plot() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 1 };
        let out = tour_burgers_control(&ctx).unwrap();
        assert_eq!(out.rows.len(), 3);
        assert!(out.rows.iter().all(|r| r.error.is_some_and(f64::is_finite)), "{:?}", out.rows);
        assert!(dir.path().join("burgers_control.png").exists());
    }

    /// The quick smoke-control tour runs end to end, writes its GIF, and the optimiser's
    /// final-density error is finite.
    #[test]
    fn quick_smoke_control_tour_writes_its_gif() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 1 };
        let out = tour_smoke_control(&ctx).unwrap();
        assert_eq!(out.rows.len(), 2);
        assert!(out.rows.iter().all(|r| r.error.is_some_and(f64::is_finite)), "{:?}", out.rows);
        assert!(dir.path().join("smoke_control.gif").exists());
    }

    /// The quick Solver-in-the-Loop tour runs end to end (tiny wake, a few SOL-4 updates),
    /// writes its GIF, and both MAEs are finite.
    #[test]
    fn quick_solver_in_the_loop_tour_writes_its_gif() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 1 };
        let out = tour_solver_in_the_loop(&ctx).unwrap();
        eprintln!("{}", out.markdown);
        assert_eq!(out.rows.len(), 2);
        assert!(out.rows.iter().all(|r| r.error.is_some_and(f64::is_finite)), "{:?}", out.rows);
        assert!(dir.path().join("solver_in_the_loop.gif").exists());
        assert!(out.markdown.contains("acceptance test"));
    }

    /// The quick long-rollout stress (50 corrected steps) stays finite and bounded.
    #[test]
    fn quick_sil_long_rollout_stays_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 1 };
        let checks = stress_sil_long_rollout(&ctx).unwrap();
        assert_eq!(checks.len(), 2);
        assert!(checks.iter().all(|c| c.passed), "{checks:?}");
    }

    /// The quick time-against-error bench (16 x 8 wake, 10 SOL-8 updates) runs end to end: five
    /// rows, errors finite (none for the reference), times positive; the second run reuses the
    /// cached corrector and gets the same errors.
    #[test]
    fn quick_sil_time_vs_error_bench_runs_and_caches() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 1 };
        let rows = bench_sil_time_vs_error(&ctx).unwrap();
        assert_eq!(rows.len(), 5);
        assert!(rows.iter().all(|r| r.seconds > 0.0), "{rows:?}");
        assert!(rows[..4].iter().all(|r| r.error.is_some_and(f64::is_finite)), "{rows:?}");
        assert!(rows[4].error.is_none());
        assert!(dir.path().join("sil_sol8_16x8_seed0.safetensors").is_file());
        let md = std::fs::read_to_string(dir.path().join("sil_time_vs_error.md")).unwrap();
        assert!(md.contains("BAR (set before measuring)"), "{md}");
        let again = bench_sil_time_vs_error(&ctx).unwrap();
        let errs = |r: &[BenchRow]| r.iter().map(|r| r.error).collect::<Vec<_>>();
        assert_eq!(errs(&rows), errs(&again));
        assert!(std::fs::read_to_string(dir.path().join("sil_time_vs_error.md")).unwrap().contains("cached"));
    }

    /// Full-size smoke-control tour: prints the markdown and keeps the GIF in
    /// `target/pbdl/tour-check/smoke_control.gif`.
    #[test]
    #[ignore]
    fn full_smoke_control_tour() {
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/pbdl/tour-check");
        std::fs::create_dir_all(&dir).unwrap();
        let ctx = TaskContext { out_dir: dir, quick: false, threads: 2 };
        let t = Instant::now();
        let out = tour_smoke_control(&ctx).unwrap();
        eprintln!("{}\n{:?}\ntotal {:.1} s", out.markdown, out.rows, t.elapsed().as_secs_f64());
        assert!(out.rows[1].error.unwrap() < out.rows[0].error.unwrap(), "{:?}", out.rows);
    }

    /// Full-size tour (release, about a minute): prints the markdown.
    /// `cargo test --release -p xtask --lib entries::sol -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn full_solver_in_the_loop_tour() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: false, threads: 2 };
        let t = Instant::now();
        let out = tour_solver_in_the_loop(&ctx).unwrap();
        eprintln!("{}\n{:?}\ntotal {:.1} s", out.markdown, out.rows, t.elapsed().as_secs_f64());
        let checks = stress_sil_long_rollout(&ctx).unwrap();
        eprintln!("{checks:?}");
    }
}
