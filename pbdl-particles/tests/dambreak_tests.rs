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

#[test]
fn surge_front_within_0_to_12_percent_of_martin_moyce() {
    assert_within_band(&surge_fronts::<f64>());
}

/// The same run in `f32`: the same acceptance band, and a front that stays within a tenth of a
/// particle spacing (dx = a/20) of the `f64` run's.
#[test]
fn surge_front_in_f32_matches_martin_moyce_and_f64() {
    let f32_fronts = surge_fronts::<f32>();
    assert_within_band(&f32_fronts);
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
}
