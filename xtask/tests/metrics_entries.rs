//! pbdl-metrics' entries: registered, and the tour entry reproduces the published LSiM plume
//! distances (it needs `../shared`: a visible skip locally, a failure in CI without it).

use xtask::registry::TaskContext;

#[test]
fn the_tour_entry_reports_the_published_distances() {
    let tasks = xtask::entries::metrics::tasks();
    assert_eq!(tasks.crate_name, "metrics");
    assert_eq!(tasks.tour.iter().map(|e| e.name).collect::<Vec<_>>(), ["lsim"]);
    assert_eq!(tasks.bench.iter().map(|e| e.name).collect::<Vec<_>>(), ["lsim", "classic"]);
    // The entries read ../shared relative to the working directory, which is the workspace root
    // under `cargo xtask`; this test binary has no other test that depends on the directory.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    std::env::set_current_dir(&root).unwrap();
    if !root.join("../shared/data/lsim-example").is_dir() || pbdl_metrics::weights::weights_dir().is_none() {
        pbdl_core::testing::skip_or_fail("../shared/data/lsim-example or the LSiM weights not found");
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let ctx = TaskContext { out_dir: out.path().to_path_buf(), quick: true, threads: 2 };
    let outcome = (tasks.tour[0].run)(&ctx).unwrap();
    assert_eq!(outcome.rows.len(), 2);
    for row in &outcome.rows {
        // The published values have four decimals: pbdl must round to them.
        assert!(row.error.unwrap() <= 5e-5, "{}: {:?} ({})", row.item, row.error, row.note);
    }
}
