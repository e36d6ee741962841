//! kill -9 during forecaster training and inside its checkpoint writes, then resume: the resumed
//! run reproduces the uninterrupted epoch history (train and validation losses, learning-rate
//! drops, early stopping) and every checkpoint (`train-<n>` with Adam state and best weights,
//! `last`, `best`) bit for bit. The 20-kill variant is ignored: run it with
//! `cargo test -p pbdl-weather --test crash_resume -- --ignored`.

use candle_core::{DType, Device};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::io::{list_checkpoints, read_checkpoint_info};
use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
use pbdl_weather::forecaster::{
    train, Dataset, Lead, Normalizer, ResNetConfig, SampleSpec, TrainConfig, WeatherResNet,
};
use pbdl_weather::lorenz96::Lorenz96;
use std::path::Path;

fn dataset(seed: u64, n: usize) -> Dataset {
    let f = Lorenz96::default().trajectory(seed, 200, n).unwrap();
    Dataset::from_fields(&[f], vec![]).unwrap()
}

/// A width-8, one-block ResNet with dropout on Lorenz-96, random leads of 1 or 2 steps: 8 epochs
/// of 3 updates, the learning rate cut after every epoch without improvement.
fn train_tiny(dir: &Path) -> pbdl_weather::Result<()> {
    let (tr, va) = (dataset(1, 200), dataset(3, 60));
    let norm = Normalizer::fit(&tr);
    let spec = SampleSpec { history: vec![0, 1], lead: Lead::Continuous { min: 1, max: 2 }, targets: vec![0] };
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let net_cfg = ResNetConfig {
        width: 8,
        blocks: 1,
        first_kernel: 5,
        dropout: 0.1,
        ..ResNetConfig::cpu_size(spec.in_channels(1, 0), 1)
    };
    let net = WeatherResNet::new(net_cfg, vb).unwrap();
    pbdl_nets::seeded_init(&varmap, 4).unwrap();
    let cfg = TrainConfig {
        lr: 3e-3,
        batch: 8,
        max_epochs: 8,
        steps_per_epoch: Some(3),
        plateau_patience: 1,
        stop_patience: 4,
        seed: 9,
        dir: Some(dir.to_path_buf()),
        progress: false,
        ..Default::default()
    };
    train(&net, &varmap, &tr, &va, &norm, &spec, &cfg)?;
    Ok(())
}

#[test]
fn crash_child() {
    child(train_tiny);
}

/// Every checkpoint's tensors, plus the training state (history, plateau and stopping
/// counters) of the newest training checkpoint, as JSON (which reads back exactly).
fn outcome(dir: &Path) -> Result<Fingerprint, String> {
    let mut f = Fingerprint::default();
    f.add_checkpoints(dir)?;
    let train = list_checkpoints(dir)
        .map_err(|e| e.to_string())?
        .into_iter()
        .rfind(|(p, _)| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("train-")))
        .ok_or("no training checkpoint")?;
    let state = read_checkpoint_info(&train.0).map_err(|e| e.to_string())?.config["state"].to_string();
    f.entries.insert("state".into(), state.into_bytes());
    Ok(f)
}

fn kill_and_resume(kills: usize, seed: u64) {
    let root = tempfile::tempdir().unwrap();
    let report = CrashTest::new("crash_child", root.path(), kills, seed).run(outcome).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{report:?}");
    assert_eq!(report.kills, kills);
    assert!(report.in_write >= 1, "no kill landed inside a checkpoint write: {report:?}");
}

/// Three kills (the first inside a write by this seed's schedule); after each, every committed
/// checkpoint loads, and the finished run equals the uninterrupted one bit for bit.
#[test]
fn forecaster_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume(3, 5);
}

#[test]
#[ignore = "stress: 20 kill -9 / resume cycles"]
fn forecaster_kill_9_twenty_times_then_resume_exactly() {
    kill_and_resume(20, 20);
}
