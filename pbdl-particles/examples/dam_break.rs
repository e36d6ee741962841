//! Runs the dam break and prints the surge front Z = z/a at T = 1.0 .. 2.5 (env: DX, ALPHA, NU, DELTA, HDX, KERNEL;
//! unset ones take `WcsphParams::default()`, the parameter set documented there).
use pbdl_particles::{DamBreak, Evolve, WcsphParams};
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let env = |k: &str, d: f64| std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d);
    // Defaults: the scene and parameters of the dam-break tests.
    let scene = DamBreak { dx: env("DX", 0.05), ..Default::default() };
    let kernel = match std::env::var("KERNEL").as_deref() {
        Ok("cubic") => pbdl_particles::KernelKind::CubicSpline,
        Ok("quintic") => pbdl_particles::KernelKind::Quintic,
        Ok("c4") => pbdl_particles::KernelKind::WendlandC4,
        _ => pbdl_particles::KernelKind::WendlandC2,
    };
    let d = WcsphParams::default();
    let params = WcsphParams {
        alpha: env("ALPHA", d.alpha),
        nu: env("NU", d.nu),
        delta: env("DELTA", d.delta),
        h_over_dx: env("HDX", d.h_over_dx),
        kernel,
        ..d
    };
    let mut sim = scene.build(params)?;
    let t0 = std::time::Instant::now();
    for big_t in [1.0, 1.2, 1.4, 1.602, 1.8, 1.997, 2.283, 2.5] {
        sim.run_until(scene.physical_time(big_t))?;
        print!("{:.3} ", sim.front() / scene.a);
    }
    println!(" ({:.1}s, leaked {})", t0.elapsed().as_secs_f64(), sim.leaked());
    Ok(())
}
