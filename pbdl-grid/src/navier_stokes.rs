//! Incompressible Navier-Stokes on a MAC grid: central flux-form advection, explicit viscosity,
//! a projection after every Runge-Kutta stage.
//!
//! A [`NavierStokes`] stepper is *built* once from a grid, boundaries and a
//! [`NavierStokesConfig`]: it factors the pressure matrix (or plans the FFT) and keeps only the
//! operators the configuration needs (no viscous term at `nu = 0`); [`NavierStokes::operators`]
//! lists them. It is a [`pbdl_core::stepper::Stepper`] (state: the [`MacField`] velocity).

use crate::advect::MomentumRhs;
use crate::field::MacField;
use crate::pressure::{PressureSolver, Projection};
use crate::stability::{check_nu, check_time_step, stable_time_step, StabilityReport};
use crate::time_stepping::fused::fused_projected_runge_kutta;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau, Scheme};
use crate::{Boundaries, Error, Grid, Result};
use candle_core::{CpuStorage, Tensor};
use pbdl_core::stepper::{Differentiability, Stepper};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Physical and numerical parameters of a Navier-Stokes stepper, 2D ([`NavierStokes`]) or 3D
/// ([`crate::grid3d::NavierStokes3d`], [`crate::grid3d::Cavity3d`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavierStokesConfig {
    /// Kinematic viscosity (>= 0; 0 builds an inviscid stepper without the viscous operator).
    pub nu: f64,
    /// Time step.
    pub dt: f64,
    /// Runge-Kutta scheme. Default: RK4.
    #[serde(default)]
    pub scheme: Scheme,
}

impl NavierStokesConfig {
    /// Checks the viscosity and the scheme; returns the scheme's tableau.
    pub(crate) fn tableau(&self) -> Result<ButcherTableau> {
        check_nu(self.nu)?;
        let tableau = self.scheme.tableau();
        tableau.validate()?;
        Ok(tableau)
    }

    /// The operator list of a stepper with these parameters: advection, the viscous term when
    /// `nu > 0`, the pressure solve, the time scheme.
    pub(crate) fn operators(
        &self,
        advect: &'static str,
        diffuse: &'static str,
        pressure: &'static str,
    ) -> Vec<&'static str> {
        let mut operators = vec![advect];
        if self.nu > 0.0 {
            operators.push(diffuse);
        }
        operators.extend([pressure, self.scheme.operator_name()]);
        operators
    }
}

/// A built Navier-Stokes stepper.
pub struct NavierStokes {
    grid: Grid,
    bc: Boundaries,
    config: NavierStokesConfig,
    tableau: ButcherTableau,
    rhs: MomentumRhs,
    projection: Projection,
    solver: Arc<PressureSolver>,
    operators: Vec<&'static str>,
}

impl std::fmt::Debug for NavierStokes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NavierStokes")
            .field("grid", &self.grid)
            .field("config", &self.config)
            .field("operators", &self.operators)
            .finish()
    }
}

impl NavierStokes {
    /// Builds the stepper: validates the parameters, refuses a `dt` beyond the diffusive limit,
    /// and builds the pressure solver.
    pub fn new(grid: Grid, bc: Boundaries, config: NavierStokesConfig) -> Result<Self> {
        grid.validate()?;
        bc.validate()?;
        let tableau = config.tableau()?;
        check_time_step(&grid, [0.0, 0.0], config.nu, &tableau, config.dt)?;
        let solver = PressureSolver::new(grid, &bc)?;
        let projection = Projection::new(grid, &bc, &solver)?;
        let rhs = MomentumRhs { grid, ghosts: bc.mac_ghosts(grid.nx, grid.ny), advect: true, nu: config.nu };
        let pressure = if solver.method_name() == "fft" { "pressure.fft" } else { "pressure.sparse_cholesky" };
        let operators = config.operators("advect.flux_form", "diffuse.explicit", pressure);
        Ok(Self { grid, bc, config, tableau, rhs, projection, solver, operators })
    }

    /// The operators this stepper runs, e.g. `["advect.flux_form", "diffuse.explicit",
    /// "pressure.fft", "time_stepping.rk4"]`.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The configuration.
    pub fn config(&self) -> &NavierStokesConfig {
        &self.config
    }

    /// The pressure solver (shared).
    pub fn solver(&self) -> &Arc<PressureSolver> {
        &self.solver
    }

    /// The largest stable time step for a velocity with the given largest speeds `[|u|, |v|]`.
    pub fn stable_time_step(&self, max_speed: [f64; 2]) -> f64 {
        stable_time_step(&self.grid, max_speed, self.config.nu, &self.tableau)
    }

    /// Projects `u` onto divergence-free fields (use once on an initial condition).
    pub fn project(&self, u: &MacField) -> Result<MacField> {
        self.check_field(u)?;
        Ok(MacField::from_parts(self.projection.apply(u.values())?, self.grid, self.bc))
    }

    /// Checks that `dt` is stable for `u`; returns the CFL and diffusion numbers.
    pub fn check(&self, u: &MacField) -> Result<StabilityReport> {
        check_time_step(&self.grid, max_abs_components(u.values())?, self.config.nu, &self.tableau, self.config.dt)
    }

    /// One time step. Refuses (typed error) when `dt` is unstable for `u` or `u` is not finite.
    pub fn step(&self, u: &MacField) -> Result<MacField> {
        self.check_field(u)?;
        self.check(u)?;
        self.step_unchecked(u)
    }

    /// One time step without the stability check (for callers that check every few steps).
    ///
    /// Same numbers as [`projected_runge_kutta`] with this stepper's operators, but each stage's
    /// linear combination is fused with its projection (fewer temporaries per step).
    pub fn step_unchecked(&self, u: &MacField) -> Result<MacField> {
        let rhs = |x: &Tensor| Ok(self.rhs.apply(x)?);
        let out = fused_projected_runge_kutta(u.values(), self.config.dt, &self.tableau, rhs, &self.projection)?;
        Ok(MacField::from_parts(out, self.grid, self.bc))
    }

    /// The same step through the generic [`projected_runge_kutta`] (unfused; for cross-checks).
    pub fn step_reference(&self, u: &MacField) -> Result<MacField> {
        let out = projected_runge_kutta(
            u.values(),
            self.config.dt,
            &self.tableau,
            |x| Ok(self.rhs.apply(x)?),
            |x| Ok(self.projection.apply(x)?),
        )?;
        Ok(MacField::from_parts(out, self.grid, self.bc))
    }

    fn check_field(&self, u: &MacField) -> Result<()> {
        if u.grid() != &self.grid || u.bc() != &self.bc {
            return Err(Error::Invalid {
                field: "u",
                reason: format!(
                    "the field lives on {:?} with {:?}; the stepper was built for {:?} with {:?}",
                    u.grid(),
                    u.bc(),
                    self.grid,
                    self.bc
                ),
            });
        }
        Ok(())
    }
}

/// [`NavierStokes`] as a [`pbdl_core::stepper::Stepper`]: state in, state out, for code that is
/// generic over simulators (rollouts, solver-in-the-loop training). [`Stepper::step`] is
/// [`NavierStokes::step`] (checked); every operator has a hand-written adjoint, so gradients flow
/// through a rollout.
///
/// ```
/// use candle_core::DType;
/// use pbdl_core::stepper::{Differentiability, Stepper};
/// use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
/// use std::f64::consts::PI;
///
/// let (grid, bc) = (Grid::new(16, 16, 2.0 * PI, 2.0 * PI)?, Boundaries::periodic());
/// let config = NavierStokesConfig { nu: 0.01, dt: 0.05, scheme: Scheme::Rk4 };
/// let ns = NavierStokes::new(grid, bc, config)?;
/// let u0 = MacField::from_fn(grid, bc, DType::F64, |x, y| [x.sin() * y.cos(), -x.cos() * y.sin()])?;
/// let states = ns.rollout(&ns.project(&u0)?, 4)?; // the start and 4 steps
/// assert_eq!(states.len(), 5);
/// assert_eq!(Stepper::operators(&ns), ns.operators());
/// assert_eq!(ns.differentiability(), Differentiability::Full);
/// # Ok::<(), pbdl_grid::Error>(())
/// ```
impl Stepper for NavierStokes {
    type State = MacField;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config.dt
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    /// Full: flux-form advection, the fused combine-and-project and the projection all have
    /// hand-written adjoints.
    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }

    fn step(&self, u: &MacField) -> Result<MacField> {
        NavierStokes::step(self, u)
    }
}

/// `[max |u|, max |v|]` over a `[batch, 2, ny, nx]` tensor, read in place (no copy); NaN/Inf
/// propagate as a non-finite result.
pub fn max_abs_components(t: &Tensor) -> Result<[f64; 2]> {
    let t = if t.is_contiguous() { t.clone() } else { t.contiguous()? };
    let (b, c, ny, nx) = t.dims4()?;
    let n = ny * nx;
    let (storage, layout) = t.storage_and_layout();
    let start = layout.start_offset();
    let mut m = [0.0f64; 2];
    let mut bad = None;
    // Branch-free over 8 lanes so that it vectorises: `x * 0` is 0 for finite x and NaN for
    // Inf/NaN, so a non-finite value shows up in the `poison` sums; the first one is then
    // looked up (the error path only).
    fn scan<T: pbdl_core::Real + Into<f64>>(s: &[T], m: &mut f64, bad: &mut Option<f64>) {
        let (mut mx, mut poison) = ([T::zero(); 8], [T::zero(); 8]);
        let chunks = s.chunks_exact(8);
        let tail = chunks.remainder();
        for c in chunks {
            for k in 0..8 {
                let a = c[k].abs();
                mx[k] = if a > mx[k] { a } else { mx[k] };
                poison[k] += c[k] * T::zero();
            }
        }
        for (k, &x) in tail.iter().enumerate() {
            let a = x.abs();
            mx[k] = if a > mx[k] { a } else { mx[k] };
            poison[k] += x * T::zero();
        }
        if poison.iter().any(|p| !p.is_finite() || *p != T::zero()) {
            *bad = s.iter().map(|&x| x.into()).find(|x: &f64| !x.is_finite());
            return;
        }
        *m = mx.iter().fold(*m, |a, &x| a.max(x.into()));
    }
    for bi in 0..b {
        for ci in 0..c.min(2) {
            let off = start + (bi * c + ci) * n;
            match &*storage {
                candle_core::Storage::Cpu(CpuStorage::F32(v)) => scan(&v[off..off + n], &mut m[ci], &mut bad),
                candle_core::Storage::Cpu(CpuStorage::F64(v)) => scan(&v[off..off + n], &mut m[ci], &mut bad),
                _ => {
                    drop(storage);
                    let a = t
                        .abs()?
                        .max_keepdim(3)?
                        .max_keepdim(2)?
                        .max_keepdim(0)?
                        .flatten_all()?
                        .to_dtype(candle_core::DType::F64)?
                        .to_vec1::<f64>()?;
                    return Ok([a[0], a.get(1).copied().unwrap_or(0.0)]);
                }
            }
        }
    }
    if let Some(value) = bad {
        return Err(Error::NonFinite { what: "velocity", value });
    }
    Ok(m)
}
