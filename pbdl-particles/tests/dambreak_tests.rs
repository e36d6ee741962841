//! The WCSPH dam break (Martin & Moyce 1952, H = 2a) against the measured surge front.
//!
//! `tests/data/dambreak_exp_data.csv` is the digitised data shipped with PySPH
//! (`pysph/examples/db_exp_data.py`): T = t sqrt(2g/a), Z = z/a.

use pbdl_particles::{DamBreak, WcsphParams};

fn martin_moyce() -> Vec<(f64, f64)> {
    let text = include_str!("data/dambreak_exp_data.csv");
    text.lines()
        .filter(|l| l.starts_with("MM1952"))
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            (v[1].parse().unwrap(), v[2].parse().unwrap())
        })
        .collect()
}

#[test]
fn surge_front_within_0_to_12_percent_of_martin_moyce() {
    let scene = DamBreak::default();
    let mut sim = scene.build(WcsphParams::default()).unwrap();
    let mut points: Vec<(f64, f64)> = martin_moyce().into_iter().filter(|(t, _)| (1.0..=2.5).contains(t)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert_eq!(points.len(), 5);
    let mut worst: (f64, f64) = (f64::INFINITY, f64::NEG_INFINITY);
    for (big_t, z_exp) in points {
        sim.run_until(scene.physical_time(big_t)).unwrap();
        let z = sim.front() / scene.a;
        let rel = z / z_exp - 1.0;
        eprintln!("T = {big_t:.3}: Z = {z:.3} vs {z_exp:.3} measured ({:+.1}%)", 100.0 * rel);
        worst = (worst.0.min(rel), worst.1.max(rel));
        assert_eq!(sim.leaked(), 0, "fluid left the tank by T = {big_t}");
    }
    assert!(worst.0 >= 0.0 && worst.1 <= 0.12, "front error range {:+.1}%..{:+.1}%", 100.0 * worst.0, 100.0 * worst.1);
    assert!(sim.is_finite());
    assert!(sim.mean_density_error() < 0.02, "mean density error {}", sim.mean_density_error());
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
