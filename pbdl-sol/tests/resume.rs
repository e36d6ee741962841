//! Crash-safe checkpoints and exact resume of pbdl-sol's trainers
//! (`sil::train_resumable`, `control::{pretrain_supervised_resumable,
//! train_end_to_end_resumable}`): a run stopped after `k` updates and called again equals the
//! uninterrupted run bit for bit (losses, weights, Adam state, `loss.csv`, every checkpoint); a
//! run directory changes no number of the in-memory training, whose numbers are those from
//! before the run directories existed; a resume with other settings is refused with a typed
//! error; without Adam's state the resumed run differs (so the comparison can fail); kill -9 at
//! random times and inside checkpoint writes, then resume, reproduces the uninterrupted run.
//! Tiny f64 problems: each test takes well under a second after the build.

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use pbdl_core::io::{list_checkpoints, load_checkpoint, save_checkpoint, CheckpointMeta};
use pbdl_core::train::crash::{child, CrashTest, Fingerprint};
use pbdl_core::train::{sorted_vars, ClipConfig, OPTIM_PREFIX};
use pbdl_sol::control::{
    self, pretrain_supervised, pretrain_supervised_resumable, train_end_to_end, train_end_to_end_resumable,
    BurgersControlConfig, ControlScenes, Controller, ConvNetConfig, RunDir,
};
use pbdl_sol::sil::*;
use pbdl_sol::Error;
use std::path::Path;

// ---------------------------------------------------------------------------------------------
// Tiny problems

fn wake() -> WakeConfig {
    WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() }
}

fn sil_data(train_re: Vec<f64>) -> ReferenceSet {
    let cfg = DataConfig { train_re, test_re: vec![], warmup: 10, train_frames: 12, test_frames: 0 };
    generate(&wake(), &cfg, DType::F64).unwrap()
}

fn sil_cfg(variant: Variant, iterations: usize) -> TrainConfig {
    TrainConfig {
        corrector: CorrectorConfig { width: 4, blocks: 1, kernel: 3, negative_slope: 0.3, zero_output: false },
        lr: 1e-3,
        batch: 2,
        progress: false,
        checkpoint_every: 3,
        ..TrainConfig::new(variant, iterations, 3)
    }
}

fn problem() -> BurgersControlConfig {
    BurgersControlConfig { cells: 32, steps: 4, ..Default::default() }
}

fn scenes(seed: u64) -> ControlScenes {
    control::scene::generate(&problem(), seed, 0..6, DType::F64, &Device::Cpu).unwrap()
}

fn controller() -> Controller {
    let net = ConvNetConfig { width: 4, levels: 2, kernel: 3, ..Default::default() };
    Controller::new(&problem(), &net, DType::F64, &Device::Cpu, 2).unwrap()
}

fn sup_cfg(iterations: usize) -> control::TrainConfig {
    control::TrainConfig { iterations, batch: 3, lr: 3e-3, seed: 4, ..Default::default() }
}

fn e2e_cfg(iterations: usize) -> control::TrainConfig {
    control::TrainConfig { iterations, batch: 3, lr: 1e-3, seed: 5, clip_norm: 1.0, ..Default::default() }
}

/// Every variable's bits, by name.
fn bits(varmap: &VarMap) -> Vec<(String, Vec<u64>)> {
    sorted_vars(varmap)
        .into_iter()
        .map(|(n, v)| {
            let x = v.as_tensor().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            (n, x.iter().map(|x| x.to_bits()).collect())
        })
        .collect()
}

fn loss_bits(l: &[f64]) -> Vec<u64> {
    l.iter().map(|x| x.to_bits()).collect()
}

fn same_dirs(a: &Path, b: &Path) {
    let (fa, fb) = (Fingerprint::of_run_dir(a).unwrap(), Fingerprint::of_run_dir(b).unwrap());
    assert!(!fa.entries.is_empty());
    assert_eq!(fa.diff(&fb), None, "{} vs {}", a.display(), b.display());
}

// ---------------------------------------------------------------------------------------------
// The in-memory numbers

/// The losses the in-memory trainers gave before the run directories existed (recorded with
/// the previous code on these tiny f64 problems; the tolerance only absorbs other CPUs' SIMD
/// rounding, any change of the draws or the update moves them by far more), and a run
/// directory changes none of them, bit for bit, nor the trained weights.
#[test]
fn in_memory_training_keeps_its_numbers_and_a_run_directory_changes_none() {
    let recorded: [(Variant, [f64; 6]); 3] = [
        (
            Variant::Sol { m: 2 },
            [
                0.1303750909652806,
                0.11716980654008018,
                0.10477700700877245,
                0.09615883062809835,
                0.08592306306541572,
                0.07748538814316785,
            ],
        ),
        (
            Variant::Pre,
            [
                0.09322930411097129,
                0.08333295456539205,
                0.07428754539207488,
                0.06774662201508425,
                0.060635555830138105,
                0.054738115729450317,
            ],
        ),
        (
            Variant::Non,
            [
                0.10208872679979798,
                0.09512746058619866,
                0.08063136824425943,
                0.08507640818420097,
                0.06930631283666575,
                0.06299883655393523,
            ],
        ),
    ];
    let close = |got: &[f64], want: &[f64], what: &str| {
        assert_eq!(got.len(), want.len(), "{what}");
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() <= 1e-9 * w.abs(), "{what}: {got:?} vs recorded {want:?}");
        }
    };
    let data = sil_data(vec![200.0, 800.0]);
    for (variant, want) in recorded {
        let cfg = sil_cfg(variant, 6);
        let memory = train(&data, &cfg).unwrap();
        close(&memory.losses, &want, &variant.name());
        let dir = tempfile::tempdir().unwrap();
        let stored = train_resumable(&data, &cfg, dir.path()).unwrap();
        assert_eq!((stored.resumed_from, stored.optimizer_restored), (0, false));
        assert_eq!(loss_bits(&stored.losses), loss_bits(&memory.losses), "{}", variant.name());
        assert_eq!(bits(stored.corrector.varmap()), bits(memory.corrector.varmap()), "{}", variant.name());
        let steps: Vec<u64> = list_checkpoints(dir.path()).unwrap().iter().map(|(_, i)| i.step).collect();
        assert_eq!(steps, [3, 6]);
        // The run directory's corrector reads back.
        let (loaded, step) = load_trained(dir.path()).unwrap();
        assert_eq!(step, 6);
        assert_eq!(bits(loaded.varmap()), bits(memory.corrector.varmap()));
        assert_eq!(loaded.normalisation(), memory.corrector.normalisation());
    }

    let s = scenes(5);
    let (memory, stored) = (controller(), controller());
    let sup = pretrain_supervised(&memory, &s, &sup_cfg(6)).unwrap();
    let e2e = train_end_to_end(&memory, &s, &control::TrainConfig { clip_norm: 0.0, ..e2e_cfg(4) }).unwrap();
    close(
        &sup.losses,
        &[
            0.8042494613085778,
            0.8566797404220188,
            0.9951968278507495,
            0.5953049890754859,
            0.9689102611747452,
            0.6021301822229084,
        ],
        "supervised",
    );
    close(&e2e.losses, &[0.4464609154984296, 0.5043480526823626, 0.36580224037152376, 0.2937419016376155], "e2e");
    let root = tempfile::tempdir().unwrap();
    let sup2 = pretrain_supervised_resumable(&stored, &s, &sup_cfg(6), &RunDir::new(root.path().join("sup"))).unwrap();
    let e2e2 = train_end_to_end_resumable(
        &stored,
        &s,
        &control::TrainConfig { clip_norm: 0.0, ..e2e_cfg(4) },
        &RunDir::new(root.path().join("e2e")),
    )
    .unwrap();
    assert_eq!(loss_bits(&sup2.losses), loss_bits(&sup.losses));
    assert_eq!(loss_bits(&e2e2.losses), loss_bits(&e2e.losses));
    assert_eq!(bits(stored.varmap()), bits(memory.varmap()));
}

// ---------------------------------------------------------------------------------------------
// Stop after k, resume

/// SOL-2 (through the solver, with gradient clipping), PRE and NON: stopped after 6 of 9
/// updates (on a checkpoint) or after 4 (between checkpoints: the last committed checkpoint is
/// the stop's own) and called again with 9, the run ends as the uninterrupted one: losses,
/// weights and, for the stop on the cadence, every file of the run directory (Adam's moments
/// in each checkpoint included).
#[test]
fn sil_stopped_and_resumed_equals_uninterrupted() {
    let data = sil_data(vec![200.0, 800.0]);
    for cfg in [
        TrainConfig { clip: ClipConfig::Norm { max_norm: 0.05 }, ..sil_cfg(Variant::Sol { m: 2 }, 9) },
        sil_cfg(Variant::Pre, 9),
        sil_cfg(Variant::Non, 9),
    ] {
        let name = cfg.variant.name();
        let root = tempfile::tempdir().unwrap();
        let whole = root.path().join("whole");
        let full = train_resumable(&data, &cfg, &whole).unwrap();
        assert_eq!(full.losses.len(), 9);
        for stop in [6, 4] {
            let parts = root.path().join(format!("parts-{stop}"));
            let first = train_resumable(&data, &TrainConfig { iterations: stop, ..cfg.clone() }, &parts).unwrap();
            assert_eq!(loss_bits(&first.losses), loss_bits(&full.losses[..stop]), "{name}");
            let rest = train_resumable(&data, &cfg, &parts).unwrap();
            assert_eq!((rest.resumed_from, rest.optimizer_restored), (stop as u64, true), "{name}");
            assert_eq!(loss_bits(&rest.losses), loss_bits(&full.losses), "{name}, stopped at {stop}");
            assert_eq!(bits(rest.corrector.varmap()), bits(full.corrector.varmap()), "{name}, stopped at {stop}");
            if stop % 3 == 0 {
                same_dirs(&parts, &whole);
            }
        }
        // A finished run called again has nothing left to do and returns the same network.
        let again = train_resumable(&data, &cfg, &whole).unwrap();
        assert_eq!(again.resumed_from, 9);
        assert_eq!(loss_bits(&again.losses), loss_bits(&full.losses));
        assert_eq!(bits(again.corrector.varmap()), bits(full.corrector.varmap()));
    }
}

/// Both control phases, each stopped and resumed (the end-to-end phase with gradient clipping):
/// the pre-training stopped after 4 of 6 updates, the end-to-end phase after 2 of 4, each
/// called again, ends with the uninterrupted run's weights, losses and run directories.
#[test]
fn control_stopped_and_resumed_equals_uninterrupted() {
    let s = scenes(5);
    let root = tempfile::tempdir().unwrap();
    let dirs = |tag: &str| {
        (
            RunDir::new(root.path().join(format!("{tag}-sup"))).every(2),
            RunDir::new(root.path().join(format!("{tag}-e2e"))).every(2),
        )
    };
    let (ws, we) = dirs("whole");
    let whole = controller();
    let sup = pretrain_supervised_resumable(&whole, &s, &sup_cfg(6), &ws).unwrap();
    let e2e = train_end_to_end_resumable(&whole, &s, &e2e_cfg(4), &we).unwrap();

    let (ps, pe) = dirs("parts");
    // The first process: 4 supervised updates, then stopped.
    let first = controller();
    pretrain_supervised_resumable(&first, &s, &sup_cfg(4), &ps).unwrap();
    // The second: the supervised phase resumes at 4 and finishes; the end-to-end phase runs 2.
    let second = controller();
    let sup2 = pretrain_supervised_resumable(&second, &s, &sup_cfg(6), &ps).unwrap();
    assert_eq!(sup2.resumed_from, 4);
    assert_eq!(loss_bits(&sup2.losses), loss_bits(&sup.losses));
    train_end_to_end_resumable(&second, &s, &e2e_cfg(2), &pe).unwrap();
    // The third: the supervised phase is complete (its weights come from its last checkpoint
    // and are then replaced by the end-to-end phase's), the end-to-end phase resumes at 2.
    let third = controller();
    let sup3 = pretrain_supervised_resumable(&third, &s, &sup_cfg(6), &ps).unwrap();
    assert_eq!(sup3.resumed_from, 6);
    let e2e3 = train_end_to_end_resumable(&third, &s, &e2e_cfg(4), &pe).unwrap();
    assert_eq!(e2e3.resumed_from, 2);
    assert_eq!(loss_bits(&e2e3.losses), loss_bits(&e2e.losses));
    assert_eq!(bits(third.varmap()), bits(whole.varmap()));
    same_dirs(&ps.dir, &ws.dir);
    same_dirs(&pe.dir, &we.dir);
}

// ---------------------------------------------------------------------------------------------
// Refusals

fn mismatch(e: Error) -> String {
    match e {
        Error::ResumeMismatch { ref field, .. } => {
            let msg = e.to_string();
            assert!(msg.contains("start a new run directory"), "{msg}");
            field.clone()
        }
        other => panic!("expected ResumeMismatch, got {other:?}"),
    }
}

/// A run directory of other settings, data or another trainer is refused with
/// `Error::ResumeMismatch` naming the setting, and nothing is loaded; asking for fewer updates
/// than the directory holds is an `InvalidConfig` on `iterations`; the number of updates, the
/// checkpoint cadence and the progress bar may change.
#[test]
fn resuming_with_other_settings_is_refused_with_the_setting_named() {
    let data = sil_data(vec![200.0, 800.0]);
    let dir = tempfile::tempdir().unwrap();
    let cfg = sil_cfg(Variant::Sol { m: 2 }, 3);
    train_resumable(&data, &cfg, dir.path()).unwrap();
    let refused = |c: TrainConfig, d: &ReferenceSet| mismatch(train_resumable(d, &c, dir.path()).unwrap_err());
    assert_eq!(refused(TrainConfig { lr: 2e-3, ..cfg.clone() }, &data), "train.lr");
    assert_eq!(refused(TrainConfig { seed: 4, ..cfg.clone() }, &data), "train.seed");
    assert_eq!(refused(TrainConfig { batch: 3, ..cfg.clone() }, &data), "train.batch");
    assert_eq!(refused(TrainConfig { variant: Variant::Sol { m: 3 }, ..cfg.clone() }, &data), "train.variant.m");
    assert_eq!(refused(TrainConfig { variant: Variant::Pre, ..cfg.clone() }, &data), "train.variant.kind");
    assert_eq!(
        refused(TrainConfig { clip: ClipConfig::Norm { max_norm: 1.0 }, ..cfg.clone() }, &data),
        "train.clip.kind"
    );
    let wider = CorrectorConfig { width: 5, ..cfg.corrector };
    assert_eq!(refused(TrainConfig { corrector: wider, ..cfg.clone() }, &data), "network.parameters");
    let other_re = sil_data(vec![200.0, 700.0]);
    assert_eq!(refused(cfg.clone(), &other_re), "data.train_re[1]");
    // The same Reynolds numbers and shapes, one frame changed: only the digest tells.
    let mut touched = data.clone();
    touched.train[1].frames = (&touched.train[1].frames * 1.0000001).unwrap();
    assert_eq!(refused(cfg.clone(), &touched), "data.digest");
    let e = train_resumable(&data, &TrainConfig { iterations: 2, ..cfg.clone() }, dir.path()).unwrap_err();
    assert!(matches!(e, Error::InvalidConfig { field: "iterations", .. }), "{e}");
    // What may change: the number of updates, the cadence, the progress bar.
    let more = TrainConfig { iterations: 4, checkpoint_every: 1, progress: true, ..cfg.clone() };
    assert_eq!(train_resumable(&data, &more, dir.path()).unwrap().resumed_from, 3);

    // Control: the other phase's directory, other scenes, another learning rate; the refused
    // call leaves the controller's weights alone.
    let s = scenes(5);
    let root = tempfile::tempdir().unwrap();
    let sup_dir = RunDir::new(root.path().join("sup"));
    pretrain_supervised_resumable(&controller(), &s, &sup_cfg(2), &sup_dir).unwrap();
    let fresh = controller();
    let before = bits(fresh.varmap());
    let e = train_end_to_end_resumable(&fresh, &s, &e2e_cfg(2), &sup_dir).unwrap_err();
    assert_eq!(mismatch(e), "trainer");
    assert_eq!(
        mismatch(pretrain_supervised_resumable(&fresh, &scenes(6), &sup_cfg(2), &sup_dir).unwrap_err()),
        "scenes.digest"
    );
    let lr = control::TrainConfig { lr: 1e-2, ..sup_cfg(2) };
    assert_eq!(mismatch(pretrain_supervised_resumable(&fresh, &s, &lr, &sup_dir).unwrap_err()), "train.lr");
    let wide = Controller::new(
        &problem(),
        &ConvNetConfig { width: 6, levels: 2, kernel: 3, ..Default::default() },
        DType::F64,
        &Device::Cpu,
        2,
    )
    .unwrap();
    assert_eq!(
        mismatch(pretrain_supervised_resumable(&wide, &s, &sup_cfg(2), &sup_dir).unwrap_err()),
        "network.parameters"
    );
    let e = pretrain_supervised_resumable(&fresh, &s, &sup_cfg(1), &sup_dir).unwrap_err();
    assert!(matches!(e, Error::InvalidConfig { field: "iterations", .. }), "{e}");
    assert_eq!(bits(fresh.varmap()), before, "a refused resume loads nothing");
}

// ---------------------------------------------------------------------------------------------
// Without Adam's state

/// Copies the checkpoint of `step` from `from` into `to` without its optimiser tensors (as a
/// weights-only checkpoint of the same run), with the `loss.csv` up to it.
fn copy_without_optimizer(from: &Path, to: &Path, step: u64) {
    std::fs::create_dir_all(to).unwrap();
    let name = format!("step-{step}");
    let (tensors, info) = load_checkpoint(from.join(&name), &Device::Cpu).unwrap();
    let kept: Vec<(String, Tensor)> = tensors.into_iter().filter(|(n, _)| !n.starts_with(OPTIM_PREFIX)).collect();
    assert!(kept.len() >= 2);
    let meta = CheckpointMeta { step: info.step, seed: info.seed, config: info.config };
    save_checkpoint(to.join(&name), kept, &meta).unwrap();
    let log = std::fs::read_to_string(from.join("loss.csv")).unwrap();
    let rows: Vec<&str> = log.lines().take(1 + step as usize).collect();
    std::fs::write(to.join("loss.csv"), rows.join("\n") + "\n").unwrap();
}

/// The exact resume needs Adam's moments and update count: the same stop with the optimiser
/// state dropped from the checkpoint resumes (weights only; reported as not restored) and
/// ends elsewhere than the uninterrupted run, while the checkpoint as written ends on it.
/// SOL-2 and the end-to-end control phase.
#[test]
fn without_the_optimizer_state_the_resumed_run_differs() {
    let data = sil_data(vec![200.0, 800.0]);
    let cfg = sil_cfg(Variant::Sol { m: 2 }, 9);
    let root = tempfile::tempdir().unwrap();
    let (whole, parts, cold) = (root.path().join("whole"), root.path().join("parts"), root.path().join("cold"));
    let full = train_resumable(&data, &cfg, &whole).unwrap();
    train_resumable(&data, &TrainConfig { iterations: 6, ..cfg.clone() }, &parts).unwrap();
    copy_without_optimizer(&parts, &cold, 6);
    let warm = train_resumable(&data, &cfg, &parts).unwrap();
    let restarted = train_resumable(&data, &cfg, &cold).unwrap();
    assert!(warm.optimizer_restored && !restarted.optimizer_restored);
    assert_eq!(restarted.resumed_from, 6);
    assert_eq!(loss_bits(&warm.losses), loss_bits(&full.losses));
    assert_eq!(
        loss_bits(&restarted.losses[..7]),
        loss_bits(&full.losses[..7]),
        "update 6 starts from the same weights"
    );
    assert_ne!(loss_bits(&restarted.losses[7..]), loss_bits(&full.losses[7..]), "fresh Adam moments must show");
    assert_ne!(bits(restarted.corrector.varmap()), bits(full.corrector.varmap()));

    let s = scenes(5);
    let whole = controller();
    let (we, pe, ce) =
        (RunDir::new(root.path().join("we")), RunDir::new(root.path().join("pe")), RunDir::new(root.path().join("ce")));
    pretrain_supervised(&whole, &s, &sup_cfg(3)).unwrap();
    let full = train_end_to_end_resumable(&whole, &s, &e2e_cfg(4), &we).unwrap();
    let start = controller();
    pretrain_supervised(&start, &s, &sup_cfg(3)).unwrap();
    train_end_to_end_resumable(&start, &s, &e2e_cfg(2), &pe).unwrap();
    copy_without_optimizer(&pe.dir, &ce.dir, 2);
    let (a, b) = (controller(), controller());
    let warm = train_end_to_end_resumable(&a, &s, &e2e_cfg(4), &pe).unwrap();
    let restarted = train_end_to_end_resumable(&b, &s, &e2e_cfg(4), &ce).unwrap();
    assert_eq!(loss_bits(&warm.losses), loss_bits(&full.losses));
    assert_eq!(bits(a.varmap()), bits(whole.varmap()));
    assert_ne!(loss_bits(&restarted.losses[3..]), loss_bits(&full.losses[3..]));
    assert_ne!(bits(b.varmap()), bits(whole.varmap()));
}

// ---------------------------------------------------------------------------------------------
// kill -9

fn sil_child(dir: &Path) -> pbdl_sol::Result<()> {
    let cfg = TrainConfig { checkpoint_every: 2, ..sil_cfg(Variant::Sol { m: 2 }, 12) };
    train_resumable(&sil_data(vec![200.0, 800.0]), &cfg, dir)?;
    Ok(())
}

#[test]
fn crash_child_sil() {
    child(sil_child);
}

fn control_child(dir: &Path) -> pbdl_sol::Result<()> {
    // One phase per crash test (the harness checks one directory): the end-to-end phase from
    // the in-memory pre-training, which a restarted process repeats identically.
    let s = scenes(5);
    let ctrl = controller();
    pretrain_supervised(&ctrl, &s, &sup_cfg(3))?;
    train_end_to_end_resumable(&ctrl, &s, &e2e_cfg(10), &RunDir::new(dir).every(2))?;
    Ok(())
}

#[test]
fn crash_child_control() {
    child(control_child);
}

fn kill_and_resume(child_test: &str, kills: usize, seed: u64) {
    let root = tempfile::tempdir().unwrap();
    let started = std::time::Instant::now();
    let report = CrashTest::new(child_test, root.path(), kills, seed)
        .run(Fingerprint::of_run_dir)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{child_test}: {report:?} in {:.1} s", started.elapsed().as_secs_f64());
    assert_eq!(report.kills, kills);
    assert!(report.in_write >= 1, "no kill landed inside a checkpoint write: {report:?}");
    assert!(report.rounds >= 1);
    // The reference holds what the comparison is about: Adam's moments in every checkpoint.
    let reference = root.path().join("reference");
    let listed = list_checkpoints(&reference).unwrap();
    assert!(listed.len() >= 5);
    let (tensors, _) = load_checkpoint(&listed[listed.len() - 1].0, &Device::Cpu).unwrap();
    assert!(tensors.keys().any(|k| k.starts_with(&format!("{OPTIM_PREFIX}adamw/v/"))));
}

/// kill -9 during SOL-2 training, at random times and inside checkpoint writes (three kills,
/// seeded), each followed by `CrashTest`'s checks: committed checkpoints load after every
/// kill; a finished run has no leftovers and equals the uninterrupted one bit for bit
/// (`loss.csv` without its seconds, every checkpoint's weights and Adam state).
#[test]
fn sil_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume("crash_child_sil", 3, 11);
}

/// The same for the end-to-end control phase (with gradient clipping).
#[test]
fn control_kill_9_then_resume_reproduces_the_uninterrupted_run() {
    kill_and_resume("crash_child_control", 3, 12);
}
