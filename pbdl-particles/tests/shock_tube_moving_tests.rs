//! Shock tubes whose end states move (Toro's test problems), against the exact Riemann solver:
//! L1 errors of density, velocity and pressure at 400 particles, the outer tenth of the mobile
//! region at its end state (no spurious wave from the ends), and convergence from 400 to 1600
//! particles.
//!
//! Bars were written before the first run and are not loosened.

use pbdl_particles::riemann::RiemannSolution;
use pbdl_particles::sph1d::L1Errors;
use pbdl_particles::{Evolve, GasState, ShockTube, Sph1d, Sph1dParams};

/// A test problem: the tube, the end time, and the bars at 400 particles.
struct Case {
    name: &'static str,
    tube: ShockTube,
    t: f64,
    /// L1 bars at 400 particles: density, velocity, pressure.
    bars: [f64; 3],
}

fn gas(rho: f64, u: f64, p: f64) -> GasState {
    GasState { rho, u, p }
}

/// Toro's test 1 (modified Sod, sonic rarefaction): `u_L = 0.75`, t = 0.2; the tube is long
/// enough on the right that the shock (at 0.43) stays clear of the outer tenth.
fn toro_1() -> Case {
    Case {
        name: "toro_1_modified_sod",
        tube: ShockTube {
            left: gas(1.0, 0.75, 1.0),
            right: gas(0.125, 0.0, 0.1),
            gamma: 1.4,
            x_lo: -0.5,
            x_hi: 0.7,
            x0: 0.0,
        },
        t: 0.2,
        bars: [0.01, 0.03, 0.01],
    }
}

/// Toro's test 2 (the "123" problem): two rarefactions, `u = -2 / +2`, near-vacuum star state
/// (p* = 0.0019), t = 0.15.
fn toro_123() -> Case {
    Case {
        name: "toro_2_123",
        tube: ShockTube {
            left: gas(1.0, -2.0, 0.4),
            right: gas(1.0, 2.0, 0.4),
            gamma: 1.4,
            x_lo: 0.0,
            x_hi: 1.0,
            x0: 0.5,
        },
        t: 0.15,
        bars: [0.02, 0.06, 0.01],
    }
}

/// Colliding streams in a monatomic gas (γ = 5/3): `u_L = 0.5`, `u_R = -0.5`; a left
/// rarefaction, a contact and a right shock, t = 0.15.
fn colliding_gamma_5_3() -> Case {
    Case {
        name: "colliding_gamma_5_3",
        tube: ShockTube {
            left: gas(1.0, 0.5, 1.0),
            right: gas(0.25, -0.5, 0.2),
            gamma: 5.0 / 3.0,
            x_lo: -0.5,
            x_hi: 0.5,
            x0: 0.0,
        },
        t: 0.15,
        bars: [0.015, 0.03, 0.015],
    }
}

fn run(case: &Case, n: usize) -> (Sph1d, RiemannSolution) {
    let exact = case.tube.exact().unwrap();
    let mut sim = case.tube.build(n, Sph1dParams::default()).unwrap();
    sim.run_until(case.t).unwrap();
    (sim, exact)
}

/// L1 over every mobile particle (the whole Lagrangian interior, ends included).
fn l1(case: &Case, sim: &Sph1d, exact: &RiemannSolution) -> L1Errors {
    let e = sim.l1_errors(0.0, f64::INFINITY, |x| exact.at(x, case.tube.x0, case.t));
    assert_eq!(e.count, sim.n_mobile());
    e
}

/// Largest deviation from the end state in the outer tenth of the mobile region at each end:
/// `max(|ρ - ρ_K| / ρ_K, |v - u_K| / c_K, |P - p_K| / p_K)`, left and right.
fn end_deviation(case: &Case, sim: &Sph1d, exact: &RiemannSolution) -> [f64; 2] {
    let nm = sim.n_mobile();
    let (lo, hi) = sim.x[..nm].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let tenth = 0.1 * (hi - lo);
    let g = case.tube.gamma;
    let mut dev = [0.0f64; 2];
    for (k, state, inside) in [
        (0, case.tube.left, Box::new(|x: f64| x <= lo + tenth) as Box<dyn Fn(f64) -> bool>),
        (1, case.tube.right, Box::new(|x: f64| x >= hi - tenth)),
    ] {
        // The exact solution is the end state throughout the window (the case is set up so).
        let edge = if k == 0 { lo + tenth } else { hi - tenth };
        assert_eq!(exact.at(edge, case.tube.x0, case.t), state, "{}: a wave reached the outer tenth", case.name);
        let c = state.sound_speed(g);
        let mut count = 0;
        for i in (0..nm).filter(|&i| inside(sim.x[i])) {
            let d = ((sim.rho[i] - state.rho).abs() / state.rho)
                .max((sim.v[i] - state.u).abs() / c)
                .max((sim.p[i] - state.p).abs() / state.p);
            dev[k] = dev[k].max(d);
            count += 1;
        }
        // At least a few particles to judge (Toro 1's low-density right tenth holds 9 at N = 400).
        assert!(count >= 5, "{}: only {count} particles in the outer tenth", case.name);
    }
    dev
}

fn check_400(case: Case) {
    let (sim, exact) = run(&case, 400);
    assert!(sim.operators().contains(&"moving_buffers"), "{:?}", sim.operators());
    let e = l1(&case, &sim, &exact);
    let dev = end_deviation(&case, &sim, &exact);
    eprintln!(
        "{}: N = 400, {} steps: L1 rho {:.5} u {:.5} p {:.5}; outer-tenth deviation left {:.2e} right {:.2e}",
        case.name,
        sim.steps(),
        e.rho,
        e.u,
        e.p,
        dev[0],
        dev[1]
    );
    let [br, bu, bp] = case.bars;
    assert!(e.rho <= br, "{}: L1(rho) {} > {br}", case.name, e.rho);
    assert!(e.u <= bu, "{}: L1(u) {} > {bu}", case.name, e.u);
    assert!(e.p <= bp, "{}: L1(p) {} > {bp}", case.name, e.p);
    // No spurious wave from the ends: the outer tenth stays within 2% of its end state.
    assert!(dev[0] <= 0.02 && dev[1] <= 0.02, "{}: end deviation {dev:?}", case.name);
}

#[test]
fn toro_1_modified_sod_at_400() {
    check_400(toro_1());
}

#[test]
fn toro_123_two_rarefactions_at_400() {
    check_400(toro_123());
}

#[test]
fn colliding_streams_gamma_5_3_at_400() {
    check_400(colliding_gamma_5_3());
}

/// Rates `log(e_400 / e_1600) / log 4` of density, velocity and pressure.
fn rates(case: &Case) -> [f64; 3] {
    let (s1, ex) = run(case, 400);
    let (s2, _) = run(case, 1600);
    let (a, b) = (l1(case, &s1, &ex), l1(case, &s2, &ex));
    let r = |x: f64, y: f64| (x / y).ln() / 4f64.ln();
    let out = [r(a.rho, b.rho), r(a.u, b.u), r(a.p, b.p)];
    eprintln!(
        "{}: L1 400 -> 1600: rho {:.5} -> {:.5}, u {:.5} -> {:.5}, p {:.5} -> {:.5}; rates {:.2} {:.2} {:.2}",
        case.name, a.rho, b.rho, a.u, b.u, a.p, b.p, out[0], out[1], out[2]
    );
    out
}

/// The bar: every rate between 0.5 and 1.
fn check_rates(case: Case) {
    let r = rates(&case);
    for (q, v) in ["rho", "u", "p"].iter().zip(r) {
        assert!((0.5..=1.0).contains(&v), "{}: rate of L1({q}) = {v:.3}", case.name);
    }
}

/// Met since the round-2 defaults (conductivity + Morris & Monaghan switch; release,
/// 2026-11-29): L1 rho 0.00461 -> 0.00211, u 0.00529 -> 0.00158, p 0.00444 -> 0.00178; rates
/// 0.56, 0.87, 0.66. With the round-1 constant viscosity it was not met: L1 rho 0.00371 ->
/// 0.00172, u 0.00704 -> 0.00153, p 0.00464 -> 0.00190; rates 0.56, 1.10, 0.64. Ignored only
/// because 1600 particles are slow in debug; run with `--ignored`.
#[test]
#[ignore = "slow (1600 particles); met with the round-2 defaults, see the doc comment"]
fn toro_1_converges_at_rate_half_to_one() {
    check_rates(toro_1());
}

/// Not met (round-2 defaults, release, 2026-11-29, N = 400 -> 1600): L1 rho 0.00412 ->
/// 0.00214, u 0.00258 -> 0.00083, p 0.00198 -> 0.00096; rates 0.47, 0.82, 0.52: the density
/// rate is below 0.5 (round-1 constant viscosity: rho 0.00380 -> 0.00199, u 0.00221 ->
/// 0.00059, p 0.00185 -> 0.00089; rates 0.46, 0.95, 0.53; where the error sits, e.g. the
/// near-vacuum centre, is not yet analysed). Run with `--ignored`.
#[test]
#[ignore = "rate of L1(rho) 0.47 is below 0.5; see the doc comment"]
fn toro_123_converges_at_rate_half_to_one() {
    check_rates(toro_123());
}

/// Not met (round-2 defaults, release, 2026-11-29, N = 400 -> 1600): L1 rho 0.00495 ->
/// 0.00256, u 0.00528 -> 0.00147, p 0.00492 -> 0.00228; rates 0.48, 0.92, 0.55: the density
/// rate is below 0.5 (round-1 constant viscosity: rho 0.00404 -> 0.00210, u 0.00520 ->
/// 0.00133, p 0.00553 -> 0.00248; rates 0.47, 0.98, 0.58; where the error sits, e.g. the
/// contact, is not yet analysed). Run with `--ignored`.
#[test]
#[ignore = "rate of L1(rho) 0.48 is below 0.5; see the doc comment"]
fn colliding_gamma_5_3_converges_at_rate_half_to_one() {
    check_rates(colliding_gamma_5_3());
}

/// Sod keeps its fixed ghosts; a tube in a moving frame (Sod plus a uniform velocity) has the
/// same density profile, shifted by `u t`, to within a small fraction of the L1 error (Galilean
/// invariance: only the ends' treatment could break it).
#[test]
fn sod_keeps_fixed_ghosts_and_moving_frame_matches_sod() {
    let sod = ShockTube::sod();
    let mut a = sod.build(200, Sph1dParams::default()).unwrap();
    assert!(a.operators().contains(&"fixed_ghosts") && !a.moving_buffers());
    let shift = 0.5;
    let moved = ShockTube { left: GasState { u: shift, ..sod.left }, right: GasState { u: shift, ..sod.right }, ..sod };
    let mut b = moved.build(200, Sph1dParams::default()).unwrap();
    assert!(b.moving_buffers());
    let t = 0.2;
    a.run_until(t).unwrap();
    b.run_until(t).unwrap();
    let exact = sod.exact().unwrap();
    let ea = a.l1_errors(0.0, f64::INFINITY, |x| exact.at(x, 0.0, t));
    let eb = b.l1_errors(0.0, f64::INFINITY, |x| {
        let s = exact.at(x - shift * t, 0.0, t);
        GasState { u: s.u + shift, ..s }
    });
    eprintln!("Sod at rest: {ea:?}\nSod moving at {shift}: {eb:?}");
    // Particle i is the same material particle in both runs.
    let worst = (0..a.n_mobile()).map(|i| (a.rho[i] - b.rho[i]).abs()).fold(0.0, f64::max);
    eprintln!("largest density difference of the same particle: {worst:.2e}");
    assert!((eb.rho - ea.rho).abs() <= 0.1 * ea.rho, "{} vs {}", eb.rho, ea.rho);
    assert!(worst <= 0.02, "{worst}");
}

/// The end check can fail: with the buffers held fixed (the old ghosts) while Toro 1's left
/// state moves at 0.75, a spurious wave runs in from the left end and the outer tenth leaves
/// its end state by more than the 2% bar.
#[test]
fn fixed_ghosts_with_a_moving_end_fail_the_end_check() {
    let case = toro_1();
    let exact = case.tube.exact().unwrap();
    let mut sim = case.tube.build(400, Sph1dParams::default()).unwrap();
    sim.set_moving_buffers(false).unwrap();
    sim.run_until(case.t).unwrap();
    let dev = end_deviation(&case, &sim, &exact);
    eprintln!("fixed ghosts, Toro 1: outer-tenth deviation left {:.2e} right {:.2e}", dev[0], dev[1]);
    assert!(dev[0] > 0.02, "{dev:?}");
}

/// A restart from particles: bad input is a typed error, and a tube rebuilt from its own
/// initial particles and buffers has the same densities.
#[test]
fn build_from_particles_checks_input_and_restores_a_tube() {
    let tube = toro_1().tube;
    let p = Sph1dParams::default();
    let sim = tube.build(100, p).unwrap();
    let nm = sim.n_mobile();
    let (x, v, u, m, h) = (&sim.x[..nm], &sim.v[..nm], &sim.u[..nm], &sim.m[..nm], &sim.h[..nm]);
    let buffers = &sim.x[nm..];
    let again = tube.build_from_particles_as::<f64>(p, x, v, u, m, Some(h), Some(buffers)).unwrap();
    assert!(again.moving_buffers());
    let worst = (0..nm).map(|i| (again.rho[i] - sim.rho[i]).abs() / sim.rho[i]).fold(0.0, f64::max);
    assert!(worst < 1e-10, "{worst:.2e}");
    // Laid out without the buffers: the same spacing beyond the end particles.
    let laid = tube.build_from_particles_as::<f64>(p, x, v, u, m, Some(h), None).unwrap();
    assert_eq!(laid.x.len(), sim.x.len());
    let err = tube.build_from_particles_as::<f64>(p, x, &v[1..], u, m, None, None).unwrap_err();
    assert!(matches!(err, pbdl_particles::Error::Length { arg: "v", .. }), "{err}");
    let inside = [x[nm / 2]];
    let err = tube.build_from_particles_as::<f64>(p, x, v, u, m, None, Some(&inside)).unwrap_err();
    assert!(matches!(err, pbdl_particles::Error::Invalid { field: "buffers", .. }), "{err}");
    let mut bad_m = m.to_vec();
    bad_m[3] = -1.0;
    let err = tube.build_from_particles_as::<f64>(p, x, v, u, &bad_m, None, None).unwrap_err();
    assert!(matches!(err, pbdl_particles::Error::Invalid { field: "m", .. }), "{err}");
}
