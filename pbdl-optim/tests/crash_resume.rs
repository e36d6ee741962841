//! kill -9 during cart-pole controller training (`cartpole::adjoint::train_checkpointed`, the
//! hand-written adjoint path that runs the paper-length sweeps) and inside its checkpoint
//! writes, then resume: the resumed run reproduces the uninterrupted `loss.csv` and every
//! checkpoint (controller parameters, Adam moments and count, the evaluations and agreement
//! sums so far) bit for bit. The 20-kill variant is ignored: run it with
//! `cargo test -p pbdl-optim --test crash_resume -- --ignored`.

use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
use pbdl_core::train::ClipConfig;
use pbdl_optim::bptt::{BpttRun, GradientMode, RunDir};
use pbdl_optim::cartpole::adjoint::{train, train_checkpointed};
use pbdl_optim::cartpole::CartPoleConfig;
use std::path::Path;

/// A small cart-pole run: 2 poles, 60-step episodes, width 16, 32 training and 16 test
/// episodes in batches of 4 (8 batches, cycled), mode C, 96 Adam updates (lr 1e-2) evaluated
/// every 10.
fn tiny(mode: GradientMode, clip: ClipConfig) -> CartPoleConfig {
    let mut cfg = CartPoleConfig::new(2, mode, 96);
    cfg.physics.steps = 60;
    cfg.width = 16;
    cfg.train = 32;
    cfg.test = 16;
    cfg.batch = 4;
    cfg.lr = 1e-2;
    cfg.clip = clip;
    cfg.eval_every = 10;
    cfg.seed = 7;
    cfg
}

/// Checkpoints every 7 updates (not a multiple of the evaluation period: some resume points
/// have an evaluation, most do not).
fn run_dir(dir: &Path) -> RunDir {
    RunDir { dir: dir.to_path_buf(), checkpoint_every: 7 }
}

fn train_tiny(dir: &Path) -> pbdl_optim::Result<()> {
    train_checkpointed(&tiny(GradientMode::C, ClipConfig::None), Some(&run_dir(dir)), &mut |_, _| {})?;
    Ok(())
}

#[test]
fn crash_child() {
    child(train_tiny);
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
}

/// Three kills (this seed's schedule tries two inside a write and one at a random time); after
/// each, every committed checkpoint loads, and the finished run equals the uninterrupted one bit
/// for bit.
#[test]
fn cartpole_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume(3, 3);
}

#[test]
#[ignore = "stress: 20 kill -9 / resume cycles"]
fn cartpole_kill_9_twenty_times_then_resume_exactly() {
    kill_and_resume(20, 20);
}

fn bits(run: &BpttRun) -> (Vec<usize>, Vec<u64>, Option<u64>) {
    (run.steps.clone(), run.test_loss.iter().map(|l| l.to_bits()).collect(), run.agreement.map(f64::to_bits))
}

/// A run directory changes no number: the checkpointed run (pbdl-core's Adam on one variable)
/// returns the in-memory run's (`FlatAdam`) evaluation steps, test losses and agreement bit for
/// bit, in mode C and in mode F with norm clipping.
#[test]
fn a_run_directory_gives_the_numbers_of_a_run_without_one() {
    let root = tempfile::tempdir().unwrap();
    for (k, (mode, clip)) in
        [(GradientMode::C, ClipConfig::None), (GradientMode::F, ClipConfig::Norm { max_norm: 1.0 })]
            .into_iter()
            .enumerate()
    {
        let cfg = tiny(mode, clip);
        let plain = train(&cfg).unwrap();
        let mut seen = Vec::new();
        let dir = root.path().join(format!("run-{k}"));
        let stored = train_checkpointed(&cfg, Some(&run_dir(&dir)), &mut |s, l| seen.push((s, l))).unwrap();
        assert_eq!(bits(&stored), bits(&plain), "{mode:?}");
        assert_eq!(plain.steps, [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 96]);
        assert_eq!(seen, plain.steps.iter().copied().zip(plain.test_loss.iter().copied()).collect::<Vec<_>>());
        assert!((plain.test_loss[10] - plain.test_loss[0]).abs() > 1e-3, "training moved: {:?}", plain.test_loss);
    }
}

/// A run resumed from any checkpoint (the directory cut back to it, as a kill right after its
/// commit leaves it) returns what the uninterrupted run returns, evaluations before the resume
/// point included; `on_eval` sees only the evaluations after it. Another configuration does not
/// resume from the directory.
#[test]
fn a_resumed_run_returns_the_uninterrupted_result_and_refuses_another_config() {
    let root = tempfile::tempdir().unwrap();
    let cfg = tiny(GradientMode::C, ClipConfig::None);
    let full_dir = root.path().join("full");
    let full = train_checkpointed(&cfg, Some(&run_dir(&full_dir)), &mut |_, _| {}).unwrap();
    let reference = Fingerprint::of_run_dir(&full_dir).unwrap();
    // Step 70 is also an evaluation point; 49 is not.
    for cut in [7u64, 49, 70, 96] {
        let dir = root.path().join(format!("cut-{cut}"));
        std::fs::create_dir_all(&dir).unwrap();
        for name in [format!("step-{cut}.safetensors"), format!("step-{cut}.json"), "loss.csv".to_string()] {
            std::fs::copy(full_dir.join(&name), dir.join(&name)).unwrap();
        }
        let mut seen = Vec::new();
        let resumed = train_checkpointed(&cfg, Some(&run_dir(&dir)), &mut |s, _| seen.push(s)).unwrap();
        assert_eq!(bits(&resumed), bits(&full), "resumed at {cut}");
        let after: Vec<usize> = full.steps.iter().copied().filter(|&s| s as u64 > cut).collect();
        assert_eq!(seen, after, "resumed at {cut}");
        // Checkpoints from the resume point on, and the whole loss.csv, are the uninterrupted run's.
        let mut expected = reference.clone();
        expected.entries.retain(|k, _| {
            k.strip_prefix("step-")
                .and_then(|r| r.split('/').next())
                .and_then(|s| s.parse::<u64>().ok())
                .is_none_or(|s| s >= cut)
        });
        assert_eq!(Fingerprint::of_run_dir(&dir).unwrap().diff(&expected), None, "resumed at {cut}");
    }
    for key in [
        "step-96/controller.params",
        "step-96/bptt/eval_loss",
        "step-96/cartpole/adam/v",
        "step-96/cartpole/adam/steps",
        "loss.csv/agreement",
        "loss.csv/eval",
    ] {
        assert!(reference.entries.contains_key(key), "{key} is compared");
    }

    let other = CartPoleConfig { lr: 2e-2, ..cfg };
    let e = train_checkpointed(&other, Some(&run_dir(&full_dir)), &mut |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("resume with the configuration it was started with"), "{e}");
}
