//! Trains a metric from scratch on advection-diffusion + Burgers sequences (or the kinds of
//! `--train-kinds`) and scores it with the LSiM protocol (Spearman per data set) against L2,
//! SSIM and, when the weights exist, the published LSiM; by default smoke and shapes are kinds
//! the metric never saw.
//!
//! ```text
//! cargo run -p pbdl-metrics --example train_metric -- [--train 60] [--test 30] [--epochs 40]
//!     [--width 0.5] [--res 64] [--lr 1e-3] [--gt linear|fit2] [--seed 0] [--no-lsim]
//!     [--val 30] [--weights-only] [--recalibrate] [--dropout 0] [--scale 1]
//!     [--second-pool | --no-second-pool] [--train-kinds adv,bur,smo] [--pair-groups 1]
//!     [--run-seed S]
//!     [--out target/metric-training] [--fit2-stats] [--eval MODEL [--test-seed S] [--split val]]
//! ```
//! `--split val` with `--eval` scores the cached validation sets of all four kinds of seed `S`
//! (the experiment's are seed `seed + 500`) instead of test sets.
//! `--test 0` trains and scores the validation sets only (Adv and Bur of seed `seed + 500`),
//! for choosing settings without the test sets. Data are cached as `.npz` under `--out` (delete
//! them to regenerate); the trained model is written there as a pbdl checkpoint (`metric`, and
//! the untrained control `metric_untrained`), the per-step log as `train_log.csv`, the table
//! (with the control row) as `table.md`.

use pbdl_metrics::train::data::{cached, generate, load_sequences, DataConfig, Kind};
use pbdl_metrics::train::experiment::{cache_name, compared_metrics, published_lsim};
use pbdl_metrics::train::loss::fit2_coefficient;
use pbdl_metrics::train::{evaluate, markdown_table, MetricNet};
use pbdl_metrics::train::{run_experiment, ExperimentConfig, GroundTruth};

/// `--eval MODEL [--test-seed S]`: scores a saved model on freshly generated (cached) test sets
/// of seed `S`, next to L2, SSIM and (unless `--no-lsim`) the published LSiM, without training.
fn eval_only(cfg: &ExperimentConfig, model: &str, seed: u64, split: &str) -> Result<(), Box<dyn std::error::Error>> {
    let net = MetricNet::load(model)?;
    let dir = cfg.out_dir.clone().ok_or("no --out")?;
    let count = if split == "val" { cfg.val_per_kind } else { cfg.test_per_kind };
    let mut sets = Vec::new();
    for kind in Kind::ALL {
        let path = dir.join(cache_name(kind, split, count, cfg.resolution, seed));
        let dc = DataConfig { resolution: cfg.resolution, seed };
        sets.push((kind.short().to_string(), cached(path, || generate(kind, count, &dc))?));
    }
    let lsim = published_lsim(cfg.published_lsim);
    let rows = evaluate(&compared_metrics(lsim.as_ref(), &net), &sets)?;
    println!("{split} seed {seed}, model {model}\n\n{}", markdown_table(&rows));
    Ok(())
}

/// `--fit2-stats`: the fitted "fit2" coefficients of the cached sequences in `--out`.
fn fit2_stats(cfg: &ExperimentConfig) -> Result<(), Box<dyn std::error::Error>> {
    let dir = cfg.out_dir.as_ref().ok_or("no --out")?;
    for kind in Kind::ALL {
        for entry in std::fs::read_dir(dir)? {
            let path = entry?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
            if !name.starts_with(kind.short()) || !name.ends_with(".npz") {
                continue;
            }
            let mut c: Vec<f64> =
                load_sequences(&path)?.iter().filter_map(|s| fit2_coefficient(&s.frames).ok()).collect();
            c.sort_by(f64::total_cmp);
            if let (Some(lo), Some(hi)) = (c.first(), c.last()) {
                println!("{name}: {} fits, c min {lo:.2}, median {:.2}, max {hi:.2}", c.len(), c[c.len() / 2]);
            }
        }
    }
    Ok(())
}

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let args: Vec<String> = std::env::args().collect();
    let d = ExperimentConfig::default();
    let train_kinds = match args.iter().position(|a| a == "--train-kinds").and_then(|i| args.get(i + 1)) {
        Some(list) => list.split(',').map(Kind::parse).collect::<Result<Vec<_>, _>>()?,
        None => d.train_kinds.clone(),
    };
    let cfg = ExperimentConfig {
        train_kinds,
        train_per_kind: arg(&args, "--train", d.train_per_kind),
        test_per_kind: arg(&args, "--test", d.test_per_kind),
        val_per_kind: arg(&args, "--val", d.val_per_kind),
        train_base: !args.iter().any(|a| a == "--weights-only"),
        recalibrate: args.iter().any(|a| a == "--recalibrate"),
        dropout: arg(&args, "--dropout", d.dropout),
        input_scale: arg(&args, "--scale", d.input_scale),
        second_pool: if args.iter().any(|a| a == "--second-pool") {
            true
        } else {
            !args.iter().any(|a| a == "--no-second-pool") && d.second_pool
        },
        pair_groups: arg(&args, "--pair-groups", d.pair_groups),
        epochs: arg(&args, "--epochs", d.epochs),
        width: arg(&args, "--width", d.width),
        resolution: arg(&args, "--res", d.resolution),
        lr: arg(&args, "--lr", d.lr),
        seed: arg(&args, "--seed", d.seed),
        run_seed: args.iter().position(|a| a == "--run-seed").and_then(|i| args.get(i + 1)?.parse().ok()),
        ground_truth: match arg(&args, "--gt", "linear".to_string()).as_str() {
            "fit2" => GroundTruth::Fit2,
            _ => GroundTruth::Linear,
        },
        out_dir: Some(arg(&args, "--out", "target/metric-training".to_string()).into()),
        published_lsim: !args.iter().any(|a| a == "--no-lsim"),
        progress: true,
    };
    println!("{cfg:?}");
    if args.iter().any(|a| a == "--fit2-stats") {
        return fit2_stats(&cfg);
    }
    if let Some(model) = args.iter().position(|a| a == "--eval").and_then(|i| args.get(i + 1)) {
        let split = arg(&args, "--split", "test".to_string());
        let seed = arg(&args, "--test-seed", cfg.seed + if split == "val" { 500 } else { 1000 });
        return eval_only(&cfg, model, seed, &split);
    }
    let r = run_experiment(&cfg)?;
    let steps = cfg.epochs * r.train_sequences;
    println!(
        "data: {} training sequences ({:?}), 4 x {} test sequences, {:.1} s",
        r.train_sequences, cfg.train_kinds, cfg.test_per_kind, r.data_seconds
    );
    println!("model: LSiM base network, width x{}, {} parameters", cfg.width, r.parameters);
    println!(
        "training: calibration {:.1} s, {steps} steps in {:.1} s ({:.3} s/step)",
        r.training.calibration_seconds,
        r.training.train_seconds,
        r.training.train_seconds / steps.max(1) as f64
    );
    println!("epoch losses: {:?}", r.training.epoch_loss.iter().map(|l| format!("{l:.4}")).collect::<Vec<_>>());
    println!("evaluation: {:.1} s\n\n{}", r.eval_seconds, r.table);
    Ok(())
}
