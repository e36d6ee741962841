//! A first-order Godunov-type finite-volume reference for shock tubes: the HLL approximate
//! Riemann solver (Harten, Lax & van Leer 1983) on uniform cells, forward Euler in time.
//!
//! Equations: the 1D Euler equations of an ideal gas in conservative form,
//! `∂U/∂t + ∂F(U)/∂x = 0` with `U = (ρ, ρu, E)`, `F = (ρu, ρu² + p, u(E + p))`,
//! `E = p / (γ - 1) + ½ ρ u²`. The update of cell `i` is
//! `U_i ← U_i - dt/dx (F_{i+½} - F_{i-½})` with the HLL flux
//!
//! ```text
//! F_hll = F_L                                              if 0 <= S_L
//!       = (S_R F_L - S_L F_R + S_L S_R (U_R - U_L)) / (S_R - S_L)   if S_L < 0 < S_R
//!       = F_R                                              if S_R <= 0
//! ```
//!
//! Wave-speed estimates: Toro's pressure-based ones (*Riemann Solvers and Numerical Methods for
//! Fluid Dynamics*, §10.5.2), `S_L = u_L - c_L q_L`, `S_R = u_R + c_R q_R`,
//! `q_K = 1` if `p* <= p_K`, else `sqrt(1 + (γ+1)/(2γ) (p*/p_K - 1))`, with `p*` the star pressure
//! of the exact Riemann problem between the two cell states ([`riemann::solve`]). They bound the
//! true wave speeds (the shock speed exactly, the rarefaction heads exactly), so the flux is
//! positivity preserving and no more diffusive than needed. Where the two cell states would
//! create a vacuum (the exact solver refuses them) the face falls back to Davis's estimates
//! `S_L = min(u_L - c_L, u_R - c_R)`, `S_R = max(u_L + c_L, u_R + c_R)`, which need no star state.
//!
//! Ends: transmissive (zero-gradient ghost cells), so outgoing waves leave; judge the solution
//! away from the ends. Time step: `dt = cfl dx / max_i (|u_i| + c_i)`, the last step shortened
//! to land on `t`. The scheme is first order: its L1 error on a shock tube falls like
//! `N^(-1/2)` to `N^(-1)` (contacts converge at `N^(-1/2)`, shocks at `N^(-1)`).
//!
//! ```
//! use pbdl_particles::{hll, ShockTube};
//!
//! let tube = ShockTube::sod();
//! let sol = hll::solve(&tube, 200, 0.2, 0.9)?;
//! let exact = tube.exact()?;
//! let e = sol.l1_errors(0.0, 0.4, |x| exact.at(x, 0.0, 0.2));
//! assert!(e.rho < 0.02 && e.count > 100);
//! # Ok::<(), pbdl_particles::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::riemann::{self, GasState};
use crate::sph1d::{L1Errors, ShockTube};

/// Default Courant number of [`solve`] (below the forward-Euler HLL limit 1).
pub const DEFAULT_CFL: f64 = 0.9;

/// Largest number of time steps [`solve`] takes before giving up (a guard against a huge `t`).
pub const MAX_STEPS: u64 = 10_000_000;

/// The finite-volume solution at time `time`: cell centres and primitive states.
#[derive(Clone, Debug, PartialEq)]
pub struct HllSolution {
    /// Cell centres.
    pub x: Vec<f64>,
    /// Cell densities.
    pub rho: Vec<f64>,
    /// Cell velocities.
    pub u: Vec<f64>,
    /// Cell pressures.
    pub p: Vec<f64>,
    /// Cell width.
    pub dx: f64,
    /// Time reached.
    pub time: f64,
    /// Time steps taken.
    pub steps: u64,
}

impl HllSolution {
    /// L1 errors over the cells whose centres satisfy `|x - x0| < half_width`, against
    /// `reference(x)` at the centre: the plain mean over those cells, the same rule as
    /// [`crate::Sph1d::l1_errors`] applies to particles.
    pub fn l1_errors(&self, x0: f64, half_width: f64, reference: impl Fn(f64) -> GasState) -> L1Errors {
        let mut e = L1Errors { rho: 0.0, u: 0.0, p: 0.0, count: 0 };
        for i in 0..self.x.len() {
            let xi = self.x[i];
            if (xi - x0).abs() < half_width {
                let r = reference(xi);
                e.rho += (self.rho[i] - r.rho).abs();
                e.u += (self.u[i] - r.u).abs();
                e.p += (self.p[i] - r.p).abs();
                e.count += 1;
            }
        }
        let c = e.count.max(1) as f64;
        L1Errors { rho: e.rho / c, u: e.u / c, p: e.p / c, count: e.count }
    }
}

/// Conserved variables `(ρ, ρu, E)`.
type Cons = [f64; 3];

fn to_cons(s: GasState, gamma: f64) -> Cons {
    [s.rho, s.rho * s.u, s.p / (gamma - 1.0) + 0.5 * s.rho * s.u * s.u]
}

fn to_prim(c: &Cons, gamma: f64) -> GasState {
    let u = c[1] / c[0];
    GasState { rho: c[0], u, p: (gamma - 1.0) * (c[2] - 0.5 * c[0] * u * u) }
}

fn flux(s: &GasState, c: &Cons) -> Cons {
    [c[1], c[1] * s.u + s.p, s.u * (c[2] + s.p)]
}

/// Toro's pressure-based wave-speed estimates, or Davis's where the pair would form a vacuum.
fn wave_speeds(l: &GasState, r: &GasState, gamma: f64) -> (f64, f64) {
    let (cl, cr) = (l.sound_speed(gamma), r.sound_speed(gamma));
    match riemann::solve(*l, *r, gamma) {
        Ok(sol) => {
            let q = |s: &GasState| {
                if sol.p_star <= s.p {
                    1.0
                } else {
                    (1.0 + (gamma + 1.0) / (2.0 * gamma) * (sol.p_star / s.p - 1.0)).sqrt()
                }
            };
            (l.u - cl * q(l), r.u + cr * q(r))
        }
        Err(_) => ((l.u - cl).min(r.u - cr), (l.u + cl).max(r.u + cr)),
    }
}

/// The HLL flux of a face and its fastest wave speed `max(|S_L|, |S_R|)`.
fn hll_flux(l: &GasState, r: &GasState, ul: &Cons, ur: &Cons, gamma: f64) -> (Cons, f64) {
    let (sl, sr) = wave_speeds(l, r, gamma);
    let (fl, fr) = (flux(l, ul), flux(r, ur));
    let f = if sl >= 0.0 {
        fl
    } else if sr <= 0.0 {
        fr
    } else {
        std::array::from_fn(|k| (sr * fl[k] - sl * fr[k] + sl * sr * (ur[k] - ul[k])) / (sr - sl))
    };
    (f, sl.abs().max(sr.abs()))
}

/// Solves `tube` to time `t` with `cells` uniform cells on `[x_lo, x_hi]` (each cell takes the
/// left or right state by its centre's side of `x0`) at Courant number `cfl` (e.g.
/// [`DEFAULT_CFL`]).
///
/// Errors: [`Error::Invalid`] for `cells < 2`, `cfl` outside `(0, 1]`, a negative or non-finite
/// `t`, a tube with `x_lo < x0 < x_hi` violated, or states the exact solver rejects
/// (non-positive density or pressure, `γ <= 1`, an initial vacuum); [`Error::NonFinite`] if a
/// cell's density or pressure stops being positive and finite (not seen on Toro's tests);
/// [`Error::Invalid`] (`t`) if more than [`MAX_STEPS`] steps would be needed.
pub fn solve(tube: &ShockTube, cells: usize, t: f64, cfl: f64) -> Result<HllSolution> {
    if cells < 2 {
        return Err(Error::invalid("cells", format!("{cells}; use at least 2 cells")));
    }
    if !(cfl > 0.0 && cfl <= 1.0) {
        return Err(Error::invalid("cfl", format!("{cfl}; use 0 < cfl <= 1 (0.9 is the usual choice)")));
    }
    if !(t >= 0.0 && t.is_finite()) {
        return Err(Error::invalid("t", format!("{t}; the end time must be finite and non-negative")));
    }
    if !(tube.x_lo < tube.x0 && tube.x0 < tube.x_hi && tube.x_lo.is_finite() && tube.x_hi.is_finite()) {
        return Err(Error::invalid(
            "x0",
            format!("need finite x_lo < x0 < x_hi, got {} {} {}", tube.x_lo, tube.x0, tube.x_hi),
        ));
    }
    tube.exact()?;
    let g = tube.gamma;
    let dx = (tube.x_hi - tube.x_lo) / cells as f64;
    let x: Vec<f64> = (0..cells).map(|i| tube.x_lo + (i as f64 + 0.5) * dx).collect();
    let mut cons: Vec<Cons> =
        x.iter().map(|&xi| to_cons(if xi < tube.x0 { tube.left } else { tube.right }, g)).collect();
    let mut prim: Vec<GasState> = cons.iter().map(|c| to_prim(c, g)).collect();
    // Fluxes at the cells + 1 faces; face k lies between cells k - 1 and k (ghosts at the ends).
    let mut fluxes: Vec<Cons> = vec![[0.0; 3]; cells + 1];
    let (mut time, mut steps) = (0.0, 0u64);
    while time < t {
        if steps >= MAX_STEPS {
            return Err(Error::invalid("t", format!("{t} needs more than {MAX_STEPS} steps at {cells} cells")));
        }
        // The fastest signal: cell speeds |u| + c and the faces' wave estimates (a shock's
        // estimate can exceed every cell's |u| + c, Toro §6.3.2).
        let mut smax = prim.iter().map(|s| s.u.abs() + s.sound_speed(g)).fold(0.0, f64::max);
        for (k, f) in fluxes.iter_mut().enumerate() {
            // Transmissive ends: the ghost cell copies its neighbour.
            let (l, r) = (k.saturating_sub(1), k.min(cells - 1));
            let (flux, speed) = hll_flux(&prim[l], &prim[r], &cons[l], &cons[r], g);
            *f = flux;
            smax = smax.max(speed);
        }
        let mut dt = cfl * dx / smax;
        // Land on `t` exactly; a step within round-off of it finishes the run.
        if time + dt >= t * (1.0 - 1e-14) {
            dt = t - time;
        }
        let lambda = dt / dx;
        for (i, c) in cons.iter_mut().enumerate() {
            for q in 0..3 {
                c[q] -= lambda * (fluxes[i + 1][q] - fluxes[i][q]);
            }
        }
        for (i, (s, c)) in prim.iter_mut().zip(&cons).enumerate() {
            *s = to_prim(c, g);
            if !(s.rho > 0.0 && s.p > 0.0 && s.rho.is_finite() && s.p.is_finite() && s.u.is_finite()) {
                return Err(Error::NonFinite { what: "HLL density or pressure", index: i, step: steps });
            }
        }
        time = if dt == t - time { t } else { time + dt };
        steps += 1;
    }
    Ok(HllSolution {
        x,
        rho: prim.iter().map(|s| s.rho).collect(),
        u: prim.iter().map(|s| s.u).collect(),
        p: prim.iter().map(|s| s.p).collect(),
        dx,
        time,
        steps,
    })
}
