//! `cargo xtask data`: four shards, run out of order as separate processes, equal one run (the
//! same item files, hash for hash), read back as the data set `generate` makes in one call; a
//! missing shard is named.

use std::path::Path;
use std::process::Command;

fn xtask(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().unwrap();
    assert!(out.status.success() || args[1] == "check", "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn item_hashes(dir: &Path) -> Vec<(String, String)> {
    let set = pbdl_core::shard::open_shards(dir).unwrap();
    set.files
        .iter()
        .map(|f| (f.file_name().unwrap().to_string_lossy().into_owned(), pbdl_core::shard::sha256_file(f).unwrap()))
        .collect()
}

#[test]
fn four_metric_shards_equal_one_run() {
    let (one, four) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let common = ["--kind", "Sha", "--count", "10", "--seed", "5", "--resolution", "16"];
    let run = |dir: &Path, shard: &str| {
        let mut args = vec!["data", "metric"];
        args.extend(common);
        args.extend(["--shard", shard, "--out", dir.to_str().unwrap()]);
        xtask(&args)
    };
    run(one.path(), "0/1");
    for shard in ["3/4", "1/4", "0/4"] {
        run(four.path(), shard);
    }
    let check = xtask(&["data", "check", four.path().to_str().unwrap()]);
    assert!(!check.status.success());
    let msg = String::from_utf8_lossy(&check.stderr);
    assert!(msg.contains("run --shard 2/4"), "{msg}");
    run(four.path(), "2/4");
    assert!(xtask(&["data", "check", four.path().to_str().unwrap()]).status.success());
    let (a, b) = (item_hashes(one.path()), item_hashes(four.path()));
    assert_eq!(a.len(), 10);
    assert_eq!(a, b);
    // Training reads the directory: the same sequences as one in-memory generate call.
    let read = pbdl_metrics::train::data::load_shard_dir(four.path()).unwrap();
    let cfg = pbdl_metrics::train::data::DataConfig { resolution: 16, seed: 5 };
    let made = pbdl_metrics::train::data::generate(pbdl_metrics::train::Kind::Shapes, 10, &cfg).unwrap();
    assert_eq!(read.len(), made.len());
    for (r, m) in read.iter().zip(&made) {
        assert_eq!((r.kind, r.param), (m.kind, m.param));
        let diff = (&r.frames - &m.frames).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert_eq!(diff, 0.0);
    }
}

#[test]
fn bad_shard_arguments_are_refused_with_the_expected_form() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(["data", "metric", "--kind", "Sha", "--count", "4", "--shard", "4/4", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("0 <= i < n"), "{msg}");
}

#[test]
fn particle_seed_shards_equal_one_run() {
    let (one, two) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let run = |dir: &Path, shard: &str| {
        xtask(&[
            "sim",
            "particles",
            "periodic_1d_noise",
            "--seeds",
            "3",
            "--steps",
            "3",
            "--shard",
            shard,
            "--out",
            dir.to_str().unwrap(),
        ])
    };
    run(one.path(), "0/1");
    run(two.path(), "1/2");
    run(two.path(), "0/2");
    let (a, b) = (item_hashes(one.path()), item_hashes(two.path()));
    assert_eq!(a.len(), 3);
    assert_eq!(a, b);
    // The seeds differ: the three trajectories are not copies of one another.
    assert_ne!(a[0].1, a[1].1);
    assert_ne!(a[1].1, a[2].1);
}
