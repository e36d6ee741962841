//! Shock capturing of the 1D SPH solver (artificial conductivity, Morris & Monaghan viscosity
//! switch) on the standard shock-tube set, against a first-order HLL finite-volume scheme with
//! as many cells as particles (README, "Round 2 bars (issue 24)": S1 SPH <= HLL in L1 of ρ, u
//! and p at N = 400 and 1600; S2 rate from 400 to 1600 in [0.5, 1]); the HLL reference itself
//! is validated against the exact solution first.
//!
//! The tube and the judged interval of every case follow one rule, fixed before any error was
//! looked at:
//!
//! * the discontinuity sits at `x0 = 0`; from the exact solution take the leftmost and
//!   rightmost wave speeds `s_min`, `s_max` (a shock's speed, or a rarefaction's head) and the
//!   fan `[s_min t, s_max t]` of width `w` at the end time `t`;
//! * judged interval `J = [s_min t - w/10, s_max t + w/10]` (the whole fan and a tenth of its
//!   width either side, so a smeared head or shock is judged too);
//! * tube `x_lo = J_lo - max(u_L t, 0) - w/4`, `x_hi = J_hi - min(u_R t, 0) + w/4`: at time `t`
//!   the SPH mobile region, whose ends move with the end states (`x_lo + u_L t`,
//!   `x_hi + u_R t`), and the HLL grid `[x_lo, x_hi]` both reach at least `w/4` beyond `J`, and
//!   no wave has reached an SPH end (the distance from an end to the fan only shrinks in time,
//!   as every left wave is slower than `u_L` and every right wave faster than `u_R`).
//!
//! The L1 error is the plain mean over the particles (SPH) or cell centres (HLL) inside `J`
//! (`Sph1d::l1_errors`, `HllSolution::l1_errors`).
//!
//! Bars were written before the first run and are not loosened.

use pbdl_particles::hll::{self, HllSolution};
use pbdl_particles::riemann::RiemannSolution;
use pbdl_particles::sph1d::{L1Errors, ViscosityForm, ViscositySwitch};
use pbdl_particles::{Error, Evolve, GasState, ShockTube, Sph1d, Sph1dParams};

/// A shock-tube problem: states, γ and end time.
#[derive(Clone, Copy)]
struct Case {
    name: &'static str,
    left: GasState,
    right: GasState,
    gamma: f64,
    t: f64,
}

fn gas(rho: f64, u: f64, p: f64) -> GasState {
    GasState { rho, u, p }
}

/// Sod, Toro's tests 1-5 (*Riemann Solvers and Numerical Methods for Fluid Dynamics*, Table 4.1
/// and §4.3.3) and colliding streams at γ = 5/3 (as in `shock_tube_moving_tests.rs`).
fn cases() -> Vec<Case> {
    vec![
        Case { name: "sod", left: gas(1.0, 0.0, 1.0), right: gas(0.125, 0.0, 0.1), gamma: 1.4, t: 0.2 },
        Case { name: "toro_1", left: gas(1.0, 0.75, 1.0), right: gas(0.125, 0.0, 0.1), gamma: 1.4, t: 0.2 },
        Case { name: "toro_2_123", left: gas(1.0, -2.0, 0.4), right: gas(1.0, 2.0, 0.4), gamma: 1.4, t: 0.15 },
        Case {
            name: "toro_3_left_blast",
            left: gas(1.0, 0.0, 1000.0),
            right: gas(1.0, 0.0, 0.01),
            gamma: 1.4,
            t: 0.012,
        },
        Case {
            name: "toro_4_right_blast",
            left: gas(1.0, 0.0, 0.01),
            right: gas(1.0, 0.0, 100.0),
            gamma: 1.4,
            t: 0.035,
        },
        Case {
            name: "toro_5_colliding_shocks",
            left: gas(5.99924, 19.5975, 460.894),
            right: gas(5.99242, -6.19633, 46.0950),
            gamma: 1.4,
            t: 0.035,
        },
        Case {
            name: "colliding_gamma_5_3",
            left: gas(1.0, 0.5, 1.0),
            right: gas(0.25, -0.5, 0.2),
            gamma: 5.0 / 3.0,
            t: 0.15,
        },
    ]
}

fn case(name: &str) -> Case {
    cases().into_iter().find(|c| c.name == name).unwrap()
}

/// The tube, the exact solution and the judged interval (centre, half width) by the rule in
/// the module docs.
fn setup(c: &Case) -> (ShockTube, RiemannSolution, f64, f64) {
    let ex = pbdl_particles::riemann::solve(c.left, c.right, c.gamma).unwrap();
    let g = c.gamma;
    let shock = |s: &GasState| ((g + 1.0) / (2.0 * g) * ex.p_star / s.p + (g - 1.0) / (2.0 * g)).sqrt();
    let (cl, cr) = (c.left.sound_speed(g), c.right.sound_speed(g));
    let s_min = if ex.p_star > c.left.p { c.left.u - cl * shock(&c.left) } else { c.left.u - cl };
    let s_max = if ex.p_star > c.right.p { c.right.u + cr * shock(&c.right) } else { c.right.u + cr };
    let w = (s_max - s_min) * c.t;
    let (j_lo, j_hi) = (s_min * c.t - 0.1 * w, s_max * c.t + 0.1 * w);
    let x_lo = j_lo - (c.left.u * c.t).max(0.0) - 0.25 * w;
    let x_hi = j_hi - (c.right.u * c.t).min(0.0) + 0.25 * w;
    let tube = ShockTube { left: c.left, right: c.right, gamma: g, x_lo, x_hi, x0: 0.0 };
    (tube, ex, 0.5 * (j_lo + j_hi), 0.5 * (j_hi - j_lo))
}

/// L1 errors of SPH with `params` and of HLL, both with `n` particles / cells.
fn compare(c: &Case, n: usize, params: Sph1dParams) -> (L1Errors, L1Errors, Sph1d) {
    let (tube, ex, mid, half) = setup(c);
    let mut sim = tube.build(n, params).unwrap();
    sim.run_until(c.t).unwrap();
    // The judged interval lies inside the mobile region (the rule guarantees it).
    let nm = sim.n_mobile();
    let (lo, hi) = sim.x[..nm].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    assert!(lo < mid - half && hi > mid + half, "{}: mobile {lo}..{hi}, judged {}..{}", c.name, mid - half, mid + half);
    let reference = |x: f64| ex.at(x, 0.0, c.t);
    let es = sim.l1_errors(mid, half, reference);
    let fv = hll::solve(&tube, n, c.t, hll::DEFAULT_CFL).unwrap();
    let eh = fv.l1_errors(mid, half, reference);
    (es, eh, sim)
}

fn ratios(s: &L1Errors, h: &L1Errors) -> [f64; 3] {
    [s.rho / h.rho, s.u / h.u, s.p / h.p]
}

fn print_row(c: &Case, n: usize, label: &str, s: &L1Errors, h: &L1Errors) {
    let r = ratios(s, h);
    eprintln!(
        "{:<24} N={n:<5} {label:<9} SPH rho {:.3e} u {:.3e} p {:.3e} | HLL rho {:.3e} u {:.3e} p {:.3e} | ratio {:.2} {:.2} {:.2} | judged {} particles, {} cells",
        c.name, s.rho, s.u, s.p, h.rho, h.u, h.p, r[0], r[1], r[2], s.count, h.count
    );
}

/// Bar S1 for one case at N = 400 with the new defaults.
fn check_s1_at_400(name: &str) {
    let c = case(name);
    let (s, h, sim) = compare(&c, 400, Sph1dParams::default());
    print_row(&c, 400, "defaults", &s, &h);
    assert!(sim.operators().contains(&"artificial_conductivity"), "{:?}", sim.operators());
    assert!(sim.operators().contains(&"viscosity_switch_morris_monaghan"), "{:?}", sim.operators());
    for (q, r) in ["rho", "u", "p"].iter().zip(ratios(&s, &h)) {
        assert!(r <= 1.0, "{name}: N = 400: L1({q}) SPH / HLL = {r:.3} > 1");
    }
}

#[test]
fn s1_sod_at_400() {
    check_s1_at_400("sod");
}

/// Not met (release, measured 2026-11-29): SPH rho 6.155e-3 u 9.993e-3 p 5.900e-3, HLL rho
/// 9.287e-3 u 6.734e-3 p 4.259e-3: ratios 0.66, 1.48, 1.39 (velocity and pressure above HLL;
/// the round-1 constant viscosity gives 0.52, 1.44, 1.42). Run with `--ignored`.
#[test]
#[ignore = "bar S1 not met: L1(u) and L1(p) above HLL (ratios 1.48, 1.39); see the doc comment"]
fn s1_toro_1_at_400() {
    check_s1_at_400("toro_1");
}

/// Not met (release, measured 2026-11-29): SPH rho 9.903e-3 u 8.334e-3 p 5.058e-3, HLL rho
/// 8.498e-3 u 3.628e-2 p 5.336e-3: ratios 1.17, 0.23, 0.95 (density above HLL; constant
/// viscosity: 1.09, 0.21, 0.90). Run with `--ignored`.
#[test]
#[ignore = "bar S1 not met: L1(rho) above HLL (ratio 1.17); see the doc comment"]
fn s1_toro_2_123_at_400() {
    check_s1_at_400("toro_2_123");
}

#[test]
fn s1_toro_3_left_blast_at_400() {
    check_s1_at_400("toro_3_left_blast");
}

#[test]
fn s1_toro_4_right_blast_at_400() {
    check_s1_at_400("toro_4_right_blast");
}

#[test]
fn s1_toro_5_colliding_shocks_at_400() {
    check_s1_at_400("toro_5_colliding_shocks");
}

/// Not met (release, measured 2026-11-29): SPH rho 6.571e-3 u 6.950e-3 p 6.102e-3, HLL rho
/// 1.473e-2 u 6.663e-3 p 4.909e-3: ratios 0.45, 1.04, 1.24 (velocity and pressure above HLL;
/// constant viscosity: 0.33, 1.02, 1.44). Run with `--ignored`.
#[test]
#[ignore = "bar S1 not met: L1(u) and L1(p) above HLL (ratios 1.04, 1.24); see the doc comment"]
fn s1_colliding_gamma_5_3_at_400() {
    check_s1_at_400("colliding_gamma_5_3");
}

/// Bars S1 (N = 1600) and S2 (rates 400 -> 1600) on every case with the new defaults; prints
/// the full table, with the round-1 constant-viscosity parameters and each new term alone for
/// comparison (those rows are printed, not asserted). Release: `cargo test --release -p
/// pbdl-particles --test shock_capturing_tests -- --ignored --nocapture`.
///
/// Not met (release, measured 2026-11-29; SPH / HLL L1 ratios and SPH rates of the defaults):
/// S1 at N = 400: Toro 1 u 1.48, p 1.39; 123 problem rho 1.17; colliding γ = 5/3 u 1.04,
/// p 1.24. S1 at N = 1600: Toro 1 u 1.11, p 1.33; Toro 5 p 1.36; colliding γ = 5/3 p 1.38.
/// S2 (rate above 1, faster than the band): u on Toro 1 (1.02), Toro 3 (1.24), Toro 4 (1.24),
/// Toro 5 (1.13) and colliding γ = 5/3 (1.10). Every other case, quantity and N meets its bar.
#[test]
#[ignore = "slow (1600 particles on seven cases), and bars S1/S2 not met on some cases: see the doc comment"]
fn s1_s2_shock_tube_set_at_1600_and_rates() {
    let sigvel = Sph1dParams { viscosity_form: ViscosityForm::SignalVelocity, ..Sph1dParams::default() };
    let variants: [(&str, Sph1dParams); 5] = [
        ("defaults", Sph1dParams::default()),
        ("old", Sph1dParams::constant_viscosity()),
        ("cond_only", Sph1dParams { viscosity_switch: ViscositySwitch::Off, ..Sph1dParams::default() }),
        ("switch_only", Sph1dParams { conductivity: 0.0, ..Sph1dParams::default() }),
        ("sigvel", sigvel),
    ];
    let mut failures = Vec::new();
    for c in cases() {
        for (label, params) in variants {
            let (s4, h4, _) = compare(&c, 400, params);
            let (s16, h16, _) = compare(&c, 1600, params);
            print_row(&c, 400, label, &s4, &h4);
            print_row(&c, 1600, label, &s16, &h16);
            let rate = |a: f64, b: f64| (a / b).ln() / 4f64.ln();
            let rs = [rate(s4.rho, s16.rho), rate(s4.u, s16.u), rate(s4.p, s16.p)];
            let rh = [rate(h4.rho, h16.rho), rate(h4.u, h16.u), rate(h4.p, h16.p)];
            eprintln!(
                "{:<24} rates     {label:<9} SPH rho {:.2} u {:.2} p {:.2} | HLL rho {:.2} u {:.2} p {:.2}",
                c.name, rs[0], rs[1], rs[2], rh[0], rh[1], rh[2]
            );
            if label != "defaults" {
                continue;
            }
            for (k, q) in ["rho", "u", "p"].iter().enumerate() {
                for (n, s, h) in [(400, &s4, &h4), (1600, &s16, &h16)] {
                    let r = ratios(s, h)[k];
                    if r > 1.0 {
                        failures.push(format!("S1 {} N={n} {q}: SPH/HLL {r:.3}", c.name));
                    }
                }
                if !(0.5..=1.0).contains(&rs[k]) {
                    failures.push(format!("S2 {} {q}: rate {:.3}", c.name, rs[k]));
                }
            }
        }
    }
    eprintln!("bar failures ({}):\n{}", failures.len(), failures.join("\n"));
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The reference itself: first-order HLL converges to the exact Sod solution, with the L1 rate
/// of a first-order scheme with a contact (between 0.5 and 1) from 200 to 800 cells.
#[test]
fn hll_converges_to_exact_sod() {
    let tube = ShockTube::sod();
    let ex = tube.exact().unwrap();
    let errs: Vec<L1Errors> = [200, 800]
        .iter()
        .map(|&n| {
            let fv: HllSolution = hll::solve(&tube, n, 0.2, hll::DEFAULT_CFL).unwrap();
            assert_eq!(fv.time, 0.2);
            assert_eq!(fv.x.len(), n);
            fv.l1_errors(0.0, 0.4, |x| ex.at(x, 0.0, 0.2))
        })
        .collect();
    let rate = |a: f64, b: f64| (a / b).ln() / 4f64.ln();
    let r = [rate(errs[0].rho, errs[1].rho), rate(errs[0].u, errs[1].u), rate(errs[0].p, errs[1].p)];
    eprintln!("HLL Sod: {errs:?}, rates {r:?}");
    assert!(errs[1].rho < errs[0].rho && errs[1].u < errs[0].u && errs[1].p < errs[0].p);
    for v in r {
        assert!((0.5..=1.0).contains(&v), "HLL rate {v}");
    }
    // First order at N = 800 still smears the contact: a loose absolute check that it is the
    // right solution at all.
    assert!(errs[1].rho < 0.01, "{}", errs[1].rho);
}

/// HLL conserves mass, momentum and energy to round-off while no wave reaches the ends (the
/// transmissive ends then carry equal fluxes in and out).
#[test]
fn hll_conserves_while_waves_stay_inside() {
    let tube = ShockTube::sod();
    let n = 400;
    let fv = hll::solve(&tube, n, 0.2, 0.9).unwrap();
    let g = tube.gamma;
    let total = |rho: &dyn Fn(usize) -> GasState| {
        (0..n).fold([0.0; 3], |acc, i| {
            let s = rho(i);
            [acc[0] + s.rho, acc[1] + s.rho * s.u, acc[2] + s.p / (g - 1.0) + 0.5 * s.rho * s.u * s.u]
        })
    };
    let init = total(&|i| if fv.x[i] < 0.0 { tube.left } else { tube.right });
    let end = total(&|i| gas(fv.rho[i], fv.u[i], fv.p[i]));
    for k in [0, 2] {
        assert!((end[k] - init[k]).abs() <= 1e-12 * init[k], "{k}: {} vs {}", end[k], init[k]);
    }
    // Momentum starts at zero; the ends hold p = 1 and 0.1, so the net pressure push is
    // (p_L - p_R) t dx^-1 per cell width: sum(rho u) dx = 0.9 * 0.2.
    assert!((end[1] * fv.dx - 0.9 * 0.2).abs() < 1e-10, "{}", end[1] * fv.dx);
}

#[test]
fn hll_bad_input_is_typed_error() {
    let tube = ShockTube::sod();
    let inv = |r: pbdl_particles::Result<HllSolution>, f: &str| match r {
        Err(Error::Invalid { field, .. }) => assert_eq!(field, f),
        other => panic!("expected Invalid {f}, got {other:?}"),
    };
    inv(hll::solve(&tube, 1, 0.2, 0.9), "cells");
    inv(hll::solve(&tube, 100, 0.2, 0.0), "cfl");
    inv(hll::solve(&tube, 100, 0.2, 1.5), "cfl");
    inv(hll::solve(&tube, 100, 0.2, f64::NAN), "cfl");
    inv(hll::solve(&tube, 100, -1.0, 0.9), "t");
    inv(hll::solve(&tube, 100, f64::INFINITY, 0.9), "t");
    inv(hll::solve(&ShockTube { x0: 2.0, ..tube }, 100, 0.2, 0.9), "x0");
    inv(hll::solve(&ShockTube { left: gas(-1.0, 0.0, 1.0), ..tube }, 100, 0.2, 0.9), "left");
    inv(hll::solve(&ShockTube { right: gas(1.0, 0.0, 0.0), ..tube }, 100, 0.2, 0.9), "right");
    inv(hll::solve(&ShockTube { gamma: 1.0, ..tube }, 100, 0.2, 0.9), "gamma");
    // t = 0 returns the initial state.
    let fv = hll::solve(&tube, 10, 0.0, 0.9).unwrap();
    assert_eq!(fv.steps, 0);
    assert_eq!(fv.rho[0], 1.0);
}

/// The conductivity term exchanges heat pairwise: in a periodic box its contribution to
/// `Σ m du/dt` vanishes to round-off, and with it the semi-discrete energy rate
/// `Σ m (v a + du/dt)` of the whole scheme (viscosity, switch and conductivity on).
#[test]
fn conductivity_conserves_total_energy() {
    use pbdl_particles::neighbors::Domain;
    let n = 300;
    let dx = 1.0 / n as f64;
    let two_pi = 2.0 * std::f64::consts::PI;
    let x: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) * dx).collect();
    // Density (through the masses) and energy vary independently, so pressure varies and the
    // conductivity is active.
    let m: Vec<f64> = x.iter().map(|&x| dx * (1.0 + 0.3 * (two_pi * x).sin())).collect();
    let u: Vec<f64> = x.iter().map(|&x| 2.0 + (2.0 * two_pi * x).cos()).collect();
    let v: Vec<f64> = x.iter().map(|&x| 0.4 * (two_pi * x).cos()).collect();
    let build = |p: Sph1dParams| {
        Sph1d::new(p, x.clone(), v.clone(), u.clone(), m.clone(), None, n, Domain::periodic([0.0], [1.0])).unwrap()
    };
    let on = build(Sph1dParams::default());
    let off = build(Sph1dParams { conductivity: 0.0, ..Sph1dParams::default() });
    let (mut net, mut scale) = (0.0, 0.0);
    for i in 0..n {
        let d = m[i] * (on.energy_rate()[i] - off.energy_rate()[i]);
        net += d;
        scale += d.abs();
    }
    eprintln!("conductive heating: net {net:.3e}, sum of magnitudes {scale:.3e}");
    assert!(scale > 1e-3, "conductivity inactive: {scale}");
    assert!(net.abs() <= 1e-13 * scale, "net conductive heating {net:.3e} of {scale:.3e}");
    let (mut total, mut tscale) = (0.0, 0.0);
    for i in 0..n {
        let w = m[i] * on.v[i] * on.acceleration()[i];
        let q = m[i] * on.energy_rate()[i];
        total += w + q;
        tscale += w.abs() + q.abs();
    }
    eprintln!("energy rate: net {total:.3e}, scale {tscale:.3e}");
    assert!(total.abs() <= 1e-13 * tscale, "{total:.3e} of {tscale:.3e}");
    // And over a run the total energy drifts only by the time integration's error.
    let mut sim = on;
    let e0 = sim.total_energy();
    sim.run_until(0.1).unwrap();
    let drift = (sim.total_energy() - e0).abs() / e0;
    eprintln!("total energy drift to t = 0.1: {drift:.2e} ({} steps)", sim.steps());
    assert!(drift < 1e-4, "{drift:.2e}");
}

/// The switch keeps every `α_i` in `[α_min, α_max]`, leaves it at `α_min` in the undisturbed
/// left state and at its largest near the shock.
#[test]
fn viscosity_switch_peaks_at_the_shock_and_decays_elsewhere() {
    let tube = ShockTube::sod();
    let ex = tube.exact().unwrap();
    let mut sim = tube.build(400, Sph1dParams::default()).unwrap();
    let a0 = sim.viscosity_alpha()[0];
    assert_eq!(a0, 1.0, "starts at alpha_max");
    sim.run_until(0.2).unwrap();
    let nm = sim.n_mobile();
    let alpha = &sim.viscosity_alpha()[..nm];
    assert!(alpha.iter().all(|&a| (0.1..=1.0).contains(&a)), "alpha out of [0.1, 1]");
    let imax = (0..nm).max_by(|&a, &b| alpha[a].total_cmp(&alpha[b])).unwrap();
    let g = tube.gamma;
    let c_r = tube.right.sound_speed(g);
    let s_shock = c_r * ((g + 1.0) / (2.0 * g) * ex.p_star / tube.right.p + (g - 1.0) / (2.0 * g)).sqrt();
    let x_shock = s_shock * 0.2;
    eprintln!("alpha max {:.3} at x = {:.4} (shock at {x_shock:.4}, h {:.4})", alpha[imax], sim.x[imax], sim.h[imax]);
    assert!((sim.x[imax] - x_shock).abs() < 10.0 * sim.h[imax]);
    assert!(alpha[imax] > 0.5);
    let ahead: Vec<f64> = (0..nm).filter(|&i| sim.x[i] < -0.35).map(|i| alpha[i]).collect();
    assert!(!ahead.is_empty() && ahead.iter().all(|&a| a < 0.11), "{ahead:?}");
}

/// Old parameter files (no `conductivity`, no `viscosity_switch`) load with the new defaults;
/// each new term can be switched off; bad values are typed errors.
#[test]
fn params_serde_defaults_operators_and_bad_values() {
    let old: Sph1dParams = toml::from_str("eta = 1.2\nalpha = 1.0\nbeta = 2.0\ncfl = 0.3\ngamma = 1.4\n").unwrap();
    assert_eq!(old, Sph1dParams::default());
    let off: Sph1dParams = toml::from_str("conductivity = 0.0\nviscosity_switch = { kind = \"off\" }\n").unwrap();
    assert_eq!(off, Sph1dParams::constant_viscosity());
    let mm: Sph1dParams =
        toml::from_str("viscosity_switch = { kind = \"morris_monaghan\", alpha_min = 0.2, sigma = 0.15 }\n").unwrap();
    assert_eq!(mm.viscosity_switch, ViscositySwitch::MorrisMonaghan { alpha_min: 0.2, sigma: 0.15 });
    let sv: Sph1dParams = toml::from_str("viscosity_form = \"signal_velocity\"\n").unwrap();
    assert_eq!(sv.viscosity_form, ViscosityForm::SignalVelocity);
    let ops = ShockTube::sod().build(50, sv).unwrap().operators();
    assert!(ops.contains(&"artificial_viscosity_signal_velocity"), "{ops:?}");
    let text = toml::to_string(&Sph1dParams::default()).unwrap();
    assert_eq!(toml::from_str::<Sph1dParams>(&text).unwrap(), Sph1dParams::default());

    let tube = ShockTube::sod();
    let ops = tube.build(50, Sph1dParams::constant_viscosity()).unwrap().operators();
    assert!(!ops.contains(&"artificial_conductivity") && !ops.contains(&"viscosity_switch_morris_monaghan"));
    let ops = tube.build(50, Sph1dParams::default()).unwrap().operators();
    assert!(ops.contains(&"artificial_conductivity") && ops.contains(&"viscosity_switch_morris_monaghan"));

    let bad = |p: Sph1dParams, f: &str| match tube.build(50, p) {
        Err(Error::Invalid { field, .. }) => assert_eq!(field, f),
        other => panic!("expected Invalid {f}, got {:?}", other.map(|s| s.params().to_owned())),
    };
    bad(Sph1dParams { conductivity: -1.0, ..Default::default() }, "conductivity");
    bad(Sph1dParams { conductivity: f64::NAN, ..Default::default() }, "conductivity");
    let sw = |alpha_min, sigma| Sph1dParams {
        viscosity_switch: ViscositySwitch::MorrisMonaghan { alpha_min, sigma },
        ..Default::default()
    };
    bad(sw(f64::NAN, 0.1), "viscosity_switch.alpha_min");
    // A floor above alpha is capped at it: alpha = 0 still means no linear viscosity.
    let capped = tube.build(50, Sph1dParams { alpha: 0.0, ..sw(1.5, 0.1) }).unwrap();
    assert_eq!(capped.viscosity_alpha()[0], 0.0);
    bad(sw(-0.1, 0.1), "viscosity_switch.alpha_min");
    bad(sw(0.1, 0.0), "viscosity_switch.sigma");
    bad(sw(0.1, f64::INFINITY), "viscosity_switch.sigma");
}

/// Where the L1 error sits: the judged interval cut at the exact waves (rarefaction head and
/// tail, contact, shocks), each region's share of the L1 sum of SPH (defaults) and HLL at
/// N = 400, for the cases that miss bar S1. Prints only (a diagnostic for the report).
#[test]
#[ignore = "diagnostic, prints only"]
fn where_the_error_sits() {
    for name in ["toro_1", "toro_2_123", "colliding_gamma_5_3", "sod"] {
        let c = case(name);
        let (tube, ex, mid, half) = setup(&c);
        let g = c.gamma;
        // Wave positions at t: left wave(s), contact, right wave(s).
        let mut cuts = Vec::new();
        for (s, sign, rho_star) in [(c.left, -1.0, ex.rho_star_left), (c.right, 1.0, ex.rho_star_right)] {
            let cs = s.sound_speed(g);
            if ex.p_star > s.p {
                let q = ((g + 1.0) / (2.0 * g) * ex.p_star / s.p + (g - 1.0) / (2.0 * g)).sqrt();
                cuts.push((s.u + sign * cs * q) * c.t);
            } else {
                let c_star = (g * ex.p_star / rho_star).sqrt();
                cuts.push((s.u + sign * cs) * c.t);
                cuts.push((ex.u_star + sign * c_star) * c.t);
            }
        }
        cuts.push(ex.u_star * c.t);
        cuts.sort_by(f64::total_cmp);
        let mut sim = tube.build(400, Sph1dParams::default()).unwrap();
        sim.run_until(c.t).unwrap();
        let fv = hll::solve(&tube, 400, c.t, hll::DEFAULT_CFL).unwrap();
        let share = |xs: &[f64], q: &dyn Fn(usize) -> [f64; 3]| {
            let mut out = vec![[0.0; 3]; cuts.len() + 1];
            let mut count = 0;
            for (i, &x) in xs.iter().enumerate() {
                if (x - mid).abs() < half {
                    let r = ex.at(x, 0.0, c.t);
                    let v = q(i);
                    let k = cuts.partition_point(|&w| w < x);
                    out[k][0] += (v[0] - r.rho).abs();
                    out[k][1] += (v[1] - r.u).abs();
                    out[k][2] += (v[2] - r.p).abs();
                    count += 1;
                }
            }
            out.iter().map(|e| e.map(|v| v / count as f64)).collect::<Vec<_>>()
        };
        let nm = sim.n_mobile();
        let s = share(&sim.x[..nm], &|i| [sim.rho[i], sim.v[i], sim.p[i]]);
        let h = share(&fv.x, &|i| [fv.rho[i], fv.u[i], fv.p[i]]);
        eprintln!("{name}: cuts at {cuts:.4?} (judged {:.4}..{:.4})", mid - half, mid + half);
        for k in 0..s.len() {
            eprintln!(
                "  region {k}: SPH rho {:.2e} u {:.2e} p {:.2e} | HLL rho {:.2e} u {:.2e} p {:.2e}",
                s[k][0], s[k][1], s[k][2], h[k][0], h[k][1], h[k][2]
            );
        }
    }
}

/// `ShockTube::fitted` (what the bench and stress entries use) applies this file's rule, and
/// rejects a bad end time.
#[test]
fn fitted_tube_matches_the_rule() {
    for c in cases() {
        let (tube, _, mid, half) = setup(&c);
        let f = ShockTube::fitted(c.left, c.right, c.gamma, c.t).unwrap();
        assert_eq!(f.tube, tube, "{}", c.name);
        assert!((f.judged.0 - (mid - half)).abs() < 1e-12 && (f.judged.1 - (mid + half)).abs() < 1e-12, "{}", c.name);
    }
    let sod = ShockTube::sod();
    for t in [0.0, -1.0, f64::NAN] {
        assert!(matches!(ShockTube::fitted(sod.left, sod.right, 1.4, t), Err(Error::Invalid { field: "t", .. })));
    }
}

/// Diagnostic, not a bar (added after the S1 run, on the review's finding that the bar's SPH
/// L1 is a mean over equal-mass particles, i.e. mass-weighted, while HLL's is a mean over
/// uniform cells): at N = 400, the SPH L1 weighted by particle volume `m/ρ`
/// (`Sph1d::l1_errors_by_volume`, a quadrature of the same integral the cells sample) next to
/// the bar's measure and HLL's, for every case. Prints only; S1's verdict stays on the measure
/// it was set up with.
#[test]
#[ignore = "diagnostic, prints only"]
fn volume_weighted_l1_next_to_the_bar_measure() {
    for c in cases() {
        let (_, ex, mid, half) = setup(&c);
        let (s, h, sim) = compare(&c, 400, Sph1dParams::default());
        let v = sim.l1_errors_by_volume(mid, half, |x| ex.at(x, 0.0, c.t));
        print_row(&c, 400, "by mass", &s, &h);
        print_row(&c, 400, "by volume", &v, &h);
    }
}

/// A restart sets the switch's per-particle `α` (`sim particles --init` with a trajectory's
/// `viscosity_alpha`); bad values are typed errors naming it.
#[test]
fn set_viscosity_alpha_checks_length_and_range() {
    let mut sim = ShockTube::sod().build(100, Sph1dParams::default()).unwrap();
    let n = sim.n_mobile();
    let alpha: Vec<f64> = (0..n).map(|i| 0.1 + 0.9 * i as f64 / n as f64).collect();
    sim.set_viscosity_alpha(&alpha).unwrap();
    assert!(sim.viscosity_alpha()[..n].iter().zip(&alpha).all(|(a, b)| a == b));
    assert!(matches!(sim.set_viscosity_alpha(&alpha[1..]), Err(pbdl_particles::Error::Length { .. })));
    let mut bad = alpha.clone();
    bad[3] = 1.5;
    assert!(matches!(
        sim.set_viscosity_alpha(&bad),
        Err(pbdl_particles::Error::Invalid { field: "viscosity_alpha", .. })
    ));
}
