//! `cargo xtask pconv train|eval` end to end with `--quick` data (seconds in the debug
//! profile): output files hold finite numbers, a run missing its last checkpoints resumes to
//! the uninterrupted run's weights, and bad input gives a clear error and a non-zero exit.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `cargo xtask ARGS` with one thread (runs in different processes compare bit for bit).
fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .env("PBDL_THREADS", "1")
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .unwrap()
}

fn ok(args: &[&str]) {
    let out = xtask(args);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

fn fails(args: &[&str]) -> String {
    let out = xtask(args);
    assert!(!out.status.success(), "{args:?} should fail: {}", String::from_utf8_lossy(&out.stdout));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn train_resumes_and_eval_writes_the_table() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    let args = |dir: &Path| {
        ["pconv", "train", "--quick", "--task", "update", "--basis", "fourier", "--steps", "40", "--out"]
            .iter()
            .map(|s| s.to_string())
            .chain([dir.to_str().unwrap().to_string()])
            .collect::<Vec<_>>()
    };
    let run = |dir: &Path| ok(&args(dir).iter().map(String::as_str).collect::<Vec<_>>());
    run(&a);
    let full = json(&a.join("summary.json"));
    for key in ["test_rel_mse", "rollout_error", "momentum_drift", "frozen_rollout_error"] {
        assert!(full[key].as_f64().unwrap().is_finite(), "{key}: {full}");
    }
    // An interrupted run: the same directory without its last three checkpoints.
    std::fs::create_dir_all(&b).unwrap();
    for entry in std::fs::read_dir(&a).unwrap() {
        let p = entry.unwrap().path();
        let name = p.file_name().unwrap().to_str().unwrap().to_string();
        let late = ["step-32.", "step-36.", "step-40."].iter().any(|s| name.starts_with(s));
        if !late && name != "summary.json" {
            std::fs::copy(&p, b.join(&name)).unwrap();
        }
    }
    run(&b);
    let resumed = json(&b.join("summary.json"));
    assert_eq!(full["start_step"], 0);
    assert_eq!(resumed["start_step"], 28, "the run did not resume from its last checkpoint");
    for key in ["test_rel_mse", "rollout_error", "momentum_drift"] {
        assert_eq!(full[key], resumed[key], "{key} differs after resuming");
    }
    // Other settings on the same directory are refused, naming the directory and the setting.
    let err = fails(&[
        "pconv",
        "train",
        "--quick",
        "--task",
        "update",
        "--basis",
        "linear",
        "--steps",
        "40",
        "--out",
        a.to_str().unwrap(),
    ]);
    assert!(err.contains(a.to_str().unwrap()) && err.contains("`basis`") && err.contains("new run directory"), "{err}");

    let out = tmp.path().join("table");
    ok(&[
        "pconv",
        "eval",
        "--quick",
        "--tasks",
        "density_gradient",
        "--bases",
        "fourier_even,fourier_odd",
        "--steps",
        "30",
        "--out",
        out.to_str().unwrap(),
    ]);
    let rows = json(&out.with_extension("json"));
    assert_eq!(rows.as_array().unwrap().len(), 2);
    assert!(std::fs::read_to_string(out.with_extension("md")).unwrap().contains("| density_gradient | fourier_odd |"));
    assert!(std::fs::metadata(out.with_extension("png")).unwrap().len() > 1000);
}

#[test]
fn bad_names_are_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x");
    let err = fails(&["pconv", "train", "--quick", "--task", "pressure", "--out", out.to_str().unwrap()]);
    assert!(err.contains("density, density_gradient or update"), "{err}");
    let err = fails(&["pconv", "eval", "--quick", "--bases", "wavelet", "--out", out.to_str().unwrap()]);
    assert!(err.contains("fourier_even"), "{err}");
}
