//! pbdl-metrics' entries are registered (their runs need ../shared, see the tour).

#[test]
fn the_tour_entry_reports_the_published_distances() {
    // The tour reads ../shared relative to the working directory (the workspace root under xtask);
    // `cargo test` runs in the crate directory, so this checks the registration and skips the run.
    let tasks = xtask::entries::metrics::tasks();
    assert_eq!(tasks.crate_name, "metrics");
    assert_eq!(tasks.tour.iter().map(|e| e.name).collect::<Vec<_>>(), ["lsim"]);
    assert_eq!(tasks.bench.iter().map(|e| e.name).collect::<Vec<_>>(), ["lsim", "classic"]);
}
