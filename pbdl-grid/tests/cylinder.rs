//! Flow past a cylinder at Re = U D / nu = 100: periodic vortex shedding and its Strouhal number
//! `St = f D / U`.
//!
//! Reference: C. H. K. Williamson, "Vortex dynamics in the cylinder wake", Annu. Rev. Fluid
//! Mech. 28 (1996) 477-539: St = 0.164-0.165 at Re = 100 for the unconfined cylinder (his fit
//! St = -3.3265/Re + 0.1816 + 1.6e-4 Re gives 0.1649). Our blockage: free-slip lateral walls
//! 16 D from the axis (D/H = 1/32), close enough to unconfined that the test asks for 5% of
//! 0.165. (Measured here with walls 8 D away, D/H = 1/16: St = 0.1716 at 8 cells/D and 0.1734
//! at 10 cells/D, 4-5% above the unconfined value, the expected sign of a blockage effect.)
//!
//! Setup: domain 32 D x 32 D, cylinder centre 8 D behind the uniform inflow (U = 1) on the axis,
//! outflow on the right, a staircase cylinder (cells whose centres lie inside), MacCormack or
//! central flux form + RK4, masked projection. A small transverse kick behind the cylinder
//! starts the shedding. The frequency is measured from the upward zero crossings of the
//! transverse velocity at a probe 1.5 D behind the cylinder over the second half of the run.

use candle_core::DType;
use pbdl_grid::fluid::Advection;
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle};

const D: f64 = 1.0;
const NU: f64 = 0.01;
const LX: f64 = 32.0;
const LY: f64 = 32.0;
const CX: f64 = 8.0;
const CY: f64 = 16.0;

struct Wake {
    /// Strouhal number over the second half (NaN when fewer than 3 crossings).
    st: f64,
    /// Peak-to-peak transverse probe velocity over the last third of the run.
    amplitude: f64,
    periods: usize,
}

fn run(cells_per_d: usize, t_end: f64, cfl: f64, advection: Advection) -> Wake {
    let dx = D / cells_per_d as f64;
    let (nx, ny) = ((LX / dx).round() as usize, (LY / dx).round() as usize);
    let grid = Grid::new(nx, ny, LX, LY).unwrap();
    let bc = Boundaries::new(Bc::Inflow { velocity: [1.0, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip).unwrap();
    // Speeds near the cylinder reach ~1.5 U.
    let dt = cfl * dx / 1.5;
    let cfg = FluidConfig {
        dt,
        nu: NU,
        advection,
        density_advection: Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles: vec![Obstacle::Cylinder { center: [CX, CY], radius: D / 2.0 }],
    };
    let fluid = Fluid::new(grid, bc, None, cfg).unwrap();
    let u0 = MacField::from_fn(grid, bc, DType::F64, |x, y| {
        let kick = if (x - CX - 1.5).abs() < 0.5 && (y - CY - 0.5).abs() < 0.5 { 0.3 } else { 0.0 };
        [1.0, kick]
    })
    .unwrap();
    let mut s = FluidState { velocity: fluid.project(&u0).unwrap(), density: None };
    let steps = (t_end / dt).round() as usize;
    // Probe: the v face nearest to (CX + 1.5 D, CY).
    let (pi, pj) = (((CX + 1.5) / dx - 0.5).round() as usize, (CY / dx - 1.0).round() as usize);
    let mut signal = Vec::with_capacity(steps);
    for _ in 0..steps {
        s = fluid.step(&s, None).unwrap();
        let v = s.velocity.v().unwrap().get(0).unwrap().get(pj).unwrap().get(pi).unwrap().to_scalar::<f64>().unwrap();
        assert!(v.is_finite(), "probe velocity not finite");
        signal.push(v);
    }
    let tail = &signal[2 * steps / 3..];
    let amplitude = tail.iter().cloned().fold(f64::MIN, f64::max) - tail.iter().cloned().fold(f64::MAX, f64::min);
    // Upward zero crossings about the mean of the second half, linearly interpolated.
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
        "cylinder Re=100, {advection:?}, {cells_per_d} cells/D ({nx}x{ny}), dt {dt:.3e}, t_end {t_end}: St = {st:.4}, periods {periods}, probe v peak-to-peak {amplitude:.3}"
    );
    Wake { st, amplitude, periods }
}

/// Short default check (coarse: 4 cells per D, t = 120 D/U): the wake sheds, the transverse
/// velocity oscillates with a clear amplitude and St lies in a broad band around 0.165.
#[test]
fn cylinder_wake_sheds_vortices() {
    let w = run(4, 120.0, 1.5, Advection::MacCormack);
    assert!(w.amplitude > 0.1, "no shedding: probe amplitude {}", w.amplitude);
    assert!(w.periods >= 4, "too few periods: {}", w.periods);
    assert!((0.12..0.22).contains(&w.st), "St {}", w.st);
}

/// The accuracy check (slow, ~5 min in release): 8 cells per D, t = 200 D/U, central flux
/// form + RK4; St within 5% of Williamson's 0.165.
#[test]
#[ignore = "slow: run with --ignored (cargo xtask stress)"]
fn cylinder_strouhal_number_matches_williamson() {
    let w = run(8, 200.0, 0.7, Advection::CentralRk4);
    let st_ref = 0.165;
    println!(
        "ACCEPTANCE: cylinder_strouhal measured=St {:.4} ({:+.1}%), {} periods bar=|St - 0.165| <= 5%, >= 10 periods",
        w.st,
        100.0 * (w.st / st_ref - 1.0),
        w.periods
    );
    assert!(w.periods >= 10, "too few periods: {}", w.periods);
    assert!((w.st - st_ref).abs() <= 0.05 * st_ref, "St = {:.4}, reference {st_ref} +- 5%", w.st);
}

#[test]
#[ignore = "exploration: CELLS, TEND, ADV=mc|rk4"]
fn cylinder_explore() {
    let cells: usize = std::env::var("CELLS").ok().and_then(|v| v.parse().ok()).unwrap_or(8);
    let t: f64 = std::env::var("TEND").ok().and_then(|v| v.parse().ok()).unwrap_or(150.0);
    let adv = if std::env::var("ADV").as_deref() == Ok("mc") { Advection::MacCormack } else { Advection::CentralRk4 };
    run(cells, t, if adv == Advection::MacCormack { 1.5 } else { 0.7 }, adv);
}
