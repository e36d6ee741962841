//! 2D incompressible SPH: implicit incompressible SPH (IISPH, Ihmsen et al. 2014) with fixed
//! wall particles, and the dam break.
//!
//! One step of size `dt` (symplectic Euler, as in the paper):
//!
//! 1. summation density `ρ_i = Σ_j m_j W_ij` over fluid and wall particles (self included);
//! 2. non-pressure forces: gravity and, when `nu > 0`, Morris/Monaghan laminar viscosity
//!    `a_i += 2 (d + 2) ν Σ_j (m_j / ρ_j) (v_ij·x_ij) / (r² + 0.01 h²) ∇W_ij` (wall particles
//!    carry Adami et al.'s no-slip velocity `-ṽ_w`, see [`crate::walls`]);
//!    `v*_i = v_i + dt a_i`;
//! 3. predicted density `ρ*_i = ρ_i + dt Σ_j m_j v*_ij·∇W_ij`;
//! 4. the pressure Poisson equation `dt² Σ_j m_j (a^p_i - a^p_j)·∇W_ij = ρ0 - ρ*_i` with
//!    `a^p_i = -Σ_{j fluid} m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W_ij - Σ_{b wall} m_b (p_i/ρ_i² + p_b/ρ0²) ∇W_ib`
//!    and wall pressures extrapolated from the fluid in every iteration (Adami et al. 2012, as
//!    Band et al. 2018 do for IISPH; the one implementation in [`crate::walls`] that WCSPH and
//!    DFSPH use too), `p_b = Σ_f (p_f + ρ_f g·(x_b - x_f)) W_bf / Σ_f W_bf`
//!    (`a^p = 0` on walls), solved by relaxed Jacobi
//!    `p_i ← max(0, p_i + ω (s_i - (Ap)_i) / a_ii)`, `ω = 0.5`, warm-started from half the
//!    previous pressure; `a_ii` is the diagonal with the wall pressure approximated by
//!    mirroring (`p_b ≈ p_i`). Pressure mirroring alone (`p_b = p_i`, or Akinci et al. 2012's
//!    `p_i/ρ_i²` term) let a water column at rest churn at 0.5 to 3 m/s in our tests;
//!    extrapolation keeps it near rest;
//! 5. `v_i = v*_i + dt a^p_i`, `x_i += dt v_i`;
//! 6. impermeable walls (`v·n >= 0` on the container surface, [`crate::walls::enforce_container`],
//!    shared with WCSPH and DFSPH), as a fallback: a fluid centre
//!    that crossed the surface goes back onto it and loses its inward velocity. Wall particles
//!    alone cannot stop a density-deficient particle (spray, a broken-up film): its extrapolated
//!    wall pressure is 0 and its summation density reaches `ρ0` only about `0.25 dx` behind
//!    the surface. [`Iisph::wall_corrections`] and [`Iisph::max_penetration`] report how often
//!    and how deep (the dam break to T = 4: 40 corrections in 2.7e5 particle steps, deepest
//!    0.07 dx; to T = 10: 416, deepest 0.34 dx, still short of the first wall layer at 0.5 dx;
//!    340 and 0.29 dx since the walls moved to [`crate::walls`], the same sums in another order).
//!
//! The source term removes the density error already present over the stable step:
//! `s_i = min(1, dt/dt_stable) (ρ0 - ρ_i) - dt Σ_j m_j v*_ij·∇W_ij`, which is Ihmsen's `ρ0 - ρ*_i`
//! for a stable step. Within a much shorter step it would need velocities of order
//! `(ρ0 - ρ_i)/ρ0 dx/dt`; for the same reason the warm start of the next step is scaled by
//! that ratio too, and [`Evolve::run_until`] splits the time left into equal steps (see the
//! [`Evolve`] impl of [`Iisph`]).
//!
//! The solver stops when the average density error of the predicted state,
//! `mean_i e_i / ρ0` with `e_i = |ρ*_i + (Ap)_i - ρ0|` where `p_i > 0` and
//! `max(ρ*_i + (Ap)_i - ρ0, 0)` where `p_i = 0` (free surface: expansion allowed), is at most
//! [`IisphParams::tolerance`] after at least two iterations; otherwise it reports
//! [`Error::SolverNotConverged`] with the residual and leaves the state unchanged.
//!
//! ## Lattice stability (why `h = 1.385 dx`)
//!
//! The symmetric pressure force is the constraint force of `ρ_i(x) = ρ0`: with `λ_i = m p_i/ρ_i²`,
//! `-Σ_i λ_i ∇ρ_i` is exactly `a^p`. Linearised about a lattice at rest under a pressure `p`, the
//! motions that keep every density (`δρ_i = 0`) feel the stiffness `Σ_i λ_i ∇∇ρ_i`, i.e. that of
//! the repulsive pair potential `2 m² p/ρ² W(r)`; the pressure solve cannot resist them, since they
//! change no density. A Fourier analysis of a periodic lattice (modes `e^{i k·x}`, polarisation
//! orthogonal to the density change `Σ_j ∇W_j sin(k·x_j)`) gives their growth rate
//! `σ² = s p / (ρ0 dx²)`; for Wendland C2 on the square lattice `s = 0.061` at `h = 1.3 dx`, at
//! `k = (π/dx, 0)` (neighbouring vertical particle lines slide against each other), and `s = 0` for
//! `1.375 <= h/dx <= 1.395`, where the hexagonal lattice is stable too (`s = 0` for `1.15..1.41`).
//! The rate grows as `1/dx` at a given depth, which is why the drift of a water column at rest grew
//! with resolution at `h = 1.3 dx`: mean speed after 1 s 1.27e-2 / 1.52e-2 / 2.32e-2 `sqrt(gH)` at
//! `dx = 0.1 / 0.05 / 0.025 a`, growing exponentially from the round-off of the first steps (at
//! tolerance 1e-5: 6.8e-4 at 0.2 s, 6.6e-3 at 0.5 s, 1.48e-2 at 1 s), independent of the
//! tolerance (1e-3..1e-5) and of dt (0.005 or 0.001 s). Other choices checked: `h = 1.0 dx` (8 neighbours, square lattice stable,
//! hexagonal not) 3.3e-3 after 1 s; `h = 2.0 dx` diverged in the Jacobi solve (there the largest
//! eigenvalue of `D⁻¹A` on the lattice is 5.7, above `2/ω = 4`; 2.9 at `h = 1.385 dx`); Wendland C4
//! is unstable on the square lattice for every `h <= 2.4 dx`. With `h = 1.385 dx` the interior of
//! the column stays on its lattice (after 1 s the middle row has moved by 0.005 dx on average and
//! the bottom row by 0.002 dx, against 0.03 / 0.45 dx at `h = 1.3 dx`), and the mean speed stays at
//! 4.9e-3 (`dx = 0.05 a`) and 7.7e-3 (`dx = 0.1 a`) `sqrt(gH)` instead of growing
//! (`tests/iisph_tests.rs`; 1.6e-3 at `dx = 0.025 a`, where the default cap of 200 iterations is
//! too low: step 5 needs 594, see below). What remains has two parts. First, the stopping rule: an
//! average density error of 1e-3 is met while the pressure, warm-started from half the previous
//! one, is still far from hydrostatic, so the column sags for a few steps and then rebounds (at
//! `dx = 0.025 a` the first four steps stop after 2 iterations and the mean speed reaches 3.3e-2
//! `sqrt(gH)` at t = 0.025 s). At `dx = 0.05 a` the speed after 1 s is 3.1e-3 / 4.0e-3 / 4.9e-3 /
//! 7.1e-2 `sqrt(gH)` at tolerances 1e-4 / 5e-4 / 1e-3 / 2e-3, and 4.9e-3 / 5.6e-3 / 7.6e-3 / 6.2e-3
//! at `dt_max` 0.005 / 0.004 / 0.003 / 0.0025 s (tolerance 1e-3): the 0.5% bound is met at the
//! defaults with little margin. A full warm start (factor 1) is worse: it keeps the last step's
//! density correction and the column rises (7.3e-2 at `h = 1.4 dx`). Second, the free surface: the
//! top three rows rearrange by 0.2 to 0.6 dx (mean speed 1.4e-2 to 1.8e-2 `sqrt(gH)` in the top
//! tenth of the column, 2e-3 to 5e-3 below). Their summation density lacks the neighbours above, so
//! the clamped solve gives the top two rows `p = 0`: they rest on the pressure of the rows below
//! like balls stacked on top of each other and slide into the hollows. This does not depend on the
//! step (3.1e-3 and 3.2e-3 at dt 0.005 and 0.0025 s, tolerance 1e-4). A source term that corrects
//! compression only, `relax · min(ρ0 - ρ_i, 0) - dt Σ_j m_j v*_ij·∇W_ij`, holds those rows by their
//! own pressure and kept the column at 4.3e-4 `sqrt(gH)`, but it also makes density-deficient spray
//! resist approach at kernel range: in the dam break the corner impact threw particles at 9.5 m/s
//! (1.5 times `sqrt(2gH)`, T = 2.98), the velocities blew up and the solve failed before T = 6,
//! with ω = 0.5, 0.3 or 0.2; it is not used.
//!
//! ## The dam-break front
//!
//! The inviscid surge front leads Martin & Moyce (1952) by +16.9 / +12.2 / +13.4 / +10.8% at
//! T = 1.21 / 1.60 / 2.00 / 2.28 (+17.0 / +12.6 / +13.9 / +11.2% at `h = 1.3 dx`), the WCSPH
//! solver with its former `α = 0.15` by +11.5 / +5.8 / +5.6 / +2.2%. The pressure solve does not
//! add energy: from T = 0.5
//! on the kinetic energy stays at least 1.1% below the potential energy released (asserted in
//! `tests/iisph_tests.rs`). The difference is viscosity: WCSPH's artificial viscosity
//! (`α = 0.15`, `ν ≈ α h c0 / 8 = 0.054 m²/s` for approaching pairs) against none here; with
//! `nu = 0.005` the IISPH front leads by +12.8 / +7.4 / +8.5 / +5.7%, with `nu = 0.054` by
//! +6.0 / -0.5 / -1.4 / -4.9%. Water's 1e-6 m²/s changes nothing at this scale, so the
//! inviscid lead is the model's, not a defect of the solve. Issue 24 (bar W1, one parameter set
//! per solver fixed before the comparison): WCSPH without artificial viscosity (water's `ν`,
//! no-slip walls) leads by +16.8 / +12.5 / +14.7 / +12.2% at the same times, as IISPH does;
//! at dx = a/40 IISPH leads by +20.3 / +14.2 / +14.9 / +12.2% (all in
//! `tests/dambreak_tests.rs`): the 0..+10% band is not met, and the lead grows with resolution.
//!
//! The particle mass is `m = ρ0 / Σ_k W(|x_k|)` over the particle lattice, so that a particle
//! with full support at rest has exactly `ρ0` (the volume definition of Akinci et al. 2012 for
//! a uniform lattice); wall particles have the same mass.
//!
//! Precision: [`Iisph<T>`] keeps the particle state (positions, velocities, densities,
//! pressures) and does all per-particle arithmetic, the Jacobi iteration included, in `T`
//! (`f64` by default, or `f32`). Parameters, constants (`ρ0`, `dx`, mass, gravity), time and
//! the step size stay `f64`; the solver's average density error and the diagnostics sum in
//! `f64`. `f32` reaches the default tolerance of 1e-3 as `f64` does, in the same number of
//! iterations: the residual is a difference of density changes (of order `tolerance · ρ0`), so
//! its `f32` round-off is far below any useful tolerance (a dam break to T = 0.5 at tolerance
//! 1e-6: 9899 iterations against 9910 in `f64`; at 1e-7 both stop at step 14 after 5000
//! iterations with residuals 1.38e-7 and 1.37e-7, where at `h = 1.3 dx` both had converged in
//! 38431 and 38641 iterations). The summation density itself carries about 1e-7 relative
//! round-off in `f32`, so tolerances below about 1e-6 buy nothing there (numbers in
//! `tests/precision_tests.rs`).

use crate::error::{Error, Result};
use crate::kernels::{Kernel, KernelKind};
use crate::neighbors::{CellList, Domain, NeighborList};
use crate::walls::{self, WallStencil};
use crate::wcsph::DamBreak;
use pbdl_core::stepper::{equal_steps_dt, Evolve};
use pbdl_core::Real;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Numerical parameters of [`Iisph`], with documented defaults.
///
/// The defaults are the one parameter set of the dam-break comparison with Martin & Moyce
/// (issue 24, bar W1), fixed on 2026-11-29 at 03:50 UTC before that comparison was run, unchanged from
/// before (none was chosen on the comparison): Wendland C2 with `h = 1.385 dx` (the lattice
/// stability analysis in the module docs), `cfl = 0.4` (Ihmsen et al. 2014's λ = 0.4),
/// `dt_max = 0.005` s, `tolerance = 1e-3` (Ihmsen et al.'s 0.1% average density error),
/// `omega = 0.5` (Ihmsen et al.'s relaxation), and `nu = 0`: water's kinematic viscosity,
/// 1.0e-6 m²/s, changes a 1 m dam break by less than the solver tolerance (Reynolds number
/// ~4e6), so the model is inviscid. Walls: Adami et al. (2012) extrapolated wall pressure with
/// the hydrostatic term ([`crate::walls`]), as WCSPH and DFSPH.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IisphParams {
    /// Kernel (default Wendland C2, as the WCSPH solver; Wendland kernels are free of the
    /// pairing instability, Dehnen & Aly 2012).
    pub kernel: KernelKind,
    /// Smoothing length over particle spacing (default 1.385: 20 neighbours on the square
    /// lattice, 18 on the hexagonal one, and the middle of the band 1.375..1.395 in which a
    /// linear stability analysis finds neither lattice unstable under pressure with Wendland C2;
    /// see "Lattice stability" in the module docs. At 1.3 a water column at rest drifted at
    /// 1.5% of `sqrt(gH)` after 1 s; with the 3D habit of a cubic spline with support `2 dx` a
    /// 2D lattice particle has only 8 neighbours, and the column churned at up to 0.7 m/s).
    pub h_over_dx: f64,
    /// Courant factor: `dt <= cfl dx / |v|max` (default 0.4, the paper's λ = 0.4).
    pub cfl: f64,
    /// Largest time step in seconds (default 0.005).
    pub dt_max: f64,
    /// Allowed average density error of the pressure solve, relative (default 1e-3 = 0.1%).
    pub tolerance: f64,
    /// Iteration cap of the pressure solve (default 200).
    pub max_iterations: usize,
    /// Jacobi relaxation ω (default 0.5).
    pub omega: f64,
    /// Kinematic viscosity in m²/s (default 0: no viscosity term).
    pub nu: f64,
}

impl Default for IisphParams {
    fn default() -> Self {
        IisphParams {
            kernel: KernelKind::WendlandC2,
            h_over_dx: 1.385,
            cfl: 0.4,
            dt_max: 0.005,
            tolerance: 1e-3,
            max_iterations: 200,
            omega: 0.5,
            nu: 0.0,
        }
    }
}

impl IisphParams {
    fn validate(&self) -> Result<()> {
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
            return Err(Error::invalid("tolerance", format!("{}; use e.g. 1e-3", self.tolerance)));
        }
        if self.max_iterations < 2 {
            return Err(Error::invalid("max_iterations", "at least 2 iterations"));
        }
        if !(pos(self.omega) && self.omega <= 1.0) {
            return Err(Error::invalid("omega", format!("{}; use 0 < omega <= 1 (0.5)", self.omega)));
        }
        if !(self.nu >= 0.0 && self.nu.is_finite()) {
            return Err(Error::invalid("nu", format!("{}; the viscosity must be non-negative", self.nu)));
        }
        Ok(())
    }
}

/// Statistics of the last pressure solve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SolveStats {
    /// Jacobi iterations.
    pub iterations: usize,
    /// Final average relative density error of the predicted state.
    pub density_error: f64,
}

/// The 2D IISPH state and stepper, in `f64` (default) or `f32` (see the module docs). Fluid
/// particles come first, fixed wall particles after.
#[derive(Clone, Debug)]
pub struct Iisph<T: Real = f64> {
    params: IisphParams,
    kernel: Kernel<T>,
    rho0: f64,
    mass: f64,
    dx: f64,
    gravity: [f64; 2],
    /// Positions (fluid, then walls).
    pub x: Vec<[T; 2]>,
    /// Fluid velocities.
    pub v: Vec<[T; 2]>,
    /// Fluid summation densities (at the start of the last step).
    pub rho: Vec<T>,
    /// Fluid pressures (of the last step).
    pub p: Vec<T>,
    n_fluid: usize,
    container: [[f64; 2]; 2],
    cells: CellList<T, 2>,
    nl: NeighborList,
    grads: Vec<[T; 2]>,
    walls: WallStencil<T>,
    time: f64,
    steps: u64,
    stats: SolveStats,
    total_iterations: u64,
    /// Fluid positions put back onto the container surface (per axis), over all steps.
    wall_corrections: u64,
    /// Deepest crossing of the container surface before the correction, over all steps.
    max_penetration: f64,
    /// Factor on the stored pressure for the next warm start (1 for a given initial pressure,
    /// then 0.5 as in Ihmsen et al. 2014).
    warm: f64,
}

impl<T: Real> Iisph<T> {
    /// A stepper from particle arrays (`v` for the fluid only, walls after the fluid) in the
    /// search box `domain`; `container` is the box the fluid must stay in. The precision `T`
    /// is that of the arrays.
    ///
    /// Errors: mismatched lengths, particles outside `domain`, bad parameters or constants.
    pub fn new(
        params: IisphParams,
        rho0: f64,
        dx: f64,
        gravity: [f64; 2],
        x: Vec<[T; 2]>,
        v: Vec<[T; 2]>,
        n_fluid: usize,
        domain: Domain<T, 2>,
        container: [[f64; 2]; 2],
    ) -> Result<Self> {
        params.validate()?;
        domain.validate()?;
        if v.len() != n_fluid || n_fluid > x.len() {
            return Err(Error::Length { op: "Iisph::new", arg: "v", expected: n_fluid, got: v.len() });
        }
        if !(rho0 > 0.0 && rho0.is_finite()) {
            return Err(Error::invalid("rho0", format!("{rho0}; must be positive")));
        }
        if !(dx > 0.0 && dx.is_finite()) {
            return Err(Error::invalid("dx", format!("{dx}; must be positive")));
        }
        if let Some(i) = x.iter().position(|p| !(0..2).all(|d| p[d] >= domain.lo[d] && p[d] <= domain.hi[d])) {
            return Err(Error::OutsideDomain {
                index: i,
                position: x[i].map(Real::wide).to_vec(),
                lo: domain.lo.map(Real::wide).to_vec(),
                hi: domain.hi.map(Real::wide).to_vec(),
            });
        }
        let kernel = Kernel::<T>::new(params.kernel, 2, T::c(params.h_over_dx * dx))?;
        // Lattice sum of W (in f64): m = ρ0 / Σ W gives ρ = ρ0 for full support at rest.
        let k64 = Kernel::<f64>::new(params.kernel, 2, params.h_over_dx * dx)?;
        let reach = (k64.support() / dx).ceil() as i64 + 1;
        let mut wsum = 0.0;
        for j in -reach..=reach {
            for i in -reach..=reach {
                wsum += k64.w(((i * i + j * j) as f64).sqrt() * dx);
            }
        }
        let cells = CellList::new(domain, kernel.support())?;
        Ok(Iisph {
            params,
            kernel,
            rho0,
            mass: rho0 / wsum,
            dx,
            gravity,
            rho: vec![T::c(rho0); n_fluid],
            p: vec![T::zero(); n_fluid],
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
            stats: SolveStats::default(),
            total_iterations: 0,
            wall_corrections: 0,
            max_penetration: 0.0,
            warm: 0.5,
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
    pub fn params(&self) -> &IisphParams {
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
    pub fn container(&self) -> [[f64; 2]; 2] {
        self.container
    }

    /// Sets the fluid pressures used as the first step's initial guess (e.g. hydrostatic).
    ///
    /// Errors: a length other than the fluid count, negative or non-finite values.
    pub fn set_initial_pressure(&mut self, p: Vec<T>) -> Result<()> {
        if p.len() != self.n_fluid {
            return Err(Error::Length {
                op: "Iisph::set_initial_pressure",
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

    /// Statistics of the last pressure solve.
    pub fn last_solve(&self) -> SolveStats {
        self.stats
    }

    /// Jacobi iterations over all steps.
    pub fn total_iterations(&self) -> u64 {
        self.total_iterations
    }

    /// The terms this stepper evaluates: `summation_density`, `pressure_solve_iisph`,
    /// `pressure_acceleration`, then `gravity` (non-zero gravity), `laminar_viscosity`
    /// (`nu > 0`) and `wall_particles` (when there are any).
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = vec!["summation_density", "pressure_solve_iisph", "pressure_acceleration"];
        if self.gravity != [0.0, 0.0] {
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

    /// The stable step: `min(cfl dx / |v|max, cfl sqrt(dx / |g|), dt_max)`.
    pub fn stable_dt(&self) -> f64 {
        let vmax = self.v.iter().fold(0.0f64, |a, v| a.max((v[0] * v[0] + v[1] * v[1]).sqrt().wide()));
        let g = (self.gravity[0].powi(2) + self.gravity[1].powi(2)).sqrt();
        let mut dt = self.params.dt_max;
        if vmax > 0.0 {
            dt = dt.min(self.params.cfl * self.dx / vmax);
        }
        if g > 0.0 {
            dt = dt.min(self.params.cfl * (self.dx / g).sqrt());
        }
        dt
    }

    /// One IISPH step of size `dt` (rounded to `T` for the update; time advances by `dt` in
    /// `f64`).
    ///
    /// Errors: [`Error::UnstableTimeStep`] when `dt` exceeds [`Iisph::stable_dt`],
    /// [`Error::SolverNotConverged`] when the pressure solve does not reach the tolerance
    /// within `max_iterations` (both leave the state unchanged), [`Error::NonFinite`].
    pub fn step(&mut self, dt: f64) -> Result<()> {
        let limit = self.stable_dt();
        if dt.is_nan() || dt <= 0.0 || dt > limit * (1.0 + 1e-12) {
            return Err(Error::UnstableTimeStep { dt, limit, criterion: "CFL (particle velocity)" });
        }
        let nf = self.n_fluid;
        // Fluid rows only: the wall particles' sums come from the transposed fluid rows
        // (crate::walls::WallStencil).
        self.cells.build(&self.x)?;
        self.cells.query_first(nf, &mut self.nl);
        let dom = *self.cells.domain();
        self.walls.build(&self.x, nf, &self.nl, &self.kernel, &dom);
        let c = T::c;
        let zero = T::zero();
        let (m, rho0, k) = (c(self.mass), c(self.rho0), self.kernel);
        let h = k.h();
        let (x, nl) = (&self.x, &self.nl);
        // Kernel gradients per neighbour entry (fluid rows only), and densities.
        let end = nl.offsets[nf];
        self.grads.resize(end, [zero; 2]);
        let rows: Vec<(usize, usize)> = (0..nf).map(|i| (nl.offsets[i], nl.offsets[i + 1])).collect();
        {
            let mut rest: &mut [[T; 2]] = &mut self.grads[..end];
            let mut slices = Vec::with_capacity(nf);
            for &(a, b) in &rows {
                let (head, tail) = rest.split_at_mut(b - a);
                slices.push(head);
                rest = tail;
            }
            let rho = &mut self.rho;
            slices.into_par_iter().zip(rho.par_iter_mut()).enumerate().for_each(|(i, (g, r))| {
                let mut sum = m * k.w(zero);
                for (gij, &j) in g.iter_mut().zip(nl.neighbors(i)) {
                    let j = j as usize;
                    let d = [x[i][0] - x[j][0], x[i][1] - x[j][1]];
                    let rr = (d[0] * d[0] + d[1] * d[1]).sqrt();
                    let (w, dw) = k.w_dw(rr);
                    sum += m * w;
                    *gij = if rr > zero { [dw / rr * d[0], dw / rr * d[1]] } else { [zero; 2] };
                }
                *r = sum;
            });
        }
        let (rho, grads, v, stencil) = (&self.rho, &self.grads, &self.v, &self.walls);
        let grad_row = |i: usize| &grads[nl.offsets[i]..nl.offsets[i + 1]];
        // Non-pressure forces -> advected velocity.
        let (g, nu, eps) = (self.gravity.map(c), c(self.params.nu), c(0.01) * h * h);
        let (dt_t, viscous) = (c(dt), self.params.nu > 0.0);
        // No-slip wall velocities for the viscous term (Adami et al. 2012, crate::walls).
        let mut wall_v = Vec::new();
        if viscous {
            stencil.no_slip_velocity(v, &mut wall_v);
        }
        let v_adv: Vec<[T; 2]> = (0..nf)
            .into_par_iter()
            .map(|i| {
                let mut a = g;
                if viscous {
                    for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                        let j = j as usize;
                        let vj = if j < nf { v[j] } else { wall_v[j - nf] };
                        let rj = if j < nf { rho[j] } else { rho0 };
                        let d = [x[i][0] - x[j][0], x[i][1] - x[j][1]];
                        let vx = (v[i][0] - vj[0]) * d[0] + (v[i][1] - vj[1]) * d[1];
                        let cv = c(8.0) * nu * (m / rj) * vx / (d[0] * d[0] + d[1] * d[1] + eps);
                        a[0] += cv * gw[0];
                        a[1] += cv * gw[1];
                    }
                }
                [v[i][0] + dt_t * a[0], v[i][1] + dt_t * a[1]]
            })
            .collect();
        // Source term s_i = ρ0 - ρ*_i and diagonal a_ii. The density error already present
        // (ρ0 - ρ_i) is removed over the stable step, not over a shorter one: within a sliver
        // step dt it would need velocities ~ (ρ0 - ρ_i)/ρ0 dx/dt (a 1e-13 s step after rounding
        // in `run_until` blew a water column at rest up to 1e8 sqrt(gH)).
        let relax = (dt / limit).min(1.0);
        let (relax_t, dt2) = (c(relax), c(dt * dt));
        let (src, diag): (Vec<T>, Vec<T>) = (0..nf)
            .into_par_iter()
            .map(|i| {
                // sg = Σ_all m ∇W, sp = Σ_fluid m ∇W + 2 Σ_wall m ∇W (p_i's weight in a^p_i).
                let (mut div, mut sg, mut sp, mut sg2) = (zero, [zero; 2], [zero; 2], zero);
                for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                    let j = j as usize;
                    let vj = if j < nf { v_adv[j] } else { [zero; 2] };
                    div += m * ((v_adv[i][0] - vj[0]) * gw[0] + (v_adv[i][1] - vj[1]) * gw[1]);
                    sg[0] += m * gw[0];
                    sg[1] += m * gw[1];
                    let w = if j < nf { T::one() } else { c(2.0) };
                    sp[0] += w * m * gw[0];
                    sp[1] += w * m * gw[1];
                    if j < nf {
                        sg2 += m * (gw[0] * gw[0] + gw[1] * gw[1]);
                    }
                }
                let ri2 = rho[i] * rho[i];
                // a_ii: p_i's coefficient in (Ap)_i = dt² Σ_f m (a^p_i - a^p_j)·∇W + dt² Σ_b m a^p_i·∇W,
                // with a^p_i ∋ -p_i/ρ_i² sp and a^p_j ∋ +m p_i/ρ_i² ∇W_ij.
                let aii = -dt2 / ri2 * (sp[0] * sg[0] + sp[1] * sg[1]) - dt2 * m / ri2 * sg2;
                (relax_t * (rho0 - rho[i]) - dt_t * div, aii)
            })
            .unzip();
        // Relaxed Jacobi.
        let omega = c(self.params.omega);
        let warm = c(self.warm);
        let mut p: Vec<T> = self.p.iter().map(|&pi| warm * pi).collect();
        let mut ap = vec![[zero; 2]; nf];
        // Wall pressures extrapolated from the fluid (Adami et al. 2012; Band et al. 2018 for
        // IISPH): p_b = Σ_f (p_f + ρ_f g·(x_b - x_f)) W_bf / Σ_f W_bf, clamped at 0.
        let wall_pressure = |p: &[T]| -> Vec<T> {
            let mut pw = Vec::new();
            stencil.pressure(p, rho, g, &mut pw);
            pw
        };
        let pressure_acc = |p: &[T], ap: &mut [[T; 2]]| {
            let pw = wall_pressure(p);
            let r02 = rho0 * rho0;
            ap.par_iter_mut().enumerate().for_each(|(i, a)| {
                let pi = p[i] / (rho[i] * rho[i]);
                let mut acc = [zero; 2];
                for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                    let j = j as usize;
                    let c = if j < nf { m * (pi + p[j] / (rho[j] * rho[j])) } else { m * (pi + pw[j - nf] / r02) };
                    acc[0] -= c * gw[0];
                    acc[1] -= c * gw[1];
                }
                *a = acc;
            });
        };
        let mut stats = SolveStats::default();
        let mut converged = false;
        for it in 1..=self.params.max_iterations {
            pressure_acc(&p, &mut ap);
            let (new_p, err): (Vec<T>, Vec<T>) = (0..nf)
                .into_par_iter()
                .map(|i| {
                    let mut s = zero;
                    for (gw, &j) in grad_row(i).iter().zip(nl.neighbors(i)) {
                        let j = j as usize;
                        let aj = if j < nf { ap[j] } else { [zero; 2] };
                        s += m * ((ap[i][0] - aj[0]) * gw[0] + (ap[i][1] - aj[1]) * gw[1]);
                    }
                    let apv = dt2 * s;
                    let dev = apv - src[i]; // ρ*_i + (Ap)_i - ρ0
                    let e = if p[i] > zero { dev.abs() } else { dev.fmax(zero) };
                    let pn = if diag[i] < zero { (p[i] + omega * (src[i] - apv) / diag[i]).fmax(zero) } else { zero };
                    (pn, e)
                })
                .unzip();
            // Summed in f64: the tolerance is a mean over all fluid particles.
            let avg = err.iter().map(|&e| e.wide()).sum::<f64>() / (nf.max(1) as f64 * self.rho0);
            stats = SolveStats { iterations: it, density_error: avg };
            if !avg.is_finite() {
                return Err(Error::NonFinite { what: "pressure", index: 0, step: self.steps });
            }
            if it >= 2 && avg <= self.params.tolerance {
                converged = true;
                break;
            }
            p = new_p;
        }
        if !converged {
            return Err(Error::SolverNotConverged {
                solver: "IISPH pressure (relaxed Jacobi)",
                iterations: stats.iterations,
                residual: stats.density_error,
                tolerance: self.params.tolerance,
                step: self.steps,
            });
        }
        pressure_acc(&p, &mut ap);
        for i in 0..nf {
            for d in 0..2 {
                self.v[i][d] = v_adv[i][d] + dt_t * ap[i][d];
                self.x[i][d] += dt_t * self.v[i][d];
            }
        }
        // Impermeable walls, v·n >= 0 on the surface (see the module docs and
        // crate::walls::enforce_container).
        if self.x.len() > nf {
            let fix = walls::enforce_container(&mut self.x, &mut self.v, nf, self.container);
            self.wall_corrections += fix.corrections;
            self.max_penetration = self.max_penetration.max(fix.depth);
        }
        if let Some(i) = (0..nf).find(|&i| !(self.x[i][0].is_finite() && self.x[i][1].is_finite())) {
            return Err(Error::NonFinite { what: "position", index: i, step: self.steps });
        }
        self.p = p;
        // Pressure scales as 1/dt for a given impulse: a short step's pressure, warm-started
        // as it is, would be far too large for the next (stable) step.
        self.warm = 0.5 * relax;
        self.stats = stats;
        self.total_iterations += stats.iterations as u64;
        self.time += dt;
        self.steps += 1;
        Ok(())
    }

    /// How often (particle and axis) a fluid centre crossed the container surface and was put
    /// back onto it by the impermeability condition, over all steps (0 when there are no walls).
    pub fn wall_corrections(&self) -> u64 {
        self.wall_corrections
    }

    /// The deepest crossing of the container surface before that correction, over all steps
    /// (0 when none happened). Above `dx / 2` a centre would have passed the first wall layer.
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
                            let d = [x[i][0] - x[j][0], x[i][1] - x[j][1]];
                            m * k.w((d[0] * d[0] + d[1] * d[1]).sqrt())
                        })
                        .sum::<T>()
            })
            .collect())
    }

    /// Average compression `mean_i max(ρ_i/ρ0 - 1, 0)` of the summation densities at the
    /// current positions (free-surface particles with missing neighbours do not count as
    /// error; compression does), summed in `f64`.
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

impl DamBreak {
    /// The dam break with the incompressible IISPH stepper (`c0_factor` is not used), at rest
    /// with the hydrostatic pressure `ρ0 g (H - y)` as the first pressure guess (the WCSPH
    /// dam break starts hydrostatic too).
    ///
    /// Errors: as [`DamBreak::build`], and bad [`IisphParams`].
    pub fn build_iisph(&self, params: IisphParams) -> Result<Iisph> {
        self.build_iisph_as::<f64>(params)
    }

    /// As [`DamBreak::build_iisph`] in precision `T` (`f32` or `f64`): the layout and the
    /// hydrostatic pressure are computed in `f64` and rounded once.
    ///
    /// Errors: as [`DamBreak::build_iisph`].
    pub fn build_iisph_as<T: Real>(&self, params: IisphParams) -> Result<Iisph<T>> {
        params.validate()?;
        let support = params.kernel.support_factor() * params.h_over_dx;
        let lay = self.layout(support, self.wall_layers)?;
        let p0 = lay.x[..lay.n_fluid].iter().map(|x| T::c(self.rho0 * self.g * (lay.height - x[1]).max(0.0))).collect();
        let cast = |p: [f64; 2]| p.map(T::c);
        let domain = Domain { lo: cast(lay.domain.lo), hi: cast(lay.domain.hi), periodic: lay.domain.periodic };
        let mut sim = Iisph::new(
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

/// Adaptive stepping in equal steps: [`Evolve::run_until`] splits the time left into equal steps
/// no longer than the stable `dt` ([`Iisph::stable_dt`], re-evaluated each step) with
/// [`equal_steps_dt`], so that no sliver step is left at the end (see [`Iisph::step`]; a
/// rounding remainder may still give one, which `step` handles).
impl<T: Real> Evolve for Iisph<T> {
    type Error = Error;

    fn time(&self) -> f64 {
        self.time
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn stable_dt(&self) -> f64 {
        Iisph::stable_dt(self)
    }

    fn step(&mut self, dt: f64) -> Result<()> {
        Iisph::step(self, dt)
    }

    fn next_dt(&self, t_end: f64) -> f64 {
        equal_steps_dt(self.time, t_end, Iisph::stable_dt(self))
    }
}
