//! The incompressible (IISPH) dam break: density error, solver errors, bad input.

use pbdl_particles::{DamBreak, Error, Evolve, IisphParams, Kernel, KernelKind};

/// Kinetic and potential energy of the fluid (per metre of depth).
fn energies(sim: &pbdl_particles::Iisph, g: f64) -> (f64, f64) {
    let m = sim.mass();
    sim.x[..sim.n_fluid()]
        .iter()
        .zip(&sim.v)
        .fold((0.0, 0.0), |(ke, pe), (x, v)| (ke + 0.5 * m * (v[0] * v[0] + v[1] * v[1]), pe + m * g * x[1]))
}

/// Runs to `big_t` (dimensionless) and checks the density error on the way, and the energy
/// budget: an inviscid fluid can only convert the potential energy it releases into kinetic
/// energy, so from T = 0.5 on `KE <= PE0 - PE` must hold at every step (the pressure solve may
/// dissipate but must not create energy). Measured: at least 1.1% of the released energy lost
/// at every step to T = 2.5 and to T = 6 (max (KE - released PE) / released PE = -1.09e-2; at T = 0.1 the kinetic energy leads the released potential energy by 9% in the
/// symplectic Euler staggering of the first steps, hence the start at T = 0.5).
fn run_dam_break(big_t: f64) {
    let scene = DamBreak::default();
    let params = IisphParams::default();
    let mut sim = scene.build_iisph(params).unwrap();
    let t_end = scene.physical_time(big_t);
    let pe0 = energies(&sim, scene.g).1;
    let mut worst_energy = f64::NEG_INFINITY;
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
        if sim.time() >= scene.physical_time(0.5) {
            let (ke, pe) = energies(&sim, scene.g);
            worst_energy = worst_energy.max((ke - (pe0 - pe)) / (pe0 - pe));
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
    eprintln!("energy budget from T = 0.5: max (KE - released PE) / released PE = {worst_energy:+.2e}");
    assert!(worst_energy <= 0.0, "kinetic energy above the released potential energy: {worst_energy}");
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
        (IisphParams { h_over_dx: 1e9, ..Default::default() }, "h_over_dx"),
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
/// 3 m/s; with extrapolated wall pressures it stays near rest; the rest is asserted by
/// `iisph_hydrostatic_column_mean_speed_below_half_percent`.)
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

/// Mean speed of the fluid over `sqrt(gH)`.
fn mean_speed(scene: &DamBreak, sim: &pbdl_particles::Iisph) -> f64 {
    let vmean = sim.v.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).sum::<f64>() / sim.n_fluid() as f64;
    vmean / (scene.g * scene.height_ratio * scene.a).sqrt()
}

/// A converged IISPH column at rest stays at rest: mean speed at most 0.5% of sqrt(gH) at
/// t = 1 s. Before `h = 1.385 dx` (at 1.3) it was 1.5%, the same at tolerances 1e-3..1e-5 and
/// dt 0.005 or 0.001 s: the square lattice was unstable under pressure (module docs, "Lattice
/// stability"; `iisph_square_lattice_is_stable_at_the_default_smoothing_length`). Measured now
/// 4.93e-3: the margin is small. Neighbouring settings miss the bound (dt_max 0.004 s: 5.6e-3,
/// 0.003 s: 7.6e-3; tolerance 2e-3: 7.1e-2): what remains comes from the stopping rule and the
/// top particle rows (module docs), not from the lattice.
#[test]
fn iisph_hydrostatic_column_mean_speed_below_half_percent() {
    let (scene, mut sim) = column();
    sim.run_until(1.0).unwrap();
    let rel = mean_speed(&scene, &sim);
    eprintln!("hydrostatic column mean |v| at t = 1 s: {rel:.2e} sqrt(gH)");
    assert!(rel <= 5e-3, "mean speed {rel} sqrt(gH)");
}

/// The drift of the column at rest must not grow with resolution (at h = 1.3 dx it did: 1.27e-2,
/// 1.52e-2, 2.32e-2 sqrt(gH) at dx = 0.1, 0.05, 0.025 a, since the lattice mode grows at a rate
/// proportional to 1/dx). Measured the speed at t = 0.5 s and 1 s for dx = 0.1 and 0.05: the
/// finer column may not be faster than the coarse one, and neither may speed up by more than
/// a factor 2 between 0.5 s and 1 s (an exponential mode would, from round-off).
#[test]
fn iisph_column_drift_does_not_grow_with_resolution() {
    let mut at_1s = Vec::new();
    for dx in [0.1, 0.05] {
        let scene = DamBreak { tank_width: 1.0, dx, ..Default::default() };
        let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
        sim.run_until(0.5).unwrap();
        let half = mean_speed(&scene, &sim);
        sim.run_until(1.0).unwrap();
        let one = mean_speed(&scene, &sim);
        eprintln!("column dx = {dx} a: mean |v| {half:.2e} sqrt(gH) at 0.5 s, {one:.2e} at 1 s");
        assert!(one <= 2.0 * half.max(1e-3), "dx = {dx}: mean speed grew from {half} to {one}");
        at_1s.push(one);
    }
    assert!(at_1s[1] <= at_1s[0], "the finer column drifts faster: {at_1s:?}");
}

/// Largest squared growth rate `σ² dx² ρ0 / p` of the lattice modes that change no density
/// (the analysis in the iisph module docs, "Lattice stability"): a lattice of spacing 1 (`hex`:
/// the hexagonal one of the same area per particle) under uniform pressure `p`, Wendland C2.
fn lattice_growth(h_over_dx: f64, hex: bool) -> f64 {
    let k = Kernel::<f64>::new(KernelKind::WendlandC2, 2, h_over_dx).unwrap();
    let support = k.support();
    let a = if hex { (2.0 / 3f64.sqrt()).sqrt() } else { 1.0 };
    let n = (support / a).ceil() as i64 + 2;
    let mut pts = Vec::new();
    for j in -2 * n..=2 * n {
        for i in -2 * n..=2 * n {
            let p = if hex {
                [(i as f64 + 0.5 * j.rem_euclid(2) as f64) * a, j as f64 * a * 3f64.sqrt() / 2.0]
            } else {
                [i as f64, j as f64]
            };
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            if r > 0.0 && r < support {
                pts.push((p, r));
            }
        }
    }
    let mass = 1.0 / (k.w(0.0) + pts.iter().map(|&(_, r)| k.w(r)).sum::<f64>()); // ρ0 = 1
    let dr = 1e-6;
    let mut worst = 0.0f64;
    let steps = 60;
    for a1 in 0..=steps {
        for a2 in 0..=steps {
            let kv = [
                std::f64::consts::PI * (a1 as f64 / steps as f64 * 2.4 - 1.2),
                std::f64::consts::PI * a2 as f64 / steps as f64 * 1.2,
            ];
            if kv[0].abs() + kv[1].abs() < 1e-9 {
                continue;
            }
            // Dynamical matrix of the pair potential W and the density-change direction g(k).
            let (mut d, mut g) = ([[0.0; 2]; 2], [0.0; 2]);
            for &(p, r) in &pts {
                let ph = kv[0] * p[0] + kv[1] * p[1];
                let e = [p[0] / r, p[1] / r];
                let (dw, d2w) = (k.dw_dr(r), (k.dw_dr(r + dr) - k.dw_dr(r - dr)) / (2.0 * dr));
                for (x, row) in d.iter_mut().enumerate() {
                    for (y, v) in row.iter_mut().enumerate() {
                        let delta = if x == y { 1.0 } else { 0.0 };
                        *v += (1.0 - ph.cos()) * (d2w * e[x] * e[y] + dw / r * (delta - e[x] * e[y]));
                    }
                    g[x] += dw * e[x] * ph.sin();
                }
            }
            let gn = (g[0] * g[0] + g[1] * g[1]).sqrt();
            let stiff = if gn < 1e-9 {
                // No density change at first order: both polarisations count.
                let (tr, det) = (d[0][0] + d[1][1], d[0][0] * d[1][1] - d[0][1] * d[1][0]);
                0.5 * tr - (0.25 * tr * tr - det).max(0.0).sqrt()
            } else {
                let t = [-g[1] / gn, g[0] / gn];
                t[0] * (d[0][0] * t[0] + d[0][1] * t[1]) + t[1] * (d[1][0] * t[0] + d[1][1] * t[1])
            };
            worst = worst.max(-2.0 * mass * stiff);
        }
    }
    worst
}

/// The cause of the former drift: at h = 1.3 dx the square lattice of a column at rest has a
/// growing density-neutral mode under pressure (σ² = 0.061 p/(ρ0 dx²), Python check of the same
/// analysis: 0.0615); at the default h both the square and the hexagonal lattice have none.
#[test]
fn iisph_square_lattice_is_stable_at_the_default_smoothing_length() {
    let h = IisphParams::default().h_over_dx;
    let (old, sq, hex) = (lattice_growth(1.3, false), lattice_growth(h, false), lattice_growth(h, true));
    eprintln!(
        "lattice growth s = σ² dx² ρ0/p: square h = 1.3 dx {old:.4}; h = {h} dx: square {sq:.1e}, hexagonal {hex:.1e}"
    );
    assert!(old > 0.05, "the analysis should find the h = 1.3 dx square lattice unstable: {old}");
    assert!(sq < 1e-6 && hex < 1e-6, "unstable lattice at the default h: square {sq}, hex {hex}");
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
    println!(
        "ACCEPTANCE: iisph_t10 measured={} leaked, compression max {:.3}%, deepest crossing {:.3} dx, finite {} \
         bar=0 leaked at every 0.1, compression <= 1%, crossing < 0.5 dx",
        sim.leaked(),
        100.0 * comp,
        sim.max_penetration() / sim.dx(),
        sim.is_finite()
    );
    assert!(sim.is_finite());
    assert!(comp <= 0.01, "average compression {comp}");
    assert!(sim.max_penetration() < 0.5 * sim.dx(), "a particle crossed the first wall-particle layer");
}
