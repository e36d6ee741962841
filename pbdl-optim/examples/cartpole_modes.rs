//! The stabilized-BPTT cart-pole experiment at the paper's length on the hand-written adjoint `f64` path:
//! modes x poles x clipping, Adam lr 1e-3, b = 8, 256 train / 256 test episodes, seed 42,
//! epochs of 32 steps. Appends one JSON object per run to `--out` (JSON lines, so an
//! interrupted sweep keeps its finished runs) and prints a table at the end.
//!
//! ```text
//! cargo run --release -p pbdl-optim --example cartpole_modes -- \
//!     --poles 1,2,3,4 --modes F,P,C --clip none --epochs 1000 --eval-epochs 50 --out cartpole.jsonl
//! ```
//!
//! `--clip` takes `none`, `value` (each entry clamped to 1.0) or `norm` (global norm 1.0), or a
//! comma list of them. `--seed` (default 42) seeds the controller and the training episodes;
//! the test episodes use `seed + 1`.

use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::GradientMode;
use pbdl_optim::cartpole::{adjoint, CartPoleConfig};
use std::io::Write;

struct Args {
    poles: Vec<usize>,
    modes: Vec<GradientMode>,
    clips: Vec<(String, ClipConfig)>,
    epochs: usize,
    eval_epochs: usize,
    seed: u64,
    out: Option<String>,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        poles: vec![1, 2, 3, 4],
        modes: vec![GradientMode::F, GradientMode::P, GradientMode::C],
        clips: vec![("none".into(), ClipConfig::None)],
        epochs: 1000,
        eval_epochs: 50,
        seed: 42,
        out: None,
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    for pair in argv.chunks(2) {
        let [key, val] = pair else { return Err(format!("{} needs a value", pair[0])) };
        let list = || val.split(',').map(str::trim).filter(|s| !s.is_empty());
        match key.as_str() {
            "--poles" => {
                a.poles =
                    list().map(|s| s.parse().map_err(|e| format!("--poles {s}: {e}"))).collect::<Result<_, _>>()?
            }
            "--modes" => {
                a.modes = list()
                    .map(|s| match s {
                        "F" => Ok(GradientMode::F),
                        "P" => Ok(GradientMode::P),
                        "S" => Ok(GradientMode::S),
                        "C" => Ok(GradientMode::C),
                        _ => Err(format!("--modes {s}: use F, P, S or C")),
                    })
                    .collect::<Result<_, _>>()?
            }
            "--clip" => {
                a.clips = list()
                    .map(|s| match s {
                        "none" => Ok((s.to_string(), ClipConfig::None)),
                        "value" => Ok((s.to_string(), ClipConfig::Value { max_value: 1.0 })),
                        "norm" => Ok((s.to_string(), ClipConfig::Norm { max_norm: 1.0 })),
                        _ => Err(format!("--clip {s}: use none, value or norm")),
                    })
                    .collect::<Result<_, _>>()?
            }
            "--epochs" => a.epochs = val.parse().map_err(|e| format!("--epochs: {e}"))?,
            "--eval-epochs" => a.eval_epochs = val.parse().map_err(|e| format!("--eval-epochs: {e}"))?,
            "--seed" => a.seed = val.parse().map_err(|e| format!("--seed: {e}"))?,
            "--out" => a.out = Some(val.clone()),
            _ => return Err(format!("unknown option {key}")),
        }
    }
    Ok(a)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let args = parse()?;
    let mut table = Vec::new();
    for (clip_name, clip) in &args.clips {
        for &poles in &args.poles {
            for &mode in &args.modes {
                let mut cfg = CartPoleConfig::new(poles, mode, 0);
                let steps_per_epoch = cfg.train / cfg.batch;
                cfg.iterations = args.epochs * steps_per_epoch;
                cfg.eval_every = args.eval_epochs.max(1) * steps_per_epoch;
                cfg.clip = *clip;
                cfg.seed = args.seed;
                let label = format!("nc{poles} {mode:?} clip={clip_name} seed={}", cfg.seed);
                let t = std::time::Instant::now();
                let run = adjoint::train_with(&cfg, &mut |step, loss| {
                    println!("{label} epoch {:>5} test loss {loss:.5}", step / steps_per_epoch);
                })?;
                let total = t.elapsed().as_secs_f64();
                let per_update = run.seconds / cfg.iterations.max(1) as f64;
                let best = run.test_loss.iter().copied().fold(f64::INFINITY, f64::min);
                println!(
                    "{label} done: final {:.5}, best {best:.5}, {:.2} ms/update, {total:.0} s total",
                    run.final_loss(),
                    per_update * 1e3
                );
                if let Some(path) = &args.out {
                    let curve: Vec<String> = run.test_loss.iter().map(|l| format!("{l:.8}")).collect();
                    let steps: Vec<String> = run.steps.iter().map(|s| s.to_string()).collect();
                    let agreement = run.agreement.map_or("null".to_string(), |a| format!("{a:.6}"));
                    let row = format!(
                        "{{\"poles\":{poles},\"mode\":\"{mode:?}\",\"clip\":\"{clip_name}\",\"lr\":{},\"batch\":{},\
                         \"train\":{},\"test\":{},\"seed\":{},\"epochs\":{},\"iterations\":{},\"final_test_loss\":{:.8},\
                         \"best_test_loss\":{best:.8},\"seconds_per_update\":{per_update:.6e},\"train_seconds\":{:.3},\
                         \"total_seconds\":{total:.3},\"agreement\":{agreement},\"steps\":[{}],\"test_loss\":[{}]}}",
                        cfg.lr,
                        cfg.batch,
                        cfg.train,
                        cfg.test,
                        cfg.seed,
                        args.epochs,
                        cfg.iterations,
                        run.final_loss(),
                        run.seconds,
                        steps.join(","),
                        curve.join(",")
                    );
                    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path)?;
                    writeln!(f, "{row}")?;
                }
                table.push((poles, mode, clip_name.clone(), run.final_loss(), best, per_update, total));
            }
        }
    }
    println!("\n| poles | mode | clip | final test loss | best test loss | ms/update | total s |");
    println!("|---:|---|---|---:|---:|---:|---:|");
    for (poles, mode, clip, fin, best, per, total) in table {
        println!("| {poles} | {mode:?} | {clip} | {fin:.4} | {best:.4} | {:.2} | {total:.0} |", per * 1e3);
    }
    Ok(())
}
