//! The 1D SPH and IISPH solvers in `f32` against the same outside references as in `f64`: Sod
//! against the exact Riemann solution, momentum conservation in a periodic box, the IISPH dam
//! break's density error, containment and surge front. Each `f32` run is printed beside the
//! `f64` one.

use pbdl_core::Real;
use pbdl_particles::neighbors::Domain;
use pbdl_particles::sph1d::L1Errors;
use pbdl_particles::{DamBreak, Evolve, Iisph, IisphParams, ShockTube, Sph1d, Sph1dParams};
use std::time::Instant;

/// Sod at `t = 0.2` with `n` particles in precision `T`: L1 errors over `|x| < 0.4` against the
/// exact Riemann solution, steps and wall time.
fn sod<T: Real>(n: usize) -> (L1Errors, u64, f64) {
    let tube = ShockTube::sod();
    let exact = tube.exact().unwrap();
    let mut sim = tube.build_as::<T>(n, Sph1dParams::default()).unwrap();
    let start = Instant::now();
    sim.run_until(0.2).unwrap();
    let secs = start.elapsed().as_secs_f64();
    (sim.l1_errors(0.0, 0.4, |x| exact.at(x, 0.0, 0.2)), sim.steps(), secs)
}

/// Sod in `f32` meets the `f64` test's bounds (L1(ρ) <= 0.012 at 225, <= 0.008 at 450
/// particles), converges with N, and its errors are those of `f64` within 10%: `f32` round-off
/// (1e-7) is far below the discretisation error (1e-2).
#[test]
fn sod_f32_meets_the_f64_bounds_against_the_exact_solution() {
    let mut errs = Vec::new();
    for (n, bound) in [(225, 0.012), (450, 0.008)] {
        let (e32, s32, _) = sod::<f32>(n);
        let (e64, s64, _) = sod::<f64>(n);
        eprintln!(
            "Sod N = {n}: f32 L1 rho {:.5} u {:.5} p {:.5} ({s32} steps) | f64 L1 rho {:.5} u {:.5} p {:.5} ({s64} steps)",
            e32.rho, e32.u, e32.p, e64.rho, e64.u, e64.p
        );
        assert!(e32.rho <= bound, "f32 L1(rho) at {n} = {}", e32.rho);
        assert_eq!(e32.count, e64.count);
        for (name, a, b) in [("rho", e32.rho, e64.rho), ("u", e32.u, e64.u), ("p", e32.p, e64.p)] {
            assert!((a - b).abs() <= 0.1 * b, "N = {n}: f32 L1({name}) {a} vs f64 {b}");
        }
        errs.push(e32);
    }
    let (e225, e450) = (errs[0], errs[1]);
    assert!(e450.rho < e225.rho && e450.u < e225.u && e450.p < e225.p);
}

/// The periodic box of `sod_tests::periodic_box_conserves_momentum_and_mass` in precision `T`:
/// relative momentum drift, steps, mass change, and whether every particle stayed in the box.
fn periodic_box<T: Real>() -> (f64, u64, f64, bool) {
    let n = 400;
    let dx = 1.0 / n as f64;
    let xs: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) * dx).collect();
    let two_pi = 2.0 * std::f64::consts::PI;
    let c = |v: &[f64]| v.iter().map(|&a| T::c(a)).collect::<Vec<T>>();
    let v: Vec<f64> = xs.iter().map(|&x| 0.3 * (two_pi * x).sin() + 0.1 * (3.0 * two_pi * x).cos()).collect();
    let u: Vec<f64> = xs.iter().map(|&x| 2.5 + 0.5 * (two_pi * x).cos()).collect();
    let domain = Domain::periodic([T::zero()], [T::one()]);
    let mut sim = Sph1d::new(Sph1dParams::default(), c(&xs), c(&v), c(&u), vec![T::c(dx); n], None, n, domain).unwrap();
    let (p0, mass0, scale) = (sim.momentum(), sim.total_mass(), sim.momentum_scale());
    sim.run_until(0.5).unwrap();
    let inside = sim.x.iter().all(|&x| x >= T::zero() && x < T::one());
    ((sim.momentum() - p0).abs() / scale, sim.steps(), sim.total_mass() - mass0, inside)
}

/// Pair forces stay exactly antisymmetric in `f32`, but each particle's sum of pair terms and
/// each velocity update round at `f32`'s ε = 1.2e-7. A pair term changes a velocity by up to
/// about the velocity scale per step, so 400 particles over ~2000 steps, as a random walk,
/// give a relative drift of at most about ε sqrt(400 · 2000) / sqrt(400) ≈ 5e-6; the bound is
/// 1e-5, set from that estimate (f64 keeps 1e-13 in the same run). Measured: 1.9e-8, the pair
/// terms being much smaller than that worst case.
#[test]
fn periodic_box_f32_momentum_drift_is_f32_round_off() {
    let (d32, s32, dm32, in32) = periodic_box::<f32>();
    let (d64, s64, dm64, in64) = periodic_box::<f64>();
    eprintln!(
        "periodic box to t = 0.5: f32 relative momentum drift {d32:.2e} ({s32} steps), f64 {d64:.2e} ({s64} steps); \
         mass change f32 {dm32:e}, f64 {dm64:e}"
    );
    assert!(d32 <= 1e-5, "f32 relative momentum drift {d32:.2e}");
    assert!(d64 <= 1e-13, "f64 relative momentum drift {d64:.2e}");
    assert_eq!(dm32, 0.0);
    assert!(in32 && in64);
}

/// What a dam-break run records.
struct DamRun {
    /// Surge front `Z = x_front / a` at the Martin & Moyce times, then at the end.
    fronts: Vec<f64>,
    worst_solve: f64,
    worst_comp: f64,
    max_leaked: usize,
    steps: u64,
    iterations: u64,
    secs: f64,
    finite: bool,
    dx_over_a: f64,
}

/// Martin & Moyce (1952) measured surge front, `(T, Z)` (tests/data/dambreak_exp_data.csv).
const MARTIN_MOYCE: [(f64, f64); 4] = [(1.212, 1.443), (1.602, 1.884), (1.997, 2.292), (2.283, 2.689)];

/// The default IISPH dam break (dx = a/20) to `big_t` in precision `T`, checking the leak count
/// after every step and the summation density every 10 steps.
fn dam_break<T: Real>(big_t: f64, params: IisphParams) -> DamRun {
    let scene = DamBreak::default();
    let mut sim: Iisph<T> = scene.build_iisph_as::<T>(params).unwrap();
    let t_end = scene.physical_time(big_t);
    let mut stops: Vec<f64> = MARTIN_MOYCE.iter().map(|p| p.0).filter(|&t| t < big_t).collect();
    stops.push(big_t);
    let mut run = DamRun {
        fronts: Vec::new(),
        worst_solve: 0.0,
        worst_comp: 0.0,
        max_leaked: 0,
        steps: 0,
        iterations: 0,
        secs: 0.0,
        finite: true,
        dx_over_a: sim.dx() / scene.a,
    };
    let start = Instant::now();
    let mut next = 0;
    while sim.time() < t_end * (1.0 - 1e-14) {
        let stop = scene.physical_time(stops[next]);
        sim.step(sim.stable_dt().min(stop - sim.time())).unwrap();
        run.worst_solve = run.worst_solve.max(sim.last_solve().density_error);
        run.max_leaked = run.max_leaked.max(sim.leaked());
        if sim.steps() % 10 == 0 {
            run.worst_comp = run.worst_comp.max(sim.average_compression().unwrap());
        }
        if sim.time() >= stop * (1.0 - 1e-14) {
            run.fronts.push(sim.front() / scene.a);
            next += 1;
        }
    }
    run.secs = start.elapsed().as_secs_f64();
    run.worst_comp = run.worst_comp.max(sim.average_compression().unwrap());
    run.steps = sim.steps();
    run.iterations = sim.total_iterations();
    run.finite = sim.is_finite();
    run
}

/// The IISPH dam break in `f32` to T = 2.5 (the horizon of the `f64` test in iisph_tests.rs,
/// before the surge reaches the far wall): every pressure solve reaches the default tolerance
/// (0.1% average density error; `f32` round-off is about 1e-6 of ρ0), the average compression
/// of the summation density stays <= 1%, no fluid centre leaves the tank, and the surge front
/// stays within 2 dx of the `f64` run at the Martin & Moyce times and at T = 2.5.
#[test]
fn iisph_dam_break_f32_density_error_containment_and_front() {
    let params = IisphParams::default();
    let r32 = dam_break::<f32>(2.5, params);
    let r64 = dam_break::<f64>(2.5, params);
    for (name, r) in [("f32", &r32), ("f64", &r64)] {
        eprintln!(
            "IISPH dam break to T = 2.5, {name}: {} steps, {} Jacobi iterations, solver density error max {:.2e} \
             (tol {:.0e}), average compression max {:.2e}, leaked max {}, fronts Z {:?}",
            r.steps, r.iterations, r.worst_solve, params.tolerance, r.worst_comp, r.max_leaked, r.fronts
        );
    }
    for (k, (z32, z64)) in r32.fronts.iter().zip(&r64.fronts).enumerate() {
        let (t, measured) = MARTIN_MOYCE.get(k).copied().unwrap_or((2.5, f64::NAN));
        eprintln!(
            "T = {t:.3}: front f32 {z32:.3}, f64 {z64:.3}, diff {:+.3} = {:+.2} dx; Martin & Moyce {measured:.3}",
            z32 - z64,
            (z32 - z64) / r32.dx_over_a
        );
    }
    assert!(r32.finite);
    assert!(r32.worst_solve <= params.tolerance);
    assert!(r32.worst_comp <= 0.01, "f32 average compression {}", r32.worst_comp);
    assert_eq!(r32.max_leaked, 0, "f32 fluid centres outside the tank");
    assert_eq!(r32.fronts.len(), r64.fronts.len());
    for (z32, z64) in r32.fronts.iter().zip(&r64.fronts) {
        assert!((z32 - z64).abs() <= 2.0 * r32.dx_over_a, "front f32 {z32} vs f64 {z64}");
    }
}

/// A tighter tolerance gives a smaller density error in `f32` too (as
/// `iisph_density_error_follows_the_tolerance` in `f64`): 1e-4 is still far above `f32`
/// round-off, so the solve converges and the error halves at least.
#[test]
fn iisph_f32_density_error_follows_the_tolerance() {
    let mut errs = Vec::new();
    for tol in [1e-3, 1e-4] {
        let r = dam_break::<f32>(1.0, IisphParams { tolerance: tol, max_iterations: 1000, ..Default::default() });
        eprintln!(
            "f32, tolerance {tol:.0e}: average compression max {:.2e}, solver error max {:.2e}, {} Jacobi iterations in {} steps",
            r.worst_comp, r.worst_solve, r.iterations, r.steps
        );
        assert!(r.worst_solve <= tol);
        errs.push(r.worst_comp);
    }
    assert!(errs[1] < 0.5 * errs[0], "{errs:?}");
}

/// Where `f32` stops converging: the pressure solve at tolerances 1e-5, 1e-6 and 1e-7 over a
/// dam break to T = 0.5 in `f32` and `f64`, printed (converged, or the residual reached).
/// Measured at h = 1.3 dx: both converged at all three (3715 / 8346 / 38431 iterations, `f64`
/// 38641). At the default h = 1.385 dx: 1e-6 converges (9899 f32 / 9910 f64 iterations); 1e-7
/// stops at the 5000-iteration cap in `f32` (residual 1.37e-7 at step 14).
#[test]
#[ignore = "prints the f32 tolerance floor; about 20 s"]
fn iisph_f32_tolerance_floor() {
    let scene = DamBreak::default();
    for tol in [1e-5, 1e-6, 1e-7] {
        for f32_run in [true, false] {
            let params = IisphParams { tolerance: tol, max_iterations: 5000, ..Default::default() };
            let t_end = scene.physical_time(0.5);
            let outcome = if f32_run {
                let mut sim = scene.build_iisph_as::<f32>(params).unwrap();
                sim.run_until(t_end).map(|_| (sim.total_iterations(), sim.steps()))
            } else {
                let mut sim = scene.build_iisph(params).unwrap();
                sim.run_until(t_end).map(|_| (sim.total_iterations(), sim.steps()))
            };
            let name = if f32_run { "f32" } else { "f64" };
            match outcome {
                Ok((it, steps)) => {
                    eprintln!("{name}, tolerance {tol:.0e}: converged, {it} iterations in {steps} steps")
                }
                Err(e) => eprintln!("{name}, tolerance {tol:.0e}: {e}"),
            }
        }
    }
}

/// Time per step, `f32` against `f64` (dev profile: our code at opt-level 1, dependencies at 3;
/// ratios only, the release numbers are the bench's). Prints, asserts nothing about speed.
#[test]
#[ignore = "timing only, prints; about 10 s"]
fn f32_vs_f64_time_per_step() {
    let best = |f: &dyn Fn() -> (u64, f64)| {
        (0..3).map(|_| f()).fold((0, f64::INFINITY), |a, (s, t)| if t < a.1 { (s, t) } else { a })
    };
    let (s32, t32) = best(&|| {
        let (_, s, t) = sod::<f32>(450);
        (s, t)
    });
    let (s64, t64) = best(&|| {
        let (_, s, t) = sod::<f64>(450);
        (s, t)
    });
    eprintln!(
        "Sod 450 to t = 0.2: f32 {:.1} us/step ({s32} steps), f64 {:.1} us/step ({s64} steps), f64/f32 {:.2}",
        1e6 * t32 / s32 as f64,
        1e6 * t64 / s64 as f64,
        (t64 / s64 as f64) / (t32 / s32 as f64)
    );
    let params = IisphParams::default();
    let (d32, d64) = (dam_break::<f32>(2.5, params), dam_break::<f64>(2.5, params));
    let (d32b, d64b) = (dam_break::<f32>(2.5, params), dam_break::<f64>(2.5, params));
    let (t32, t64) = (d32.secs.min(d32b.secs), d64.secs.min(d64b.secs));
    eprintln!(
        "IISPH dam break dx = 0.05 to T = 2.5 (incl. a density check every 10 steps): f32 {:.2} ms/step \
         ({} steps, {} iterations), f64 {:.2} ms/step ({} steps, {} iterations), f64/f32 {:.2}",
        1e3 * t32 / d32.steps as f64,
        d32.steps,
        d32.iterations,
        1e3 * t64 / d64.steps as f64,
        d64.steps,
        d64.iterations,
        (t64 / d64.steps as f64) / (t32 / d32.steps as f64)
    );
}
