//! `cargo xtask pconv train|eval`: learned particle convolutions on SFBC's periodic test cases
//! I (1D compressible SPH) and II (2D weakly compressible SPH) (pbdl_pconv::periodic_case).
//!
//! `train` fits one network (task, basis, seed) in a resumable run directory; `eval` trains
//! every requested basis in memory and writes the time-against-error table: test relative MSE,
//! rollout error, momentum drift, training seconds and the network's time per frame, as
//! `<out>.md`, `<out>.json` and a Pareto plot `<out>.png` (time per frame against test error).

use anyhow::Context as _;
use pbdl_core::viz::{pareto_plot, ParetoPoint, PlotStyle};
use pbdl_pconv::periodic_case::{
    train_and_evaluate, train_and_evaluate_in, CaseConfig, CaseKind, CaseResult, Dataset, Task, TrainConfig,
};
use pbdl_pconv::Basis;
use std::path::PathBuf;

/// `cargo xtask pconv ...`.
#[derive(clap::Subcommand)]
pub enum PconvCommand {
    /// Train one network of test case I into a run directory (checkpoints, loss.csv,
    /// summary.json); the same command on the same directory resumes a stopped run.
    Train(TrainArgs),
    /// Every basis on the chosen tasks and seeds (trained in memory): <out>.md, .json, .png.
    Eval(EvalArgs),
}

/// Arguments of `pconv train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// 1d (SFBC test case I: periodic compressible SPH) or 2d (test case II: periodic weakly
    /// compressible SPH).
    #[arg(long, default_value = "1d")]
    pub case: String,
    /// density, density_gradient or update.
    #[arg(long, default_value = "update")]
    pub task: String,
    /// linear, fourier, fourier_full, fourier_even, fourier_odd, chebyshev or gaussian.
    #[arg(long, default_value = "fourier")]
    pub basis: String,
    /// Antisymmetric last layer (momentum-conserving; update task).
    #[arg(long)]
    pub antisymmetric: bool,
    /// Update task: frames unrolled per training sample (1: one-step targets).
    #[arg(long, default_value_t = 1)]
    pub rollout_steps: usize,
    /// Seed of the initial weights and the batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Adam updates (default: the task's, 1000).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Run directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Small data (256 particles or 16 x 16, 3 + 1 simulations of 12 frames): seconds, for tests.
    #[arg(long)]
    pub quick: bool,
}

/// Arguments of `pconv eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// 1d (SFBC test case I: periodic compressible SPH) or 2d (test case II: periodic weakly
    /// compressible SPH).
    #[arg(long, default_value = "1d")]
    pub case: String,
    /// Comma-separated tasks.
    #[arg(long, default_value = "density,density_gradient,update")]
    pub tasks: String,
    /// Comma-separated bases (default: all).
    #[arg(long)]
    pub bases: Option<String>,
    /// Training seeds per basis (0..N).
    #[arg(long, default_value_t = 1)]
    pub seeds: u64,
    /// Adam updates per network (default: the task's, 1000).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Also train the update task with an antisymmetric last layer.
    #[arg(long)]
    pub antisymmetric: bool,
    /// Update task: frames unrolled per training sample (1: one-step targets).
    #[arg(long, default_value_t = 1)]
    pub rollout_steps: usize,
    /// Small data, for tests.
    #[arg(long)]
    pub quick: bool,
    /// Output path: writes <out>.md, <out>.json and <out>.png (an extension given is replaced).
    #[arg(long)]
    pub out: PathBuf,
}

fn parse_task(name: &str) -> anyhow::Result<Task> {
    Task::from_name(name).with_context(|| format!("unknown task `{name}`; use density, density_gradient or update"))
}

fn parse_basis(name: &str) -> anyhow::Result<Basis> {
    Basis::from_name(name).with_context(|| {
        let all: Vec<&str> = Basis::ALL.iter().map(|b| b.name()).collect();
        format!("unknown basis `{name}`; use one of {}", all.join(", "))
    })
}

fn data_config(case: &str, quick: bool) -> anyhow::Result<CaseConfig> {
    let kind = match case {
        "1d" => CaseKind::Compressible1d,
        "2d" => CaseKind::WeaklyCompressible2d,
        other => anyhow::bail!("unknown case `{other}`; use 1d (SFBC test case I) or 2d (test case II)"),
    };
    Ok(if quick { CaseConfig::small(kind) } else { CaseConfig::for_kind(kind) })
}

fn train_config(task: Task, steps: Option<u64>, antisymmetric: bool, rollout_steps: usize) -> TrainConfig {
    let mut t = TrainConfig { antisymmetric, rollout_steps, ..TrainConfig::for_task(task) };
    if let Some(s) = steps {
        t.steps = s;
    }
    t
}

/// Runs `cargo xtask pconv ...`.
pub fn run(cmd: PconvCommand) -> anyhow::Result<()> {
    match cmd {
        PconvCommand::Train(a) => {
            let task = parse_task(&a.task)?;
            let basis = parse_basis(&a.basis)?;
            let data = Dataset::generate(&data_config(&a.case, a.quick)?)?;
            let train = train_config(task, a.steps, a.antisymmetric, a.rollout_steps);
            let r = train_and_evaluate_in(&data, task, basis, &train, a.seed, Some(&a.out))?;
            let json = serde_json::to_vec_pretty(&r)?;
            pbdl_core::io::write_atomic(a.out.join("summary.json"), |w| std::io::Write::write_all(w, &json))?;
            println!("{}", header());
            println!("{}", row(&r, a.antisymmetric));
            println!("run directory: {}", a.out.display());
            Ok(())
        }
        PconvCommand::Eval(a) => {
            let tasks = a.tasks.split(',').map(parse_task).collect::<anyhow::Result<Vec<_>>>()?;
            let bases = match &a.bases {
                None => Basis::ALL.to_vec(),
                Some(list) => list.split(',').map(parse_basis).collect::<anyhow::Result<Vec<_>>>()?,
            };
            let data = Dataset::generate(&data_config(&a.case, a.quick)?)?;
            let mut rows = Vec::new();
            let mut md = format!(
                "# pconv eval: SFBC test case {} ({} particles{}, {} + {} simulations of {} frames)\n\n{}\n",
                if data.dim() == 1 { "I" } else { "II" },
                data.config.particles,
                if data.dim() == 1 { "" } else { " per side" },
                data.train.len(),
                data.test.len(),
                data.config.frames,
                header()
            );
            for &task in &tasks {
                let variants: &[bool] = if task == Task::Update && a.antisymmetric { &[false, true] } else { &[false] };
                for &anti in variants {
                    for &basis in &bases {
                        for seed in 0..a.seeds {
                            let r = train_and_evaluate(
                                &data,
                                task,
                                basis,
                                &train_config(task, a.steps, anti, a.rollout_steps),
                                seed,
                            )?;
                            let line = row(&r, anti);
                            println!("{line}");
                            md.push_str(&line);
                            md.push('\n');
                            rows.push((anti, r));
                        }
                    }
                }
            }
            let out = a.out.with_extension("");
            pbdl_core::io::write_atomic(out.with_extension("md"), |w| std::io::Write::write_all(w, md.as_bytes()))?;
            let json: Vec<serde_json::Value> =
                rows.iter().map(|(anti, r)| serde_json::json!({ "antisymmetric": anti, "result": r })).collect();
            let json = serde_json::to_vec_pretty(&json)?;
            pbdl_core::io::write_atomic(out.with_extension("json"), |w| std::io::Write::write_all(w, &json))?;
            let points: Vec<ParetoPoint> = rows
                .iter()
                .filter(|(_, r)| r.test_rel_mse > 0.0 && r.forward_seconds > 0.0)
                .map(|(anti, r)| ParetoPoint {
                    method: format!("{}{}", r.task.name(), if *anti { " (anti)" } else { "" }),
                    time: r.forward_seconds * 1e3,
                    error: r.test_rel_mse,
                    label: Some(r.basis.name().to_string()),
                })
                .collect();
            let style = PlotStyle {
                title: format!(
                    "SFBC test case {}: network time per frame vs test error",
                    if data.dim() == 1 { "I" } else { "II" }
                ),
                x_label: "ms per frame".into(),
                y_label: "test relative MSE".into(),
                ..PlotStyle::pareto()
            };
            pareto_plot(out.with_extension("png"), &points, &style)?;
            println!("wrote {}.md, .json, .png", out.display());
            Ok(())
        }
    }
}

fn header() -> String {
    "| task | basis | antisymmetric | seed | train loss | test rel. MSE | rollout err (dx) | no-update rollout (dx) | momentum drift | train s | ms / frame |\n|---|---|---|---|---|---|---|---|---|---|---|".into()
}

fn row(r: &CaseResult, anti: bool) -> String {
    let opt = |v: Option<f64>| v.map_or("-".into(), |e| format!("{e:.3}"));
    format!(
        "| {} | {} | {} | {} | {:.3e} | {:.3e} | {} | {} | {} | {:.1} | {:.2} |",
        r.task.name(),
        r.basis.name(),
        anti,
        r.seed,
        r.train_loss,
        r.test_rel_mse,
        opt(r.rollout_error),
        opt(r.frozen_rollout_error),
        r.momentum_drift.map_or("-".into(), |e| format!("{e:.1e}")),
        r.train_seconds,
        r.forward_seconds * 1e3
    )
}
