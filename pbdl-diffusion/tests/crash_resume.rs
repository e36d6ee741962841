//! kill -9 during ACDM training and inside its checkpoint writes, then resume: the resumed run
//! reproduces the uninterrupted `loss.csv` and every checkpoint (U-Net weights and Adam
//! state) bit for bit. The 20-kill variant is ignored: run it with
//! `cargo test -p pbdl-diffusion --test crash_resume -- --ignored`.

use candle_core::{DType, Device, Tensor};
use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
use pbdl_diffusion::acdm::model::{Model, ModelConfig};
use pbdl_diffusion::acdm::train::{train, TrainConfig};
use std::path::Path;

/// A width-4 ACDM (20 diffusion steps) on two random 10-frame sequences of 4 x 8 x 16: 24
/// updates of 2 windows, a learning-rate drop at 12, checkpoints every 5.
fn train_tiny(dir: &Path) -> pbdl_diffusion::Result<()> {
    let seqs: Vec<Tensor> = (0..2)
        .map(|s| pbdl_core::seed::randn((10, 4, 8, 16), 0.0, 1.0, DType::F32, &Device::Cpu, 40 + s))
        .collect::<candle_core::Result<_>>()?;
    let model = Model::new(ModelConfig::acdm(4))?;
    let cfg = TrainConfig { steps: 24, batch: 2, lr_late_from: 12, seed: 3, checkpoint_every: 5, ..Default::default() };
    train(&model, &seqs, &cfg, Some(dir))?;
    Ok(())
}

#[test]
fn crash_child() {
    child(train_tiny);
}

fn kill_and_resume(kills: usize, seed: u64) {
    let root = tempfile::tempdir().unwrap();
    let report = CrashTest::new("crash_child", root.path(), kills, seed)
        .run(Fingerprint::of_run_dir)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{report:?}");
    assert_eq!(report.kills, kills);
    assert!(report.in_write >= 1, "no kill landed inside a checkpoint write: {report:?}");
}

/// Three kills (the first inside a write by this seed's schedule); after each, every committed
/// checkpoint loads, and the finished run equals the uninterrupted one bit for bit.
#[test]
fn acdm_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume(3, 5);
}

#[test]
#[ignore = "stress: 20 kill -9 / resume cycles"]
fn acdm_kill_9_twenty_times_then_resume_exactly() {
    kill_and_resume(20, 20);
}
