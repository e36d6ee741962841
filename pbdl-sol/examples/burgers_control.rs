//! Learning to control forced 1D Burgers (Holl et al. 2020) in a few minutes on a CPU:
//! scenes, supervised pre-training, end-to-end training through the solver, and a comparison
//! with the iterative optimiser and with no control on held-out scenes.
//!
//! `cargo run --release -p pbdl-sol --example burgers_control -- [train_scenes] [supervised_its] [e2e_its]`

use candle_core::{DType, Device, Tensor};
use pbdl_sol::control::*;
use std::time::Instant;

fn main() -> pbdl_sol::Result<()> {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let arg = |i: usize, d: usize| args.get(i).copied().unwrap_or(d);
    let (n_train, sup_its, e2e_its) = (arg(0, 64), arg(1, 100), arg(2, 10));
    let dev = Device::Cpu;
    let problem = BurgersControlConfig::default();
    let physics = ForcedBurgers::new(&problem)?;
    println!(
        "Burgers: {} cells, nu {}, dt {}, {} steps, {} RK4 sub-steps",
        problem.cells,
        problem.nu,
        problem.dt,
        problem.steps,
        physics.substeps()
    );

    let t = Instant::now();
    let train = scene::generate(&problem, 1, 0..n_train, DType::F32, &dev)?;
    let test = scene::generate(&problem, 2, 0..16, DType::F32, &dev)?;
    println!("scenes: {n_train} train, 16 test in {:.2}s", t.elapsed().as_secs_f64());

    let ctrl = Controller::new(&problem, &ConvNetConfig::default(), DType::F32, &dev, 0)?;
    println!("{ctrl:?}");
    let sup = pretrain_supervised(
        &ctrl,
        &train,
        &TrainConfig { iterations: sup_its, batch: 16, lr: 1e-3, ..Default::default() },
    )?;
    println!(
        "supervised: {} its in {:.1}s, loss {:.4} -> {:.4}",
        sup.losses.len(),
        sup.seconds,
        sup.losses[0],
        sup.tail_mean(10)
    );
    let e2e = train_end_to_end(
        &ctrl,
        &train,
        &TrainConfig { iterations: e2e_its, batch: 8, lr: 1e-4, clip_norm: 10.0, ..Default::default() },
    )?;
    println!(
        "end to end: {} its in {:.1}s, loss {:.4} -> {:.4}",
        e2e.losses.len(),
        e2e.seconds,
        e2e.losses[0],
        e2e.tail_mean(3)
    );

    let t = Instant::now();
    let r = ctrl.rollout(&test.initial, &test.target)?;
    let secs = t.elapsed().as_secs_f64();
    let ours = ControlScore::of(&r.forces, problem.dt, &r.states[problem.steps], &test.target, problem.target_weight)?;
    println!("controller ({secs:.3}s for 16 scenes): {ours:?}");
    for budget in [secs, 10.0 * secs] {
        let o = optimize_forces(
            &problem,
            &test.initial,
            &test.target,
            &DirectOptimConfig { time_budget_s: budget, ..Default::default() },
        )?;
        println!("optimiser, {budget:.3}s budget ({} its): {:?}", o.iterations, o.score);
    }
    let zero: Vec<Tensor> =
        (0..problem.steps).map(|_| test.initial.zeros_like()).collect::<candle_core::Result<_>>()?;
    let natural = physics.rollout(&test.initial, &zero)?;
    println!(
        "no control: {:?}",
        ControlScore::of(&zero, problem.dt, &natural[problem.steps], &test.target, problem.target_weight)?
    );
    Ok(())
}
