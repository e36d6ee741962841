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

/// The tour's run (`dam_break_iisph` in `tasks.rs`): T = 4 at dx = a/20, stopped at the Martin
/// & Moyce times and every 0.1 in T. No fluid centre may be outside the tank at any frame.
/// Before the impermeability condition 1 to 5 centres sat beyond the wall surface from T = 2.3
/// on (6 at T = 4 in the tour): density-deficient particles (p = 0, spray sliding up the right
/// wall, a broken-up bottom layer) feel no wall force, since their extrapolated wall pressure is
/// 0 and a lone particle's summation density reaches ρ0 only about 0.25 dx behind the surface.
/// The deepest crossing before a correction must stay below dx/2 (the first wall-particle
/// layer): the wall particles, not the fallback, do the work.
#[test]
fn iisph_dam_break_to_t4_leaks_no_particle() {
    let scene = DamBreak::default();
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    let mm = [1.212, 1.219, 1.602, 1.997, 2.283];
    let mut stops: Vec<f64> = (1..=40).map(|k| 0.1 * k as f64).chain(mm).collect();
    stops.sort_by(f64::total_cmp);
    let mut worst = 0;
    for big_t in stops {
        sim.run_until(scene.physical_time(big_t)).unwrap();
        worst = worst.max(sim.leaked());
        assert_eq!(sim.leaked(), 0, "fluid centres outside the tank at T = {big_t}");
    }
    eprintln!(
        "IISPH dam break to T = 4: {} steps, {} leaked (max over frames {worst}), {} wall corrections \
         (particle x axis, of {} particle steps), deepest crossing before correction {:.3} dx, front Z = {:.3}",
        sim.steps(),
        sim.leaked(),
        sim.wall_corrections(),
        sim.steps() * sim.n_fluid() as u64,
        sim.max_penetration() / sim.dx(),
        sim.front() / scene.a
    );
    assert!(sim.max_penetration() < 0.5 * sim.dx(), "a particle crossed the first wall-particle layer");
    assert!(sim.is_finite());
}

/// The standing column of `iisph_hydrostatic_column_pressure_within_ten_percent`.
fn column() -> (DamBreak, pbdl_particles::Iisph) {
    let scene = DamBreak { tank_width: 1.0, dx: 0.05, ..Default::default() };
    let sim = scene.build_iisph(IisphParams::default()).unwrap();
    (scene, sim)
}

/// Energy bound: no particle of a column at rest can be faster than free fall from the top,
/// `sqrt(2 g H)`. Stopped every 0.1 s to t = 2 s as a user recording frames would: before the
/// fix `run_until` took a sliver step (about 1e-13 s, rounding) near t = 1.9 s, whose pressure
/// solve removed the 0.1% density error within it and threw particles at 1e8 sqrt(gH).
#[test]
fn iisph_column_stays_bounded_with_frequent_stops() {
    let (scene, mut sim) = column();
    let height = scene.height_ratio * scene.a;
    let mut vmax = 0.0f64;
    for k in 1..=20 {
        sim.run_until(0.1 * k as f64).unwrap();
        vmax = sim.v.iter().fold(vmax, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt()));
    }
    let vmean = sim.v.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).sum::<f64>() / sim.n_fluid() as f64;
    eprintln!(
        "column to t = 2 s with 20 stops: {} steps, max |v| {:.2e} sqrt(2gH), mean |v| at 2 s {:.2e} sqrt(gH)",
        sim.steps(),
        vmax / (2.0 * scene.g * height).sqrt(),
        vmean / (scene.g * height).sqrt()
    );
    assert!(sim.is_finite());
    assert!(vmax <= (2.0 * scene.g * height).sqrt(), "max speed {vmax} m/s");
    assert_eq!(sim.leaked(), 0);
}

/// A step much shorter than the stable one changes velocities by no more than a full step
/// does: the density error already present is removed over the stable step, not within the
/// short one (before: 1e-12 s gave |Δv| of order 1e7 m/s).
#[test]
fn iisph_sliver_step_gives_no_velocity_spike() {
    let (scene, mut sim) = column();
    sim.run_until(0.2).unwrap();
    let v0 = sim.v.clone();
    sim.step(1e-12).unwrap();
    let dv =
        sim.v.iter().zip(&v0).fold(0.0f64, |a, (v, w)| a.max(((v[0] - w[0]).powi(2) + (v[1] - w[1]).powi(2)).sqrt()));
    let full = {
        let v1 = sim.v.clone();
        sim.step(sim.stable_dt()).unwrap();
        sim.v.iter().zip(&v1).fold(0.0f64, |a, (v, w)| a.max(((v[0] - w[0]).powi(2) + (v[1] - w[1]).powi(2)).sqrt()))
    };
    let sgh = (scene.g * scene.height_ratio * scene.a).sqrt();
    eprintln!("max |dv|: {dv:.2e} m/s in a 1e-12 s step, {full:.2e} m/s in a stable step; sqrt(gH) = {sgh:.2} m/s");
    assert!(dv <= 0.1 * sgh, "a 1e-12 s step changed a velocity by {dv} m/s");
}

/// Known failing (the drift is not fixed): a converged IISPH column at rest should stay at rest
/// up to the solver tolerance; 0.5% of sqrt(gH) is the bound asked for. Measured 1.5% at
/// t = 1 s, the same at tolerances 1e-3..1e-5 and dt 0.005 or 0.001 s (a mode of the discrete
/// equations, not solver noise): vertical particle lines slide by about 0.3 dx, as a square
/// lattice under load rearranges towards a staggered packing, which barely changes density.
#[test]
#[ignore = "known failing: mean speed 1.5% of sqrt(gH) at t = 1 s (bound 0.5%); about 1 s"]
fn iisph_hydrostatic_column_mean_speed_below_half_percent() {
    let (scene, mut sim) = column();
    sim.run_until(1.0).unwrap();
    let vmean = sim.v.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).sum::<f64>() / sim.n_fluid() as f64;
    let rel = vmean / (scene.g * scene.height_ratio * scene.a).sqrt();
    eprintln!("hydrostatic column mean |v| at t = 1 s: {rel:.2e} sqrt(gH)");
    assert!(rel <= 5e-3, "mean speed {rel} sqrt(gH)");
}

/// The stress run (`cargo xtask stress particles`): T = 10, stopped every 0.1. No fluid centre
/// outside the tank, none past dx/2 before a correction, average compression <= 1%.
#[test]
#[ignore = "the stress horizon; about 2 s (8 s on a busy machine)"]
fn iisph_dam_break_to_t10_leaks_no_particle() {
    let scene = DamBreak::default();
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    let mut comp = 0.0f64;
    for k in 1..=100 {
        let big_t = 0.1 * k as f64;
        sim.run_until(scene.physical_time(big_t)).unwrap();
        comp = comp.max(sim.average_compression().unwrap());
        assert_eq!(sim.leaked(), 0, "fluid centres outside the tank at T = {big_t}");
    }
    eprintln!(
        "IISPH dam break to T = 10: {} steps, {} Jacobi iterations, average compression max {comp:.2e}, \
         {} wall corrections, deepest crossing before correction {:.3} dx",
        sim.steps(),
        sim.total_iterations(),
        sim.wall_corrections(),
        sim.max_penetration() / sim.dx()
    );
    assert!(sim.is_finite());
    assert!(comp <= 0.01, "average compression {comp}");
    assert!(sim.max_penetration() < 0.5 * sim.dx(), "a particle crossed the first wall-particle layer");
}
