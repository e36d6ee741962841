//! Flow past a cylinder at Re = 100 in the confined channel of the DFG benchmark 2D-2:
//! M. Schäfer and S. Turek, "Benchmark computations of laminar flow around a cylinder", in Flow
//! Simulation with High-Performance Computers II, Notes Numer. Fluid Mech. 52, Vieweg (1996),
//! pp. 547-566. Channel 2.2 x 0.41, cylinder D = 0.1 centred at (0.2, 0.2) (blockage
//! D/H = 0.24), parabolic inflow with Um = 1.5 (mean 1.0), nu = 1e-3, so Re = U_mean D / nu = 100;
//! their reference Strouhal number St = D f / U_mean is 0.2950 - 0.3050 (0.3 +- 0.005).
//!
//! Setup here: no-slip walls, uniform inflow 1.0 on the inlet face with the parabolic profile
//! imposed on the first faces by a velocity source (same flux), outflow on the right, a
//! staircase cylinder (cells whose centres lie inside), MacCormack advection, backward-Euler
//! viscosity, masked projection. The shedding frequency is measured from the upward zero
//! crossings of the transverse velocity at a probe 1.5 D behind the cylinder.

use candle_core::DType;
use pbdl_grid::fluid::Advection;
use pbdl_grid::forcing::VelocitySource;
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, Grid, MacField, Obstacle};

const H: f64 = 0.41;
const D: f64 = 0.1;
const UM: f64 = 1.5;

struct Wake {
    /// Strouhal number from the last periods (NaN when fewer than 3 crossings).
    st: f64,
    /// Peak-to-peak transverse probe velocity over the last third of the run.
    amplitude: f64,
    periods: usize,
}

fn run(cells_per_d: usize, t_end: f64, cfl_umax: f64, advection: Advection) -> Wake {
    let dx = D / cells_per_d as f64;
    let (nx, ny) = ((2.2 / dx).round() as usize, (H / dx).round() as usize);
    let grid = Grid::new(nx, ny, 2.2, H).unwrap();
    let bc = Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::NoSlip, Bc::NoSlip).unwrap();
    let dt = cfl_umax * dx / 2.0;
    let cfg = FluidConfig {
        dt,
        nu: 1e-3,
        advection,
        density_advection: Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles: vec![Obstacle::Cylinder { center: [0.2, 0.2], radius: D / 2.0 }],
    };
    let profile = |_x: f64, y: f64| [4.0 * UM * y * (H - y) / (H * H), 0.0];
    let inlet =
        VelocitySource::new(grid, &bc, Obstacle::Box { lo: [0.0, 0.0], hi: [2.0 * dx + 1e-12, H] }, profile).unwrap();
    let fluid = Fluid::new(grid, bc, None, cfg).unwrap().with_velocity_source(inlet);
    // Start from the parabolic profile everywhere with a small transverse kick behind the
    // cylinder, so shedding starts within a few convective times.
    let u0 = MacField::from_fn(grid, bc, DType::F64, |x, y| {
        let kick = if (x - 0.35).abs() < 0.05 && (y - 0.25).abs() < 0.05 { 0.3 } else { 0.0 };
        [profile(x, y)[0], kick]
    })
    .unwrap();
    let mut s = pbdl_grid::FluidState { velocity: fluid.project(&u0).unwrap(), density: None };
    let steps = (t_end / dt).round() as usize;
    // Probe: v face nearest to (0.35, 0.2).
    let (pi, pj) = ((0.35 / dx - 0.5).round() as usize, (0.2 / dx - 1.0).round() as usize);
    let mut signal = Vec::with_capacity(steps);
    for _ in 0..steps {
        s = fluid.step(&s, None).unwrap();
        let v = s.velocity.v().unwrap().get(0).unwrap().get(pj).unwrap().get(pi).unwrap().to_scalar::<f64>().unwrap();
        assert!(v.is_finite(), "probe velocity not finite");
        signal.push(v);
    }
    let tail = &signal[2 * steps / 3..];
    let amplitude = tail.iter().cloned().fold(f64::MIN, f64::max) - tail.iter().cloned().fold(f64::MAX, f64::min);
    // Upward zero crossings (about the tail mean) in the second half, linearly interpolated.
    let half = &signal[steps / 2..];
    let mean = half.iter().sum::<f64>() / half.len() as f64;
    let mut cross = Vec::new();
    for k in 1..half.len() {
        let (a, b) = (half[k - 1] - mean, half[k] - mean);
        if a < 0.0 && b >= 0.0 {
            cross.push((k - 1) as f64 + a / (a - b));
        }
    }
    let (st, periods) = if cross.len() >= 3 {
        let p = (cross[cross.len() - 1] - cross[0]) / (cross.len() - 1) as f64 * dt;
        (D / p, cross.len() - 1)
    } else {
        (f64::NAN, 0)
    };
    eprintln!(
        "cylinder Re=100, {advection:?}, {cells_per_d} cells/D ({nx}x{ny}), dt {dt:.2e}, t_end {t_end}: St = {st:.4}, periods {periods}, probe v peak-to-peak {amplitude:.3}"
    );
    Wake { st, amplitude, periods }
}

/// Short default check (coarse, 8 cells per D, t = 6): the wake sheds, the transverse velocity
/// oscillates with a clear amplitude and a Strouhal number in a broad band around the reference.
#[test]
fn cylinder_wake_sheds_vortices() {
    let w = run(8, 6.0, 2.0, Advection::MacCormack);
    assert!(w.amplitude > 0.2, "no shedding: probe amplitude {}", w.amplitude);
    assert!(w.periods >= 4, "too few periods: {}", w.periods);
    assert!((0.2..0.4).contains(&w.st), "St {}", w.st);
}

/// The accuracy check (slow): 20 cells per D, t = 8; St within 5% of Schäfer & Turek's 0.300.
#[test]
#[ignore = "slow: run with --ignored (cargo xtask stress)"]
fn cylinder_strouhal_number_matches_schafer_turek() {
    let w = run(20, 8.0, 0.7, Advection::CentralRk4);
    let st_ref = 0.300;
    assert!(w.periods >= 8, "too few periods: {}", w.periods);
    assert!((w.st - st_ref).abs() <= 0.05 * st_ref, "St = {:.4}, reference {st_ref} +- 5%", w.st);
}
