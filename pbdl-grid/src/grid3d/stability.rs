//! Stable time steps of the explicit schemes on a 3D grid.
//!
//! Central advection has eigenvalues on the imaginary axis up to `|u|/dx + |v|/dy + |w|/dz`; the
//! seven-point viscous term on the negative real axis down to `4 nu (1/dx^2 + 1/dy^2 + 1/dz^2)`.
//! As in 2D ([`crate::stability`]), a step is accepted when `dt (adv / imag_limit + diff /
//! real_limit) <= 1`.

use super::Grid3d;
use crate::stability::{check_rates, stable_time_step_for_rates, StabilityReport};
use crate::time_stepping::ButcherTableau;
use crate::Result;

/// The largest stable time step of `tableau` for the largest speeds `[|u|, |v|, |w|]` and
/// viscosity `nu` (`f64::INFINITY` when nothing moves or diffuses).
pub fn stable_time_step(grid: &Grid3d, max_speed: [f64; 3], nu: f64, tableau: &ButcherTableau) -> f64 {
    let (adv, diff) = rates(grid, max_speed, nu);
    stable_time_step_for_rates(adv, diff, tableau)
}

/// Checks `dt` against [`stable_time_step`]; an [`crate::Error::Unstable`] names the dominant number.
/// In the report, `cfl` is `dt (|u|/dx + |v|/dy + |w|/dz)` and `diffusion_number` is
/// `4 dt nu (1/dx^2 + 1/dy^2 + 1/dz^2)`.
pub fn check_time_step(
    grid: &Grid3d,
    max_speed: [f64; 3],
    nu: f64,
    tableau: &ButcherTableau,
    dt: f64,
) -> Result<StabilityReport> {
    let (adv, diff) = rates(grid, max_speed, nu);
    let names =
        ("advective CFL number dt (|u|/dx + |v|/dy + |w|/dz)", "diffusion number 4 dt nu (1/dx^2 + 1/dy^2 + 1/dz^2)");
    check_rates(adv, diff, &max_speed, tableau, dt, names)
}

fn rates(grid: &Grid3d, max_speed: [f64; 3], nu: f64) -> (f64, f64) {
    let h = grid.spacing();
    let adv = (0..3).map(|a| max_speed[a].abs() / h[a]).sum();
    let diff = nu * (0..3).map(|a| 4.0 / (h[a] * h[a])).sum::<f64>();
    (adv, diff)
}
