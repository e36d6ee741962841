//! Sod's shock tube with 1D SPH: L1 errors against the exact solution at t = 0.2.
//!
//! `cargo run -p pbdl-particles --example sod -- 450`
use pbdl_particles::{Evolve, ShockTube, Sph1dParams};

fn main() -> Result<(), pbdl_particles::Error> {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(225);
    let tube = ShockTube::sod();
    let exact = tube.exact()?;
    let mut sim = tube.build(n, Sph1dParams::default())?;
    let steps = sim.run_until(0.2)?;
    let e = sim.l1_errors(0.0, 0.4, |x| exact.at(x, 0.0, 0.2));
    println!("N = {n}, {steps} steps: L1(rho) = {:.5}, L1(u) = {:.5}, L1(p) = {:.5}", e.rho, e.u, e.p);
    Ok(())
}
