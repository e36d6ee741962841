//! A stepper for smoke and obstacle flows: Lagrangian-type advection, optional density with
//! buoyancy and inflow, optional implicit viscosity, obstacles, pressure projection.
//!
//! One step (PhiFlow's smoke-plume order):
//! 1. density: advect (MacCormack by default; [`Advection::Conservative`] for mass conserved to
//!    round-off), add the inflow `dt * rate * mask`;
//! 2. velocity: advect by itself (MacCormack by default), add `dt * buoyancy(density)`;
//! 3. implicit viscosity `(I - nu dt L)^-1` when `nu > 0`;
//! 4. velocity source (e.g. an inlet profile), when one was given;
//! 5. projection: FFT / sparse Cholesky, or the masked Cholesky when there are obstacles.
//!
//! [`Fluid::with_options`] adds, through [`FluidOptions`], a no-slip treatment of curved
//! obstacle surfaces better than the staircase mask ([`ObstacleTreatment::ImmersedBoundary`]: a
//! direct-forcing immersed boundary, second order in the wall position, alternated with the
//! projection) and an inflow profile ([`InflowProfile::Parabolic`], held on the `u` faces at
//! `x = dx`).
//!
//! A [`Fluid`] is *built* once from a [`FluidConfig`] and holds only what it needs: no density
//! operators without density, no diffusion solve at `nu = 0`, no mask without obstacles;
//! [`Fluid::operators`] lists them. Semi-Lagrangian and MacCormack advection (the limiter keeps
//! it bounded), conservative density transport (sub-cycled to its CFL limit) and backward-Euler
//! diffusion are unconditionally stable, so
//! [`Fluid::stable_time_step`] is infinite for them; [`Fluid::cfl`] reports the CFL number for
//! accuracy control. [`Advection::CentralRk4`] replaces steps 2-3 for the velocity by the
//! second-order central flux form with explicit viscosity and RK4 (a projection, with the
//! velocity source, after every stage): no numerical diffusion, an RK4 time-step limit that
//! every step checks (typed [`Error::Unstable`]). Every part is differentiable (hand-written adjoints), including with respect to the
//! inflow rate and the initial state.

use crate::advect::{conservative, mac_cormack, semi_lagrangian, Advected, MomentumRhs};
use crate::boundary::InflowProfile;
use crate::diffuse::ImplicitDiffusion;
use crate::field::{CenteredField, MacField};
use crate::forcing::{buoyancy, DensitySource, VelocitySource};
use crate::navier_stokes::max_abs_components;
use crate::obstacle::{ImmersedBoundary, Obstacle, ObstacleMask, ObstacleTreatment};
use crate::pressure::{MaskedPressureSolver, MaskedProjection, PressureSolver, Projection};
use crate::stability::{check_time_step, stable_time_step};
use crate::time_stepping::projected_runge_kutta;
use crate::{Boundaries, ButcherTableau, Error, Grid, Result, ScalarBoundaries};
use candle_core::Tensor;
use serde::{Deserialize, Serialize};

/// Advection scheme of the [`Fluid`] stepper.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Advection {
    /// First-order semi-Lagrangian.
    SemiLagrangian,
    /// MacCormack with the Selle et al. (2008) limiter (default).
    #[default]
    MacCormack,
    /// Velocity only: second-order central flux form with explicit viscosity, classic RK4 with
    /// a projection after every stage (no numerical diffusion, but a stable time step that
    /// [`Fluid::step`] checks).
    CentralRk4,
    /// Density only: finite-volume flux form with flux-corrected transport
    /// ([`crate::advect::conservative()`]): the density's mass changes only by the inflow (to
    /// round-off), no new extrema for the projected velocity, second order where smooth,
    /// sub-cycled internally to its CFL limit (no time-step limit for the stepper).
    Conservative,
}

/// Parameters of a [`Fluid`] stepper. Optional parts are `None` / empty.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidConfig {
    /// Time step (> 0; no stability limit, but keep the CFL number moderate for accuracy).
    pub dt: f64,
    /// Kinematic viscosity (>= 0; 0 builds no diffusion solve). Default 0.
    #[serde(default)]
    pub nu: f64,
    /// Velocity advection. Default MacCormack.
    #[serde(default)]
    pub advection: Advection,
    /// Density advection (`semi_lagrangian`, `mac_cormack`, `conservative`). Default MacCormack.
    #[serde(default)]
    pub density_advection: Advection,
    /// Boussinesq coefficient `beta` (force `beta rho` along +y); needs a density.
    #[serde(default)]
    pub buoyancy: Option<f64>,
    /// Density inflow region (rate given per step, see [`Fluid::step`]); needs a density.
    #[serde(default)]
    pub inflow: Option<Obstacle>,
    /// Static obstacles.
    #[serde(default)]
    pub obstacles: Vec<Obstacle>,
}

/// Options of a [`Fluid`] beyond [`FluidConfig`] ([`Fluid::with_options`]); the default is what
/// [`Fluid::new`] builds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidOptions {
    /// How the obstacle surfaces are treated. Default: the staircase mask.
    #[serde(default)]
    pub obstacle_treatment: ObstacleTreatment,
    /// Inflow profile at `x = 0`. Default: uniform (the `x_lo` condition). A profile turns the
    /// first cell column into a solid buffer and holds the profile on the `u` faces at
    /// `x = dx`: the inflow plane is `x = dx` (see [`InflowProfile`]); `x_lo` must then be a
    /// wall or an inflow (its values no longer reach the fluid).
    #[serde(default)]
    pub inflow_profile: InflowProfile,
}

/// The state a [`Fluid`] advances.
#[derive(Clone, Debug)]
pub struct FluidState {
    /// MAC velocity.
    pub velocity: MacField,
    /// Advected scalar (smoke density), when the stepper has one.
    pub density: Option<CenteredField>,
}

enum Proj {
    Plain(Box<Projection>),
    Masked(MaskedProjection),
}

/// A built smoke / obstacle-flow stepper.
pub struct Fluid {
    grid: Grid,
    bc: Boundaries,
    density_bc: Option<ScalarBoundaries>,
    config: FluidConfig,
    rhs: Option<MomentumRhs>,
    viscosity: Option<ImplicitDiffusion>,
    source: Option<DensitySource>,
    velocity_source: Option<VelocitySource>,
    mask: Option<ObstacleMask>,
    projection: Proj,
    /// The immersed-boundary forcing and its number of forcing / projection pairs.
    immersed: Option<(ImmersedBoundary, usize)>,
    options: FluidOptions,
    operators: Vec<&'static str>,
}

impl std::fmt::Debug for Fluid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fluid")
            .field("grid", &self.grid)
            .field("config", &self.config)
            .field("operators", &self.operators)
            .finish()
    }
}

impl Fluid {
    /// Builds the stepper. `density_bc` is `Some` when the flow carries a density (required by
    /// buoyancy and inflow). Factors the pressure matrix (masked with obstacles) and, when
    /// `nu > 0`, the implicit viscosity matrices.
    pub fn new(grid: Grid, bc: Boundaries, density_bc: Option<ScalarBoundaries>, config: FluidConfig) -> Result<Self> {
        Self::with_options(grid, bc, density_bc, config, FluidOptions::default())
    }

    /// [`Fluid::new`] with [`FluidOptions`]: an immersed-boundary treatment of the obstacles
    /// (the pressure solve then covers the obstacles too) and / or an inflow profile (the first
    /// cell column then leaves the pressure solve and the `u` faces at `x = dx` carry the
    /// profile).
    pub fn with_options(
        grid: Grid,
        bc: Boundaries,
        density_bc: Option<ScalarBoundaries>,
        config: FluidConfig,
        options: FluidOptions,
    ) -> Result<Self> {
        grid.validate()?;
        bc.validate()?;
        if let Some(d) = &density_bc {
            d.validate()?;
        }
        if !(config.dt > 0.0 && config.dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("time step must be positive and finite, got {}", config.dt),
            });
        }
        if !(config.nu >= 0.0 && config.nu.is_finite()) {
            return Err(Error::Invalid {
                field: "nu",
                reason: format!("viscosity must be finite and >= 0, got {}", config.nu),
            });
        }
        if config.density_advection == Advection::CentralRk4 {
            return Err(Error::Invalid {
                field: "density_advection",
                reason: "central_rk4 is for the velocity; use semi_lagrangian, mac_cormack or conservative for the \
                         density"
                    .into(),
            });
        }
        if config.advection == Advection::Conservative {
            return Err(Error::Invalid {
                field: "advection",
                reason: "conservative transport is for the density (a cell-centred scalar); use semi_lagrangian, \
                         mac_cormack or central_rk4 for the velocity"
                    .into(),
            });
        }
        if density_bc.is_none() && (config.buoyancy.is_some() || config.inflow.is_some()) {
            return Err(Error::Invalid {
                field: "density",
                reason: "buoyancy and inflow act on a density; give density boundaries or drop them".into(),
            });
        }
        if let Some(b) = config.buoyancy {
            if !b.is_finite() {
                return Err(Error::Invalid { field: "buoyancy", reason: format!("must be finite, got {b}") });
            }
        }
        let mut operators = Vec::new();
        let name = |a: Advection, what: &str| match (a, what) {
            (Advection::SemiLagrangian, "density") => "advect.semi_lagrangian(density)",
            (Advection::MacCormack, "density") => "advect.mac_cormack(density)",
            (Advection::SemiLagrangian, _) => "advect.semi_lagrangian(velocity)",
            (Advection::MacCormack, _) => "advect.mac_cormack(velocity)",
            (Advection::CentralRk4, _) => "advect.flux_form(velocity)",
            // Refused above for the velocity.
            (Advection::Conservative, _) => "advect.conservative(density)",
        };
        if density_bc.is_some() {
            operators.push(name(config.density_advection, "density"));
        }
        let source = match config.inflow {
            Some(shape) => {
                operators.push("source.inflow");
                Some(DensitySource::new(grid, shape)?)
            }
            None => None,
        };
        operators.push(name(config.advection, "velocity"));
        if config.buoyancy.is_some() {
            operators.push("buoyancy");
        }
        let central = config.advection == Advection::CentralRk4;
        let rhs = if central {
            Some(MomentumRhs { grid, ghosts: bc.mac_ghosts(grid.nx, grid.ny), advect: true, nu: config.nu })
        } else {
            None
        };
        if central && config.nu > 0.0 {
            operators.push("diffuse.explicit");
        }
        let viscosity = if config.nu > 0.0 && !central {
            operators.push("diffuse.implicit");
            let like = MacField::zeros(grid, bc, 1, candle_core::DType::F64)?;
            Some(ImplicitDiffusion::new(&like, config.nu, config.dt)?)
        } else {
            None
        };
        let immersed = match options.obstacle_treatment {
            ObstacleTreatment::ImmersedBoundary { iterations } if !config.obstacles.is_empty() => {
                if iterations == 0 {
                    return Err(Error::Invalid {
                        field: "obstacle_treatment",
                        reason: "the immersed boundary needs at least 1 forcing / projection pair".into(),
                    });
                }
                operators.push("obstacles.immersed_boundary");
                Some((ImmersedBoundary::new(grid, &bc, &config.obstacles)?, iterations))
            }
            _ => None,
        };
        let staircase = if immersed.is_none() { config.obstacles.as_slice() } else { &[] };
        let profile: Option<Vec<f64>> = match options.inflow_profile {
            InflowProfile::Uniform => None,
            p => {
                if bc.x_lo == crate::Bc::Periodic || bc.x_lo == crate::Bc::Outflow {
                    return Err(Error::Invalid {
                        field: "inflow_profile",
                        reason: format!("an inflow profile needs a wall or an inflow at x_lo, got {:?}", bc.x_lo),
                    });
                }
                if let InflowProfile::Parabolic { max_velocity } = p {
                    if !max_velocity.is_finite() {
                        return Err(Error::Invalid {
                            field: "inflow_profile",
                            reason: format!("max_velocity must be finite, got {max_velocity}"),
                        });
                    }
                }
                if let InflowProfile::ParabolicBand { max_velocity, y_lo, y_hi } = p {
                    if !(max_velocity.is_finite() && y_lo.is_finite() && y_hi.is_finite() && y_lo < y_hi) {
                        return Err(Error::Invalid {
                            field: "inflow_profile",
                            reason: format!(
                                "parabolic band needs a finite max_velocity and y_lo < y_hi, got {max_velocity}, \
                                 [{y_lo}, {y_hi}]"
                            ),
                        });
                    }
                }
                operators.push("inflow.profile");
                let (nx, ny, dy) = (grid.nx, grid.ny, grid.dy());
                let mut b = vec![0.0; 2 * nx * ny];
                for j in 0..ny {
                    b[j * nx] = p.velocity((j as f64 + 0.5) * dy, grid.ly).unwrap_or(0.0);
                }
                Some(b)
            }
        };
        let (mask, projection) = if staircase.is_empty() && profile.is_none() {
            let solver = PressureSolver::new(grid, &bc)?;
            operators.push(if solver.method_name() == "fft" { "pressure.fft" } else { "pressure.sparse_cholesky" });
            (None, Proj::Plain(Box::new(Projection::new(grid, &bc, &solver)?)))
        } else {
            let mut solid = if staircase.is_empty() {
                vec![false; grid.cells()]
            } else {
                operators.push("obstacles");
                ObstacleMask::new(grid, staircase)?.solid_flags()
            };
            if profile.is_some() {
                for j in 0..grid.ny {
                    solid[j * grid.nx] = true;
                }
            }
            let mask = ObstacleMask::from_cells(grid, solid)?;
            operators.push("pressure.masked_cholesky");
            let solver = match &profile {
                Some(b) => MaskedPressureSolver::with_prescribed_faces(grid, &bc, &mask, b)?,
                None => MaskedPressureSolver::new(grid, &bc, &mask)?,
            };
            (Some(mask), Proj::Masked(MaskedProjection(solver)))
        };
        if central {
            operators.push("time_stepping.rk4");
        }
        Ok(Self {
            grid,
            bc,
            density_bc,
            config,
            rhs,
            viscosity,
            source,
            velocity_source: None,
            mask,
            projection,
            immersed,
            options,
            operators,
        })
    }

    /// The options it was built with.
    pub fn options(&self) -> &FluidOptions {
        &self.options
    }

    /// The immersed-boundary forcing, when the obstacles are treated that way.
    pub fn immersed_boundary(&self) -> Option<&ImmersedBoundary> {
        self.immersed.as_ref().map(|(ib, _)| ib)
    }

    /// Adds a velocity source (e.g. an inlet profile), applied before the projection.
    pub fn with_velocity_source(mut self, source: VelocitySource) -> Self {
        if self.velocity_source.is_none() {
            let at = self.operators.len() - 1 - usize::from(self.rhs.is_some());
            self.operators.insert(at, "source.velocity");
        }
        self.velocity_source = Some(source);
        self
    }

    /// The operators this stepper runs, in order, e.g. `["advect.mac_cormack(density)",
    /// "source.inflow", "advect.mac_cormack(velocity)", "buoyancy", "pressure.sparse_cholesky"]`.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The velocity boundary conditions.
    pub fn boundaries(&self) -> &Boundaries {
        &self.bc
    }

    /// The configuration.
    pub fn config(&self) -> &FluidConfig {
        &self.config
    }

    /// The mask of the cells out of the pressure solve: staircase obstacles and, with an inflow
    /// profile, the buffer column `0 < x < dx` (`None` when there are neither).
    pub fn mask(&self) -> Option<&ObstacleMask> {
        self.mask.as_ref()
    }

    /// The largest stable time step for the largest speeds `[|u|, |v|]`. Infinite for
    /// semi-Lagrangian and MacCormack velocity advection: every part is then unconditionally
    /// stable (both interpolate between old values, the limiter keeps MacCormack bounded;
    /// backward Euler damps every mode; the projection is an orthogonal projector), though
    /// accuracy degrades with the CFL number ([`Fluid::cfl`]). For
    /// [`Advection::CentralRk4`] the RK4 limit of [`crate::stability::stable_time_step`].
    pub fn stable_time_step(&self, max_speed: [f64; 2]) -> f64 {
        match self.rhs {
            Some(_) => stable_time_step(&self.grid, max_speed, self.config.nu, &ButcherTableau::rk4()),
            None => f64::INFINITY,
        }
    }

    /// `dt (max|u|/dx + max|v|/dy)` of a state (typed error when it is not finite).
    pub fn cfl(&self, state: &FluidState) -> Result<f64> {
        let m = max_abs_components(state.velocity.values())?;
        Ok(self.config.dt * (m[0] / self.grid.dx() + m[1] / self.grid.dy()))
    }

    /// A state at rest (density zero when the stepper has one), batch `batch`.
    pub fn rest(&self, batch: usize, dtype: candle_core::DType) -> Result<FluidState> {
        let velocity = MacField::zeros(self.grid, self.bc, batch, dtype)?;
        let density = match self.density_bc {
            Some(bc) => {
                let z = Tensor::zeros((batch, 1, self.grid.ny, self.grid.nx), dtype, &candle_core::Device::Cpu)?;
                Some(CenteredField::new(z, self.grid, bc)?)
            }
            None => None,
        };
        Ok(FluidState { velocity, density })
    }

    /// Projects a velocity (use once on an initial condition). With the immersed boundary, the
    /// forcing and the projection alternate `iterations` times (ending with a projection).
    pub fn project(&self, u: &MacField) -> Result<MacField> {
        let proj = |x: &Tensor| -> Result<Tensor> {
            Ok(match &self.projection {
                Proj::Plain(p) => p.apply(x)?,
                Proj::Masked(p) => p.apply(x)?,
            })
        };
        let v = match &self.immersed {
            Some((ib, iterations)) => {
                let mut v = u.values().clone();
                for _ in 0..*iterations {
                    v = proj(&ib.apply(&v)?)?;
                }
                v
            }
            None => proj(u.values())?,
        };
        Ok(MacField::from_parts(v, self.grid, self.bc))
    }

    /// One step. `inflow_rate` (a scalar tensor, or `[B, 1, 1, 1]`; differentiable) is required
    /// when the stepper has an inflow, and ignored otherwise.
    pub fn step(&self, state: &FluidState, inflow_rate: Option<&Tensor>) -> Result<FluidState> {
        let u = &state.velocity;
        if u.grid() != &self.grid || u.bc() != &self.bc {
            return Err(Error::Invalid {
                field: "velocity",
                reason: "lives on another grid or boundaries than the stepper".into(),
            });
        }
        let dt = self.config.dt;
        let density = self.transported_density(state, inflow_rate)?;
        // The force of the old density (explicit in time, as in PhiFlow's plume).
        let force = match (self.config.buoyancy, &state.density) {
            (Some(beta), Some(rho)) => Some(buoyancy(rho, &self.bc, beta)?.into_values()),
            _ => None,
        };
        if let Some(rhs) = &self.rhs {
            check_time_step(&self.grid, max_abs_components(u.values())?, self.config.nu, &ButcherTableau::rk4(), dt)?;
            let f = |x: &Tensor| -> Result<Tensor> {
                let k = rhs.apply(x)?;
                Ok(match &force {
                    Some(fv) => (k + fv)?,
                    None => k,
                })
            };
            let p = |x: &Tensor| -> Result<Tensor> {
                let x = match &self.velocity_source {
                    Some(src) => src.apply(&MacField::from_parts(x.clone(), self.grid, self.bc), None)?.into_values(),
                    None => x.clone(),
                };
                Ok(self.project(&MacField::from_parts(x, self.grid, self.bc))?.into_values())
            };
            let v = projected_runge_kutta(u.values(), dt, &ButcherTableau::rk4(), f, p)?;
            return Ok(FluidState { velocity: MacField::from_parts(v, self.grid, self.bc), density });
        }
        let v = self.velocity_before_projection(u, force.as_ref())?;
        Ok(FluidState { velocity: self.project(&v)?, density })
    }

    /// The density after transport and inflow (`None` without a density).
    fn transported_density(&self, state: &FluidState, inflow_rate: Option<&Tensor>) -> Result<Option<CenteredField>> {
        let (u, dt) = (&state.velocity, self.config.dt);
        Ok(match (&state.density, self.density_bc) {
            (Some(rho), Some(_)) => {
                let mut r = match self.config.density_advection {
                    Advection::Conservative => conservative(rho, u, dt)?,
                    scheme => advect(rho, u, dt, scheme)?,
                };
                if let Some(src) = &self.source {
                    let rate = inflow_rate.ok_or_else(|| Error::Invalid {
                        field: "inflow_rate",
                        reason: "the stepper has an inflow; pass its rate".into(),
                    })?;
                    r = src.apply(&r, rate, dt)?;
                }
                Some(r)
            }
            (None, None) => None,
            _ => {
                return Err(Error::Invalid {
                    field: "density",
                    reason: "the state's density does not match the stepper (built with density boundaries or not)"
                        .into(),
                })
            }
        })
    }

    /// Advection, buoyancy, viscosity and velocity source: the velocity before the projection.
    fn velocity_before_projection(&self, u: &MacField, force: Option<&Tensor>) -> Result<MacField> {
        let dt = self.config.dt;
        let mut v = advect(u, u, dt, self.config.advection)?;
        if let Some(f) = force {
            v = v.with_values((v.values() + f.affine(dt, 0.0)?)?)?;
        }
        if let Some(visc) = &self.viscosity {
            v = visc.apply(&v)?;
        }
        if let Some(src) = &self.velocity_source {
            v = src.apply(&v, None)?;
        }
        Ok(v)
    }

    /// The pressure split of [`Fluid::step`], for steppers that replace the pressure solve on
    /// some steps (latent-space physics): everything of one step before the projection
    /// (density transport and inflow, velocity advection, buoyancy, viscosity, velocity
    /// source). [`Fluid::step`] equals [`Fluid::project_keep_pressure`] of this state's velocity.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a stepper with more than one projection per step (central RK4
    /// velocity advection projects after every stage; the immersed boundary alternates forcing
    /// and projection), and as [`Fluid::step`].
    pub fn step_unprojected(&self, state: &FluidState, inflow_rate: Option<&Tensor>) -> Result<FluidState> {
        self.check_single_projection()?;
        let u = &state.velocity;
        if u.grid() != &self.grid || u.bc() != &self.bc {
            return Err(Error::Invalid {
                field: "velocity",
                reason: "lives on another grid or boundaries than the stepper".into(),
            });
        }
        let density = self.transported_density(state, inflow_rate)?;
        let force = match (self.config.buoyancy, &state.density) {
            (Some(beta), Some(rho)) => Some(buoyancy(rho, &self.bc, beta)?.into_values()),
            _ => None,
        };
        Ok(FluidState { velocity: self.velocity_before_projection(u, force.as_ref())?, density })
    }

    /// The projection of [`Fluid::step`] that also returns its pressure (cell-centred,
    /// `[B, 1, ny, nx]`, in the units of the solve: `u <- u - G p`, so `p` is the physical
    /// pressure times `dt / density`). Not differentiable.
    ///
    /// # Errors
    /// As [`Fluid::step_unprojected`]; [`Error::Invalid`] when `u` lives on another grid.
    pub fn project_keep_pressure(&self, u: &MacField) -> Result<(MacField, CenteredField)> {
        let (v, p) = match u.values().dtype() {
            candle_core::DType::F32 => self.pressure_split::<f32>(u, None)?,
            _ => self.pressure_split::<f64>(u, None)?,
        };
        Ok((v, p.expect("the solve returns its pressure")))
    }

    /// The velocity correction of [`Fluid::step`] with a given pressure (e.g. a predicted one)
    /// instead of a solve: `m u - m G p` (+ prescribed faces), the boundary faces set as the
    /// projection sets them. With the pressure of [`Fluid::project_keep_pressure`] it equals
    /// that projection. Not differentiable.
    ///
    /// # Errors
    /// As [`Fluid::project_keep_pressure`]; [`Error::Invalid`] when `pressure` is not
    /// `[B, 1, ny, nx]` for `u`'s batch `B`.
    pub fn correct_with_pressure(&self, u: &MacField, pressure: &CenteredField) -> Result<MacField> {
        let b = u.values().dims().first().copied().unwrap_or(0);
        let pd = pressure.values().dims();
        if pd != [b, 1, self.grid.ny, self.grid.nx] {
            return Err(Error::Invalid {
                field: "pressure",
                reason: format!("has shape {pd:?}; the velocity needs [{b}, 1, {}, {}]", self.grid.ny, self.grid.nx),
            });
        }
        Ok(match u.values().dtype() {
            candle_core::DType::F32 => self.pressure_split::<f32>(u, Some(pressure.values()))?.0,
            _ => self.pressure_split::<f64>(u, Some(pressure.values()))?.0,
        })
    }

    /// The projection in `T` (the velocity's dtype, so that it equals [`Fluid::step`]'s to the
    /// bit): with `given` the correction by that pressure, else the solve, returning its pressure.
    fn pressure_split<T: pbdl_core::Real>(
        &self,
        u: &MacField,
        given: Option<&Tensor>,
    ) -> Result<(MacField, Option<CenteredField>)> {
        self.check_single_projection()?;
        if u.grid() != &self.grid || u.bc() != &self.bc {
            return Err(Error::Invalid {
                field: "velocity",
                reason: "lives on another grid or boundaries than the stepper".into(),
            });
        }
        let (dev, dtype) = (u.values().device(), u.values().dtype());
        let shape = u.values().shape().clone();
        let x: Vec<T> = u.values().to_dtype(T::DTYPE)?.flatten_all()?.to_vec1::<T>()?;
        let b = shape.dims()[0];
        let mut out = vec![T::zero(); x.len()];
        let pressure = match given {
            Some(p) => {
                let p: Vec<T> = p.to_dtype(T::DTYPE)?.flatten_all()?.to_vec1::<T>()?;
                match &self.projection {
                    Proj::Plain(proj) => proj.correct(&x, &p, &mut out),
                    Proj::Masked(proj) => proj.correct(&x, &p, &mut out),
                }
                None
            }
            None => {
                let mut p = vec![T::zero(); b * self.grid.cells()];
                match &self.projection {
                    Proj::Plain(proj) => proj.project_keep_pressure(&x, &mut out, &mut p),
                    Proj::Masked(proj) => proj.project_keep_pressure(&x, &mut out, &mut p),
                }
                let p = Tensor::from_vec(p, (b, 1, self.grid.ny, self.grid.nx), dev)?.to_dtype(dtype)?;
                Some(CenteredField::new(p, self.grid, self.bc.pressure())?)
            }
        };
        let v = Tensor::from_vec(out, shape, dev)?.to_dtype(dtype)?;
        Ok((MacField::from_parts(v, self.grid, self.bc), pressure))
    }

    fn check_single_projection(&self) -> Result<()> {
        if self.rhs.is_some() || self.immersed.is_some() {
            return Err(Error::Invalid {
                field: "pressure split",
                reason: "this stepper projects more than once per step (central RK4 or immersed boundary); use \
                         semi_lagrangian or mac_cormack velocity advection and staircase obstacles"
                    .into(),
            });
        }
        Ok(())
    }
}

/// [`Fluid`] as a [`pbdl_core::stepper::Stepper`] (state: [`FluidState`]). Its
/// [`step`](pbdl_core::stepper::Stepper::step) is [`Fluid::step`] without an inflow rate: it fits
/// steppers without a density inflow (obstacle flows, a passive density); one built with an
/// inflow refuses (typed [`Error::Invalid`]), call [`Fluid::step`] with the rate instead.
impl pbdl_core::stepper::Stepper for Fluid {
    type State = FluidState;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config.dt
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    /// Full: every part has a hand-written adjoint (see the module docs).
    fn differentiability(&self) -> pbdl_core::stepper::Differentiability {
        pbdl_core::stepper::Differentiability::Full
    }

    fn step(&self, state: &FluidState) -> Result<FluidState> {
        Fluid::step(self, state, None)
    }
}

fn advect<F: Advected>(q: &F, u: &MacField, dt: f64, scheme: Advection) -> Result<F> {
    match scheme {
        Advection::SemiLagrangian => semi_lagrangian(q, u, dt),
        Advection::MacCormack => mac_cormack(q, u, dt),
        Advection::CentralRk4 => unreachable!("refused at build time for densities, handled in step for velocities"),
        Advection::Conservative => {
            unreachable!("refused at build time for velocities, handled in step for densities")
        }
    }
}
