//! `cargo xtask latent train|eval` end to end at `--quick` size (seconds in the debug
//! profile), and pbdl-latent's registry entries in quick mode: output files hold finite
//! numbers, a second `train` on the same directory resumes (nothing retrained, same scores),
//! bad input gives a clear error and a non-zero exit.

use std::path::Path;
use std::process::{Command, Output};
use xtask::registry::TaskContext;

fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .env("PBDL_THREADS", "1")
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn train_resumes_and_eval_writes_the_table() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let r = run.to_str().unwrap();
    let out = xtask(&["latent", "train", "--quick", "--out", r]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let first = json(&run.join("summary.json"));
    let ae = first["autoencoder_rel_l2_heldout"].as_f64().unwrap();
    assert!(ae.is_finite() && ae > 0.0, "{first}");
    // Same command again: both phases find their last checkpoint and train nothing more.
    let out = xtask(&["latent", "train", "--quick", "--out", r]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let second = json(&run.join("summary.json"));
    assert_eq!(first["autoencoder_rel_l2_heldout"], second["autoencoder_rel_l2_heldout"]);
    assert_eq!(first["prediction_heldout"], second["prediction_heldout"]);
    // Other settings on the same directory are refused, naming one.
    let out = xtask(&["latent", "train", "--quick", "--seed", "5", "--out", r]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("seed"), "{}", String::from_utf8_lossy(&out.stderr));
    let table = tmp.path().join("eval");
    let out = xtask(&[
        "latent",
        "eval",
        "--run",
        r,
        "--intervals",
        "1,3",
        "--steps",
        "30",
        "--warmup",
        "10",
        "--out",
        table.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v = json(&table.with_extension("json"));
    let rows = v["rollouts"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    // Interval 1 is the solver: no predicted step, zero density error.
    assert_eq!(rows[0]["rollout"]["predicted_steps"], 0);
    assert_eq!(rows[0]["rollout"]["density_error_max"].as_f64().unwrap(), 0.0);
    assert!(rows[1]["rollout"]["predicted_steps"].as_u64().unwrap() > 0);
    assert!(table.with_extension("md").exists());
    let out = xtask(&["latent", "eval", "--run", tmp.path().to_str().unwrap(), "--out", table.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("data.json"));
    let out = xtask(&["latent", "eval", "--run", r, "--intervals", "2,x", "--out", table.to_str().unwrap()]);
    assert!(!out.status.success());
}

#[test]
fn quick_entries_run() {
    let dir = tempfile::tempdir().unwrap();
    let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: rayon::current_num_threads() };
    let tasks = xtask::entries::latent::tasks();
    assert_eq!(tasks.crate_name, "latent");
    for e in &tasks.tour {
        let out = (e.run)(&ctx).unwrap_or_else(|err| panic!("tour {}: {err}", e.name));
        assert!(!out.files.is_empty());
        for f in &out.files {
            assert!(dir.path().join(f).exists(), "{} missing", f.display());
        }
        assert!(out.rows.iter().all(|r| r.error.is_some_and(f64::is_finite)), "{:?}", out.rows);
    }
    let rows = (tasks.bench[0].run)(&ctx).unwrap();
    assert_eq!(rows.len(), 7);
    assert!(rows.iter().all(|r| r.seconds > 0.0), "{rows:?}");
    for e in &tasks.stress {
        for c in (e.run)(&ctx).unwrap() {
            if c.invariant.contains("finite") {
                assert!(c.passed, "{}: {}: {}", e.name, c.invariant, c.detail);
            }
        }
    }
}
