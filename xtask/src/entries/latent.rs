//! pbdl-latent's entries: a hybrid smoke rollout against the solver (GIF), the time of the
//! latent operators against the pressure solve they replace, and a long hybrid rollout.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::latent::{configs, TrainArgs};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::Tensor;
use pbdl_core::stepper::Stepper;
use pbdl_core::viz::{rollout_to_gif, GifStyle};
use pbdl_latent::data::{generate, PlumeData};
use pbdl_latent::eval::{autoencoder_error, prediction_error, relative_l2};
use pbdl_latent::hybrid::{HybridSmoke, HybridState, PressureSource, Schedule};
use pbdl_latent::model::LatentModel;
use pbdl_latent::train::train;
use std::path::PathBuf;
use std::time::Instant;

/// This crate's entries.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "latent",
        tour: vec![Entry {
            name: "hybrid_plume",
            about: "Latent-space physics on 2D smoke plumes (quick: 16^2 toy; full: 32^2, 12 + 4 scenes): the pressure autoencoder and LSTM trained, then a held-out plume run by the solver and by the hybrid loop (solver every 2nd step after 50 warm-up steps); GIF of both densities side by side and the density error.",
            run: tour_hybrid,
        }],
        bench: vec![Entry {
            name: "hybrid_step_vs_solver",
            about: "Median time per step of the solver's pressure solve + correction against the latent replacement (encode, LSTM predict, decode, correction) and the whole steps, default architecture (untrained weights: time does not depend on them) at 32^2, 64^2, 128^2 (quick: 32^2).",
            run: bench_hybrid_step,
        }],
        stress: vec![Entry {
            name: "hybrid_long_rollout",
            about: "A hybrid rollout (solver every 2nd step) of 1000 steps (quick: 150) with a briefly trained model: every state finite, density bounded by the injected mass.",
            run: stress_long_rollout,
        }],
    }
}

fn quick_args(quick: bool) -> TrainArgs {
    TrainArgs {
        out: PathBuf::new(),
        res: 32,
        train_scenes: 12,
        test_scenes: 4,
        frames: 160,
        ae_steps: 2000,
        lstm_steps: 3000,
        latent: 8,
        seed: 0,
        quick,
    }
}

fn tour_hybrid(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let (data_cfg, cfg) = configs(&quick_args(ctx.quick));
    let data = generate(&data_cfg)?;
    let t = Instant::now();
    let model = train(&data, &cfg, None)?;
    let train_seconds = t.elapsed().as_secs_f64();
    let ae = autoencoder_error(&model, &data.test)?;
    let pred = prediction_error(&model, &data.test)?;
    let scene = data.config.scene(data.test[0].param);
    let fluid = scene.fluid()?;
    let rate = scene.rate()?;
    let warmup = if ctx.quick { 10 } else { 50 };
    let steps = if ctx.quick { 40 } else { 200 };
    let hybrid = HybridSmoke::new(scene.fluid()?, rate.clone(), &model, Schedule { warmup, interval: 2 })?;
    let mut solver = scene.start(&fluid)?;
    let mut state = HybridState::new(solver.clone());
    let n = data_cfg.resolution;
    let mut frames: Vec<Vec<f32>> = Vec::new();
    let mut worst = 0.0f64;
    for k in 0..steps {
        solver = fluid.step(&solver, Some(&rate))?;
        state = hybrid.step(&state)?;
        let a = solver.density.as_ref().expect("density").values();
        let b = state.fluid.density.as_ref().expect("density").values();
        worst = worst.max(relative_l2(b, a)?);
        if k % 2 == 1 {
            // Rows run from y = 0 upwards in the solver; flip so the plume rises in the picture.
            let pair = Tensor::cat(&[a, b], 3)?.flip(&[2])?;
            frames.push(pair.flatten_all()?.to_vec1::<f32>()?);
        }
    }
    let path = ctx.out_dir.join("latent_hybrid_plume.gif");
    rollout_to_gif(&path, &frames, n, 2 * n, &GifStyle::default())?;
    let md = format!(
        "Latent-space physics, {n}^2 plumes ({} + {} scenes of {} frames), code of {} entries, trained in {train_seconds:.0} s.\n\n\
         Held-out pressure reconstruction rel L2 {ae:.4}; one-step prediction rel L2 {:.4} ({:.2} x the autoencoder floor).\n\
         Hybrid rollout (solver every 2nd step after {warmup} warm-up steps) of a held-out scene: largest density rel L2 \
         against the solver over {steps} steps {worst:.4}.\n\n![solver (left) and hybrid (right) density](latent_hybrid_plume.gif)\n",
        data.train.len(),
        data.test.len(),
        data_cfg.frames,
        model.autoencoder.code_size(),
        pred.predicted,
        pred.ratio
    );
    let rows = vec![
        TourRow {
            item: "pressure autoencoder, held-out".into(),
            seconds: train_seconds,
            error: Some(ae),
            error_kind: "rel L2".into(),
            note: "training time of both networks".into(),
        },
        TourRow {
            item: "hybrid rollout, interval 2".into(),
            seconds: 0.0,
            error: Some(worst),
            error_kind: "max density rel L2 vs solver".into(),
            note: format!("{steps} steps"),
        },
    ];
    Ok(TourOutcome { rows, files: vec![path], markdown: md })
}

fn bench_hybrid_step(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let sizes: &[usize] = if ctx.quick { &[32] } else { &[32, 64, 128] };
    let reps = if ctx.quick { 5 } else { 21 };
    let mut rows = Vec::new();
    for &n in sizes {
        let data_cfg = PlumeData { resolution: n, ..PlumeData::default() };
        let scene = data_cfg.scene(0.5);
        let fluid = scene.fluid()?;
        let rate = scene.rate()?;
        let model = LatentModel::untrained(n)?;
        let mut state = scene.start(&fluid)?;
        for _ in 0..20 {
            state = fluid.step(&state, Some(&rate))?;
        }
        let before = fluid.step_unprojected(&state, Some(&rate))?;
        let (_, pressure) = fluid.project_keep_pressure(&before.velocity)?;
        let w = model.predictor.config().window;
        let code = model.encode_pressure(pressure.values())?;
        let history = Tensor::stack(&vec![code.clone(); w], 1)?;
        let mut row = |case: &str, seconds: f64| {
            rows.push(BenchRow {
                case: format!("latent_{case}"),
                method: "pbdl".into(),
                size: format!("{n}x{n}"),
                seconds,
                unit: "step".into(),
                error: None,
                error_kind: String::new(),
                peer: false,
                threads: ctx.threads,
            })
        };
        row(
            "solver_pressure_solve_and_correct",
            median_seconds(1, reps, || fluid.project_keep_pressure(&before.velocity)),
        );
        row("encode", median_seconds(1, reps, || model.encode_pressure(pressure.values())));
        row("lstm_predict", median_seconds(1, reps, || model.predict(&history)));
        row("decode", median_seconds(1, reps, || model.decode_pressure(&code)));
        row(
            "predicted_pressure_correct",
            median_seconds(1, reps, || fluid.correct_with_pressure(&before.velocity, &pressure)),
        );
        row("solver_step", median_seconds(1, reps, || fluid.step(&state, Some(&rate))));
        let hybrid =
            HybridSmoke::new(scene.fluid()?, rate.clone(), &model, Schedule { warmup: w, interval: 1_000_000 })?;
        let mut hs = HybridState::new(state.clone());
        // The warm-up, then the first solve of the schedule: the next step predicts.
        for _ in 0..=w {
            hs = hybrid.step(&hs)?;
        }
        let probe = hybrid.step(&hs)?;
        if probe.last != Some(PressureSource::Predicted) {
            return Err("the timed hybrid step must use the predicted pressure".into());
        }
        row("hybrid_predicted_step", median_seconds(1, reps, || hybrid.step(&hs)));
    }
    Ok(rows)
}

fn stress_long_rollout(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (data_cfg, cfg) = configs(&quick_args(true));
    let data = generate(&data_cfg)?;
    let model = train(&data, &cfg, None)?;
    let scene = data.config.scene(data.test[0].param);
    let steps: u64 = if ctx.quick { 150 } else { 1000 };
    let hybrid = HybridSmoke::new(scene.fluid()?, scene.rate()?, &model, Schedule { warmup: 10, interval: 2 })?;
    let fluid = scene.fluid()?;
    let rate = scene.rate()?;
    let mut solver = scene.start(&fluid)?;
    let mut state = HybridState::new(solver.clone());
    let mut first_bad = None;
    let (mut max_speed, mut solver_speed) = (0.0f32, 0.0f32);
    let speed = |u: &Tensor| -> TaskResult<f32> { Ok(u.abs()?.max_all()?.to_scalar::<f32>()?) };
    for k in 0..steps {
        state = hybrid.step(&state)?;
        solver = fluid.step(&solver, Some(&rate))?;
        let d = speed(state.fluid.density.as_ref().expect("density").values())?;
        let v = speed(state.fluid.velocity.values())?;
        if !(d.is_finite() && v.is_finite()) {
            first_bad = Some(k);
            break;
        }
        max_speed = max_speed.max(v);
        solver_speed = solver_speed.max(speed(solver.velocity.values())?);
    }
    Ok(vec![
        StressCheck {
            invariant: "hybrid state finite".into(),
            passed: first_bad.is_none(),
            first_broken_step: first_bad,
            detail: format!("{steps} steps at {0}^2, solver every 2nd step, quick-trained model", data_cfg.resolution),
            measure: first_bad.is_none().then_some(StressMeasure::StableSteps(steps)),
        },
        StressCheck {
            invariant: "max speed <= 2x the solver's".into(),
            passed: first_bad.is_none() && max_speed <= 2.0 * solver_speed,
            first_broken_step: None,
            detail: format!("hybrid max |u| {max_speed:.3}, solver {solver_speed:.3}"),
            measure: None,
        },
    ])
}
