//! The incompressible (IISPH) dam break: density error, solver errors, bad input.

use pbdl_particles::{DamBreak, Error, IisphParams};

/// Runs to `big_t` (dimensionless) and checks the density error on the way.
fn run_dam_break(big_t: f64) {
    let scene = DamBreak::default();
    let params = IisphParams::default();
    let mut sim = scene.build_iisph(params).unwrap();
    let t_end = scene.physical_time(big_t);
    let (mut worst_solve, mut worst_comp, mut iters_max) = (0.0f64, 0.0f64, 0);
    let mut checks = 0;
    // Martin & Moyce (1952) surge front, T in [1, 2.5] (tests/data/dambreak_exp_data.csv).
    let mut mm = vec![(1.212, 1.443), (1.602, 1.884), (1.997, 2.292), (2.283, 2.689)];
    mm.retain(|p| p.0 <= big_t);
    let mut next = 0;
    while sim.time() < t_end * (1.0 - 1e-14) {
        let stop = mm.get(next).map(|p| scene.physical_time(p.0)).unwrap_or(t_end);
        let dt = sim.stable_dt().min(stop - sim.time());
        sim.step(dt).unwrap();
        if next < mm.len() && sim.time() >= stop * (1.0 - 1e-14) {
            let z = sim.front() / scene.a;
            eprintln!(
                "T = {:.3}: front Z = {z:.3} vs {:.3} measured ({:+.1}%)",
                mm[next].0,
                mm[next].1,
                100.0 * (z / mm[next].1 - 1.0)
            );
            next += 1;
        }
        let s = sim.last_solve();
        worst_solve = worst_solve.max(s.density_error);
        iters_max = iters_max.max(s.iterations);
        if sim.steps() % 10 == 0 {
            worst_comp = worst_comp.max(sim.average_compression().unwrap());
            checks += 1;
        }
    }
    let comp_end = sim.average_compression().unwrap();
    eprintln!(
        "IISPH dam break to T = {big_t}: {} fluid particles, {} steps, {} Jacobi iterations \
         (max {iters_max}/step), solver density error max {worst_solve:.2e} (tol {:.0e}), \
         average compression of summation density max {worst_comp:.2e} over {checks} checks, {comp_end:.2e} at the end; \
         front Z = {:.3}",
        sim.n_fluid(),
        sim.steps(),
        sim.total_iterations(),
        params.tolerance,
        sim.front() / scene.a,
    );
    assert!(worst_solve <= params.tolerance);
    assert!(worst_comp <= 0.01 && comp_end <= 0.01, "average density error {worst_comp}");
    // Particles whose centre crossed the nominal wall surface, and the deepest penetration
    // (the first wall-particle layer sits dx/2 behind the surface).
    let [lo, hi] = sim.container();
    let depth = sim.x[..sim.n_fluid()]
        .iter()
        .map(|p| (lo[0] - p[0]).max(p[0] - hi[0]).max(lo[1] - p[1]).max(p[1] - hi[1]))
        .fold(f64::NEG_INFINITY, f64::max);
    eprintln!("{} particle centres beyond the wall surface, deepest {:.3} dx", sim.leaked(), depth / sim.dx());
    assert!(depth < 0.5 * sim.dx(), "a particle crossed the first wall-particle layer");
    assert!(sim.is_finite());
}

#[test]
fn iisph_dam_break_density_error_below_one_percent() {
    run_dam_break(2.5);
}

/// The whole surge to the far wall and back (`cargo test -- --ignored`).
#[test]
#[ignore]
fn iisph_dam_break_long_density_error_below_one_percent() {
    run_dam_break(6.0);
}

#[test]
fn iisph_non_convergence_is_a_typed_error_with_the_residual() {
    let scene = DamBreak { dx: 0.1, ..Default::default() };
    let params = IisphParams { max_iterations: 2, tolerance: 1e-9, ..Default::default() };
    let mut sim = scene.build_iisph(params).unwrap();
    let x0 = sim.x.clone();
    let err = sim.step(sim.stable_dt()).unwrap_err();
    match &err {
        Error::SolverNotConverged { iterations, residual, tolerance, .. } => {
            assert_eq!(*iterations, 2);
            assert!(*residual > *tolerance);
        }
        e => panic!("unexpected {e}"),
    }
    assert!(err.to_string().contains("residual"), "{err}");
    assert_eq!(sim.x, x0);
    assert_eq!(sim.steps(), 0);
}

#[test]
fn iisph_refuses_large_steps_and_bad_parameters() {
    let scene = DamBreak { dx: 0.1, ..Default::default() };
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    let err = sim.step(10.0 * sim.stable_dt()).unwrap_err();
    assert!(matches!(err, Error::UnstableTimeStep { .. }), "{err}");
    for (p, field) in [
        (IisphParams { h_over_dx: 0.0, ..Default::default() }, "h_over_dx"),
        (IisphParams { tolerance: -1.0, ..Default::default() }, "tolerance"),
        (IisphParams { nu: -1.0, ..Default::default() }, "nu"),
    ] {
        match scene.build_iisph(p) {
            Err(Error::Invalid { field: f, .. }) => assert_eq!(f, field),
            r => panic!("expected invalid {field}, got {:?}", r.map(|_| ())),
        }
    }
    assert_eq!(
        sim.operators(),
        vec!["summation_density", "pressure_solve_iisph", "pressure_acceleration", "gravity", "wall_particles"]
    );
}

/// A water column filling a tank at rest: the solved pressure is the hydrostatic
/// `ρ0 g (H - y)` within 10% (L1, lower three quarters) and the column does not collapse.
/// (This test found the wall treatment: with pressure mirroring the column churned at up to
/// 3 m/s; with extrapolated wall pressures it stays near rest.) Known gap, printed, not
/// asserted: a slowly growing left-right symmetric particle mode, mean speed about 1.5% of
/// `sqrt(gH)` at t = 1 s without viscosity.
#[test]
fn iisph_hydrostatic_column_pressure_within_ten_percent() {
    let scene = DamBreak { tank_width: 1.0, dx: 0.05, ..Default::default() };
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    sim.run_until(1.0).unwrap();
    let height = scene.height_ratio * scene.a;
    let vmax = sim.v.iter().fold(0.0f64, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt()));
    let vmean = sim.v.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).sum::<f64>() / sim.n_fluid() as f64;
    let (mut num, mut den, mut count) = (0.0, 0.0, 0);
    for i in 0..sim.n_fluid() {
        let y = sim.x[i][1];
        if y < 0.75 * height {
            let exact = sim.rho0() * scene.g * (height - y);
            num += (sim.p[i] - exact).abs();
            den += exact;
            count += 1;
        }
    }
    let rel = num / den;
    let comp = sim.average_compression().unwrap();
    eprintln!(
        "hydrostatic column: {} steps to t = 1 s, max |v| = {vmax:.2e} m/s ({:.2e} sqrt(gH)), mean |v| {:.2e} sqrt(gH), \
         pressure L1 error vs rho0 g (H - y) over {count} particles below 0.75 H: {:.2}%, average compression {comp:.2e}",
        sim.steps(),
        vmax / (scene.g * height).sqrt(),
        vmean / (scene.g * height).sqrt(),
        100.0 * rel
    );
    assert!(rel < 0.1, "pressure off hydrostatic by {rel}");
    assert!(comp <= 0.01, "average compression {comp}");
    let top = sim.x[..sim.n_fluid()].iter().fold(0.0f64, |a, p| a.max(p[1]));
    assert!((top - (height - 0.5 * sim.dx())).abs() < 0.5 * sim.dx(), "free surface at {top}");
    assert_eq!(sim.leaked(), 0);
}

/// A tighter solver tolerance gives a smaller density error (the error is the solver's, not a
/// floor of the discretisation).
#[test]
fn iisph_density_error_follows_the_tolerance() {
    let scene = DamBreak::default();
    let mut errs = Vec::new();
    for tol in [1e-3, 1e-4] {
        let mut sim =
            scene.build_iisph(IisphParams { tolerance: tol, max_iterations: 1000, ..Default::default() }).unwrap();
        let mut worst = 0.0f64;
        for k in 1..=5 {
            sim.run_until(scene.physical_time(0.2 * k as f64)).unwrap();
            worst = worst.max(sim.average_compression().unwrap());
        }
        eprintln!(
            "tolerance {tol:.0e}: average compression max {worst:.2e}, {} Jacobi iterations in {} steps",
            sim.total_iterations(),
            sim.steps()
        );
        errs.push(worst);
    }
    assert!(errs[1] < 0.5 * errs[0], "{errs:?}");
}
