//! The exact solution of the Riemann problem of the 1D Euler equations (ideal gas), after
//! Toro, *Riemann Solvers and Numerical Methods for Fluid Dynamics*, ch. 4.
//!
//! The star pressure solves `f_L(p) + f_R(p) + u_R - u_L = 0` with
//! `f_K(p) = (p - p_K) sqrt(A_K / (p + B_K))` for a shock (`p > p_K`, `A_K = 2 / ((γ+1) ρ_K)`,
//! `B_K = (γ-1)/(γ+1) p_K`) and `f_K(p) = 2 c_K / (γ-1) ((p/p_K)^((γ-1)/(2γ)) - 1)` for a
//! rarefaction, by Newton's method; the solution is then sampled at `S = (x - x0) / t`.
//! For Sod's problem it reproduces `p* = 0.30313, u* = 0.927453, ρ*_L = 0.426319,
//! ρ*_R = 0.265574` and the shock speed 1.752156.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// A primitive gas state: density, velocity, pressure.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GasState {
    /// Density.
    pub rho: f64,
    /// Velocity.
    pub u: f64,
    /// Pressure.
    pub p: f64,
}

impl GasState {
    /// Sound speed `sqrt(γ p / ρ)`.
    pub fn sound_speed(&self, gamma: f64) -> f64 {
        (gamma * self.p / self.rho).sqrt()
    }

    /// Specific internal energy `p / ((γ - 1) ρ)`.
    pub fn internal_energy(&self, gamma: f64) -> f64 {
        self.p / ((gamma - 1.0) * self.rho)
    }

    fn validate(&self, side: &'static str) -> Result<()> {
        if !(self.rho > 0.0 && self.p > 0.0 && self.rho.is_finite() && self.p.is_finite() && self.u.is_finite()) {
            return Err(Error::invalid(side, format!("{self:?}; density and pressure must be positive and finite")));
        }
        Ok(())
    }
}

/// The solved Riemann problem: star state and wave structure, sampled by [`RiemannSolution::sample`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RiemannSolution {
    /// Left state.
    pub left: GasState,
    /// Right state.
    pub right: GasState,
    /// Adiabatic index.
    pub gamma: f64,
    /// Star-region pressure.
    pub p_star: f64,
    /// Star-region velocity (contact speed).
    pub u_star: f64,
    /// Density left of the contact.
    pub rho_star_left: f64,
    /// Density right of the contact.
    pub rho_star_right: f64,
}

fn f_k(p: f64, s: &GasState, gamma: f64) -> (f64, f64) {
    let c = s.sound_speed(gamma);
    if p > s.p {
        let a = 2.0 / ((gamma + 1.0) * s.rho);
        let b = (gamma - 1.0) / (gamma + 1.0) * s.p;
        let q = (a / (p + b)).sqrt();
        ((p - s.p) * q, q * (1.0 - 0.5 * (p - s.p) / (b + p)))
    } else {
        let e = (gamma - 1.0) / (2.0 * gamma);
        let pr = p / s.p;
        (2.0 * c / (gamma - 1.0) * (pr.powf(e) - 1.0), 1.0 / (s.rho * c) * pr.powf(-(gamma + 1.0) / (2.0 * gamma)))
    }
}

/// Solves the Riemann problem between `left` and `right` with adiabatic index `gamma`.
///
/// Errors: non-positive density or pressure, `gamma <= 1`, or data that create a vacuum.
pub fn solve(left: GasState, right: GasState, gamma: f64) -> Result<RiemannSolution> {
    left.validate("left")?;
    right.validate("right")?;
    if !(gamma > 1.0 && gamma.is_finite()) {
        return Err(Error::invalid("gamma", format!("{gamma}; the adiabatic index must exceed 1")));
    }
    let (cl, cr) = (left.sound_speed(gamma), right.sound_speed(gamma));
    let du = right.u - left.u;
    if 2.0 * (cl + cr) / (gamma - 1.0) <= du {
        return Err(Error::invalid("right.u", "the states separate into a vacuum; reduce u_R - u_L"));
    }
    let mut p = (0.5 * (left.p + right.p)).max(1e-10);
    for _ in 0..100 {
        let (fl, dfl) = f_k(p, &left, gamma);
        let (fr, dfr) = f_k(p, &right, gamma);
        let p_new = (p - (fl + fr + du) / (dfl + dfr)).max(1e-12 * p);
        let change = 2.0 * (p_new - p).abs() / (p_new + p);
        p = p_new;
        if change < 1e-14 {
            break;
        }
    }
    let (fl, _) = f_k(p, &left, gamma);
    let (fr, _) = f_k(p, &right, gamma);
    let u_star = 0.5 * (left.u + right.u) + 0.5 * (fr - fl);
    let g = (gamma - 1.0) / (gamma + 1.0);
    let star_rho = |s: &GasState| {
        let pr = p / s.p;
        if p > s.p {
            s.rho * (pr + g) / (g * pr + 1.0)
        } else {
            s.rho * pr.powf(1.0 / gamma)
        }
    };
    Ok(RiemannSolution {
        left,
        right,
        gamma,
        p_star: p,
        u_star,
        rho_star_left: star_rho(&left),
        rho_star_right: star_rho(&right),
    })
}

impl RiemannSolution {
    /// The state at similarity coordinate `s = (x - x0) / t`.
    pub fn sample(&self, s: f64) -> GasState {
        let g = self.gamma;
        let (p, u) = (self.p_star, self.u_star);
        // Mirror the right side onto the left so one code path handles both.
        let (side, s, sign, rho_star) = if s <= u {
            (self.left, s, 1.0, self.rho_star_left)
        } else {
            let r = self.right;
            (GasState { rho: r.rho, u: -r.u, p: r.p }, -s, -1.0, self.rho_star_right)
        };
        let u_star = sign * u;
        let c = side.sound_speed(g);
        let out = if p > side.p {
            // Shock.
            let speed = side.u - c * ((g + 1.0) / (2.0 * g) * p / side.p + (g - 1.0) / (2.0 * g)).sqrt();
            if s <= speed {
                side
            } else {
                GasState { rho: rho_star, u: u_star, p }
            }
        } else {
            // Rarefaction.
            let head = side.u - c;
            let c_star = c * (p / side.p).powf((g - 1.0) / (2.0 * g));
            let tail = u_star - c_star;
            if s <= head {
                side
            } else if s >= tail {
                GasState { rho: rho_star, u: u_star, p }
            } else {
                let f = 2.0 / (g + 1.0) + (g - 1.0) / ((g + 1.0) * c) * (side.u - s);
                let rho = side.rho * f.powf(2.0 / (g - 1.0));
                let uu = 2.0 / (g + 1.0) * (c + (g - 1.0) / 2.0 * side.u + s);
                GasState { rho, u: uu, p: side.p * f.powf(2.0 * g / (g - 1.0)) }
            }
        };
        GasState { u: sign * out.u, ..out }
    }

    /// The state at position `x` and time `t > 0`, the discontinuity starting at `x0`.
    pub fn at(&self, x: f64, x0: f64, t: f64) -> GasState {
        self.sample((x - x0) / t)
    }
}
