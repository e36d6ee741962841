//! pbdl-optim's tour and bench entries (see [`pbdl_core::registry`]).
//!
//! * bench `linear_chain`, `oscillators`: test loss against training wall-clock for HIG, Adam
//!   and Gauss-Newton, each with the same time budget (PNG line plot + rows whose `error` is the
//!   final test loss and `seconds` the median step time).
//! * tour `hig_vs_adam`: the same on the linear chain with a short budget.

use crate::hig::{run_curve, Budget, Curve, HigConfig, Method};
use crate::mlp::{Activation, Mlp};
use crate::physics::{Dataset, Oscillators, Physics};
use pbdl_core::bench::BenchRow;
use pbdl_core::registry::{CrateTasks, Entry, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_core::viz::{line_plot, PlotStyle, Series};
use std::path::PathBuf;

/// The entries of `pbdl-optim`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "optim",
        tour: vec![Entry {
            name: "hig_vs_adam",
            about: "HIG against Adam on the pbdl-book linear chain at equal wall-clock: loss curves (PNG).",
            run: tour_hig_vs_adam,
        }],
        bench: vec![
            Entry {
                name: "linear_chain",
                about: "Test loss vs wall-clock: HIG, Adam, Gauss-Newton on the pbdl-book linear chain (J 128x1444).",
                run: bench_linear_chain,
            },
            Entry {
                name: "oscillators",
                about: "Test loss vs wall-clock: HIG, Adam, Gauss-Newton on the nonlinear oscillators (J 512x2956).",
                run: bench_oscillators,
            },
        ],
        stress: vec![],
    }
}

/// One optimiser of a comparison.
struct Contender {
    name: &'static str,
    method: Method,
    batch: usize,
}

struct Setup<'a> {
    case: &'static str,
    physics: &'a dyn Physics,
    sizes: &'a [usize],
    activation: Activation,
    train: Dataset,
    test: Dataset,
    seconds: f64,
    contenders: Vec<Contender>,
}

/// Trains every contender from the same initial network for the same wall-clock budget.
fn compare(setup: &Setup<'_>, ctx: &TaskContext) -> TaskResult<(Vec<(String, Curve)>, PathBuf)> {
    let net0 = Mlp::new(setup.sizes, setup.activation, 0)?;
    let mut curves = Vec::new();
    for c in &setup.contenders {
        let mut net = net0.clone();
        let budget = Budget { seconds: setup.seconds, max_steps: u64::MAX };
        let eval_every = (setup.train.len / c.batch).max(1) as u64 / 4;
        let curve = run_curve(
            &mut net,
            setup.physics,
            c.method,
            &setup.train,
            &setup.test,
            c.batch,
            budget,
            eval_every.max(1),
        )?;
        curves.push((c.name.to_string(), curve));
    }
    let path = ctx.out_dir.join(format!("optim_{}.png", setup.case));
    let series: Vec<Series> = curves
        .iter()
        .map(|(name, c)| {
            let xs: Vec<f64> = c.seconds.iter().map(|s| s.max(1e-3)).collect();
            Series::new(name.clone(), xs, c.loss.clone())
        })
        .collect();
    line_plot(
        &path,
        &series,
        &PlotStyle {
            title: format!("{}: test loss vs training wall-clock ({} threads)", setup.case, ctx.threads),
            x_label: "seconds".into(),
            y_label: "mean test loss".into(),
            log_x: true,
            log_y: true,
            ..Default::default()
        },
    )?;
    Ok((curves, path))
}

fn rows(setup: &Setup<'_>, curves: &[(String, Curve)], ctx: &TaskContext) -> Vec<BenchRow> {
    curves
        .iter()
        .zip(&setup.contenders)
        .map(|((name, c), who)| BenchRow {
            case: setup.case.into(),
            method: name.clone(),
            size: format!("b{}_steps{}", who.batch, c.steps.last().copied().unwrap_or(0)),
            seconds: c.median_step_seconds(),
            unit: "step".into(),
            error: Some(c.final_loss()),
            error_kind: format!("test_loss_after_{}s", setup.seconds),
            peer: false,
            threads: ctx.threads,
        })
        .collect()
}

fn linear_chain_setup(physics: &dyn Physics, seconds: f64) -> Setup<'_> {
    Setup {
        case: "linear_chain",
        physics,
        sizes: &[4, 20, 20, 20, 24],
        activation: Activation::Tanh,
        train: Dataset::return_to_start(4096, 4, 1),
        test: Dataset::return_to_start(1024, 4, 2),
        seconds,
        contenders: vec![
            Contender { name: "hig", method: Method::Hig(HigConfig::hig(1.0, 1e-10)), batch: 32 },
            Contender { name: "adam", method: Method::Adam { lr: 1e-3 }, batch: 256 },
            Contender { name: "gauss_newton", method: Method::Hig(HigConfig::gauss_newton(1.0, 1e-10)), batch: 32 },
        ],
    }
}

fn bench_linear_chain(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let physics = Oscillators::linear_chain();
    let setup = linear_chain_setup(&physics, if ctx.quick { 3.0 } else { 20.0 });
    let (curves, _) = compare(&setup, ctx)?;
    Ok(rows(&setup, &curves, ctx))
}

fn bench_oscillators(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let physics = Oscillators::nonlinear();
    let n = if ctx.quick { 1024 } else { 4096 };
    let setup = Setup {
        case: "oscillators",
        physics: &physics,
        sizes: &[4, 20, 20, 20, 96],
        activation: Activation::Relu,
        train: Dataset::return_to_start(n, 4, 3),
        test: Dataset::return_to_start(n, 4, 4),
        seconds: if ctx.quick { 10.0 } else { 60.0 },
        contenders: vec![
            Contender { name: "hig", method: Method::Hig(HigConfig::hig(1.0, 1e-6)), batch: 128 },
            Contender { name: "adam", method: Method::Adam { lr: 3e-4 }, batch: 512 },
            Contender { name: "gauss_newton", method: Method::Hig(HigConfig::gauss_newton(1.0, 1e-6)), batch: 128 },
        ],
    };
    let (curves, _) = compare(&setup, ctx)?;
    Ok(rows(&setup, &curves, ctx))
}

fn tour_hig_vs_adam(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let physics = Oscillators::linear_chain();
    let mut setup = linear_chain_setup(&physics, if ctx.quick { 2.0 } else { 5.0 });
    setup.contenders.truncate(2);
    let (curves, path) = compare(&setup, ctx)?;
    let mut md = format!(
        "Linear chain (pbdl-book): {} s of training each, same initial network.\n\n| optimiser | steps | median step | final test loss |\n|---|---:|---:|---:|\n",
        setup.seconds
    );
    let mut tour_rows = Vec::new();
    for (name, c) in &curves {
        md.push_str(&format!(
            "| {name} | {} | {} | {:.3e} |\n",
            c.steps.last().unwrap_or(&0),
            pbdl_core::bench::format_seconds(c.median_step_seconds()),
            c.final_loss()
        ));
        tour_rows.push(TourRow {
            item: format!("linear chain, {name}, {} s", setup.seconds),
            seconds: c.seconds.last().copied().unwrap_or(0.0),
            error: Some(c.final_loss()),
            error_kind: "mean test loss".into(),
            note: format!("{} steps", c.steps.last().unwrap_or(&0)),
        });
    }
    let ratio = curves[1].1.final_loss() / curves[0].1.final_loss();
    md.push_str(&format!("\nAdam / HIG final loss: {ratio:.0}x.\n\n![loss vs time]({})\n", path.display()));
    Ok(TourOutcome { rows: tour_rows, files: vec![path], markdown: md })
}
