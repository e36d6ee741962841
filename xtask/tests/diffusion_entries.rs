//! pbdl-diffusion's ACDM entries in quick mode (ignored: minutes; run with
//! `cargo test -p xtask --test diffusion_entries -- --ignored --nocapture`).

/// Runs this part's `cargo xtask` entries in quick mode (plumbing only; trains a few updates).
#[test]
#[ignore = "quick tour/bench/stress smoke: trains 4 models for 4 updates on the tiny data (minutes under load)"]
fn quick_entries_run() {
    let tasks = xtask::entries::diffusion::tasks();
    let dir = tempfile::tempdir().unwrap();
    let ctx = xtask::registry::TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 2 };
    let tour = tasks.tour.iter().find(|e| e.name == "acdm_cylinder").unwrap();
    let out = (tour.run)(&ctx).unwrap();
    println!("{}", out.markdown);
    assert!(out.files.iter().all(|f| f.exists()));
    let bench = tasks.bench.iter().find(|e| e.name == "acdm_samplers").unwrap();
    for r in (bench.run)(&ctx).unwrap() {
        println!("{r:?}");
    }
    let stress = tasks.stress.iter().find(|e| e.name == "acdm_long_rollout").unwrap();
    let checks = (stress.run)(&ctx).unwrap();
    for c in &checks {
        println!("{c:?}");
    }
    assert!(checks.last().unwrap().passed, "typed-error check");
}
