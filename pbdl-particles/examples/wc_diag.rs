//! Diagnostic (temporary).
use pbdl_particles::{DamBreak, WcsphParams};
fn main() {
    let scene = DamBreak { tank_width: 1.0, dx: 0.05, ..Default::default() };
    let mut sim = scene.build(WcsphParams::default()).unwrap();
    for k in 1..=5 {
        sim.run_until(0.2 * k as f64).unwrap();
        let vmax = sim.v.iter().fold(0.0f64, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt()));
        println!("wcsph t {:.1} vmax {vmax:.3e} p[20] {:.1}", sim.time(), sim.p[20]);
    }
    let mut sim = scene.build(WcsphParams { alpha: 0.0, ..Default::default() }).unwrap();
    for k in 1..=5 {
        sim.run_until(0.2 * k as f64).unwrap();
        let vmax = sim.v.iter().fold(0.0f64, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt()));
        println!("wcsph alpha0 t {:.1} vmax {vmax:.3e} p[20] {:.1}", sim.time(), sim.p[20]);
    }
}
