//! pbdl-sol's entries: PDE control of forced Burgers (Holl et al. 2020) on held-out scenes.

use crate::registry::{CrateTasks, Entry, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::viz::{line_plot, PlotStyle, Series};
use pbdl_sol::control::{
    optimize_forces, pretrain_supervised, scene, train_end_to_end, BurgersControlConfig, ControlScore, Controller,
    ConvNetConfig, DirectOptimConfig, ForcedBurgers, TrainConfig,
};
use std::time::Instant;

/// This crate's entries.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "sol",
        tour: vec![Entry {
            name: "burgers_control",
            about: "PDE control of forced 1D Burgers (128 cells, 32 steps): a short supervised + end-to-end training through the solver, then held-out scenes against the iterative optimiser at equal wall-clock and no control (PNG).",
            run: tour_burgers_control,
        }],
        bench: vec![],
        stress: vec![],
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
}
