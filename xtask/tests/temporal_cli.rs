//! `cargo xtask temporal train|eval|upscale` end to end at `--quick` size, and pbdl-temporal's
//! registry entries in quick mode: a second `train` on the same directory resumes (same
//! models), other settings are refused naming one, `upscale` writes the 4x density of an
//! `.npz` with every model kind, and bad input gives an error naming the array.

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

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every weight of a model file, by name (the sidecar's creation time differs between writes).
fn weights(p: &Path) -> Vec<(String, Vec<f32>)> {
    let (map, _) = pbdl_core::io::load_checkpoint(p, &candle_core::Device::Cpu).unwrap();
    let mut w: Vec<(String, Vec<f32>)> =
        map.into_iter().map(|(n, t)| (n, t.flatten_all().unwrap().to_vec1::<f32>().unwrap())).collect();
    w.sort_by(|a, b| a.0.cmp(&b.0));
    w
}

#[test]
fn train_resumes_eval_scores_and_upscale_reads_npz() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let r = run.to_str().unwrap();
    let out = xtask(&["temporal", "train", "--quick", "--out", r]);
    assert!(out.status.success(), "{}", stderr(&out));
    let model = run.join("models").join("temporal.safetensors");
    let first = weights(&model);
    // Same command again: every phase finds its last checkpoint; the models are the same.
    let out = xtask(&["temporal", "train", "--quick", "--out", r]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(weights(&model), first);
    let out = xtask(&["temporal", "train", "--quick", "--seed", "5", "--out", r]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("seed"), "{}", stderr(&out));
    // The refused call left the run's settings as they were.
    let data: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("data.json")).unwrap()).unwrap();
    assert_eq!(data["seed"], 0);
    // Eval: bicubic + three models, finite scores.
    let table = tmp.path().join("eval");
    let out = xtask(&["temporal", "eval", "--run", r, "--out", table.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(table.with_extension("json")).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(
        rows.iter().map(|r| r["method"].as_str().unwrap()).collect::<Vec<_>>(),
        ["bicubic", "baseline", "per_frame", "temporal"]
    );
    for row in rows {
        for key in ["psnr", "ssim", "tof"] {
            assert!(row[key].as_f64().is_some_and(f64::is_finite), "{row}");
        }
        // The LSiM scores need the published weights (../shared or PBDL_WEIGHTS_DIR).
        let with_weights = pbdl_temporal::eval::default_lsim().unwrap().is_some();
        for key in ["lsim", "tlsim"] {
            assert_eq!(row[key].as_f64().is_some_and(f64::is_finite), with_weights, "{row}");
        }
    }
    assert!(std::fs::read_to_string(table.with_extension("md")).unwrap().contains("tOF"));
    // Upscale with each model kind, and with the run directory (its temporal GAN).
    let dev = candle_core::Device::Cpu;
    let lr = candle_core::Tensor::rand(0f32, 1.0, (5, 1, 8, 12), &dev).unwrap();
    let vel = candle_core::Tensor::zeros((5, 2, 8, 12), candle_core::DType::F32, &dev).unwrap();
    let input = tmp.path().join("lr.npz");
    pbdl_core::io::write_npz(&input, &[("density", &lr), ("velocity", &vel)]).unwrap();
    let hr = tmp.path().join("hr.npz");
    for m in ["baseline", "per_frame", "temporal"] {
        let path = run.join("models").join(format!("{m}.safetensors"));
        let out = xtask(&[
            "temporal",
            "upscale",
            "--model",
            path.to_str().unwrap(),
            "--input",
            input.to_str().unwrap(),
            "--out",
            hr.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{m}: {}", stderr(&out));
        let d = pbdl_core::io::read_npz_array(&hr, "density").unwrap();
        assert_eq!(d.dims(), [5, 1, 32, 48]);
    }
    let out = xtask(&[
        "temporal",
        "upscale",
        "--model",
        r,
        "--input",
        input.to_str().unwrap(),
        "--out",
        hr.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    // A recurrent TecoGAN model file (seeded, untrained): the CLI's frames equal the in-process
    // rollout.
    let varmap = candle_nn::VarMap::new();
    let vb = candle_nn::VarBuilder::from_varmap(&varmap, candle_core::DType::F32, &dev);
    let teco = pbdl_temporal::tecogan::TecoGan::new(Default::default(), vb).unwrap();
    pbdl_nets::seeded_init(&varmap, 1).unwrap();
    let info = pbdl_temporal::model::RecurrentModelInfo {
        tecogan: Default::default(),
        objective: "untrained".into(),
        updates: 0,
    };
    let teco_path = tmp.path().join("teco.safetensors");
    pbdl_temporal::model::RecurrentModel::new(info, varmap).unwrap().save(&teco_path).unwrap();
    let out = xtask(&[
        "temporal",
        "upscale",
        "--model",
        teco_path.to_str().unwrap(),
        "--input",
        input.to_str().unwrap(),
        "--out",
        hr.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("recurrent TecoGAN"));
    let d = pbdl_core::io::read_npz_array(&hr, "density").unwrap();
    let expected = teco.infer_sequence(&lr).unwrap();
    let diff: f32 =
        (&d - &expected).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap();
    assert_eq!(diff, 0.0);
    // Bad inputs name the array.
    let bad = tmp.path().join("bad.npz");
    pbdl_core::io::write_npz(&bad, &[("rho", &lr)]).unwrap();
    let out =
        xtask(&["temporal", "upscale", "--model", r, "--input", bad.to_str().unwrap(), "--out", hr.to_str().unwrap()]);
    assert!(!out.status.success() && stderr(&out).contains("density"), "{}", stderr(&out));
    let wrong_v = candle_core::Tensor::zeros((4, 2, 8, 12), candle_core::DType::F32, &dev).unwrap();
    pbdl_core::io::write_npz(&bad, &[("density", &lr), ("velocity", &wrong_v)]).unwrap();
    let out =
        xtask(&["temporal", "upscale", "--model", r, "--input", bad.to_str().unwrap(), "--out", hr.to_str().unwrap()]);
    assert!(!out.status.success() && stderr(&out).contains("velocity"), "{}", stderr(&out));
    let out = xtask(&["temporal", "eval", "--run", tmp.path().to_str().unwrap(), "--out", table.to_str().unwrap()]);
    assert!(!out.status.success() && stderr(&out).contains("data.json"), "{}", stderr(&out));
}

#[test]
fn quick_entries_run() {
    let dir = tempfile::tempdir().unwrap();
    let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: rayon::current_num_threads() };
    let tasks = xtask::entries::temporal::tasks();
    assert_eq!(tasks.crate_name, "temporal");
    for e in &tasks.tour {
        let out = (e.run)(&ctx).unwrap_or_else(|err| panic!("tour {}: {err}", e.name));
        for f in &out.files {
            assert!(dir.path().join(f).exists(), "{} missing", f.display());
        }
        assert_eq!(out.rows.len(), 4);
        assert!(out.rows.iter().all(|r| r.error.is_some_and(f64::is_finite)), "{:?}", out.rows);
    }
    let rows = (tasks.bench[0].run)(&ctx).unwrap();
    assert_eq!(rows.len(), 5);
    assert!(rows.iter().all(|r| r.seconds > 0.0), "{rows:?}");
    for e in &tasks.stress {
        for c in (e.run)(&ctx).unwrap() {
            if c.invariant.contains("finite") {
                assert!(c.passed, "{}: {}: {}", e.name, c.invariant, c.detail);
            }
        }
    }
}
