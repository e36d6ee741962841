//! Sharded `sim grid --seeds N` and `weather generate`: shards run out of order as separate
//! processes equal one run (the same item files, hash for hash), `data check` accepts the
//! directory, and the runs differ from one another; `weather train` reads a directory of shards
//! and refuses a damaged one.

use std::path::Path;
use std::process::{Command, Output};

fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().unwrap()
}

fn ok(args: &[&str]) -> Output {
    let out = xtask(args);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn item_hashes(dir: &Path) -> Vec<(String, String)> {
    let set = pbdl_core::shard::open_shards(dir).unwrap();
    set.files
        .iter()
        .map(|f| (f.file_name().unwrap().to_string_lossy().into_owned(), pbdl_core::shard::sha256_file(f).unwrap()))
        .collect()
}

fn hash(path: &Path) -> String {
    pbdl_core::shard::sha256_file(path).unwrap()
}

/// burgers_2d starts from random modes (seed 3): 5 runs of 3 steps at 16^2.
const GRID: [&str; 9] = ["sim", "grid", "burgers_2d", "--seeds", "5", "--res", "16", "--steps", "3"];

fn grid(dir: &Path, shard: Option<&str>) -> Output {
    let mut args = GRID.to_vec();
    if let Some(s) = shard {
        args.extend(["--shard", s]);
    }
    args.extend(["--out", dir.to_str().unwrap()]);
    ok(&args)
}

#[test]
fn four_grid_seed_shards_equal_one_run() {
    let (one, four, plain) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    grid(one.path(), Some("0/1"));
    // Out of order, as a scheduler may run them; the last one is checked for first.
    for shard in ["2/4", "0/4", "3/4"] {
        grid(four.path(), Some(shard));
    }
    let check = xtask(&["data", "check", four.path().to_str().unwrap()]);
    assert!(!check.status.success());
    let msg = String::from_utf8_lossy(&check.stderr);
    assert!(msg.contains("run --shard 1/4"), "{msg}");
    grid(four.path(), Some("1/4"));
    let check = ok(&["data", "check", four.path().to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&check.stdout).contains("5 items of `pbdl-grid/sim`"));
    let (a, b) = (item_hashes(one.path()), item_hashes(four.path()));
    assert_eq!(a.len(), 5);
    assert_eq!(a, b);
    // The seeds differ: no two runs are the same file.
    for i in 0..a.len() {
        for j in i + 1..a.len() {
            assert_ne!(a[i].1, a[j].1, "runs {i} and {j}");
        }
    }
    // Without --shard the same runs are `<scene>_seed<k>.npz` (the same bytes: only the name
    // differs), and run 0 is the scene itself.
    grid(plain.path(), None);
    for (k, (_, h)) in a.iter().enumerate() {
        assert_eq!(&hash(&plain.path().join(format!("burgers_2d_seed{k}.npz"))), h, "seed {k}");
    }
    ok(&["sim", "grid", "burgers_2d", "--res", "16", "--steps", "3", "--out", plain.path().to_str().unwrap()]);
    assert_eq!(hash(&plain.path().join("burgers_2d.npz")), a[0].1);
    // Another resolution is another data set: its job writing into this directory (replacing
    // item 0 and manifest 0) is refused by the check.
    let mut args = GRID.to_vec();
    args[6] = "8";
    args.extend(["--shard", "0/4", "--out", four.path().to_str().unwrap()]);
    ok(&args);
    let check = xtask(&["data", "check", four.path().to_str().unwrap()]);
    assert!(!check.status.success());
    assert!(String::from_utf8_lossy(&check.stderr).contains("another generator or config"));
}

#[test]
fn grid_seeds_are_refused_where_they_would_repeat_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = xtask(&["sim", "grid", "taylor_green", "--seeds", "2", "--res", "8", "--steps", "1", "--out", d]);
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("`taylor_green` has no random input") && msg.contains("burgers_2d"), "{msg}");
    let out = xtask(&["sim", "grid", "burgers_2d", "--res", "8", "--steps", "1", "--shard", "0/2", "--out", d]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("give --seeds"));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "nothing written");
}

fn weather(dir: &Path, shard: Option<&str>) -> Output {
    let mut args = vec!["weather", "generate", "--truth-years", "0.01", "--climate-years", "0.01", "--seed", "2"];
    if let Some(s) = shard {
        args.extend(["--shard", s]);
    }
    args.extend(["--out", dir.to_str().unwrap()]);
    ok(&args)
}

#[test]
fn two_weather_shards_equal_one_run_and_train_reads_them() {
    let (one, two) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    weather(one.path(), Some("0/1"));
    weather(two.path(), Some("1/2"));
    weather(two.path(), Some("0/2"));
    ok(&["data", "check", two.path().to_str().unwrap()]);
    let (a, b) = (item_hashes(one.path()), item_hashes(two.path()));
    assert_eq!(a.len(), 2);
    assert_eq!(a, b);
    // The truth and the biased climate run are different runs.
    assert_ne!(a[0].1, a[1].1);
    // `weather train` reads the shard directory: past the reading, it stops at the truth's length
    // (training needs 3 years), naming the 15 fields it read.
    let train = |dir: &Path| {
        let run = dir.join("run");
        xtask(&["weather", "train", "--data", dir.to_str().unwrap(), "--out", run.to_str().unwrap(), "--epochs", "1"])
    };
    let out = train(two.path());
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("the truth run has 15 times"), "{msg}");
    // A damaged item is named instead.
    let item = two.path().join(&a[1].0);
    let mut bytes = std::fs::read(&item).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&item, bytes).unwrap();
    let msg = String::from_utf8_lossy(&train(two.path()).stderr).into_owned();
    assert!(msg.contains("SHA-256") && msg.contains("rerun shard 1/2"), "{msg}");
}
