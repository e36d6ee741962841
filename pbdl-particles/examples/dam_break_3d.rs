//! The 3D dam break: a quasi-2D water column (H = 2a, spanning the tank's depth) collapsing in
//! a closed tank, with the surge front printed against Martin & Moyce (1952).
//!
//! ```text
//! cargo run --release -p pbdl-particles --example dam_break_3d [-- DX_OVER_A]
//! ```
//!
//! `DX_OVER_A` defaults to 0.1 (a/10, about 10 s in release); the README's bar 3D1 uses 0.05.

use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::wcsph3d::{DamBreak3d, Wcsph3dParams};
use pbdl_particles::Evolve;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dx: f64 = match std::env::args().nth(1) {
        Some(s) => s.parse().map_err(|e| format!("DX_OVER_A `{s}`: {e}"))?,
        None => 0.1,
    };
    let scene = DamBreak3d { dx, ..DamBreak3d::default() };
    let mut sim = scene.build(Wcsph3dParams::default())?;
    println!(
        "3D dam break, dx = {dx} a, depth {} a: {} fluid + {} wall particles",
        scene.depth,
        sim.n_fluid(),
        sim.x.len() - sim.n_fluid()
    );
    println!("{:>6} {:>8} {:>8} {:>8}", "T", "Z", "Z_MM", "dev");
    let t0 = std::time::Instant::now();
    for (tm, zm) in martin_moyce_1952().into_iter().filter(|p| p.0 <= 3.0) {
        sim.run_until(scene.physical_time(tm))?;
        let z = sim.front() / scene.a;
        println!("{tm:>6.3} {z:>8.3} {zm:>8.3} {:>+7.1}%", 100.0 * (z / zm - 1.0));
    }
    println!(
        "{} steps in {:.1} s, {} leaked, mean density error {:.2}%",
        sim.steps(),
        t0.elapsed().as_secs_f64(),
        sim.leaked(),
        100.0 * sim.mean_density_error()
    );
    Ok(())
}
