//! The WCSPH dam break (Martin & Moyce 1952, H = 2a) against the measured surge front.
//!
//! `tests/data/dambreak_exp_data.csv` is the digitised data shipped with PySPH
//! (`pysph/examples/db_exp_data.py`): T = t sqrt(2g/a), Z = z/a.

use pbdl_core::Real;
use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::{DamBreak, Evolve, WcsphParams};

/// Runs the default dam break in precision `T` through the measured times in [1, 2.5] and
/// returns (T, Z simulated, Z measured); asserts no leak and a finite state on the way.
fn surge_fronts<T: Real>() -> Vec<(f64, f64, f64)> {
    let scene = DamBreak::default();
    let mut sim = scene.build_as::<T>(WcsphParams::default()).unwrap();
    let mut points: Vec<(f64, f64)> =
        martin_moyce_1952().into_iter().filter(|(t, _)| (1.0..=2.5).contains(t)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert_eq!(points.len(), 5);
    let mut out = Vec::new();
    for (big_t, z_exp) in points {
        sim.run_until(scene.physical_time(big_t)).unwrap();
        let z = sim.front() / scene.a;
        eprintln!("T = {big_t:.3}: Z = {z:.3} vs {z_exp:.3} measured ({:+.1}%)", 100.0 * (z / z_exp - 1.0));
        assert_eq!(sim.leaked(), 0, "fluid left the tank by T = {big_t}");
        out.push((big_t, z, z_exp));
    }
    assert!(sim.is_finite());
    assert!(sim.mean_density_error() < 0.02, "mean density error {}", sim.mean_density_error());
    out
}

fn assert_within_band(fronts: &[(f64, f64, f64)]) {
    let rel: Vec<f64> = fronts.iter().map(|(_, z, z_exp)| z / z_exp - 1.0).collect();
    let (lo, hi) = rel.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &r| (a.0.min(r), a.1.max(r)));
    assert!(lo >= 0.0 && hi <= 0.12, "front error range {:+.1}%..{:+.1}%", 100.0 * lo, 100.0 * hi);
}

/// The round-1 bar (0..+12%, dx = a/20). It held with `alpha = 0.15`, a value chosen while
/// looking at this comparison; with the principled defaults of issue 24 (no artificial
/// viscosity, water's viscosity, see `WcsphParams`) it MISSES: +16.8 / +14.9 / +12.5 / +14.7 /
/// +12.2% at T = 1.212 / 1.219 / 1.602 / 1.997 / 2.283 (the bar is kept, not loosened).
#[test]
#[ignore = "misses with the issue-24 defaults: +12.2..+16.8% > +12% (see doc)"]
fn surge_front_within_0_to_12_percent_of_martin_moyce() {
    assert_within_band(&surge_fronts::<f64>());
}

/// The same run in `f32`: the same band (missed, as above; ignored with it).
#[test]
#[ignore = "misses with the issue-24 defaults, as surge_front_within_0_to_12_percent_of_martin_moyce"]
fn surge_front_in_f32_within_0_to_12_percent_of_martin_moyce() {
    assert_within_band(&surge_fronts::<f32>());
}

/// The `f32` run's front stays within a tenth of a particle spacing (dx = a/20) of the `f64`
/// run's at every measured time in [1, 2.5] (the round-1 precision bar, unchanged).
#[test]
fn surge_front_in_f32_matches_f64() {
    let f32_fronts = surge_fronts::<f32>();
    let f64_fronts = surge_fronts::<f64>();
    let worst = f32_fronts.iter().zip(&f64_fronts).map(|(a, b)| (a.1 - b.1).abs()).fold(0.0f64, f64::max);
    eprintln!("max |Z_f32 - Z_f64| = {worst:.2e} (a = 1, dx = 0.05)");
    assert!(worst <= 0.005, "f32 front departs from f64 by {worst}");
}

#[test]
fn unstable_step_is_refused_and_bad_scenes_are_errors() {
    let scene = DamBreak { dx: 0.1, ..Default::default() };
    let mut sim = scene.build(WcsphParams::default()).unwrap();
    let (dt, criterion) = sim.stable_dt();
    assert_eq!(criterion, "CFL (sound speed)");
    let err = sim.step(3.0 * dt).unwrap_err();
    assert!(matches!(err, pbdl_particles::Error::UnstableTimeStep { .. }), "{err}");
    assert_eq!(sim.steps(), 0);
    sim.step(dt).unwrap();
    assert!(DamBreak { dx: 0.0, ..Default::default() }.build(WcsphParams::default()).is_err());
    assert!(DamBreak { tank_width: 0.5, ..Default::default() }.build(WcsphParams::default()).is_err());
    assert!(DamBreak::default().build(WcsphParams { h_over_dx: -1.0, ..Default::default() }).is_err());
    let bad_nu = DamBreak::default().build(WcsphParams { nu: -1.0, ..Default::default() });
    assert!(matches!(bad_nu, Err(pbdl_particles::Error::Invalid { field: "nu", .. })));
}

// ---------------------------------------------------------------------------------------------
// Bar W1 of issue 24 (written before any run): with one parameter set per solver, documented in
// the code before the comparison (the defaults of `WcsphParams`, `IisphParams`, `DfsphParams`,
// fixed 2026-11-29 03:50 UTC), the surge front lies within 0..+10% of Martin & Moyce for T in
// [1, 2.5] at dx = a/20 and dx = a/40 for WCSPH; IISPH and DFSPH are reported against the same
// band. `cargo test --release -p pbdl-particles --test dambreak_tests -- --ignored --nocapture`
// prints the table (T, Z measured, Z experiment, deviation) of each run.
//
// Measured 2026-11-29 (after the parameters were fixed): NOT met. Deviation at T = 1.212 / 1.219
// / 1.602 / 1.997 / 2.283:
//   WCSPH a/20 +16.8 / +14.9 / +12.5 / +14.7 / +12.2%;  a/40 +20.6 / +18.6 / +14.7 / +14.9 / +12.3%
//   IISPH a/20 +16.9 / +14.9 / +12.1 / +13.4 / +10.8%;  a/40 +20.3 / +18.2 / +14.2 / +14.9 / +12.2%
//   DFSPH a/20 +17.7 / +15.7 / +12.3 / +13.1 / +10.5%;  a/40 +20.8 / +18.7 / +14.4 / +15.4 / +12.7%
// The three solvers agree within 1.1% of Z; the lead over the experiment grows with resolution.

use pbdl_particles::dfsph::DfsphParams;
use pbdl_particles::IisphParams;

/// The W1 band: deviation from the measured front in [0, +10%].
const W1_BAND: (f64, f64) = (0.0, 0.10);

/// Runs `step_to(t) -> (front, leaked)` through the measured times in [1, 2.5] of `scene` and
/// prints and returns the deviations `Z / Z_exp - 1`.
fn front_table(label: &str, scene: &DamBreak, mut step_to: impl FnMut(f64) -> (f64, usize)) -> Vec<f64> {
    let points: Vec<(f64, f64)> = martin_moyce_1952().into_iter().filter(|(t, _)| (1.0..=2.5).contains(t)).collect();
    eprintln!("{label}: T | Z measured | Z experiment | deviation");
    let mut rel = Vec::new();
    for (big_t, z_exp) in points {
        let (front, leaked) = step_to(scene.physical_time(big_t));
        let z = front / scene.a;
        let r = z / z_exp - 1.0;
        eprintln!("{label}: {big_t:.3} | {z:.3} | {z_exp:.3} | {:+.1}%", 100.0 * r);
        assert_eq!(leaked, 0, "{label}: fluid left the tank by T = {big_t}");
        rel.push(r);
    }
    rel
}

fn wcsph_fronts(dx: f64) -> Vec<f64> {
    let scene = DamBreak { dx, ..Default::default() };
    let mut sim = scene.build(WcsphParams::default()).unwrap();
    front_table(&format!("WCSPH dx = a/{}", (1.0 / dx).round()), &scene, |t| {
        sim.run_until(t).unwrap();
        (sim.front(), sim.leaked())
    })
}

fn iisph_fronts(dx: f64) -> Vec<f64> {
    let scene = DamBreak { dx, ..Default::default() };
    let mut sim = scene.build_iisph(IisphParams::default()).unwrap();
    front_table(&format!("IISPH dx = a/{}", (1.0 / dx).round()), &scene, |t| {
        sim.run_until(t).unwrap();
        (sim.front(), sim.leaked())
    })
}

fn dfsph_fronts(dx: f64) -> Vec<f64> {
    let scene = DamBreak { dx, ..Default::default() };
    let mut sim = scene.build_dfsph(DfsphParams::default()).unwrap();
    front_table(&format!("DFSPH dx = a/{}", (1.0 / dx).round()), &scene, |t| {
        sim.run_until(t).unwrap();
        (sim.front(), sim.leaked())
    })
}

fn assert_w1(label: &str, rel: &[f64]) {
    let (lo, hi) = rel.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &r| (a.0.min(r), a.1.max(r)));
    eprintln!("{label}: range {:+.1}%..{:+.1}%", 100.0 * lo, 100.0 * hi);
    assert!(
        lo >= W1_BAND.0 && hi <= W1_BAND.1,
        "{label}: front {:+.1}%..{:+.1}% outside 0..+10%",
        100.0 * lo,
        100.0 * hi
    );
}

#[test]
#[ignore = "bar W1, MISSES: +12.2..+16.8% (release; seconds)"]
fn w1_wcsph_front_a20() {
    assert_w1("WCSPH a/20", &wcsph_fronts(0.05));
}

#[test]
#[ignore = "bar W1, MISSES: +12.3..+20.6% (release; seconds)"]
fn w1_wcsph_front_a40() {
    assert_w1("WCSPH a/40", &wcsph_fronts(0.025));
}

#[test]
#[ignore = "W1 band for IISPH, misses: +10.8..+16.9% (release; seconds)"]
fn w1_iisph_front_a20() {
    assert_w1("IISPH a/20", &iisph_fronts(0.05));
}

#[test]
#[ignore = "W1 band for IISPH, misses: +12.2..+20.3% (release; seconds)"]
fn w1_iisph_front_a40() {
    assert_w1("IISPH a/40", &iisph_fronts(0.025));
}

#[test]
#[ignore = "W1 band for DFSPH, misses: +10.5..+17.7% (release; seconds)"]
fn w1_dfsph_front_a20() {
    assert_w1("DFSPH a/20", &dfsph_fronts(0.05));
}

#[test]
#[ignore = "W1 band for DFSPH, misses: +12.7..+20.8% (release; seconds)"]
fn w1_dfsph_front_a40() {
    assert_w1("DFSPH a/40", &dfsph_fronts(0.025));
}

/// NOT the acceptance bar: a fast regression sanity check at the coarse dx = a/10 (200 fluid
/// particles), bound written before its first run: every solver's front stays within
/// -5%..+30% of Martin & Moyce for T in [1, 2.5] and no particle leaves the tank.
#[test]
fn coarse_dam_break_fronts_sanity_not_the_w1_bar() {
    for (label, rel) in
        [("WCSPH a/10", wcsph_fronts(0.1)), ("IISPH a/10", iisph_fronts(0.1)), ("DFSPH a/10", dfsph_fronts(0.1))]
    {
        assert!(rel.iter().all(|r| (-0.05..=0.30).contains(r)), "{label}: {rel:?}");
    }
}

/// Diagnostic for the W1 miss, print only (added after the W1 runs, on the review's question
/// whether spray drives the lead): the bar's front is the single furthest fluid particle; the
/// "bulk front" here is the furthest particle with at least 4 other fluid particles within
/// 1.5 dx (half of the 8 a square-lattice particle has there), defined before this was run.
/// Both printed against Martin & Moyce for every solver at dx = a/20 and a/40.
#[test]
#[ignore = "diagnostic, prints only (release: seconds)"]
fn w1_bulk_front_next_to_the_furthest_particle() {
    fn bulk_front(x: &[[f64; 2]], dx: f64) -> f64 {
        let r2 = (1.5 * dx) * (1.5 * dx);
        let mut best = f64::NEG_INFINITY;
        for (i, p) in x.iter().enumerate() {
            if p[0] <= best {
                continue;
            }
            let near = x
                .iter()
                .enumerate()
                .filter(|&(j, q)| j != i && (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) <= r2)
                .count();
            if near >= 4 {
                best = p[0];
            }
        }
        best
    }
    for dx in [0.05, 0.025] {
        let scene = DamBreak { dx, ..Default::default() };
        let mut w = scene.build(WcsphParams::default()).unwrap();
        let mut i = scene.build_iisph(IisphParams::default()).unwrap();
        let mut d = scene.build_dfsph(DfsphParams::default()).unwrap();
        for (big_t, z_mm) in martin_moyce_1952().into_iter().filter(|(t, _)| (1.0..=2.5).contains(t)) {
            let t = scene.physical_time(big_t);
            w.run_until(t).unwrap();
            i.run_until(t).unwrap();
            d.run_until(t).unwrap();
            let rows = [
                ("WCSPH", w.front(), bulk_front(&w.x[..w.n_fluid()], dx)),
                ("IISPH", i.front(), bulk_front(&i.x[..i.n_fluid()], dx)),
                ("DFSPH", d.front(), bulk_front(&d.x[..d.n_fluid()], dx)),
            ];
            for (label, far, bulk) in rows {
                eprintln!(
                    "dx = a/{:.0} T = {big_t:.3} {label}: furthest {:+.1}%, bulk {:+.1}% (Z_MM {z_mm:.3})",
                    1.0 / dx,
                    100.0 * (far / scene.a / z_mm - 1.0),
                    100.0 * (bulk / scene.a / z_mm - 1.0)
                );
            }
        }
    }
}
