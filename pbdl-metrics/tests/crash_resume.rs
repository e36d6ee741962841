//! kill -9 during LSiM metric training and inside its checkpoint writes, then resume: the
//! resumed run reproduces the uninterrupted `loss.csv` and every checkpoint (weights, Adam
//! state, normalisation statistics) bit for bit. In-process: a run stopped after some epochs and
//! continued equals the uninterrupted one, and a run directory changes no number of the
//! in-memory training. The 20-kill variant is ignored: run it with
//! `cargo test -p pbdl-metrics --test crash_resume -- --ignored`.

use pbdl_core::io::{list_checkpoints, load_checkpoint};
use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
use pbdl_core::train::ClipConfig;
use pbdl_metrics::train::data::{generate, DataConfig};
use pbdl_metrics::train::{train, train_resumable, Kind, MetricNet, MetricNetConfig, Sequence, TrainConfig};
use std::path::Path;

fn data() -> Vec<Sequence> {
    generate(Kind::Shapes, 3, &DataConfig { resolution: 56, seed: 7 }).unwrap()
}

fn tiny_net() -> MetricNet {
    MetricNet::new(MetricNetConfig { width: 0.25, seed: 2, ..Default::default() }).unwrap()
}

/// The published augmentation (flips, quarter turns, crops), dropout, recalibration after every
/// epoch and gradient clipping: 6 epochs of 3 sequences, checkpoints every 2 updates.
fn crash_config() -> TrainConfig {
    TrainConfig {
        epochs: 6,
        adam: pbdl_core::train::AdamConfig { lr: 1e-3, ..Default::default() },
        recalibrate: true,
        clip: ClipConfig::Norm { max_norm: 5.0 },
        seed: 5,
        checkpoint_every: 2,
        ..Default::default()
    }
}

fn train_tiny(dir: &Path) -> pbdl_metrics::Result<()> {
    train_resumable(&mut tiny_net(), &data(), &crash_config(), dir)?;
    Ok(())
}

#[test]
fn crash_child() {
    child(train_tiny);
}

/// The tensor `name` of the checkpoint `step-<step>` of `dir`, as `f32`.
fn tensor(dir: &Path, step: u64, name: &str) -> Vec<f32> {
    let (t, _) = load_checkpoint(dir.join(format!("step-{step}")), &candle_core::Device::Cpu).unwrap();
    t[name].flatten_all().unwrap().to_dtype(candle_core::DType::F32).unwrap().to_vec1().unwrap()
}

fn kill_and_resume(kills: usize, seed: u64) {
    let root = tempfile::tempdir().unwrap();
    let started = std::time::Instant::now();
    let report = CrashTest::new("crash_child", root.path(), kills, seed)
        .run(Fingerprint::of_run_dir)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{report:?} in {:.1} s", started.elapsed().as_secs_f64());
    assert_eq!(report.kills, kills);
    assert!(report.in_write >= 1, "no kill landed inside a checkpoint write: {report:?}");
    assert!(report.rounds >= 1);
    // What was compared holds what the run depends on: the checkpoints carry the statistics,
    // which the recalibration after epoch 1 (step 3) changed, and Adam's moments.
    let reference = root.path().join("reference");
    let steps: Vec<u64> = list_checkpoints(&reference).unwrap().iter().map(|(_, i)| i.step).collect();
    assert_eq!(steps, (1..=9).map(|k| 2 * k).collect::<Vec<u64>>());
    assert_ne!(tensor(&reference, 2, "norm.mean.1"), tensor(&reference, 4, "norm.mean.1"));
    assert_eq!(tensor(&reference, 4, "norm.count.1"), [33.0]);
    assert!(tensor(&reference, 18, "__optim__/adamw/v/net.00.conv0.weight").iter().any(|&v| v > 0.0));
}

/// Three kills (at least one inside a write, by this seed's schedule), each followed by the
/// checks of [`CrashTest::run`]: committed checkpoints load after every kill; a finished run has
/// no leftovers and equals the uninterrupted one (loss.csv without the seconds column, every
/// checkpoint's weights, Adam moments and statistics) bit for bit.
#[test]
fn lsim_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume(3, 5);
}

#[test]
#[ignore = "stress: 20 kill -9 / resume cycles"]
fn lsim_kill_9_twenty_times_then_resume_exactly() {
    kill_and_resume(20, 20);
}

fn weights(net: &MetricNet) -> Vec<Vec<u32>> {
    let vars = net.vars().into_iter().map(|v| v.as_tensor().clone());
    let stats = net.stats().unwrap().iter().flat_map(|s| [s.mean.clone(), s.m2.clone()]);
    vars.chain(stats)
        .map(|t| t.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().map(|x| x.to_bits()).collect())
        .collect()
}

/// A run directory changes nothing (the same losses, gradient norms, weights and statistics as
/// `train`), and a run stopped after 2 of 4 epochs and called again with 4 ends as the
/// uninterrupted run, bit for bit: per-group augmentation with frozen conv layers, and the
/// per-sequence augmentation with recalibration.
#[test]
fn a_stopped_run_continues_exactly_and_a_run_directory_changes_no_number() {
    let data = data();
    for cfg in [
        TrainConfig { epochs: 4, pair_groups: 3, train_base: false, seed: 1, ..crash_config() },
        TrainConfig { epochs: 4, dropout: 0.0, seed: 3, checkpoint_every: 3, ..crash_config() },
    ] {
        let root = tempfile::tempdir().unwrap();
        let (whole, parts) = (root.path().join("whole"), root.path().join("parts"));
        let mut memory = tiny_net();
        let in_memory = train(&mut memory, &data, &cfg).unwrap();
        let mut net = tiny_net();
        let report = train_resumable(&mut net, &data, &cfg, &whole).unwrap();
        assert_eq!(report.resumed_from, 0);
        let bits = |r: &pbdl_metrics::train::TrainReport, c: &str| -> Vec<(u64, u64)> {
            r.log.column(c).iter().map(|&(s, v)| (s, v.to_bits())).collect()
        };
        for c in ["loss", "grad_norm"] {
            assert_eq!(bits(&report, c), bits(&in_memory, c), "{c} with a run directory, {cfg:?}");
        }
        assert_eq!(report.epoch_loss, in_memory.epoch_loss);
        assert_eq!(weights(&net), weights(&memory));

        let mut first = tiny_net();
        let half = train_resumable(&mut first, &data, &TrainConfig { epochs: 2, ..cfg }, &parts).unwrap();
        assert_eq!(half.epoch_loss, report.epoch_loss[..2]);
        let mut second = tiny_net();
        let rest = train_resumable(&mut second, &data, &cfg, &parts).unwrap();
        assert_eq!(rest.resumed_from, 6);
        assert_eq!(rest.epoch_loss, report.epoch_loss, "the whole run's epochs, {cfg:?}");
        assert_eq!(weights(&second), weights(&net));
        let (a, b) = (Fingerprint::of_run_dir(&parts).unwrap(), Fingerprint::of_run_dir(&whole).unwrap());
        assert_eq!(a.diff(&b), None, "{cfg:?}");
    }
}

/// A run directory started with another seed or other data does not resume (its replayed draws
/// would not be the run's), and the frozen conv weights of `train_base = false` come back from
/// the checkpoint, not from the network passed in.
#[test]
fn resuming_with_another_seed_or_data_is_refused() {
    let data = data();
    let dir = tempfile::tempdir().unwrap();
    let cfg = TrainConfig { epochs: 1, train_base: false, ..crash_config() };
    let mut net = tiny_net();
    train_resumable(&mut net, &data, &cfg, dir.path()).unwrap();
    let e = train_resumable(&mut tiny_net(), &data, &TrainConfig { seed: 6, ..cfg }, dir.path()).unwrap_err();
    assert!(e.to_string().contains("seed"), "{e}");
    let e = train_resumable(&mut tiny_net(), &data[..2], &cfg, dir.path()).unwrap_err();
    assert!(e.to_string().contains("training sequences"), "{e}");
    let mut other = MetricNet::new(MetricNetConfig { width: 0.25, seed: 9, ..Default::default() }).unwrap();
    assert_ne!(weights_of_convs(&other), weights_of_convs(&net));
    train_resumable(&mut other, &data, &cfg, dir.path()).unwrap();
    assert_eq!(weights(&other), weights(&net));
}

fn weights_of_convs(net: &MetricNet) -> Vec<Vec<f32>> {
    net.vars()[..10].iter().map(|v| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
}
