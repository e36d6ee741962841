//! SFBC test case I (or II with `2d`) at CPU size: every basis on the three tasks, a table of
//! test errors.
//!
//! `cargo run --release -p pbdl-pconv --example periodic_cases [2d] [small] [seeds=N] [steps=N] [lr=X] [rollout=K]
//! [tasks=density,update,...] [bases=fourier,linear,...] [anti=no|only]`

use pbdl_pconv::periodic_case::{train_and_evaluate, CaseConfig, CaseKind, Dataset, Task, TrainConfig};
use pbdl_pconv::Basis;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn arg(name: &str) -> Option<String> {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).map(str::to_string))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let small = std::env::args().any(|a| a == "small");
    let seeds: u64 = arg("seeds").map_or(Ok(1), |s| s.parse())?;
    let steps: Option<u64> = arg("steps").map(|s| s.parse()).transpose()?;
    let rollout: usize = arg("rollout").map_or(Ok(1), |s| s.parse())?;
    let lr: Option<f64> = arg("lr").map(|s| s.parse()).transpose()?;
    let bases: Vec<Basis> = match arg("bases") {
        None => Basis::ALL.to_vec(),
        Some(list) => list
            .split(',')
            .map(|b| Basis::from_name(b).ok_or(format!("unknown basis {b}")))
            .collect::<Result<_, _>>()?,
    };
    let anti_variants: Vec<bool> = match arg("anti").as_deref() {
        Some("no") => vec![false],
        Some("only") => vec![true],
        _ => vec![false, true],
    };
    let tasks: Vec<Task> = match arg("tasks") {
        None => vec![Task::Density, Task::DensityGradient, Task::Update],
        Some(list) => list
            .split(',')
            .map(|t| match t {
                "density" => Ok(Task::Density),
                "density_gradient" => Ok(Task::DensityGradient),
                "update" => Ok(Task::Update),
                other => Err(format!("unknown task {other}")),
            })
            .collect::<Result<_, _>>()?,
    };
    let kind =
        if std::env::args().any(|a| a == "2d") { CaseKind::WeaklyCompressible2d } else { CaseKind::Compressible1d };
    let cfg = if small { CaseConfig::small(kind) } else { CaseConfig::for_kind(kind) };
    let t = std::time::Instant::now();
    let data = Dataset::generate(&cfg)?;
    println!(
        "data: {} + {} simulations of {} frames, frame dt {:.2e} s, {:.1} s",
        data.train.len(),
        data.test.len(),
        cfg.frames,
        data.frame_dt,
        t.elapsed().as_secs_f64()
    );
    println!("| task | basis | anti | seed | train loss | test rel. MSE | rollout err (dx) | frozen (dx) | momentum drift | s |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for task in tasks {
        let variants: &[bool] = if task == Task::Update { &anti_variants } else { &[false] };
        for &anti in variants {
            for &basis in &bases {
                for seed in 0..seeds {
                    let mut train =
                        TrainConfig { antisymmetric: anti, rollout_steps: rollout, ..TrainConfig::for_task(task) };
                    if let Some(s) = steps {
                        train.steps = s;
                    }
                    if let Some(lr) = lr {
                        train.lr = lr;
                    }
                    let r = train_and_evaluate(&data, task, basis, &train, seed)?;
                    let opt = |v: Option<f64>, p: usize| v.map_or("-".into(), |e| format!("{e:.p$}"));
                    println!(
                        "| {} | {} | {} | {} | {:.3e} | {:.3e} | {} | {} | {} | {:.1} |",
                        task.name(),
                        basis.name(),
                        anti,
                        r.seed,
                        r.train_loss,
                        r.test_rel_mse,
                        opt(r.rollout_error, 3),
                        opt(r.frozen_rollout_error, 3),
                        r.momentum_drift.map_or("-".into(), |e| format!("{e:.1e}")),
                        r.train_seconds
                    );
                }
            }
        }
    }
    Ok(())
}
