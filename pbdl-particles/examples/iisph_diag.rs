//! Diagnostic (temporary).
use pbdl_particles::{DamBreak, IisphParams, KernelKind};
fn main() {
    for (tol, dtm, kern, hdx, nu) in [
        (1e-3, 0.005, KernelKind::WendlandC2, 1.3, 1e-3),
        (1e-3, 0.005, KernelKind::WendlandC2, 1.3, 1e-2),
        (1e-3, 0.005, KernelKind::CubicSpline, 1.0, 1e-2),
    ] {
        let scene = DamBreak { tank_width: 1.0, dx: 0.05, ..Default::default() };
        let mut sim = scene
            .build_iisph(IisphParams {
                tolerance: tol,
                dt_max: dtm,
                max_iterations: 20000,
                kernel: kern,
                h_over_dx: hdx,
                nu,
                ..Default::default()
            })
            .unwrap();
        let mut k = 0;
        let mut next = 0.0;
        while sim.time() < 1.0 {
            let dt = sim.stable_dt();
            sim.step(dt).unwrap();
            k += 1;
            if sim.time() >= next {
                next += 0.2;
                let vmax = sim.v.iter().fold(0.0f64, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt()));
                println!("nu {nu} {kern:?} tol {tol} dtmax {dtm} step {k} t {:.3} it {} err {:.2e} vmax {vmax:.3e} p[20] {:.1} (hydro {:.1})", sim.time(), sim.last_solve().iterations, sim.last_solve().density_error, sim.p[20], 1000.0*9.81*(2.0 - sim.x[20][1]));
            }
        }
    }
}
