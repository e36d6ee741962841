//! Latent space subdivision on 2D smoke plumes at CPU size: simulate, train the split
//! autoencoder and the predictor, and print every score on the held-out scenes as a table
//! (swap test, parameter, reconstruction, split leak, rollouts with re-encoded advected density).
//!
//! `cargo run --release -p pbdl-latent --example lss_smoke [res=32] [train=12] [test=4]
//! [frames=80] [ae_steps=2000] [pred_steps=1000] [rollout=6] [widths=16,32,64] [latent=8]
//! [start=20] [steps=40] [seed=0] [dir=PATH]`
//!
//! Bars registered before measuring: swap velocity change <= 5%, parameter MAE <= 10% of the
//! range.

use pbdl_latent::data::{generate, PlumeData};
use pbdl_latent::lss::{lss_rollout, param_score, reconstruction_score, split_leak, swap_score, train_lss, LssConfig};
use pbdl_latent::train::PhaseSettings;
use std::path::PathBuf;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).and_then(|v| v.parse().ok())).unwrap_or(default)
}

fn list(name: &str, default: &str) -> Vec<usize> {
    arg(name, default.to_string()).split(',').filter_map(|s| s.parse().ok()).collect()
}

fn verdict(ok: bool) -> &'static str {
    if ok {
        "pass"
    } else {
        "MISS"
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let res: usize = arg("res", 32);
    let seed: u64 = arg("seed", 0);
    let data_cfg = PlumeData {
        resolution: res,
        train_scenes: arg("train", 12),
        test_scenes: arg("test", 4),
        frames: arg("frames", 80),
        seed,
        ..PlumeData::default()
    };
    let t = std::time::Instant::now();
    let data = generate(&data_cfg)?;
    println!(
        "data: {} + {} scenes of {} frames at {res}^2 in {:.1} s",
        data.train.len(),
        data.test.len(),
        data_cfg.frames,
        t.elapsed().as_secs_f64()
    );
    let defaults = LssConfig::default();
    let cfg = LssConfig {
        resolution: res,
        widths: list("widths", "16,32,64"),
        latent_channels: arg("latent", 8),
        rollout: arg("rollout", defaults.rollout),
        autoencoder_training: PhaseSettings { steps: arg("ae_steps", 2000), ..defaults.autoencoder_training.clone() },
        predictor_training: PhaseSettings { steps: arg("pred_steps", 1000), ..defaults.predictor_training.clone() },
        seed,
        ..defaults
    };
    let dir: Option<PathBuf> = std::env::args().find_map(|a| a.strip_prefix("dir=").map(PathBuf::from));
    let t = std::time::Instant::now();
    let model = train_lss(&data, &cfg, dir.as_deref())?;
    println!(
        "trained in {:.1} s ({} autoencoder + {} predictor updates, training rollout {})",
        t.elapsed().as_secs_f64(),
        cfg.autoencoder_training.steps,
        cfg.predictor_training.steps,
        cfg.rollout
    );
    let ae = &model.autoencoder;
    let swap = swap_score(ae, &data.test)?;
    let par = param_score(ae, &data.test)?;
    let rec = reconstruction_score(ae, &data.test)?;
    let rec_train = reconstruction_score(ae, &data.train)?;
    let leak = split_leak(ae, &data.test)?;
    println!();
    println!("| score (held-out scenes) | value | bar |");
    println!("|---|---|---|");
    println!(
        "| (a) swap: rel L2 change of decoded velocity | {:.4} | <= 0.05 {} |",
        swap.velocity_change,
        verdict(swap.velocity_change <= 0.05)
    );
    println!(
        "| (a) for scale: rel L2 between the scenes' decoded velocities | {:.4} | |",
        swap.scene_velocity_difference
    );
    println!("| (b) parameter MAE (disc x, fraction of width) | {:.4} | |", par.mae);
    println!(
        "| (b) parameter MAE / range | {:.4} | <= 0.10 {} |",
        par.range_fraction,
        verdict(par.range_fraction <= 0.10)
    );
    println!("| (b) parameter MAE, second half of the frames | {:.4} | |", par.mae_late);
    println!("| (c) reconstruction rel L2 velocity (train) | {:.4} ({:.4}) | |", rec.velocity, rec_train.velocity);
    println!("| (c) reconstruction rel L2 density (train) | {:.4} ({:.4}) | |", rec.density, rec_train.density);
    println!(
        "| split leak: mean abs density part of enc(u, 0) / velocity part of enc(0, rho) / density part of enc(u, rho) | {:.4} / {:.4} / {:.4} | |",
        leak.density_part_of_velocity, leak.velocity_part_of_density, leak.density_part_of_full
    );
    let start: usize = arg("start", 20);
    let steps: usize = arg("steps", 40).min(data_cfg.frames.saturating_sub(start + 1));
    println!();
    println!("(d) rollouts from frame {start}, {steps} steps (rel L2 vs the solver's frames):");
    let marks: Vec<usize> = [1, 5, 10, 20].into_iter().filter(|k| *k < steps).chain([steps]).collect();
    let cols: Vec<String> = marks.iter().map(|k| format!("step {k}")).collect();
    println!(
        "| scene x | density err at {} | density mean | decoded density (no advection) final | velocity err at {} | finite |",
        cols.join(" / "),
        cols.join(" / ")
    );
    println!("|---|---|---|---|---|---|");
    let (mut mean_final, mut count) = (0.0, 0);
    for s in &data.test {
        let r = lss_rollout(&model, &data.config.scene(s.param), s, start, steps)?;
        let at = |v: &[f64]| -> String {
            marks
                .iter()
                .map(|k| format!("{:.3}", v.get(k - 1).copied().unwrap_or(f64::NAN)))
                .collect::<Vec<_>>()
                .join(" / ")
        };
        println!(
            "| {:.3} | {} | {:.4} | {:.4} | {} | {} |",
            s.param,
            at(&r.density_error),
            r.density_error_mean,
            r.decoded_density_error.last().copied().unwrap_or(f64::NAN),
            at(&r.velocity_error),
            r.finite
        );
        mean_final += r.density_error_final;
        count += 1;
    }
    println!("mean final density error over held-out scenes: {:.4}", mean_final / count.max(1) as f64);
    Ok(())
}
