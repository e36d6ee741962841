//! pbdl-temporal's entries: a side-by-side GIF of the super-resolution methods on a held-out
//! plume, the time per generated frame and per training update against the solver's step, and
//! a long generation.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use crate::temporal::{configs, TrainArgs};
use candle_core::{Device, Tensor};
use pbdl_core::viz::{rollout_to_gif, GifStyle};
use pbdl_temporal::data::{generate, SmokeData};
use pbdl_temporal::eval::{bicubic, default_lsim, evaluate, MARKDOWN_HEADER};
use pbdl_temporal::generator::GeneratorConfig;
use pbdl_temporal::model::{ModelKind, TemporalModel};
use pbdl_temporal::tecogan::{
    train_tecogan, MotionNetConfig, RecurrentGeneratorConfig, Rollout, TecoGanConfig, TecoTrainConfig,
};
use pbdl_temporal::train::{finetune, pretrain, train_all, PhaseSettings, TrainConfig};
use std::path::PathBuf;
use std::time::Instant;

/// This crate's entries.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "temporal",
        tour: vec![Entry {
            name: "superres_plume",
            about: "Temporally coherent 4x super-resolution of smoke (quick: 8^2 -> 32^2 toy; full: 16^2 -> 64^2, 6 + 2 scenes, 300 pre-training + 200 updates per objective): bicubic, per-frame GAN, temporal GAN and the truth side by side on a held-out plume (GIF), with PSNR / LSiM / tOF / tLSiM of each.",
            run: tour_superres,
        }],
        bench: vec![Entry {
            name: "generation_vs_solver",
            about: "Median time per generated frame of the default generator (untrained weights: time does not depend on them) at 16->64 and 64->256 (quick: 16->64) against the solver's step at the high resolution, and one training update of each objective at 16->64 (batch 4 triplets).",
            run: bench_generation,
        }],
        stress: vec![
            Entry {
                name: "long_generation",
                about: "1000 frames (quick: 100) of a held-out sequence played forwards and backwards, upscaled by a briefly trained temporal GAN: every frame finite, the mean density of the output stays within 5% of the input's (no drift of mass).",
                run: stress_long_generation,
            },
            Entry {
                name: "recurrent_long_generation",
                about: "1000 frames (quick: 100) of a held-out sequence played forwards and backwards through a briefly trained frame-recurrent TecoGAN generator (its own output warped and fed back every frame): every frame finite, and no drift: the last frame differs from a fresh run to the same low-resolution frame by at most 10% of the frame's mean density.",
                run: stress_recurrent_generation,
            },
        ],
    }
}

fn args(quick: bool) -> TrainArgs {
    TrainArgs {
        out: PathBuf::new(),
        lr_res: 16,
        train_scenes: 6,
        test_scenes: 2,
        frames: 48,
        pretrain_steps: 300,
        steps: 200,
        channels: 32,
        temporal_weight: 1.0,
        seed: 0,
        quick,
    }
}

fn tour_superres(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let (data_cfg, cfg) = configs(&args(ctx.quick));
    let data = generate(&data_cfg)?;
    let t = Instant::now();
    let models: Vec<TemporalModel> = train_all(&data, &cfg, None)?.into_iter().map(|(m, _)| m).collect();
    let train_seconds = t.elapsed().as_secs_f64();
    let lsim = default_lsim()?;
    let rows = evaluate(&models, &data.test, lsim.as_ref())?;
    let clip = &data.test[0];
    let f = data_cfg.factor;
    let pick = |k: ModelKind| models.iter().find(|m| m.info.kind == k).expect("trained");
    let panels = [
        bicubic(&clip.lr_density, f)?,
        pick(ModelKind::PerFrame).upscale(&clip.lr_density, None)?,
        pick(ModelKind::Temporal).upscale(&clip.lr_density, None)?,
        clip.hr_density.clone(),
    ];
    // Rows run from y = 0 upwards; flip so the plume rises in the picture.
    let strip = Tensor::cat(&panels, 3)?.flip(&[2])?;
    let n = data_cfg.hr_resolution();
    let frames: Vec<Vec<f32>> =
        (0..clip.frames()).map(|t| strip.get(t)?.flatten_all()?.to_vec1::<f32>()).collect::<Result<_, _>>()?;
    let path = ctx.out_dir.join("temporal_superres_plume.gif");
    rollout_to_gif(&path, &frames, n, 4 * n, &GifStyle::default())?;
    let mut md = format!(
        "Temporally coherent super-resolution, {0}^2 -> {1}^2 plumes ({2} + {3} scenes of {4} frames), three models trained in {train_seconds:.0} s from one L1 pre-training{5}.\n\n{MARKDOWN_HEADER}\n",
        data_cfg.lr_resolution,
        n,
        data.train.len(),
        data.test.len(),
        data_cfg.frames,
        if lsim.is_none() { " (no LSiM weights found: LSiM and tLSiM not computed)" } else { "" }
    );
    for r in &rows {
        md.push_str(&r.markdown_row());
        md.push('\n');
    }
    md.push_str("\n![bicubic | per-frame GAN | temporal GAN | truth](temporal_superres_plume.gif)\n");
    let tour_rows = rows
        .iter()
        .map(|r| TourRow {
            item: r.method.clone(),
            seconds: r.ms_per_frame * 1e-3,
            error: Some(r.tof),
            error_kind: "tOF (px)".into(),
            note: format!("LSiM {:?}, tLSiM {:?}, PSNR {:.2} dB", r.lsim, r.tlsim, r.psnr),
        })
        .collect();
    Ok(TourOutcome { rows: tour_rows, files: vec![path], markdown: md })
}

fn bench_generation(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let sizes: &[usize] = if ctx.quick { &[16] } else { &[16, 64] };
    let reps = if ctx.quick { 3 } else { 11 };
    let mut rows = Vec::new();
    let mut row = |case: &str, size: String, seconds: f64, unit: &str| {
        rows.push(BenchRow {
            case: format!("temporal_{case}"),
            method: "pbdl".into(),
            size,
            seconds,
            unit: unit.into(),
            error: None,
            error_kind: String::new(),
            peer: false,
            threads: ctx.threads,
        })
    };
    let model = TemporalModel::untrained(ModelKind::Temporal, GeneratorConfig::default(), 0)?;
    for &n in sizes {
        let batch = 8;
        let lr = Tensor::rand(0f32, 1.0, (batch, 1, n, n), &Device::Cpu)?;
        let s = median_seconds(1, reps, || model.upscale(&lr, None));
        row("generate_frame", format!("{n}->{}", 4 * n), s / batch as f64, "frame");
        // The solver step at the high resolution (one noisy-inflow plume step).
        let data = SmokeData {
            lr_resolution: n,
            train_scenes: 1,
            test_scenes: 1,
            frames: 1,
            warmup: 0,
            ..SmokeData::default()
        };
        let (scenes, _) = data.scenes();
        let t = Instant::now();
        let steps = 20;
        let long = SmokeData { frames: steps, ..data.clone() };
        pbdl_temporal::data::simulate(&long, &scenes[0])?;
        row("solver_step", format!("{}x{}", 4 * n, 4 * n), t.elapsed().as_secs_f64() / steps as f64, "step");
    }
    // One training update of each objective at 16 -> 64 (median of the phase's own timings).
    let data = generate(&SmokeData { train_scenes: 2, test_scenes: 1, frames: 8, ..SmokeData::default() })?;
    let updates = if ctx.quick { 3 } else { 11 };
    let cfg = TrainConfig {
        pretrain: PhaseSettings { steps: 1, ..TrainConfig::default().pretrain },
        finetune: PhaseSettings { steps: updates, ..TrainConfig::default().finetune },
        ..TrainConfig::default()
    };
    let (start, _) = pretrain(&data, &cfg, None)?;
    for kind in ModelKind::ALL {
        let (_, s) = finetune(&data, &cfg, kind, &start, None)?;
        row(&format!("train_update_{}", kind.name()), "16->64_b4x3".into(), s.median_step_seconds, "update");
    }
    Ok(rows)
}

/// Indices `0, 1, .., T-1, T-2, .., 0, 1, ..` (`total` of them): a clip played forwards and
/// backwards.
fn ping_pong_order(t_len: usize, total: usize) -> Vec<u32> {
    (0..total)
        .map(|k| {
            let p = k % (2 * t_len - 2).max(1);
            (if p < t_len { p } else { 2 * t_len - 2 - p }) as u32
        })
        .collect()
}

fn stress_recurrent_generation(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (data_cfg, _) = configs(&args(true));
    let data = generate(&data_cfg)?;
    let cfg = TecoTrainConfig {
        model: TecoGanConfig {
            motion: MotionNetConfig { base_width: 8, ..Default::default() },
            generator: RecurrentGeneratorConfig { channels: 8, blocks: 2, ..Default::default() },
        },
        steps: 20,
        batch: 2,
        ..Default::default()
    };
    let (model, _, _) = train_tecogan(&data.train, &cfg)?;
    let clip = &data.test[0];
    let total = if ctx.quick { 100 } else { 1000 };
    let order = ping_pong_order(clip.frames(), total);
    let mut rollout = Rollout::new(&model);
    let (mut first_bad, mut last) = (None, None);
    let mut max_abs = 0.0f32;
    for (k, &i) in order.iter().enumerate() {
        let g = rollout.step(&clip.lr_density.narrow(0, i as usize, 1)?)?;
        let m = g.abs()?.max_all()?.to_scalar::<f32>()?;
        if !m.is_finite() {
            first_bad = Some(k as u64);
            break;
        }
        max_abs = max_abs.max(m);
        last = Some(g);
    }
    // A fresh run over the last few frames before the end: after the same recent inputs, a
    // generator that does not drift gives (nearly) the same last frame.
    let mut fresh = Rollout::new(&model);
    let mut fresh_last = None;
    for &i in &order[total - 8..] {
        fresh_last = Some(fresh.step(&clip.lr_density.narrow(0, i as usize, 1)?)?);
    }
    let (diff, scale) = match (&last, &fresh_last) {
        (Some(a), Some(b)) => {
            ((a - b)?.abs()?.mean_all()?.to_scalar::<f32>()? as f64, b.abs()?.mean_all()?.to_scalar::<f32>()? as f64)
        }
        _ => (f64::NAN, f64::NAN),
    };
    Ok(vec![
        StressCheck {
            invariant: "every recurrent frame finite".into(),
            passed: first_bad.is_none(),
            first_broken_step: first_bad,
            detail: format!(
                "{total} frames at {}^2 -> {}^2, max |g| {max_abs:.3}",
                data_cfg.lr_resolution,
                data_cfg.hr_resolution()
            ),
            measure: first_bad.is_none().then_some(StressMeasure::StableSteps(total as u64)),
        },
        StressCheck {
            invariant: "last frame within 10% of a fresh run's".into(),
            passed: first_bad.is_none() && diff <= 0.1 * scale,
            first_broken_step: None,
            detail: format!(
                "mean |g - g_fresh| {diff:.3e} vs mean |g_fresh| {scale:.3e} (fresh run over the last 8 inputs)"
            ),
            measure: None,
        },
    ])
}

fn stress_long_generation(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (data_cfg, cfg) = configs(&args(true));
    let data = generate(&data_cfg)?;
    let models = train_all(&data, &cfg, None)?;
    let model = &models.iter().find(|(m, _)| m.info.kind == ModelKind::Temporal).expect("trained").0;
    let clip = &data.test[0];
    let total = if ctx.quick { 100 } else { 1000 };
    let t_len = clip.frames();
    // Forwards and backwards through the clip (a ping-pong of the input) up to `total` frames.
    let order = ping_pong_order(t_len, total);
    let lr = clip.lr_density.index_select(&Tensor::new(order, &Device::Cpu)?, 0)?;
    let out = model.upscale(&lr, None)?;
    let means_out = out.mean((1, 2, 3))?.to_vec1::<f32>()?;
    let means_in = lr.mean((1, 2, 3))?.to_vec1::<f32>()?;
    let first_bad = means_out.iter().position(|v| !v.is_finite()).map(|k| k as u64);
    let worst =
        means_out.iter().zip(&means_in).map(|(o, i)| ((o - i).abs() / i.abs().max(1e-6)) as f64).fold(0.0, f64::max);
    Ok(vec![
        StressCheck {
            invariant: "every generated frame finite".into(),
            passed: first_bad.is_none(),
            first_broken_step: first_bad,
            detail: format!("{total} frames at {}^2 -> {}^2", data_cfg.lr_resolution, data_cfg.hr_resolution()),
            measure: first_bad.is_none().then_some(StressMeasure::StableSteps(total as u64)),
        },
        StressCheck {
            invariant: "mean density within 5% of the input's".into(),
            passed: first_bad.is_none() && worst <= 0.05,
            first_broken_step: None,
            detail: format!("largest relative deviation of a frame's mean {worst:.4}"),
            measure: None,
        },
    ])
}
