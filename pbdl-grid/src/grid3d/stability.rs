//! Stable time steps of the explicit schemes on a 3D grid.
//!
//! Central advection has eigenvalues on the imaginary axis up to `|u|/dx + |v|/dy + |w|/dz`; the
//! seven-point viscous term on the negative real axis down to `4 nu (1/dx^2 + 1/dy^2 + 1/dz^2)`.
//! As in 2D ([`crate::stability`]), a step is accepted when `dt (adv / imag_limit + diff /
//! real_limit) <= 1`.

use super::Grid3d;
use crate::stability::StabilityReport;
use crate::time_stepping::ButcherTableau;
use crate::{Error, Result};

/// The largest stable time step of `tableau` for the largest speeds `[|u|, |v|, |w|]` and
/// viscosity `nu` (`f64::INFINITY` when nothing moves or diffuses).
pub fn stable_time_step(grid: &Grid3d, max_speed: [f64; 3], nu: f64, tableau: &ButcherTableau) -> f64 {
    let (adv, diff) = rates(grid, max_speed, nu);
    let imag = if adv > 0.0 { adv / tableau.imag_limit } else { 0.0 };
    let real = if diff > 0.0 { diff / tableau.real_limit } else { 0.0 };
    let s = imag + real;
    if s > 0.0 {
        1.0 / s
    } else {
        f64::INFINITY
    }
}

/// Checks `dt` against [`stable_time_step`]; an [`Error::Unstable`] names the dominant number.
/// In the report, `cfl` is `dt (|u|/dx + |v|/dy + |w|/dz)` and `diffusion_number` is
/// `4 dt nu (1/dx^2 + 1/dy^2 + 1/dz^2)`.
pub fn check_time_step(
    grid: &Grid3d,
    max_speed: [f64; 3],
    nu: f64,
    tableau: &ButcherTableau,
    dt: f64,
) -> Result<StabilityReport> {
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(Error::Invalid { field: "dt", reason: format!("time step must be positive and finite, got {dt}") });
    }
    if let Some(&value) = max_speed.iter().find(|s| !s.is_finite()) {
        return Err(Error::NonFinite { what: "velocity", value });
    }
    let (adv, diff) = rates(grid, max_speed, nu);
    let stable_dt = stable_time_step(grid, max_speed, nu, tableau);
    let report = StabilityReport { cfl: dt * adv, diffusion_number: dt * diff, stable_dt };
    if dt > stable_dt * (1.0 + 1e-12) {
        let adv_part = if adv > 0.0 { adv / tableau.imag_limit } else { 0.0 };
        let diff_part = if diff > 0.0 { diff / tableau.real_limit } else { 0.0 };
        let (what, value, limit) = if adv_part >= diff_part {
            ("advective CFL number dt (|u|/dx + |v|/dy + |w|/dz)", report.cfl, tableau.imag_limit)
        } else {
            ("diffusion number 4 dt nu (1/dx^2 + 1/dy^2 + 1/dz^2)", report.diffusion_number, tableau.real_limit)
        };
        return Err(Error::Unstable { what, value, limit, scheme: tableau.name.clone(), dt, stable_dt });
    }
    Ok(report)
}

fn rates(grid: &Grid3d, max_speed: [f64; 3], nu: f64) -> (f64, f64) {
    let h = grid.spacing();
    let adv = (0..3).map(|a| max_speed[a].abs() / h[a]).sum();
    let diff = nu * (0..3).map(|a| 4.0 / (h[a] * h[a])).sum::<f64>();
    (adv, diff)
}
