//! Divergence-free SPH (DFSPH, Bender & Koschier 2015, 2017) in 2D or 3D (`Dfsph<T, D>`, `D = 2`
//! by default) with the wall particles of [`crate::walls`] (shared with IISPH and WCSPH), the 2D
//! dam break ([`DamBreak::build_dfsph`]) and the 3D one ([`DamBreak3d::build_dfsph`], see "3D"
//! below).
//!
//! DFSPH enforces two conditions with one kind of pressure solve: a divergence-free velocity
//! field (`Dρ/Dt = 0`, solved at the start of the step on the current velocities) and constant
//! density (`ρ = ρ0` after the step, solved on the velocities advected by the non-pressure
//! forces). One step of size `dt` (symplectic Euler):
//!
//! 1. summation density `ρ_i = Σ_j m_j W_ij` over fluid and wall particles (self included), and
//!    the DFSPH factor `α_i = ρ_i / (|Σ_j m_j ∇W_ij|·|Σ_f m_f ∇W_if + 2 Σ_b m_b ∇W_ib| + Σ_f |m_f ∇W_if|²)`
//!    (fluid neighbours `f`, wall neighbours `b`). This is the paper's
//!    `α_i = ρ_i / (|Σ_j m_j ∇W_ij|² + Σ_j |m_j ∇W_ij|²)` with the wall terms of the crate's wall
//!    treatment: a wall particle does not move, and its pressure is close to the neighbouring
//!    fluid's (extrapolated, see below), so a pressure `p_i` pushes against the wall twice;
//! 2. **divergence-free solve** (when [`DfsphParams::divergence_free`]): find the impulse
//!    pressures `p^v` such that `v_i ← v_i + dt a^p_i(p^v)` gives
//!    `Dρ_i/Dt = Σ_j m_j (v_i - v_j)·∇W_ij = 0` where `p^v_i > 0` and `Dρ_i/Dt <= 0` (expansion
//!    allowed: free surface) where `p^v_i = 0`. Each iteration is the paper's
//!    `κ^v_i = (1/dt) (Dρ_i/Dt) α_i`, `v_i ← v_i - dt Σ_j m_j (κ^v_i/ρ_i + κ^v_j/ρ_j) ∇W_ij`,
//!    written with `p^v_i = κ^v_i ρ_i` (then `κ_i/ρ_i + κ_j/ρ_j = p_i/ρ_i² + p_j/ρ_j²`, the
//!    symmetric pressure force) and accumulated, relaxed by `ω` and clamped at `p >= 0`;
//!    it stops when `dt mean_i e_i / ρ0 <= divergence_tolerance` (the relative density change
//!    the remaining divergence would cause within the step) after at least one iteration, or at
//!    its cap (not an error, as in SPlisHSPlasH: the constant-density solve follows). Only
//!    particles with a full neighbourhood are constrained
//!    ([`DfsphParams::divergence_min_neighbours`]);
//! 3. non-pressure forces as in IISPH (gravity; Morris/Monaghan laminar viscosity when `nu > 0`),
//!    `v*_i = v_i + dt a_i`;
//! 4. **constant-density solve**: pressures `p` with predicted density `ρ*_i = ρ0` where
//!    `p_i > 0` and `<= ρ0` where `p_i = 0`, `ρ*_i = ρ0 + r (ρ_i - ρ0) + (ρ^Σ_i(x') - ρ_i)`: the
//!    change of the summation density over the step at the predicted positions
//!    `x'_i = x_i + dt (v*_i + dt a^p_i)` (walls fixed; see "Predicted density" below), or with
//!    `summation_prediction = false` the paper's linearisation
//!    `dt Σ_j m_j (v*_i + dt a^p_i - v*_j - dt a^p_j)·∇W_ij`; each iteration
//!    `κ_i = (ρ*_i - ρ0)/dt² α_i`, `p_i ← max(0, p_i + ω κ_i ρ_i)` (the paper's update of the
//!    velocities by `κ`, accumulated into the pressure); `r = min(1, dt/dt_stable)` removes the
//!    density error already present over the stable step, as in [`crate::iisph`]. It stops when
//!    the mean density error of the predicted state (`|ρ*_i - ρ0|` where `p_i > 0`,
//!    `max(ρ*_i - ρ0, 0)` where `p_i = 0`), over `ρ0`, is at most [`DfsphParams::tolerance`]
//!    after at least two iterations (the paper's `l < 2` rule);
//! 5. `v_i = v*_i + dt a^p_i(p)`, `x_i += dt v_i`, and the impermeable-wall fallback shared
//!    with IISPH and WCSPH ([`crate::walls::enforce_container`]: a centre that crossed the
//!    container surface goes back onto it and loses its inward velocity;
//!    [`Dfsph::wall_corrections`], [`Dfsph::max_penetration`]).
//!
//! The pressure acceleration is IISPH's,
//! `a^p_i = -Σ_f m (p_i/ρ_i² + p_f/ρ_f²) ∇W_if - Σ_b m (p_i/ρ_i² + p_b/ρ0²) ∇W_ib`, with wall
//! pressures extrapolated from the fluid in every iteration (Adami et al. 2012, the one
//! implementation in [`crate::walls`] that WCSPH and IISPH use too):
//! `p_b = max(0, Σ_f (p_f + ρ_f g·(x_b - x_f)) W_bf / Σ_f W_bf)`; the divergence solve's impulse
//! pressure has no hydrostatic part, so its extrapolation leaves out the `g` term.
//!
//! Both solves are warm-started (Bender & Koschier 2017): from `warm_start` times the last
//! step's pressures (default 1, the paper's full warm start), scaled by `r` as IISPH scales its
//! own, since a pressure for a given impulse scales as `1/dt`.
//!
//! How it relates to IISPH: with `α_i` as above, `-ω κ_i ρ_i = ω (ρ0 - ρ*_i) / a_ii` with IISPH's
//! diagonal `a_ii`, so one DFSPH density iteration is one relaxed-Jacobi sweep of IISPH's pressure
//! equation; the paper's `ω = 1` is beyond the Jacobi stability limit on our particle lattice
//! (the largest eigenvalue of `D⁻¹A` is 2.9 at `h = 1.385 dx`, see the iisph module docs), hence
//! the relaxation [`DfsphParams::omega`] (default 0.5, as IISPH). What DFSPH adds is the
//! divergence-free solve and the full warm start: the velocities entering the density solve are
//! already (nearly) divergence-free, so the density solve starts from a small residual.
//!
//! ## Predicted density
//!
//! The bar on DFSPH (issue 24, D1) is on the summation density `ρ_i = Σ_j m_j W_ij` after each
//! step, measured as the mean compression `mean_i max(ρ_i/ρ0 - 1, 0)` (free-surface particles
//! lack neighbours and have `ρ_i < ρ0`; that deficit is not counted as error, compression is).
//! With the paper's linear prediction both solves bounded the linearised density, and the
//! summation density drifted past it: the largest mean compression after a step of the dam
//! break (dx = a/20, to T = 2, tolerance 1e-3) was 1.118e-3 (IISPH 1.166e-3). The prediction by
//! summation at the predicted positions (as PCISPH, Solenthaler & Pajarola 2009, predicts its
//! density) makes the solve bound the quantity the bar measures, up to pairs that enter the
//! kernel support during the step (the neighbour list is that of the step's start) and the wall
//! fallback. Its cost is one kernel evaluation per pair and iteration in place of a dot product.
//! Measured (`tests/dfsph_tests.rs`, same run): mean compression max 9.50e-4, 4.30
//! constant-density + 1.50 divergence-free iterations per step (5.80 in all) against IISPH's
//! 6.76 (IISPH keeps the linear prediction and its 1.166e-3); before, with the linear
//! prediction: 1.118e-3 and 3.69 + 2.15.
//!
//! Known limit: with the full warm start a water column at rest does not stay at rest (mean
//! speed 7.97e-2 `sqrt(gH)` after 1 s, 8.25e-2 before the summation prediction, against IISPH's
//! 4.93e-3): the warm start keeps the last step's correction of the density error, as the iisph
//! module docs found for IISPH. With `warm_start = 0.5` the column keeps 4.95e-3, but then the
//! divergence-free solve stops after one iteration. Numbers from before the summation
//! prediction: warm start 0.6 to 0.9 gave 1.4e-2 to 6.6e-2 in the column (5.7 + 1.0 to
//! 4.2 + 1.5 iterations in the dam break); `omega = 0.6` with the full warm start 3.46 + 4.60
//! iterations, mean compression 8.4e-4 in the dam break, 5.8e-2 in the column. The defaults
//! were not tuned on these runs.
//!
//! ## 3D
//!
//! One implementation serves both dimensions (`Dfsph<T, 3>`; in 2D every sum runs in the order
//! of the former 2D-only code, so 2D results are unchanged bit for bit). The particle mass comes
//! from the lattice as in 2D (`m = ρ0 / Σ_k W(|x_k|)` over the cubic lattice), the full
//! neighbourhood of the particle-deficiency rule from the same lattice (80 neighbours at
//! `h = 1.385 dx`), and the walls are [`crate::wcsph3d::Tank3d`]'s layers with the same
//! [`crate::walls`] extrapolation. The one 3D parameter is the relaxation: the 2D `ω = 0.5` is
//! beyond the Jacobi stability limit on the cubic lattice (`λ_max = 4.96` against 2.89 in 2D),
//! so the 3D set is [`DfsphParams::default_3d`] (`ω = 0.29`, the 2D margin; derived from the
//! lattice, fixed before any dx = a/20 run or comparison).
//!
//! Bar 3D3 of issue 24 (`tests/dfsph3d_tests.rs`, written before any 3D DFSPH run; dam break of
//! [`DamBreak3d`], dx = a/20, 8000 fluid and 54,336 wall particles, tolerance 0.1%): the largest
//! mean compression of the summation density to T = 2 (D1's measure) is 1.184e-3, above the
//! 1e-3 of the bar (**not met**; the largest value is left at T = 0.84, it exceeds 1e-3 while
//! the column collapses and the surge runs along the floor, T ~ 0.5-2.5, and stays below 3.4e-4
//! after T = 3.5); 0 particles leave the tank to T = 10 (met; 6951 fallback corrections,
//! deepest crossing 0.36 dx); per step 4.12 constant-density and 1.00 divergence-free
//! iterations to T = 2 (2.29 and 1.49 to T = 10, 1082 steps, ~30 ms per step on 2 threads); the
//! front leads Martin & Moyce by 11.1 to 17.3% at T in [1, 2.5] (outside 3D1's band 0..+10%,
//! as 2D DFSPH's 10.5 to 17.7%).
//!
//! Precision: as [`crate::iisph`], state and per-particle arithmetic in `T`, parameters, time
//! and the mean errors in `f64`.

use crate::error::{Error, Result};
use crate::kernels::{Kernel, KernelKind};
use crate::neighbors::{CellList, Domain, NeighborList};
use crate::walls::{self, WallStencil};
use crate::wcsph::DamBreak;
use crate::wcsph3d::DamBreak3d;
use pbdl_core::stepper::{equal_steps_dt, Evolve};
use pbdl_core::Real;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Numerical parameters of [`Dfsph`], with documented defaults (those shared with
/// [`crate::IisphParams`] have the same defaults).
///
/// The defaults are the one parameter set of the dam-break comparison with Martin & Moyce
/// (issue 24, bar W1), fixed on 2026-11-29 at 03:50 UTC before that comparison was run: IISPH's (see
/// [`crate::IisphParams`]: Wendland C2, `h = 1.385 dx`, `cfl = 0.4`, `dt_max = 0.005` s,
/// tolerance 0.1%, `omega = 0.5`, inviscid as water at this scale), the paper's full warm start
/// (Bender & Koschier 2017), the summation-density prediction (chosen for the density bar D1,
/// on the density error, not on the front) and SPlisHSPlasH's particle-deficiency rule for the
/// divergence-free solve (chosen because the dam break failed without it, see
/// [`DfsphParams::divergence_min_neighbours`]; it was added during the T = 10 leak runs, and
/// whether that was before or after the first front comparison was not recorded). Walls: Adami et al. (2012),
/// [`crate::walls`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DfsphParams {
    /// Kernel (default Wendland C2, as IISPH).
    pub kernel: KernelKind,
    /// Smoothing length over particle spacing (default 1.385, as IISPH: the band in which the
    /// square and hexagonal lattices are stable under pressure; see the iisph module docs).
    pub h_over_dx: f64,
    /// Courant factor: `dt <= cfl dx / |v|max` (default 0.4).
    pub cfl: f64,
    /// Largest time step in seconds (default 0.005).
    pub dt_max: f64,
    /// Allowed mean density error of the constant-density solve, relative (default 1e-3 = 0.1%).
    pub tolerance: f64,
    /// Iteration cap of the constant-density solve (default 200).
    pub max_iterations: usize,
    /// Run the divergence-free solve (default true; false leaves a constant-density solver with
    /// warm start only).
    pub divergence_free: bool,
    /// Allowed mean divergence error `dt mean(Dρ/Dt) / ρ0` of the divergence-free solve
    /// (default 1e-3).
    pub divergence_tolerance: f64,
    /// Iteration cap of the divergence-free solve (default 100).
    pub max_divergence_iterations: usize,
    /// The divergence-free condition holds only for particles with at least this fraction of a
    /// full neighbourhood (neighbours, fluid and wall, over those of a lattice particle inside
    /// the fluid; default 0.875). A particle with fewer (free surface, spray) is left to the
    /// constant-density solve. This is the particle-deficiency rule of SPlisHSPlasH, Bender's
    /// reference implementation of DFSPH (2D: at least 7 of the 8 lattice neighbours of its
    /// kernel, i.e. 7/8; here 0.875 of the lattice count, e.g. 70 of 80 neighbours in 3D at
    /// `h = 1.385 dx`): a density-deficient spray particle that approaches the wall or another
    /// particle has a positive `Dρ/Dt` without being compressed, and its impulse
    /// pressure threw particles off the corner impact of the dam break at 15 m/s (2.4 times
    /// `sqrt(2gH)`) until the constant-density solve failed at T = 4.8 (T = 8.8 with the warm
    /// start at 0.5). 0 imposes the condition everywhere.
    pub divergence_min_neighbours: f64,
    /// Relaxation ω of both solves (default 0.5; the paper's 1 diverges on the particle lattice,
    /// see the module docs; in 3D 0.5 diverges too: [`DfsphParams::default_3d`] has 0.29).
    pub omega: f64,
    /// Factor on the last step's pressures for the warm start of both solves (default 1, the
    /// paper's; 0 disables the warm start).
    pub warm_start: f64,
    /// Kinematic viscosity in m²/s (default 0: no viscosity term).
    pub nu: f64,
    /// Predict the density of the constant-density solve by summation at the predicted
    /// positions `x_i + dt (v*_i + dt a^p_i)` (default true) instead of linearly,
    /// `ρ_i + dt Σ_j m_j (v_i - v_j)·∇W_ij` (false: Bender & Koschier's prediction). See
    /// "Predicted density" in the module docs.
    pub summation_prediction: bool,
}

impl Default for DfsphParams {
    fn default() -> Self {
        DfsphParams {
            kernel: KernelKind::WendlandC2,
            h_over_dx: 1.385,
            cfl: 0.4,
            dt_max: 0.005,
            tolerance: 1e-3,
            max_iterations: 200,
            divergence_free: true,
            divergence_tolerance: 1e-3,
            max_divergence_iterations: 100,
            divergence_min_neighbours: 0.875,
            omega: 0.5,
            warm_start: 1.0,
            nu: 0.0,
            summation_prediction: true,
        }
    }
}

impl DfsphParams {
    /// The parameter set of the 3D DFSPH ([`DamBreak3d::build_dfsph`], bar 3D3 of issue 24):
    /// [`DfsphParams::default`] with `omega = 0.29`. Fixed on 2026-11-29 at 04:21 UTC, after
    /// the first coarse 3D runs (dx = a/8) had shown the 2D ω diverging and before any run at
    /// dx = a/20 or any comparison with Martin & Moyce; derived from the lattice, not from a run:
    /// one iteration of either solve is a relaxed-Jacobi sweep of IISPH's pressure equation
    /// (module docs), which converges for `ω λ_max < 2`, `λ_max` the largest eigenvalue of
    /// `D⁻¹A` on the particle lattice. For Wendland C2 at `h = 1.385 dx`,
    /// `λ_max(k) = |Σ_r sin(k·r) ∇W(r)|² / Σ_r |∇W(r)|²` maximised over wave vectors `k` is
    /// 2.886 on the square lattice (2D: `ω λ_max = 1.44` with the default 0.5) and 4.961 on the
    /// cubic lattice (at `k = (0.79, 0.79, 0.79)/dx`), where 0.5 gives 2.48: the 2D ω diverges
    /// in 3D (a column at rest reached a 16% mean density error at its third step). 0.29 keeps
    /// the 2D margin, `ω λ_max = 1.44`. Everything else (kernel, `h/dx`, tolerances, warm
    /// start, summation prediction, particle-deficiency fraction) is the 2D default, unchanged.
    pub fn default_3d() -> Self {
        DfsphParams { omega: 0.29, ..DfsphParams::default() }
    }

    /// Checks every field; the first bad one is an [`Error::Invalid`] naming it.
    pub fn validate(&self) -> Result<()> {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        if !(pos(self.h_over_dx) && (crate::MIN_H_OVER_DX..=crate::MAX_H_OVER_DX).contains(&self.h_over_dx)) {
            return Err(Error::invalid(
                "h_over_dx",
                format!(
                    "{}; use a value in [{}, {}] (typically 1.2 to 2)",
                    self.h_over_dx,
                    crate::MIN_H_OVER_DX,
                    crate::MAX_H_OVER_DX
                ),
            ));
        }
        if !(pos(self.cfl) && self.cfl <= 1.0) {
            return Err(Error::invalid("cfl", format!("{}; use 0 < cfl <= 1 (0.4 is usual)", self.cfl)));
        }
        if !pos(self.dt_max) {
            return Err(Error::invalid("dt_max", format!("{}; must be positive", self.dt_max)));
        }
        if !(pos(self.tolerance) && self.tolerance < 1.0) {
            return Err(Error::invalid("tolerance", format!("{}; use 0 < tolerance < 1, e.g. 1e-3", self.tolerance)));
        }
        if self.max_iterations < 2 {
            return Err(Error::invalid(
                "max_iterations",
                format!("{}; the density solve does at least 2 iterations", self.max_iterations),
            ));
        }
        if !(pos(self.divergence_tolerance) && self.divergence_tolerance < 1.0) {
            return Err(Error::invalid(
                "divergence_tolerance",
                format!("{}; use 0 < divergence_tolerance < 1, e.g. 1e-3", self.divergence_tolerance),
            ));
        }
        if self.max_divergence_iterations < 1 {
            return Err(Error::invalid(
                "max_divergence_iterations",
                "0; the divergence solve needs at least 1 iteration (set divergence_free = false to skip it)",
            ));
        }
        if !(self.divergence_min_neighbours >= 0.0 && self.divergence_min_neighbours <= 1.0) {
            return Err(Error::invalid(
                "divergence_min_neighbours",
                format!("{}; use a fraction in [0, 1] (0.875)", self.divergence_min_neighbours),
            ));
        }
        if !(pos(self.omega) && self.omega <= 1.0) {
            return Err(Error::invalid("omega", format!("{}; use 0 < omega <= 1 (0.5)", self.omega)));
        }
        if !(self.warm_start >= 0.0 && self.warm_start <= 1.0) {
            return Err(Error::invalid("warm_start", format!("{}; use 0 <= warm_start <= 1", self.warm_start)));
        }
        if !(self.nu >= 0.0 && self.nu.is_finite()) {
            return Err(Error::invalid("nu", format!("{}; the viscosity must be non-negative", self.nu)));
        }
        Ok(())
    }
}

/// The largest eigenvalue `λ_max` of one relaxed-Jacobi sweep's operator `D⁻¹A` on the regular
/// particle lattice of spacing 1 in `dim` dimensions (2 or 3) for `kernel` at `h = h_over_dx`:
/// `λ(k) = |Σ_r sin(k·r) ∇W(r)|² / Σ_r |∇W(r)|²` over the lattice offsets `r` within the
/// support, maximised over wave vectors `k` in `[0, π]^dim` (a grid of 33 points per axis: the
/// function is smooth in `k`). The pressure solves of [`Dfsph`] converge for `ω λ_max < 2`; the
/// constructors refuse an `omega` beyond that. Wendland C2 at `h = 1.385`: 2.886 (2D), 4.961
/// (3D), see [`DfsphParams::default_3d`].
pub fn jacobi_lambda_max(kernel: KernelKind, h_over_dx: f64, dim: usize) -> Result<f64> {
    if !(dim == 2 || dim == 3) {
        return Err(Error::invalid("dim", format!("{dim}; the lattice estimate covers 2D and 3D")));
    }
    let k = Kernel::<f64>::new(kernel, dim, h_over_dx)?;
    let reach = k.support().ceil() as i64;
    // Gradient vectors ∇W(r) of every lattice offset inside the support.
    let mut grads: Vec<([f64; 3], [f64; 3])> = Vec::new();
    let range = -reach..=reach;
    for a in range.clone() {
        for b in range.clone() {
            for c in if dim == 3 { range.clone() } else { 0..=0 } {
                let r = [a as f64, b as f64, c as f64];
                let len = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                if len == 0.0 || len >= k.support() {
                    continue;
                }
                let s = k.dw_dr(len) / len;
                grads.push((r, [s * r[0], s * r[1], s * r[2]]));
            }
        }
    }
    let norm: f64 = grads.iter().map(|(_, g)| g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sum();
    if norm <= 0.0 {
        return Err(Error::invalid(
            "h_over_dx",
            format!("{h_over_dx}; the kernel's support holds no lattice neighbour"),
        ));
    }
    const STEPS: usize = 32;
    let at = |i: usize| std::f64::consts::PI * i as f64 / STEPS as f64;
    let mut best = 0.0f64;
    for i in 0..=STEPS {
        for j in 0..=STEPS {
            for l in 0..=(if dim == 3 { STEPS } else { 0 }) {
                let kv = [at(i), at(j), at(l)];
                let mut sum = [0.0f64; 3];
                for (r, g) in &grads {
                    let sn = (kv[0] * r[0] + kv[1] * r[1] + kv[2] * r[2]).sin();
                    for d in 0..3 {
                        sum[d] += sn * g[d];
                    }
                }
                best = best.max((sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]) / norm);
            }
        }
    }
    Ok(best)
}

/// Statistics of the last DFSPH step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DfsphStats {
    /// Iterations of the constant-density solve.
    pub iterations: usize,
    /// Final mean relative density error of the predicted state (constant-density solve).
    pub density_error: f64,
    /// Iterations of the divergence-free solve (0 when it is off).
    pub divergence_iterations: usize,
    /// Final mean divergence error `dt mean(Dρ/Dt) / ρ0` of the divergence-free solve.
    pub divergence_error: f64,
    /// Mean compression `mean_i max(ρ_i/ρ0 - 1, 0)` of the summation density at the start of
    /// the step (the actual density error the previous step left).
    pub compression: f64,
}

/// Outcome of one pressure solve.
struct Solved<T, const D: usize> {
    p: Vec<T>,
    ap: Vec<[T; D]>,
    iterations: usize,
    error: f64,
    converged: bool,
}

/// The DFSPH state and stepper in `D` dimensions (default 2; 3D: [`DamBreak3d::build_dfsph`]),
/// in `f64` (default) or `f32`. Fluid particles come first, fixed wall particles after (the
/// layout of [`crate::Iisph`]). Positions, velocities and gravity are `[_; D]`.
#[derive(Clone, Debug)]
pub struct Dfsph<T: Real = f64, const D: usize = 2> {
    params: DfsphParams,
    kernel: Kernel<T>,
    rho0: f64,
    mass: f64,
    dx: f64,
    gravity: [f64; D],
    /// Positions (fluid, then walls).
    pub x: Vec<[T; D]>,
    /// Fluid velocities.
    pub v: Vec<[T; D]>,
    /// Fluid summation densities (at the start of the last step).
    pub rho: Vec<T>,
    /// Fluid pressures of the last constant-density solve.
    pub p: Vec<T>,
    /// Fluid impulse pressures of the last divergence-free solve.
    pub p_div: Vec<T>,
    n_fluid: usize,
    container: [[f64; D]; 2],
    cells: CellList<T, D>,
    nl: NeighborList,
    grads: Vec<[T; D]>,
    walls: WallStencil<T, D>,
    time: f64,
    steps: u64,
    stats: DfsphStats,
    total_iterations: u64,
    total_divergence_iterations: u64,
    divergence_unconverged: u64,
    full_neighbours: usize,
    wall_corrections: u64,
    max_penetration: f64,
    /// Factor on the stored pressures for the next warm start (1 for a given initial pressure).
    warm: f64,
}

impl<T: Real, const D: usize> Dfsph<T, D> {
    /// A stepper from particle arrays (`v` for the fluid only, walls after the fluid) in the
    /// search box `domain`; `container` is the box the fluid must stay in (as [`crate::Iisph::new`]).
    ///
    /// Errors: mismatched lengths, particles outside `domain`, bad parameters or constants.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        params: DfsphParams,
        rho0: f64,
        dx: f64,
        gravity: [f64; D],
        x: Vec<[T; D]>,
        v: Vec<[T; D]>,
        n_fluid: usize,
        domain: Domain<T, D>,
        container: [[f64; D]; 2],
    ) -> Result<Self> {
        params.validate()?;
        domain.validate()?;
        if v.len() != n_fluid || n_fluid > x.len() {
            return Err(Error::Length { op: "Dfsph::new", arg: "v", expected: n_fluid, got: v.len() });
        }
        if !(rho0 > 0.0 && rho0.is_finite()) {
            return Err(Error::invalid("rho0", format!("{rho0}; must be positive")));
        }
        if !(dx > 0.0 && dx.is_finite()) {
            return Err(Error::invalid("dx", format!("{dx}; must be positive")));
        }
        if !gravity.iter().all(|g| g.is_finite()) {
            return Err(Error::invalid("gravity", format!("{gravity:?}; must be finite")));
        }
        if let Some(i) = x.iter().position(|p| !(0..D).all(|d| p[d] >= domain.lo[d] && p[d] <= domain.hi[d])) {
            return Err(Error::OutsideDomain {
                index: i,
                position: x[i].map(Real::wide).to_vec(),
                lo: domain.lo.map(Real::wide).to_vec(),
                hi: domain.hi.map(Real::wide).to_vec(),
            });
        }
        let kernel = Kernel::<T>::new(params.kernel, D, T::c(params.h_over_dx * dx))?;
        // m = ρ0 / Σ_k W(|x_k|) over the lattice (in f64), as IISPH: ρ = ρ0 at rest, full support.
        let k64 = Kernel::<f64>::new(params.kernel, D, params.h_over_dx * dx)?;
        let reach = (k64.support() / dx).ceil() as i64 + 1;
        // Squared lengths (in dx²) of the lattice offsets within `reach` per axis, the first
        // axis fastest (in 2D the order of the former hand-written double loop, so the mass is
        // unchanged bit for bit).
        let side = (2 * reach + 1) as usize;
        let lattice: Vec<i64> = (0..side.pow(D as u32))
            .map(|idx| {
                let mut rem = idx;
                (0..D).fold(0i64, |r2, _| {
                    let o = (rem % side) as i64 - reach;
                    rem /= side;
                    r2 + o * o
                })
            })
            .collect();
        let wsum: f64 = lattice.iter().map(|&r2| k64.w((r2 as f64).sqrt() * dx)).sum();
        // Neighbours of a lattice particle inside the fluid (strictly within the support, as
        // the neighbour search).
        let s2 = (k64.support() / dx).powi(2);
        let full_neighbours = lattice.iter().filter(|&&r2| r2 != 0 && (r2 as f64) < s2).count();
        // A relaxation past the Jacobi limit of this lattice diverges within a few steps (in
        // 3D the 2D default does): refuse it with the value that would work.
        let lambda = jacobi_lambda_max(params.kernel, params.h_over_dx, D)?;
        if params.omega * lambda >= 2.0 {
            return Err(Error::invalid(
                "omega",
                format!(
                    "{}: the pressure solves diverge on this {D}D particle lattice (omega * lambda_max = {:.2} >= 2, lambda_max = {lambda:.3} for this kernel and h_over_dx); use omega < {:.3}{}",
                    params.omega,
                    params.omega * lambda,
                    2.0 / lambda,
                    if D == 3 { ", e.g. DfsphParams::default_3d()" } else { "" }
                ),
            ));
        }
        let cells = CellList::new(domain, kernel.support())?;
        Ok(Dfsph {
            full_neighbours,
            params,
            kernel,
            rho0,
            mass: rho0 / wsum,
            dx,
            gravity,
            rho: vec![T::c(rho0); n_fluid],
            p: vec![T::zero(); n_fluid],
            p_div: vec![T::zero(); n_fluid],
            x,
            v,
            n_fluid,
            container,
            cells,
            nl: NeighborList::default(),
            grads: Vec::new(),
            walls: WallStencil::default(),
            time: 0.0,
            steps: 0,
            stats: DfsphStats::default(),
            total_iterations: 0,
            total_divergence_iterations: 0,
            divergence_unconverged: 0,
            wall_corrections: 0,
            max_penetration: 0.0,
            warm: params.warm_start,
        })
    }

    /// Number of fluid particles (the first ones).
    pub fn n_fluid(&self) -> usize {
        self.n_fluid
    }

    /// Simulated time.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Parameters.
    pub fn params(&self) -> &DfsphParams {
        &self.params
    }

    /// Particle mass (fluid and walls).
    pub fn mass(&self) -> f64 {
        self.mass
    }

    /// Rest density.
    pub fn rho0(&self) -> f64 {
        self.rho0
    }

    /// Particle spacing.
    pub fn dx(&self) -> f64 {
        self.dx
    }

    /// The container box `[lo, hi]`.
    pub fn container(&self) -> [[f64; D]; 2] {
        self.container
    }

    /// Sets the fluid pressures used as the first constant-density solve's initial guess (e.g.
    /// hydrostatic).
    ///
    /// Errors: a length other than the fluid count, negative or non-finite values.
    pub fn set_initial_pressure(&mut self, p: Vec<T>) -> Result<()> {
        if p.len() != self.n_fluid {
            return Err(Error::Length {
                op: "Dfsph::set_initial_pressure",
                arg: "p",
                expected: self.n_fluid,
                got: p.len(),
            });
        }
        if let Some(i) = p.iter().position(|v| !(*v >= T::zero() && v.is_finite())) {
            return Err(Error::invalid("p", format!("particle {i} has pressure {}", p[i].wide())));
        }
        self.p = p;
        self.warm = 1.0;
        Ok(())
    }

    /// Statistics of the last step (both solves).
    pub fn last_solve(&self) -> DfsphStats {
        self.stats
    }

    /// Constant-density iterations over all steps.
    pub fn total_iterations(&self) -> u64 {
        self.total_iterations
    }

    /// Divergence-free iterations over all steps.
    pub fn total_divergence_iterations(&self) -> u64 {
        self.total_divergence_iterations
    }

    /// Steps whose divergence-free solve stopped at its iteration cap above its tolerance (the
    /// step went on; see [`Dfsph::step`]).
    pub fn divergence_unconverged(&self) -> u64 {
        self.divergence_unconverged
    }

    /// The terms this stepper evaluates: `summation_density`, `dfsph_alpha`,
    /// `divergence_solve_dfsph` (when `divergence_free`), `density_solve_dfsph`,
    /// `pressure_acceleration`, then `gravity` (non-zero gravity), `laminar_viscosity`
    /// (`nu > 0`) and `wall_particles` (when there are any).
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = vec!["summation_density", "dfsph_alpha"];
        if self.params.divergence_free {
            ops.push("divergence_solve_dfsph");
        }
        ops.extend(["density_solve_dfsph", "pressure_acceleration"]);
        if self.gravity != [0.0; D] {
            ops.push("gravity");
        }
        if self.params.nu > 0.0 {
            ops.push("laminar_viscosity");
        }
        if self.x.len() > self.n_fluid {
            ops.push("wall_particles");
        }
        ops
    }

    /// The stable step: `min(cfl dx / |v|max, cfl sqrt(dx / |g|), dt_max)` (as IISPH).
    pub fn stable_dt(&self) -> f64 {
        let vmax = self.v.iter().fold(0.0f64, |a, v| a.max(dot(v, v).sqrt().wide()));
        let g = self.gravity.iter().fold(0.0, |a, g| a + g.powi(2)).sqrt();
        let mut dt = self.params.dt_max;
        if vmax > 0.0 {
            dt = dt.min(self.params.cfl * self.dx / vmax);
        }
        if g > 0.0 {
            dt = dt.min(self.params.cfl * (self.dx / g).sqrt());
        }
        dt
    }

    /// One DFSPH step of size `dt` (see the module docs).
    ///
    /// A divergence-free solve that reaches its cap above its tolerance does not stop the step
    /// (counted by [`Dfsph::divergence_unconverged`]; SPlisHSPlasH does the same).
    ///
    /// Errors: [`Error::UnstableTimeStep`] when `dt` exceeds [`Dfsph::stable_dt`],
    /// [`Error::SolverNotConverged`] when the constant-density solve misses its tolerance within
    /// its cap (both leave the state unchanged), [`Error::NonFinite`].
    pub fn step(&mut self, dt: f64) -> Result<()> {
        let limit = self.stable_dt();
        if dt.is_nan() || dt <= 0.0 || dt > limit * (1.0 + 1e-12) {
            return Err(Error::UnstableTimeStep { dt, limit, criterion: "CFL (particle velocity)" });
        }
        let nf = self.n_fluid;
        // Fluid rows only; the wall particles' sums come from crate::walls::WallStencil.
        self.cells.build(&self.x)?;
        self.cells.query_first(nf, &mut self.nl);
        let dom = *self.cells.domain();
        self.walls.build(&self.x, nf, &self.nl, &self.kernel, &dom);
        let c = T::c;
        let zero = T::zero();
        let (m, rho0, k) = (c(self.mass), c(self.rho0), self.kernel);
        let h = k.h();
        // Kernel gradients per neighbour entry (fluid rows) and summation densities.
        let end = self.nl.offsets[nf];
        self.grads.resize(end, [zero; D]);
        {
            let (x, nl) = (&self.x, &self.nl);
            let mut rest: &mut [[T; D]] = &mut self.grads[..end];
            let mut rows = Vec::with_capacity(nf);
            for i in 0..nf {
                let (head, tail) = rest.split_at_mut(nl.offsets[i + 1] - nl.offsets[i]);
                rows.push(head);
                rest = tail;
            }
            rows.into_par_iter().zip(self.rho.par_iter_mut()).enumerate().for_each(|(i, (g, r))| {
                let mut sum = m * k.w(zero);
                for (gij, &j) in g.iter_mut().zip(nl.neighbors(i)) {
                    let j = j as usize;
                    let d = sub(&x[i], &x[j]);
                    let rr = dot(&d, &d).sqrt();
                    let (w, dw) = k.w_dw(rr);
                    sum += m * w;
                    *gij = if rr > zero { d.map(|dc| dw / rr * dc) } else { [zero; D] };
                }
                *r = sum;
            });
        }
        let (x, nl, rho, grads, stencil) = (&self.x, &self.nl, &self.rho, &self.grads, &self.walls);
        let grad_row = |i: usize| &grads[nl.offsets[i]..nl.offsets[i + 1]];
        let compression = rho.iter().map(|&r| (r.wide() / self.rho0 - 1.0).max(0.0)).sum::<f64>() / nf.max(1) as f64;
        // DFSPH factor, stored as its inverse without ρ_i: den_i = ρ_i / α_i.
        let den: Vec<T> = (0..nf)
            .into_par_iter()
            .map(|i| {
                let (mut sg, mut sp, mut sg2) = ([zero; D], [zero; D], zero);
                for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                    let fluid = (j as usize) < nf;
                    let w = if fluid { T::one() } else { c(2.0) };
                    for d in 0..D {
                        sg[d] += m * gw[d];
                        sp[d] += w * m * gw[d];
                    }
                    if fluid {
                        sg2 += m * m * dot(gw, gw);
                    }
                }
                dot(&sg, &sp) + sg2
            })
            .collect();
        let (dt_t, dt2) = (c(dt), c(dt * dt));
        let g = self.gravity.map(c);
        // Wall pressures extrapolated from the fluid (Adami et al. 2012, crate::walls), as in
        // IISPH; the hydrostatic term only for the constant-density pressure.
        let wall_pressure = |p: &[T], hydro: bool| -> Vec<T> {
            let mut pw = Vec::new();
            stencil.pressure(p, rho, if hydro { g } else { [zero; D] }, &mut pw);
            pw
        };
        let pressure_acc = |p: &[T], hydro: bool| -> Vec<[T; D]> {
            let pw = wall_pressure(p, hydro);
            let r02 = rho0 * rho0;
            (0..nf)
                .into_par_iter()
                .map(|i| {
                    let pi = p[i] / (rho[i] * rho[i]);
                    let mut acc = [zero; D];
                    for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                        let j = j as usize;
                        let cf = if j < nf { m * (pi + p[j] / (rho[j] * rho[j])) } else { m * (pi + pw[j - nf] / r02) };
                        for d in 0..D {
                            acc[d] -= cf * gw[d];
                        }
                    }
                    acc
                })
                .collect()
        };
        // dt Σ_j m (u_i - u_j)·∇W_ij (walls at rest): the density change of velocities u over dt.
        let density_change = |u: &[[T; D]], i: usize| -> T {
            let mut s = zero;
            for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                let j = j as usize;
                let uj = if j < nf { u[j] } else { [zero; D] };
                s += m * dot(&sub(&u[i], &uj), gw);
            }
            dt_t * s
        };
        // One solve: pressures p >= 0 such that base + dt a^p(p) changes density by -target_i
        // over dt (target_i = the density excess to remove), with complementarity at p = 0.
        let omega = c(self.params.omega);
        // The density at the end of the step by summation at the predicted positions
        // x + dt (u + dt a^p) (walls fixed), on the neighbour list of the step's start.
        let predicted_density = |u: &[[T; D]], ap: &[[T; D]]| -> Vec<T> {
            let xp: Vec<[T; D]> = (0..nf)
                .into_par_iter()
                .map(|i| std::array::from_fn(|d| x[i][d] + dt_t * (u[i][d] + dt_t * ap[i][d])))
                .collect();
            (0..nf)
                .into_par_iter()
                .map(|i| {
                    let mut sum = m * k.w(zero);
                    for &j in nl.neighbors(i) {
                        let j = j as usize;
                        let xj = if j < nf { xp[j] } else { x[j] };
                        let d = sub(&xp[i], &xj);
                        sum += m * k.w(dot(&d, &d).sqrt());
                    }
                    sum
                })
                .collect()
        };
        #[allow(clippy::too_many_arguments)]
        let solve = |base: &[[T; D]],
                     target: &[T],
                     mut p: Vec<T>,
                     hydro: bool,
                     summation: bool,
                     active: Option<&[bool]>,
                     tol: f64,
                     cap: usize,
                     min_it: usize| {
            let mut out =
                Solved { p: Vec::new(), ap: Vec::new(), iterations: 0, error: f64::INFINITY, converged: false };
            for it in 1..=cap {
                let ap = pressure_acc(&p, hydro);
                let rho_pred = if summation { predicted_density(base, &ap) } else { Vec::new() };
                let (new_p, err): (Vec<T>, Vec<T>) = (0..nf)
                    .into_par_iter()
                    .map(|i| {
                        // ρ*_i - ρ0 with the pressure p: the excess left after the step, the
                        // change over the step by summation or linearised.
                        let dev = target[i]
                            + if summation {
                                rho_pred[i] - rho[i]
                            } else {
                                density_change(base, i)
                                    + dt2 * {
                                        let mut s = zero;
                                        for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                                            let j = j as usize;
                                            let aj = if j < nf { ap[j] } else { [zero; D] };
                                            s += m * dot(&sub(&ap[i], &aj), gw);
                                        }
                                        s
                                    }
                            };
                        if active.is_some_and(|a| !a[i]) {
                            // Not constrained (particle-deficient, see DfsphParams).
                            return (zero, zero);
                        }
                        let e = if p[i] > zero { dev.abs() } else { dev.fmax(zero) };
                        // κ_i ρ_i = (ρ*_i - ρ0)/dt² α_i ρ_i = dev ρ_i² / (dt² den_i).
                        let pn = if den[i] > zero {
                            (p[i] + omega * dev * rho[i] * rho[i] / (dt2 * den[i])).fmax(zero)
                        } else {
                            zero
                        };
                        (pn, e)
                    })
                    .unzip();
                let avg = err.iter().map(|&e| e.wide()).sum::<f64>() / (nf.max(1) as f64 * self.rho0);
                out.iterations = it;
                out.error = avg;
                if !avg.is_finite() {
                    return out;
                }
                if (it >= min_it && avg <= tol) || it == cap {
                    // At the cap, the pressures whose error was measured (the caller decides
                    // whether an unconverged solve is an error).
                    out.converged = it >= min_it && avg <= tol;
                    out.ap = ap;
                    out.p = p;
                    return out;
                }
                p = new_p;
            }
            out
        };
        let relax = (dt / limit).min(1.0);
        let warm = c(self.warm);
        let not_converged = |solver: &'static str, s: &Solved<T, D>, tolerance: f64| {
            if !s.error.is_finite() {
                Error::NonFinite { what: "pressure", index: 0, step: self.steps }
            } else {
                Error::SolverNotConverged {
                    solver,
                    iterations: s.iterations,
                    residual: s.error,
                    tolerance,
                    step: self.steps,
                }
            }
        };
        // Divergence-free solve on the current velocities.
        let v = &self.v;
        let mut div_unconverged = 0u64;
        let (v_div, p_div, div_stats) = if self.params.divergence_free && nf > 0 {
            let target = vec![zero; nf];
            let p0: Vec<T> = self.p_div.iter().map(|&q| warm * q).collect();
            let tol = self.params.divergence_tolerance;
            let need = self.params.divergence_min_neighbours * self.full_neighbours as f64;
            let active: Vec<bool> = (0..nf).map(|i| nl.neighbors(i).len() as f64 >= need).collect();
            let s = solve(v, &target, p0, false, false, Some(&active), tol, self.params.max_divergence_iterations, 1);
            // An unconverged divergence-free solve is not an error (as in Bender's SPlisHSPlasH,
            // which stops it at its iteration cap): what divergence is left, the constant-density
            // solve removes in the same step. Only a non-finite residual is.
            if !s.error.is_finite() {
                return Err(not_converged("DFSPH divergence-free solve", &s, tol));
            }
            if !s.converged {
                div_unconverged = 1;
            }
            let vd: Vec<[T; D]> = (0..nf).map(|i| std::array::from_fn(|d| v[i][d] + dt_t * s.ap[i][d])).collect();
            (vd, s.p, (s.iterations, s.error))
        } else {
            (v.clone(), vec![zero; nf], (0, 0.0))
        };
        // Non-pressure forces -> advected velocity (as IISPH).
        let (nu, eps, viscous) = (c(self.params.nu), c(0.01) * h * h, self.params.nu > 0.0);
        // No-slip wall velocities for the viscous term (Adami et al. 2012, crate::walls).
        let mut wall_v = Vec::new();
        if viscous {
            stencil.no_slip_velocity(&v_div, &mut wall_v);
        }
        let v_adv: Vec<[T; D]> = (0..nf)
            .into_par_iter()
            .map(|i| {
                let mut a = g;
                if viscous {
                    for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                        let j = j as usize;
                        let vj = if j < nf { v_div[j] } else { wall_v[j - nf] };
                        let rj = if j < nf { rho[j] } else { rho0 };
                        let d = sub(&x[i], &x[j]);
                        let vx = dot(&sub(&v_div[i], &vj), &d);
                        // The laminar-viscosity factor 2 (d + 2): 8 in 2D, 10 in 3D.
                        let cv = c(2.0 * (D as f64 + 2.0)) * nu * (m / rj) * vx / (dot(&d, &d) + eps);
                        for q in 0..D {
                            a[q] += cv * gw[q];
                        }
                    }
                }
                std::array::from_fn(|d| v_div[i][d] + dt_t * a[d])
            })
            .collect();
        // Constant-density solve: the density error present is removed over the stable step.
        let target: Vec<T> = rho.iter().map(|&r| c(relax) * (r - rho0)).collect();
        let p0: Vec<T> = self.p.iter().map(|&q| warm * q).collect();
        let tol = self.params.tolerance;
        let summation = self.params.summation_prediction;
        let s = solve(&v_adv, &target, p0, true, summation, None, tol, self.params.max_iterations, 2);
        if !s.converged {
            return Err(not_converged("DFSPH constant-density solve", &s, tol));
        }
        for i in 0..nf {
            for d in 0..D {
                self.v[i][d] = v_adv[i][d] + dt_t * s.ap[i][d];
                self.x[i][d] += dt_t * self.v[i][d];
            }
        }
        // The impermeable-wall fallback shared with IISPH (crate::walls::enforce_container).
        if self.x.len() > nf {
            let fix = walls::enforce_container(&mut self.x, &mut self.v, nf, self.container);
            self.wall_corrections += fix.corrections;
            self.max_penetration = self.max_penetration.max(fix.depth);
        }
        if let Some(i) = (0..nf).find(|&i| !self.x[i].iter().all(|c| c.is_finite())) {
            return Err(Error::NonFinite { what: "position", index: i, step: self.steps });
        }
        self.stats = DfsphStats {
            iterations: s.iterations,
            density_error: s.error,
            divergence_iterations: div_stats.0,
            divergence_error: div_stats.1,
            compression,
        };
        self.p = s.p;
        self.p_div = p_div;
        self.warm = self.params.warm_start * relax;
        self.total_iterations += s.iterations as u64;
        self.total_divergence_iterations += div_stats.0 as u64;
        self.divergence_unconverged += div_unconverged;
        self.time += dt;
        self.steps += 1;
        Ok(())
    }

    /// How often (particle and axis) a fluid centre crossed the container surface and was put
    /// back onto it, over all steps (0 when there are no walls).
    pub fn wall_corrections(&self) -> u64 {
        self.wall_corrections
    }

    /// The deepest crossing of the container surface before that correction, over all steps.
    pub fn max_penetration(&self) -> f64 {
        self.max_penetration
    }

    /// Summation densities of the fluid at the current positions (fluid and walls).
    pub fn summation_density(&mut self) -> Result<Vec<T>> {
        self.cells.build(&self.x)?;
        self.cells.query_first(self.n_fluid, &mut self.nl);
        let (x, nl, k, m) = (&self.x, &self.nl, self.kernel, T::c(self.mass));
        Ok((0..self.n_fluid)
            .into_par_iter()
            .map(|i| {
                m * k.w(T::zero())
                    + nl.neighbors(i)
                        .iter()
                        .map(|&j| {
                            let j = j as usize;
                            let d = sub(&x[i], &x[j]);
                            m * k.w(dot(&d, &d).sqrt())
                        })
                        .sum::<T>()
            })
            .collect())
    }

    /// Average compression `mean_i max(ρ_i/ρ0 - 1, 0)` of the summation densities at the
    /// current positions (the measure of [`crate::Iisph::average_compression`]).
    pub fn average_compression(&mut self) -> Result<f64> {
        let rho = self.summation_density()?;
        Ok(rho.iter().map(|&r| (r.wide() / self.rho0 - 1.0).max(0.0)).sum::<f64>() / self.n_fluid.max(1) as f64)
    }

    /// The largest x of any fluid particle (the surge front).
    pub fn front(&self) -> f64 {
        walls::front(&self.x, self.n_fluid)
    }

    /// Fluid particles outside the container (or non-finite), compared in `T`.
    pub fn leaked(&self) -> usize {
        walls::leaked(&self.x, self.n_fluid, self.container)
    }

    /// Whether every fluid position and velocity is finite.
    pub fn is_finite(&self) -> bool {
        (0..self.n_fluid).all(|i| self.x[i].iter().chain(self.v[i].iter()).all(|c| c.is_finite()))
    }
}

/// `a - b` per component.
#[inline]
fn sub<T: Real, const D: usize>(a: &[T; D], b: &[T; D]) -> [T; D] {
    std::array::from_fn(|c| a[c] - b[c])
}

/// `a·b`, summed from the first component on (in 2D `a0 b0 + a1 b1`: the operations and their
/// order of the former 2D code, so 2D results are unchanged bit for bit).
#[inline]
fn dot<T: Real, const D: usize>(a: &[T; D], b: &[T; D]) -> T {
    let mut s = a[0] * b[0];
    for c in 1..D {
        s += a[c] * b[c];
    }
    s
}

impl DamBreak {
    /// The dam break with the DFSPH stepper (the particles of [`DamBreak::build_iisph`];
    /// `c0_factor` is not used), at rest with the hydrostatic pressure `ρ0 g (H - y)` as the
    /// first pressure guess.
    ///
    /// Errors: as [`DamBreak::build`], and bad [`DfsphParams`].
    pub fn build_dfsph(&self, params: DfsphParams) -> Result<Dfsph> {
        self.build_dfsph_as::<f64>(params)
    }

    /// As [`DamBreak::build_dfsph`] in precision `T` (`f32` or `f64`).
    ///
    /// Errors: as [`DamBreak::build_dfsph`].
    pub fn build_dfsph_as<T: Real>(&self, params: DfsphParams) -> Result<Dfsph<T>> {
        params.validate()?;
        let support = params.kernel.support_factor() * params.h_over_dx;
        let lay = self.layout(support, self.wall_layers)?;
        let p0 = lay.x[..lay.n_fluid].iter().map(|x| T::c(self.rho0 * self.g * (lay.height - x[1]).max(0.0))).collect();
        let cast = |p: [f64; 2]| p.map(T::c);
        let domain = Domain { lo: cast(lay.domain.lo), hi: cast(lay.domain.hi), periodic: lay.domain.periodic };
        let mut sim = Dfsph::new(
            params,
            self.rho0,
            lay.dx,
            [0.0, -self.g],
            lay.x.into_iter().map(cast).collect(),
            vec![[T::zero(); 2]; lay.n_fluid],
            lay.n_fluid,
            domain,
            lay.container,
        )?;
        sim.set_initial_pressure(p0)?;
        Ok(sim)
    }
}

impl DamBreak3d {
    /// The 3D dam break ([`DamBreak3d`]'s column and [`crate::wcsph3d::Tank3d`]'s wall layers,
    /// `ceil(support / dx)` of them unless [`DamBreak3d::wall_layers`] is set) with the DFSPH
    /// stepper, at rest with the hydrostatic pressure `ρ0 g (H - y)` as the first pressure guess;
    /// `c0_factor` is not used. As in 2D, fluid and wall particles share one mass
    /// `m = ρ0 / Σ_k W(|x_k|)` over the (cubic) lattice, so the summation density of a particle
    /// inside the fluid at rest is `ρ0` (not the `ρ0 dx³` of [`DamBreak3d::build`]'s WCSPH).
    /// Use [`DfsphParams::default_3d`]: the 2D defaults' `ω = 0.5` diverges on the cubic
    /// lattice (module docs, "3D").
    ///
    /// ```
    /// use pbdl_particles::dfsph::DfsphParams;
    /// use pbdl_particles::wcsph3d::DamBreak3d;
    /// use pbdl_particles::Evolve;
    ///
    /// // A coarse column (dx = a/8) for a quick look; the bar 3D3 uses dx = a/20.
    /// let scene = DamBreak3d { dx: 0.125, ..DamBreak3d::default() };
    /// let mut sim = scene.build_dfsph(DfsphParams::default_3d())?;
    /// let x0 = sim.front();
    /// sim.run_until(scene.physical_time(0.3))?;
    /// assert!(sim.front() > x0 && sim.leaked() == 0 && sim.is_finite());
    /// # Ok::<(), pbdl_particles::Error>(())
    /// ```
    ///
    /// Errors: as [`DamBreak3d::build`], and bad [`DfsphParams`].
    pub fn build_dfsph(&self, params: DfsphParams) -> Result<Dfsph<f64, 3>> {
        self.build_dfsph_as::<f64>(params)
    }

    /// As [`DamBreak3d::build_dfsph`] in precision `T` (`f32` or `f64`); the layout and the
    /// hydrostatic start are computed in `f64` and rounded once.
    ///
    /// Errors: as [`DamBreak3d::build_dfsph`].
    pub fn build_dfsph_as<T: Real>(&self, params: DfsphParams) -> Result<Dfsph<T, 3>> {
        self.validate()?;
        params.validate()?;
        let support = params.kernel.support_factor() * params.h_over_dx;
        let layers = self.wall_layers.unwrap_or(support.ceil() as usize);
        let (tank, fluid, height) = self.column(layers)?;
        let p0 = fluid.iter().map(|x| T::c(self.rho0 * self.g * (height - x[1]).max(0.0))).collect();
        let n_fluid = fluid.len();
        let cast = |p: [f64; 3]| p.map(T::c);
        let dom = tank.search_domain();
        let domain = Domain { lo: cast(dom.lo), hi: cast(dom.hi), periodic: dom.periodic };
        let mut sim = Dfsph::new(
            params,
            self.rho0,
            tank.dx,
            [0.0, -self.g, 0.0],
            fluid.into_iter().chain(tank.wall_particles()).map(cast).collect(),
            vec![[T::zero(); 3]; n_fluid],
            n_fluid,
            domain,
            [[0.0; 3], tank.size()],
        )?;
        sim.set_initial_pressure(p0)?;
        Ok(sim)
    }
}

/// Adaptive stepping in equal steps, as [`crate::Iisph`]: [`Evolve::run_until`] splits the time
/// left into equal steps no longer than [`Dfsph::stable_dt`].
impl<T: Real, const D: usize> Evolve for Dfsph<T, D> {
    type Error = Error;

    fn time(&self) -> f64 {
        self.time
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn stable_dt(&self) -> f64 {
        Dfsph::stable_dt(self)
    }

    fn step(&mut self, dt: f64) -> Result<()> {
        Dfsph::step(self, dt)
    }

    fn next_dt(&self, t_end: f64) -> f64 {
        equal_steps_dt(self.time, t_end, Dfsph::stable_dt(self))
    }
}
