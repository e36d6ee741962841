//! The `abc_3d` entry of `cargo xtask bench grid` (quick mode: 16^3 and 32^3, f32): it is
//! registered, returns one row per size in the shared `BenchRow` schema, and its errors fall at
//! second order, the scheme's order in space (RK4's O(dt^4) is far below at CFL 0.5): the observed
//! order between 16^3 and 32^3 lies within 2 +- 0.1 (the first correction to the leading h^2 term
//! is relative O((k h)^2 / 12) ~ 1e-2 at 16^3), as in `tests/ns3d.rs` for f64. f32 round-off
//! adds about steps * eps ~ 21 * 1.2e-7 ~ 2.5e-6 at 32^3, a tenth of the discretisation error
//! there (measured 3.2e-5), which moves the order by at most log2(1.1) ~ 0.1 in the worst case.

use xtask::registry::TaskContext;

#[test]
fn abc_3d_bench_entry_runs_and_converges_at_second_order() {
    let tasks = xtask::entries::grid::tasks();
    let entry = tasks.bench.iter().find(|e| e.name == "abc_3d").expect("abc_3d is registered");
    let ctx = TaskContext { out_dir: std::env::temp_dir(), quick: true, threads: rayon::current_num_threads() };
    let t = std::time::Instant::now();
    let rows = (entry.run)(&ctx).unwrap();
    for r in &rows {
        eprintln!(
            "{} {} {}: {:.3e} s/{}, {} {:.3e}",
            r.case,
            r.method,
            r.size,
            r.seconds,
            r.unit,
            r.error_kind,
            r.error.unwrap()
        );
    }
    eprintln!("quick abc_3d bench: {:.1} s", t.elapsed().as_secs_f64());
    let sizes: Vec<&str> = rows.iter().map(|r| r.size.as_str()).collect();
    assert_eq!(sizes, ["16x16x16", "32x32x32"]);
    assert!(rows.iter().all(|r| r.case == "abc_3d" && r.unit == "step" && !r.peer && r.seconds > 0.0));
    assert!(rows.iter().all(|r| r.error_kind == "rel_l2_vs_analytic" && r.threads == ctx.threads));
    let (e16, e32) = (rows[0].error.unwrap(), rows[1].error.unwrap());
    let order = (e16 / e32).log2();
    eprintln!("order 16^3 -> 32^3: {order:.3}");
    assert!((1.9..=2.1).contains(&order), "order {order:.3} ({e16:e}, {e32:e})");
}
