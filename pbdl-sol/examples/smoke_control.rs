//! Learning to control 2D smoke shape transitions (Holl et al. 2020) in a few minutes on a
//! CPU: shape-pair scenes, supervision by the direct optimiser, supervised pre-training,
//! end-to-end training through pbdl-grid's fluid solver, a comparison with no control and the
//! optimiser on held-out scenes, and a PNG strip (start, controlled frames, target).
//!
//! `cargo run --release -p pbdl-sol --example smoke_control -- [train_scenes] [optimiser_its] [supervised_its] [e2e_its] [out.png]`

use candle_core::{DType, Device, Tensor};
use pbdl_sol::smoke_control::*;
use std::time::Instant;

fn main() -> pbdl_sol::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: usize| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(d);
    let (n_train, opt_its, sup_its, e2e_its) = (num(0, 32), num(1, 30), num(2, 80), num(3, 60));
    let out = args.get(4).cloned().unwrap_or_else(|| "smoke_control.png".into());
    let dev = Device::Cpu;
    let problem = SmokeControlConfig::default();
    let n_test = 8;
    let train = scene::generate(&problem, 1, 0..n_train, DType::F32, &dev)?;
    let test = scene::generate(&problem, 2, 0..n_test, DType::F32, &dev)?;
    let ctrl = SmokeController::new(&problem, &ConvNet2dConfig::default(), DType::F32, &dev, 0)?;
    println!("{}x{} box, {} steps; {ctrl:?}", problem.cells, problem.cells, problem.steps);
    println!("operators: {:?}", ctrl.physics().operators());

    let score = |r: &Rollout| -> pbdl_sol::Result<SmokeScore> {
        SmokeScore::of(&r.forces, r.final_density()?, &test.target, problem.loss_levels, problem.effort_weight)
    };
    let none = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { max_iterations: 0, ..Default::default() },
    )?
    .score;
    println!("no control: {none:?}");

    let opt = DirectOptimConfig { max_iterations: opt_its, time_budget_s: 600.0, ..Default::default() };
    let data = Supervision::generate(&ctrl, &train, &opt, 32)?;
    println!(
        "supervision: {opt_its} optimiser its on {n_train} scenes in {:.1}s, final-density error {:.3}",
        data.seconds, data.target_error
    );
    let sup = pretrain_supervised(
        &ctrl,
        &data,
        &SmokeTrainConfig { iterations: sup_its, batch: 16.min(n_train), seed: 1, ..Default::default() },
    )?;
    println!(
        "supervised: {} its in {:.1}s, loss {:.4} -> {:.4}",
        sup.losses.len(),
        sup.seconds,
        sup.head_mean(10),
        sup.tail_mean(10)
    );
    let supervised = score(&ctrl.rollout(&test.initial, &test.target)?)?;
    println!("supervised-only controller: {supervised:?}");
    let e2e = train_end_to_end(
        &ctrl,
        &train,
        &SmokeTrainConfig { iterations: e2e_its, batch: 4.min(n_train), lr: 1e-3, seed: 2, ..Default::default() },
    )?;
    println!(
        "end-to-end: {} its in {:.1}s, loss {:.3} -> {:.3}",
        e2e.losses.len(),
        e2e.seconds,
        e2e.head_mean(5),
        e2e.tail_mean(5)
    );
    let t = Instant::now();
    let r = ctrl.rollout(&test.initial, &test.target)?;
    let controlled = score(&r)?;
    let inference = t.elapsed().as_secs_f64();
    println!("end-to-end controller: {controlled:?} ({inference:.3}s for {n_test} scenes)");
    let same = optimize_forces(
        &problem,
        &test.initial,
        &test.target,
        &DirectOptimConfig { time_budget_s: inference, ..Default::default() },
    )?;
    println!("optimiser at the same wall-clock ({} its): {:?}", same.iterations, same.score);
    write_strip(&out, &test, &r, problem.steps)?;
    Ok(())
}

/// One row per scene (the first four): start, the controlled densities every quarter of the
/// horizon, the target.
#[cfg(feature = "viz")]
fn write_strip(path: &str, test: &SmokeScenes, r: &Rollout, steps: usize) -> pbdl_sol::Result<()> {
    use pbdl_core::viz::{field_to_png, ColorRange, FieldStyle};
    let rows = test.len().min(4);
    let n = test.initial.dims()[2];
    let mut frames: Vec<Tensor> = vec![test.initial.clone()];
    frames.extend((1..=4).map(|q| r.states[q * steps / 4].density.clone()));
    frames.push(test.target.clone());
    let cols = frames.len();
    let (w, h) = (cols * (n + 1) - 1, rows * (n + 1) - 1);
    let mut img = vec![0.0f64; w * h];
    for (c, f) in frames.iter().enumerate() {
        let v = f.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
        for b in 0..rows {
            for j in 0..n {
                for i in 0..n {
                    // Scene 0 on the top row (rows grow downwards in the image; y up in each cell).
                    let y = (rows - 1 - b) * (n + 1) + j;
                    img[y * w + c * (n + 1) + i] = v[b * n * n + j * n + i];
                }
            }
        }
    }
    let style = FieldStyle { range: ColorRange::Fixed(0.0, 1.5), upscale: Some(4), ..Default::default() };
    field_to_png(path, &img, h, w, &style)?;
    println!("wrote {path}: rows = held-out scenes, columns = start, t = T/4, T/2, 3T/4, T, target");
    Ok(())
}

#[cfg(not(feature = "viz"))]
fn write_strip(_: &str, _: &SmokeScenes, _: &Rollout, _: usize) -> pbdl_sol::Result<()> {
    println!("built without the `viz` feature: no PNG");
    Ok(())
}
