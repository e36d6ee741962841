//! Solver-in-the-Loop on the cylinder wake, small enough for a laptop (about a minute):
//! reference data at 2x the source resolution, a SOL-4 corrector trained through 4 unrolled
//! source steps, and its rollout on a held-out Reynolds number against the uncorrected source.
//!
//! `cargo run --release -p pbdl-sol --example solver_in_the_loop`
//!
//! The paper's sizes: `WakeConfig::default()` (64 x 32 source, 4x reference),
//! `DataConfig::default()` (six training, five held-out Re) and `CorrectorConfig::default()`
//! (260,354 parameters).

use candle_core::DType;
use pbdl_sol::sil::{evaluate, generate, train, CorrectorConfig, DataConfig, TrainConfig, Variant, WakeConfig};

fn main() -> pbdl_sol::Result<()> {
    let wake = WakeConfig { coarse: [32, 16], factor: 2, reference_substeps: 1, ..Default::default() };
    let data_cfg = DataConfig {
        train_re: vec![200.0, 400.0, 800.0],
        test_re: vec![566.0],
        warmup: 60,
        train_frames: 80,
        test_frames: 65,
    };
    let data = generate(&wake, &data_cfg, DType::F32)?;
    let config = TrainConfig {
        // A small network whose output starts at zero: the corrected solver starts as the source.
        corrector: CorrectorConfig { width: 16, blocks: 2, zero_output: true, ..Default::default() },
        lr: 1e-3,
        ..TrainConfig::new(Variant::Sol { m: 4 }, 800, 0)
    };
    let sol = train(&data, &config)?;
    println!(
        "{} trained in {:.1} s, last loss {:.3e}",
        config.variant.name(),
        sol.seconds,
        sol.losses.last().unwrap_or(&f64::NAN)
    );
    let steps = 64;
    let source = evaluate(&wake, &data.test, steps, None)?;
    let corrected = evaluate(&wake, &data.test, steps, Some(&sol.corrector))?;
    println!(
        "held-out Re {:?}: MAE over {steps} steps, source {:.4}, corrected {:.4}",
        data_cfg.test_re,
        source.mean_over(0, steps),
        corrected.mean_over(0, steps)
    );
    Ok(())
}
