//! pbdl-optim's bench entries run end to end (all `#[ignore]`d: minutes each; run with
//! `cargo test -p xtask --test optim_entries -- --ignored --nocapture`).

use std::time::Instant;
use xtask::registry::TaskContext;

/// The bench entry `cartpole` in quick mode (20 epochs, 12 runs) writes its rows and plot.
#[test]
#[ignore = "runs the quick bench entry: 12 runs of 640 Adam steps, about 1-2 min"]
fn cartpole_quick_bench_entry_runs() {
    let tasks = xtask::entries::optim::tasks();
    let entry = tasks.bench.iter().find(|e| e.name == "cartpole").expect("bench entry cartpole");
    let out_dir = std::env::temp_dir().join("pbdl_cartpole_quick_bench");
    std::fs::create_dir_all(&out_dir).unwrap();
    let ctx = TaskContext { out_dir: out_dir.clone(), quick: true, threads: 1 };
    let t = Instant::now();
    let rows = (entry.run)(&ctx).unwrap();
    println!("{} s", t.elapsed().as_secs_f64());
    assert_eq!(rows.len(), 12);
    for r in &rows {
        println!(
            "{} {} {} {:.3} ms/update, test loss {:.4}",
            r.case,
            r.method,
            r.size,
            r.seconds * 1e3,
            r.error.unwrap()
        );
        assert!(r.error.is_some_and(|e| (0.0..=2.0).contains(&e)));
    }
    assert!(out_dir.join("cartpole_modes.png").exists());
}

/// The `dipole` bench entry in quick mode (20 s per optimiser): rows in the shared schema and
/// the PNG curve are written.
#[test]
#[ignore = "runs the dipole bench entry in quick mode: 3 x 20 s of training plus evaluations, ~1.5 min"]
fn dipole_bench_entry_quick() {
    let out_dir = std::env::temp_dir().join(format!("pbdl_dipole_bench_{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    let ctx = TaskContext { out_dir: out_dir.clone(), quick: true, threads: rayon::current_num_threads() };
    let entry =
        xtask::entries::optim::tasks().bench.into_iter().find(|e| e.name == "dipole").expect("dipole bench entry");
    let rows = (entry.run)(&ctx).unwrap();
    for r in &rows {
        eprintln!("{} {} {} {:.3} s/{} {:?} {}", r.case, r.method, r.size, r.seconds, r.unit, r.error, r.error_kind);
    }
    assert_eq!(rows.iter().map(|r| r.method.as_str()).collect::<Vec<_>>(), ["hig", "adam", "gauss_newton"]);
    assert!(rows.iter().all(|r| r.error.is_some_and(|e| e.is_finite() && e <= 1.0)));
    let png = out_dir.join("loss_vs_time_dipole.png");
    assert!(std::fs::metadata(&png).map(|m| m.len() > 1000).unwrap_or(false), "{}", png.display());
    eprintln!("plot: {}", png.display());
}

/// The full (non-quick) bench entry `guidance`, printing its rows: the numbers of the report.
#[test]
#[ignore = "the full bench entry; about 5 min on 2 idle cores (12 runs of 320 Adam steps)"]
fn guidance_bench_entry_full_prints_rows() {
    print_full_bench_entry("guidance");
}

/// The full (non-quick) bench entry `quantum_control`, printing its rows: the numbers of the report.
#[test]
#[ignore = "the full bench entry; about 10-15 min on 2 idle cores (9 runs of 320 Adam steps of 128-step rollouts)"]
fn quantum_control_bench_entry_full_prints_rows() {
    print_full_bench_entry("quantum_control");
}

/// Runs the full (non-quick) bench entry `name` of pbdl-optim and prints its rows.
fn print_full_bench_entry(name: &str) {
    let tasks = xtask::entries::optim::tasks();
    let entry = tasks.bench.iter().find(|e| e.name == name).expect("entry registered");
    let out_dir = std::env::temp_dir().join(format!("pbdl_optim_bench_{name}"));
    std::fs::create_dir_all(&out_dir).unwrap();
    let ctx = TaskContext { out_dir, quick: false, threads: rayon::current_num_threads() };
    for row in (entry.run)(&ctx).unwrap() {
        println!(
            "{} {} {}: loss {:.4} ({:.1} ms/step)",
            row.case,
            row.method,
            row.size,
            row.error.unwrap(),
            1e3 * row.seconds
        );
    }
}
