//! Simulates smoke plumes, trains the three super-resolution models (L1 baseline, per-frame
//! GAN, temporal GAN) from one shared pre-training, and prints their held-out L1 error.
//!
//! `cargo run --release -p pbdl-temporal --example temporal_smoke -- [pretrain_steps] [gan_steps] [train_scenes] [dir]`
//! (defaults 300, 200, 6, no run directory). The full-size run is `cargo xtask temporal train`.

use pbdl_temporal::data::{generate, SmokeData};
use pbdl_temporal::train::{train_all, PhaseSettings, TrainConfig};
use std::time::Instant;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: u64| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(default);
    let data_cfg = SmokeData { train_scenes: arg(2, 6) as usize, test_scenes: 2, ..SmokeData::default() };
    let t = Instant::now();
    let data = generate(&data_cfg)?;
    println!("simulated {} + {} scenes in {:.1} s", data.train.len(), data.test.len(), t.elapsed().as_secs_f64());
    let cfg = TrainConfig {
        pretrain: PhaseSettings { steps: arg(0, 300), ..TrainConfig::default().pretrain },
        finetune: PhaseSettings { steps: arg(1, 200), ..TrainConfig::default().finetune },
        ..TrainConfig::default()
    };
    let dir = args.get(3).map(std::path::PathBuf::from);
    let t = Instant::now();
    let models = train_all(&data, &cfg, dir.as_deref())?;
    println!("trained in {:.1} s", t.elapsed().as_secs_f64());
    for (model, summary) in &models {
        let mut l1 = 0.0;
        for clip in &data.test {
            let hr = model.upscale(&clip.lr_density, Some(&clip.lr_velocity))?;
            l1 += (hr - &clip.hr_density)?.abs()?.mean_all()?.to_scalar::<f32>()? as f64 / data.test.len() as f64;
        }
        println!(
            "{:>10}: held-out L1 {l1:.5}, final training loss {:.4}, {:.0} ms per update",
            model.info.kind.name(),
            summary.final_loss,
            summary.median_step_seconds * 1e3
        );
    }
    let bicubic: f64 = data
        .test
        .iter()
        .map(|c| {
            let up = pbdl_core::sample::resize2d(
                &c.lr_density,
                (64, 64),
                pbdl_core::sample::Resize::Bicubic { align_corners: false },
            )
            .unwrap();
            (up - &c.hr_density).unwrap().abs().unwrap().mean_all().unwrap().to_scalar::<f32>().unwrap() as f64
        })
        .sum::<f64>()
        / data.test.len() as f64;
    println!("   bicubic: held-out L1 {bicubic:.5}");
    Ok(())
}
