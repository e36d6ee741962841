//! Stable time steps of the explicit schemes, and a check that refuses an unstable one.
//!
//! Central advection has eigenvalues on the imaginary axis up to `|u|/dx + |v|/dy`; the
//! five-point viscous term on the negative real axis down to `nu (4/dx^2 + 4/dy^2)`. A step is
//! accepted when `dt (adv / imag_limit + diff / real_limit) <= 1` (a convex combination of the two
//! axis limits, conservative for the rounded regions of RK3/RK4).

use crate::time_stepping::ButcherTableau;
use crate::{Error, Grid, Result};

/// Refuses a viscosity that is negative or not finite (typed [`Error::Invalid`]).
pub(crate) fn check_nu(nu: f64) -> Result<()> {
    if !(nu >= 0.0 && nu.is_finite()) {
        return Err(Error::Invalid { field: "nu", reason: format!("viscosity must be finite and >= 0, got {nu}") });
    }
    Ok(())
}

/// The numbers behind a stability verdict.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StabilityReport {
    /// `dt (|u|max/dx + |v|max/dy)`.
    pub cfl: f64,
    /// `dt nu (4/dx^2 + 4/dy^2)`.
    pub diffusion_number: f64,
    /// The largest stable time step for these speeds and viscosity.
    pub stable_dt: f64,
}

/// The largest stable time step of `tableau` for the largest speeds `max_speed = [|u|, |v|]` and
/// viscosity `nu` (`f64::INFINITY` when nothing moves or diffuses).
pub fn stable_time_step(grid: &Grid, max_speed: [f64; 2], nu: f64, tableau: &ButcherTableau) -> f64 {
    let (adv, diff) = rates(grid, max_speed, nu);
    stable_time_step_for_rates(adv, diff, tableau)
}

/// Checks `dt` against [`stable_time_step`]; an [`Error::Unstable`] names the dominant number.
pub fn check_time_step(
    grid: &Grid,
    max_speed: [f64; 2],
    nu: f64,
    tableau: &ButcherTableau,
    dt: f64,
) -> Result<StabilityReport> {
    let (adv, diff) = rates(grid, max_speed, nu);
    let names = ("advective CFL number dt (|u|/dx + |v|/dy)", "diffusion number dt nu (4/dx^2 + 4/dy^2)");
    check_rates(adv, diff, &max_speed, tableau, dt, names)
}

/// `1 / (adv / imag_limit + diff / real_limit)` for the advective rate `adv` (sum of |u_d|/dx_d)
/// and the diffusive rate `diff` (largest viscous eigenvalue magnitude), in any dimension.
pub(crate) fn stable_time_step_for_rates(adv: f64, diff: f64, tableau: &ButcherTableau) -> f64 {
    let imag = if adv > 0.0 { adv / tableau.imag_limit } else { 0.0 };
    let real = if diff > 0.0 { diff / tableau.real_limit } else { 0.0 };
    let s = imag + real;
    if s > 0.0 {
        1.0 / s
    } else {
        f64::INFINITY
    }
}

/// The check behind [`check_time_step`] for given rates, in any dimension; `names` are the
/// advective and diffusive numbers as the error message should spell them.
pub(crate) fn check_rates(
    adv: f64,
    diff: f64,
    max_speed: &[f64],
    tableau: &ButcherTableau,
    dt: f64,
    names: (&'static str, &'static str),
) -> Result<StabilityReport> {
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(Error::Invalid { field: "dt", reason: format!("time step must be positive and finite, got {dt}") });
    }
    if let Some(&value) = max_speed.iter().find(|s| !s.is_finite()) {
        return Err(Error::NonFinite { what: "velocity", value });
    }
    let stable_dt = stable_time_step_for_rates(adv, diff, tableau);
    let report = StabilityReport { cfl: dt * adv, diffusion_number: dt * diff, stable_dt };
    if dt > stable_dt * (1.0 + 1e-12) {
        let adv_part = if adv > 0.0 { adv / tableau.imag_limit } else { 0.0 };
        let diff_part = if diff > 0.0 { diff / tableau.real_limit } else { 0.0 };
        let (what, value, limit) = if adv_part >= diff_part {
            (names.0, report.cfl, tableau.imag_limit)
        } else {
            (names.1, report.diffusion_number, tableau.real_limit)
        };
        return Err(Error::Unstable { what, value, limit, scheme: tableau.name.clone(), dt, stable_dt });
    }
    Ok(report)
}

fn rates(grid: &Grid, max_speed: [f64; 2], nu: f64) -> (f64, f64) {
    let (dx, dy) = (grid.dx(), grid.dy());
    (max_speed[0].abs() / dx + max_speed[1].abs() / dy, nu * (4.0 / (dx * dx) + 4.0 / (dy * dy)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_euler_refuses_central_advection_and_rk4_accepts_cfl_half() {
        let g = Grid::square(64, 1.0).unwrap();
        let dt = 0.5 * g.dx();
        let err = check_time_step(&g, [1.0, 1.0], 0.0, &ButcherTableau::forward_euler(), dt).unwrap_err();
        assert!(matches!(err, Error::Unstable { .. }), "{err}");
        let r = check_time_step(&g, [1.0, 1.0], 0.0, &ButcherTableau::rk4(), dt).unwrap();
        assert!((r.cfl - 1.0).abs() < 1e-12);
        let err = check_time_step(&g, [0.0, 0.0], 1.0, &ButcherTableau::rk4(), dt).unwrap_err();
        assert!(err.to_string().contains("diffusion number"), "{err}");
    }
}
