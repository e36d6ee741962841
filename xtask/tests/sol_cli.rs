//! `cargo xtask sol train|eval` and `cargo xtask control train|eval` end to end with `--quick`
//! sizes (seconds in the debug profile): the output files parse and hold finite numbers, a
//! second `train` on the same directory resumes (and a stopped-then-continued run equals one
//! trained in one go), and bad input gives a clear error and a non-zero exit.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `cargo xtask ARGS` with one thread (reductions sum in one order, so runs in
/// different processes compare bit for bit, as in pbdl-core's crash harness).
fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .env("PBDL_THREADS", "1")
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = xtask(args);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The error message of a command that must fail.
fn fails(args: &[&str]) -> String {
    let out = xtask(args);
    assert!(!out.status.success(), "{args:?} should fail: {}", String::from_utf8_lossy(&out.stdout));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn finite(v: &serde_json::Value, what: &str) -> f64 {
    let x = v.as_f64().unwrap_or_else(|| panic!("{what}: {v} is not a number"));
    assert!(x.is_finite(), "{what}: {x}");
    x
}

/// Two runs (SOL-2 stopped after 4 updates and continued to 8, PRE), then the evaluation:
/// the table has the source and both runs with finite MAEs, the PNG exists, and the continued
/// run's `loss.csv` equals one trained in one go.
#[test]
fn sol_train_resume_and_eval() {
    let root = tempfile::tempdir().unwrap();
    let (sol, pre, once) = (root.path().join("sol2"), root.path().join("pre"), root.path().join("once"));
    let first = ok(&["sol", "train", "--variant", "sol-2", "--quick", "--iterations", "4", "--out", s(&sol)]);
    assert!(!first.contains("resuming"), "{first}");
    let second = ok(&["sol", "train", "--variant", "sol-2", "--quick", "--iterations", "8", "--out", s(&sol)]);
    assert!(second.contains("resuming") && second.contains("cached"), "{second}");
    ok(&["sol", "train", "--variant", "sol-2", "--quick", "--iterations", "8", "--out", s(&once)]);
    let loss = |d: &Path| std::fs::read_to_string(d.join("loss.csv")).unwrap();
    let values = |text: String| -> Vec<(String, String)> {
        // step and loss columns (not the wall-clock seconds).
        text.lines()
            .skip(1)
            .map(|l| {
                let c: Vec<&str> = l.split(',').collect();
                (c[0].to_string(), c[1].to_string())
            })
            .collect()
    };
    assert_eq!(values(loss(&sol)).len(), 8);
    assert_eq!(values(loss(&sol)), values(loss(&once)), "stopped and continued vs in one go");
    let summary = json(&sol.join("summary.json"));
    assert_eq!(summary["resumed_from"], 4);
    finite(&summary["final_loss_mean_last_100"], "final loss");
    ok(&["sol", "train", "--variant", "pre", "--quick", "--iterations", "5", "--seed", "1", "--out", s(&pre)]);

    let out = root.path().join("eval");
    ok(&["sol", "eval", "--runs", s(&sol), s(&pre), "--steps", "16", "--out", s(&out)]);
    let report = json(&root.path().join("eval.json"));
    let rows = report["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names.len(), 3);
    assert!(names[0] == "source" && names[1].starts_with("SOL-2") && names[2].starts_with("PRE"), "{names:?}");
    for r in rows {
        let mae = r["mean_mae"].as_array().unwrap();
        assert_eq!(mae.len(), 3);
        for m in mae {
            assert!(finite(m, "mean MAE") > 0.0);
        }
        assert_eq!(r["mae_per_step"].as_array().unwrap().len(), 16);
    }
    assert_eq!(report["columns"][2], "steps 9-16");
    let md = std::fs::read_to_string(root.path().join("eval.md")).unwrap();
    assert!(md.contains("| source |") && md.contains("eval.png"), "{md}");
    assert!(std::fs::metadata(root.path().join("eval.png")).unwrap().len() > 1000);
}

/// Unknown variants, missing or foreign run directories, too many steps and a changed setting
/// on resume are refused with messages that say what to change.
#[test]
fn sol_bad_input_is_refused_clearly() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let e = fails(&["sol", "train", "--variant", "sol-x", "--quick", "--out", s(&dir)]);
    assert!(e.contains("unknown --variant `sol-x`") && e.contains("sol-<m>"), "{e}");
    let missing = root.path().join("missing");
    let e = fails(&["sol", "eval", "--runs", s(&missing), "--out", s(&root.path().join("e"))]);
    assert!(e.contains("does not exist") && e.contains("missing"), "{e}");
    let e = fails(&["sol", "eval", "--runs", s(root.path()), "--out", s(&root.path().join("e"))]);
    assert!(e.contains("holds no reference data"), "{e}");
    ok(&["sol", "train", "--variant", "non", "--quick", "--iterations", "2", "--out", s(&dir)]);
    let e = fails(&["sol", "eval", "--runs", s(&dir), "--steps", "500", "--out", s(&root.path().join("e"))]);
    assert!(e.contains("--steps 16 at most"), "{e}");
    let e =
        fails(&["sol", "train", "--variant", "non", "--quick", "--iterations", "4", "--seed", "3", "--out", s(&dir)]);
    assert!(e.contains("`train.seed`") && e.contains("start a new run directory"), "{e}");
    let cfg = root.path().join("bad.toml");
    std::fs::write(&cfg, "learning_rate = 0.1\n").unwrap();
    let e = fails(&["sol", "train", "--quick", "--config", s(&cfg), "--out", s(&root.path().join("r2"))]);
    assert!(e.contains("bad.toml") && e.contains("learning_rate"), "{e}");
}

/// `control train --quick` (a settings file changing the end-to-end updates), a second call
/// resumes with nothing left, `control eval` writes four finite rows; bad input is refused.
#[test]
fn control_train_eval_and_bad_input() {
    let root = tempfile::tempdir().unwrap();
    let run = root.path().join("ctrl");
    let cfg = root.path().join("c.json");
    std::fs::write(&cfg, r#"{"end_to_end": {"iterations": 3}}"#).unwrap();
    ok(&["control", "train", "--quick", "--config", s(&cfg), "--out", s(&run)]);
    let again = ok(&["control", "train", "--quick", "--config", s(&cfg), "--out", s(&run)]);
    assert!(again.contains("resuming") && again.contains("(0 in this call"), "{again}");
    let stored = json(&run.join("config.json"));
    assert_eq!(stored["end_to_end"]["iterations"], 3);
    assert_eq!(stored["end_to_end"]["lr"], 1e-3, "the rest of the section keeps the --quick values");
    for phase in ["supervised", "end_to_end"] {
        assert!(run.join(phase).join("loss.csv").exists(), "{phase}");
    }
    let out = root.path().join("ctrl_eval.json");
    ok(&["control", "eval", "--run", s(&run), "--out", s(&out)]);
    let report = json(&out);
    let rows = report["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["controller (end to end)", "controller (supervised only)", "optimiser, same wall-clock", "no control"]
    );
    for r in rows {
        for k in ["effort", "target_error", "combined", "seconds"] {
            assert!(finite(&r[k], k) >= 0.0);
        }
        let sum = finite(&r["effort"], "effort") + finite(&r["target_error"], "target");
        assert!((finite(&r["combined"], "combined") - sum).abs() <= 1e-6 * sum.max(1e-12), "{r}");
    }
    assert_eq!(rows[3]["effort"], 0.0);
    assert!(std::fs::read_to_string(root.path().join("ctrl_eval.md")).unwrap().contains("| no control |"));

    let e = fails(&["control", "eval", "--run", s(&root.path().join("nope")), "--out", s(&out)]);
    assert!(e.contains("does not exist"), "{e}");
    let e = fails(&["control", "eval", "--run", s(root.path()), "--out", s(&out)]);
    assert!(e.contains("no config.json"), "{e}");
    let e = fails(&["control", "train", "--quick", "--out", s(&run)]);
    assert!(e.contains("other settings") && e.contains("another --out"), "{e}");
}
