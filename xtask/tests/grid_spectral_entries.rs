//! The pseudo-spectral and 3D smoke entries of `cargo xtask`: the tour's decaying turbulence (quick: 64^2)
//! writes its renders and closes the energy budget, the bench rows carry finite errors at the
//! level the tests of pbdl-grid show, and the stress checks pass.

use xtask::entries::spectral::{bench_spectral, stress_spectral_high_re, tour_decaying_turbulence};
use xtask::registry::TaskContext;

#[test]
fn spectral_tour_bench_and_stress_entries_run() {
    let dir = std::env::temp_dir().join(format!("pbdl_spectral_entries_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let ctx = TaskContext { out_dir: dir.clone(), quick: true, threads: 2 };
    let tour = tour_decaying_turbulence(&ctx).unwrap();
    let gap = tour.rows[0].error.unwrap();
    println!("{}", tour.markdown);
    // The budget E(0) - 2 nu int Z dt closes to the time-stepping (trapezoid) error.
    assert!(gap < 1e-2, "energy budget gap {gap:.2e}");
    assert!(tour.files.iter().any(|f| f.ends_with("energy_budget.png")));
    let rows = bench_spectral(&ctx).unwrap();
    for r in &rows {
        println!("{} {} {} {:.3e}", r.case, r.size, r.seconds, r.error.unwrap());
        assert!(r.error.unwrap().is_finite() && r.seconds > 0.0);
        if r.case != "decaying_turbulence" {
            // Taylor-Green and ABC: f32 round-off on top of the CN time error.
            assert!(r.error.unwrap() < 1e-5, "{} {}: {:.2e}", r.case, r.size, r.error.unwrap());
        }
    }
    let checks = stress_spectral_high_re(&ctx).unwrap();
    assert!(checks.iter().all(|c| c.passed), "{checks:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn smoke3d_bench_and_stress_entries_run() {
    let ctx = TaskContext { out_dir: std::env::temp_dir(), quick: true, threads: 2 };
    let rows = xtask::entries::smoke3d::bench_smoke3d(&ctx).unwrap();
    assert_eq!(rows.len(), 2);
    for r in &rows {
        println!("{} {} {:.3e} s, divergence {:.2e}", r.case, r.size, r.seconds, r.error.unwrap());
        assert!(r.error.unwrap() < 1e-5);
    }
    let checks = xtask::entries::smoke3d::stress_smoke3d(&ctx).unwrap();
    for c in &checks {
        println!("{}: {} ({})", c.invariant, c.passed, c.detail);
    }
    assert!(checks.iter().all(|c| c.passed));
}
