//! DFSPH in 3D (`Dfsph<T, 3>`, `DamBreak3d::build_dfsph`): physics sanity at coarse resolution
//! (fast, default; NOT the acceptance bar), an f32 smoke test, typed errors, and the README's
//! bar 3D3 (`#[ignore]`d, release; written at 04:14 UTC before any 3D DFSPH run): on the 3D dam
//! break of 3D1 at dx = a/20 (8000 fluid particles) with tolerance 0.1%, the mean compression of
//! the summation density (D1's measure) is at most 0.1% and no particle leaves the tank to
//! T = 10 (checked every 0.1 T); the front is reported against 3D1's band 0..+10% of Martin &
//! Moyce for T in [1, 2.5].
//!
//! `cargo test --release -p pbdl-particles --test dfsph3d_tests -- --ignored --nocapture`

use pbdl_particles::dfsph::{Dfsph, DfsphParams};
use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::wcsph3d::DamBreak3d;
use pbdl_particles::{Error, Evolve};

/// A coarse column (dx = a/8, 512 fluid particles) for the fast tests. NOT the acceptance
/// resolution: the bar 3D3 is checked at dx = a/20 by the ignored test below.
fn coarse() -> DamBreak3d {
    DamBreak3d { dx: 0.125, ..DamBreak3d::default() }
}

/// Sanity only (not the acceptance bar): at dx = a/8 to T = 1 the run stays finite, no particle
/// leaves, the summation density's mean compression stays loosely bounded (1%, ten times the
/// solver tolerance: at 4 particles across the depth most particles touch a wall), the front
/// moves right but not past Ritter's bound `Z = 1 + 2T`, and no momentum builds up across the
/// depth (the side walls are symmetric).
#[test]
fn coarse_dam_break_sanity_not_the_acceptance_bar() {
    let scene = coarse();
    let mut sim = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    assert_eq!(sim.n_fluid(), 8 * 16 * 4);
    let x0 = sim.front();
    // The lattice's summation density at rest is ρ0 inside the fluid (mass from the lattice).
    let rho = sim.summation_density().unwrap();
    let inner = rho.iter().fold(0.0f64, |a, r| a.max(*r));
    assert!((inner / scene.rho0 - 1.0).abs() < 1e-9, "largest initial density {inner}");
    let mut worst = 0.0f64;
    for k in 1..=10 {
        let big_t = 0.1 * k as f64;
        let t_end = scene.physical_time(big_t);
        while sim.time() < t_end * (1.0 - 1e-14) {
            let dt = sim.next_dt(t_end);
            sim.step(dt).unwrap();
            worst = worst.max(sim.last_solve().compression);
        }
        assert!(sim.is_finite(), "not finite at T = {big_t}");
        assert_eq!(sim.leaked(), 0, "leak at T = {big_t}");
    }
    let z = sim.front() / scene.a;
    assert!(sim.front() > x0 + 0.1 * scene.a && z < 1.0 + 2.0 * 1.0, "Z(T = 1) = {z} (start {x0})");
    assert!(worst < 1e-2, "mean compression {worst}");
    let pz: f64 = sim.v.iter().map(|v| v[2]).sum::<f64>() * sim.mass();
    let px: f64 = sim.v.iter().map(|v| v[0].abs()).sum::<f64>() * sim.mass();
    assert!(pz.abs() < 1e-6 * px, "momentum across the depth {pz} (|p_x| sum {px})");
    assert!(sim.operators().contains(&"wall_particles"));
}

/// f32 smoke test: the coarse column in f32 runs to T = 0.3, stays finite and inside, and its
/// front is within two particle spacings of f64's.
#[test]
fn f32_dam_break_runs() {
    let scene = coarse();
    let mut s32 = scene.build_dfsph_as::<f32>(DfsphParams::default_3d()).unwrap();
    s32.run_until(scene.physical_time(0.3)).unwrap();
    assert!(s32.is_finite() && s32.leaked() == 0);
    let mut s64 = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    s64.run_until(scene.physical_time(0.3)).unwrap();
    let dx = scene.dx * scene.a;
    assert!((s32.front() - s64.front()).abs() < 2.0 * dx, "{} vs {}", s32.front(), s64.front());
}

#[test]
fn bad_input_gives_typed_errors() {
    let scene = coarse();
    let bad = DfsphParams { omega: 1.5, ..DfsphParams::default() };
    assert!(matches!(scene.build_dfsph(bad), Err(Error::Invalid { .. })));
    let bad = DamBreak3d { depth: -1.0, ..coarse() };
    assert!(matches!(bad.build_dfsph(DfsphParams::default_3d()), Err(Error::Invalid { .. })));
    let bad = DamBreak3d { dx: 0.5, ..coarse() };
    assert!(matches!(bad.build_dfsph(DfsphParams::default_3d()), Err(Error::Invalid { .. })));
    // A particle outside the search box, and a step beyond the stable one.
    let domain = pbdl_particles::Domain::bounded([0.0; 3], [1.0; 3]);
    let x = vec![[0.5, 0.5, 1.5]];
    let r = Dfsph::new(
        DfsphParams::default(),
        1000.0,
        0.1,
        [0.0, -9.81, 0.0],
        x,
        vec![[0.0; 3]],
        1,
        domain,
        [[0.0; 3], [1.0; 3]],
    );
    assert!(matches!(r, Err(Error::OutsideDomain { .. })));
    let mut sim = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    let dt = sim.stable_dt();
    assert!(matches!(sim.step(2.0 * dt), Err(Error::UnstableTimeStep { .. })));
    assert_eq!(sim.steps(), 0);
}

/// Bar 3D3 (README "Round 2 bars", written before any 3D DFSPH run): DFSPH with its defaults
/// on the 3D dam break of 3D1 (dx = a/20, tolerance 0.1%). Asserted: the mean compression of
/// the summation density, D1's measure (the largest over the steps to T = 2 of
/// `mean_i max(ρ_i/ρ0 - 1, 0)` of the summation density a step leaves), is at most 0.1%, and 0
/// particles are outside the tank at any check (every 0.1 T and at the Martin & Moyce times)
/// to T = 10. Printed: the same measure over the whole run to T = 10, iterations per step, wall
/// fallback counts, and the front table against 3D1's band (reported, not asserted here).
/// `cargo test --release -p pbdl-particles --test dfsph3d_tests -- --ignored --nocapture bar_3d3`
#[test]
#[ignore = "bar 3D3, compression NOT met (1.184e-3 > 1e-3); leaks met (release, ~35 s)"]
fn bar_3d3_dam_break_dfsph_compression_leaks_and_front() {
    let scene = DamBreak3d::default();
    let mut sim = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    let t0 = std::time::Instant::now();
    println!(
        "3D DFSPH dam break, dx = a/20, depth {}a: {} fluid + {} wall particles",
        scene.depth,
        sim.n_fluid(),
        sim.x.len() - sim.n_fluid()
    );
    let mm: Vec<(f64, f64)> = martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)).collect();
    // Checkpoints: every 0.1 T and the Martin & Moyce times, in order.
    let mut checks: Vec<f64> = (1..=100).map(|k| 0.1 * k as f64).chain(mm.iter().map(|p| p.0)).collect();
    checks.sort_by(f64::total_cmp);
    checks.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    let (mut comp_t2, mut comp_all, mut worst_leaked, mut first_leak) = (0.0f64, 0.0f64, 0usize, None);
    let (mut steps_t2, mut it_t2, mut div_t2) = (0u64, 0u64, 0u64);
    let mut rows = Vec::new();
    let mut devs = Vec::new();
    // Where the largest compression occurs (T after the step that left it) and the largest per
    // 0.5 T window, for the report.
    let (mut worst_at, mut window) = (0.0f64, [0.0f64; 20]);
    for &big_t in &checks {
        let t_end = scene.physical_time(big_t);
        while sim.time() < t_end * (1.0 - 1e-14) {
            let dt = sim.next_dt(t_end);
            sim.step(dt).unwrap();
            // The summation density at the start of a step: what the previous step left.
            let c = sim.last_solve().compression;
            // `c` was left by the previous step; attribute it to the time before this one.
            let t_prev = scene.dimensionless_time(sim.time() - dt);
            if c > comp_all {
                worst_at = t_prev;
            }
            let w = ((t_prev / 0.5) as usize).min(19);
            window[w] = window[w].max(c);
            comp_all = comp_all.max(c);
            if sim.time() <= scene.physical_time(2.0) * (1.0 + 1e-12) {
                comp_t2 = comp_t2.max(c);
            }
        }
        assert!(sim.is_finite(), "not finite at T = {big_t}");
        let left = sim.average_compression().unwrap();
        comp_all = comp_all.max(left);
        if (big_t - 2.0).abs() < 1e-9 {
            comp_t2 = comp_t2.max(left);
            steps_t2 = sim.steps();
            it_t2 = sim.total_iterations();
            div_t2 = sim.total_divergence_iterations();
        }
        if sim.leaked() > 0 {
            first_leak.get_or_insert(big_t);
        }
        worst_leaked = worst_leaked.max(sim.leaked());
        if let Some(&(_, zm)) = mm.iter().find(|p| (p.0 - big_t).abs() < 1e-12) {
            let z = sim.front() / scene.a;
            let dev = z / zm - 1.0;
            rows.push(format!("| {big_t:.3} | {z:.3} | {zm:.3} | {:+.1}% |", 100.0 * dev));
            devs.push(format!("{:+.1}%", 100.0 * dev));
        }
    }
    let steps = sim.steps();
    println!(
        "largest mean compression {comp_all:.3e} left at T = {worst_at:.3}; per 0.5 T window: {}",
        window.iter().map(|c| format!("{c:.2e}")).collect::<Vec<_>>().join(" ")
    );
    println!("| T | Z measured | Z Martin & Moyce | deviation (3D1 band 0..+10%, reported) |");
    println!("|---|---|---|---|");
    for r in &rows {
        println!("{r}");
    }
    println!(
        "to T = 2: {steps_t2} steps, {:.2} constant-density + {:.2} divergence-free iterations per step",
        it_t2 as f64 / steps_t2 as f64,
        div_t2 as f64 / steps_t2 as f64
    );
    println!(
        "to T = 10: {steps} steps in {:.1} s ({:.1} ms/step), {:.2} + {:.2} iterations per step, {} divergence solves unconverged, {} wall-fallback corrections (deepest {:.3} dx)",
        t0.elapsed().as_secs_f64(),
        1e3 * t0.elapsed().as_secs_f64() / steps as f64,
        sim.total_iterations() as f64 / steps as f64,
        sim.total_divergence_iterations() as f64 / steps as f64,
        sim.divergence_unconverged(),
        sim.wall_corrections(),
        sim.max_penetration() / (scene.dx * scene.a)
    );
    println!(
        "ACCEPTANCE: dfsph3d_dam_break measured=mean compression {comp_t2:.3e} to T = 2 ({comp_all:.3e} to T = 10), {worst_leaked} leaked to T = 10 (first at T = {first_leak:?}); front Z/Z_MM - 1 = {} (reported) bar=compression <= 1e-3, 0 leaked"
        ,
        devs.join(", ")
    );
    assert_eq!(worst_leaked, 0, "leaked particles, first at T = {first_leak:?}");
    // `leaked() == 0` cannot fail while the container fallback puts crossing centres back; the
    // depth they reached can (the round-1 IISPH bar, half a spacing; measured 0.36 dx).
    let depth = sim.max_penetration() / (scene.dx * scene.a);
    assert!(depth < 0.5, "deepest wall crossing {depth:.3} dx >= 0.5 dx");
    assert!(comp_t2 <= 1e-3, "mean compression {comp_t2:.4e} > 1e-3");
}

/// Bar 3D1's band applied to 3D DFSPH's front at dx = a/20, T in [1, 2.5]: reported by the bar
/// test above; asserted only here (the issue asks 3D DFSPH to be reported against the band).
/// `cargo test --release -p pbdl-particles --test dfsph3d_tests -- --ignored --nocapture front_band`
#[test]
#[ignore = "3D1's band for 3D DFSPH, misses: +11.1..+17.7% (release)"]
fn dfsph3d_front_band_0_to_10_percent() {
    let scene = DamBreak3d::default();
    let mut sim = scene.build_dfsph(DfsphParams::default_3d()).unwrap();
    let mut outside = Vec::new();
    for (tm, zm) in martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)) {
        sim.run_until(scene.physical_time(tm)).unwrap();
        let dev = sim.front() / scene.a / zm - 1.0;
        println!("T = {tm}: {:+.1}%", 100.0 * dev);
        if !(0.0..=0.10).contains(&dev) {
            outside.push(format!("T = {tm}: {:+.1}%", 100.0 * dev));
        }
    }
    assert!(outside.is_empty(), "outside 0..+10%: {}", outside.join("; "));
}

/// The Jacobi stability estimate behind `DfsphParams::default_3d` (its docs quote 2.886 in 2D
/// and 4.961 in 3D for Wendland C2 at h = 1.385 dx), and the typed error it gives: the 2D
/// default ω = 0.5 (ω λ_max = 2.48) is refused in 3D instead of diverging silently, naming the
/// largest ω that converges.
#[test]
fn jacobi_limit_refuses_a_diverging_relaxation() {
    use pbdl_particles::dfsph::jacobi_lambda_max;
    use pbdl_particles::KernelKind;
    let l2 = jacobi_lambda_max(KernelKind::WendlandC2, 1.385, 2).unwrap();
    let l3 = jacobi_lambda_max(KernelKind::WendlandC2, 1.385, 3).unwrap();
    assert!((l2 - 2.886).abs() < 0.01 && (l3 - 4.961).abs() < 0.01, "{l2} {l3}");
    let d = DfsphParams::default();
    assert_eq!(d.h_over_dx, 1.385, "the quoted numbers assume the default smoothing length");
    let err = coarse().build_dfsph(d).unwrap_err();
    match &err {
        Error::Invalid { field, reason } => {
            assert_eq!(*field, "omega");
            assert!(reason.contains("use omega < 0.403") && reason.contains("default_3d"), "{reason}");
        }
        other => panic!("{other}"),
    }
    assert!(coarse().build_dfsph(DfsphParams::default_3d()).is_ok());
    assert!(jacobi_lambda_max(KernelKind::WendlandC2, 1.385, 4).is_err());
}
