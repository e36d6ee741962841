//! pbdl-sol's entries: PDE control of forced Burgers (Holl et al. 2020) on held-out scenes, and
//! Solver-in-the-Loop (Um et al. 2020) on a cylinder wake at a held-out Reynolds number.

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
                name: "solver_in_the_loop",
                about: "Solver-in-the-Loop on a small cylinder wake: a plumbing-sized SOL-4 training through the coarse solver, then a corrected rollout at a held-out Reynolds number against the source and the reference (GIF, MAE table).",
                run: tour_solver_in_the_loop,
            },
        ],
        bench: vec![],
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
