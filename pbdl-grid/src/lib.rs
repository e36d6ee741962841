//! # pbdl-grid
//!
//! Differentiable Eulerian solvers on uniform 2D grids (and 3D: [`grid3d`]): fields whose staggering is in the type
//! and whose boundary conditions travel with them, finite-difference operators, advection,
//! diffusion and pressure projection as candle custom ops with hand-written adjoints, and an
//! incompressible Navier-Stokes stepper built from those parts.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`domain`] | [`Grid`]: cells, extent, spacing |
//! | [`boundary`] | [`Bc`] per face (periodic, no-slip, free-slip, moving wall, inflow, outflow), [`Boundaries`], [`ScalarBoundaries`] |
//! | [`field`] | [`CenteredField`], [`MacField`]: a tensor + grid + boundaries, staggering in the type |
//! | [`fd`] | [`fd::divergence`], [`fd::gradient`], [`fd::laplacian`] |
//! | [`advect`] | [`advect::flux_form`]: second-order central flux-form advection of a MAC velocity; [`advect::semi_lagrangian`], [`advect::mac_cormack`] for scalars and velocities; [`advect::conservative()`]: flux-corrected transport of scalars (mass to round-off, no new extrema) |
//! | [`diffuse`] | [`diffuse::explicit`]: viscous tendency `nu lap u`; [`diffuse::implicit`] / [`diffuse::ImplicitDiffusion`]: backward Euler, factored once |
//! | [`pressure`] | [`PressureSolver`] (FFT when periodic, sparse Cholesky factored once otherwise), [`pressure::make_incompressible`], [`pressure::solve_poisson`] |
//! | [`time_stepping`] | [`ButcherTableau`] as data (RK4, SSP-RK3, forward Euler), [`time_stepping::projected_runge_kutta`] |
//! | [`stability`] | [`stability::stable_time_step`], [`stability::check_time_step`] (typed [`Error::Unstable`]) |
//! | [`scalar_law`] | [`scalar_law::ScalarLaw`]: periodic 1D/2D viscous Burgers and advection-diffusion (conservative, second order, differentiable), [`scalar_law::cole_hopf_sine`] |
//! | [`scene`] | [`scene::Scene`]: TOML scenes (embedded defaults), built into a [`scene::Simulation`] that holds only the operators the scene needs (one file per physics kind behind one trait) |
//! | [`obstacle`] | [`Obstacle`] (cylinder, box), [`ObstacleMask`]; masked projection in [`pressure::make_incompressible_masked`]; [`obstacle::ImmersedBoundary`]: direct-forcing no-slip on curved surfaces (second order, [`obstacle::ObstacleTreatment`]) |
//! | [`forces`] | [`forces::ControlVolume`]: force of the fluid on the obstacles inside a rectangle (drag, lift) by a control-volume momentum balance (pressure recovered along the contour), [`forces::coefficients`] (`c_D`, `c_L`) |
//! | [`forcing`] | [`forcing::buoyancy`] (Boussinesq), [`forcing::DensitySource`], [`forcing::VelocitySource`] |
//! | [`fluid`] | [`Fluid`]: smoke plume / obstacle-flow stepper (semi-Lagrangian or MacCormack; conservative flux-corrected transport for the density, buoyancy, inflow, implicit viscosity, obstacles), listing its operators |
//! | [`spectral`] | [`spectral::SpectralNavierStokes`]: 2D pseudo-spectral Navier-Stokes for periodic boxes (vorticity form, 2/3 dealiasing, low-storage IMEX CN-RK4/RK3, f32/f64), a fast path and a differentiable one; scene kind `navier_stokes_spectral` |
//! | [`navier_stokes`] | [`NavierStokes`]: a stepper built from a config, listing its operators; a [`pbdl_core::stepper::Stepper`] (as are [`Fluid`] and [`grid3d::NavierStokes3d`]) |
//! | [`grid3d`] | 3D: [`grid3d::MacField3d`], flux-form advection, FFT projection (periodic) and MIC(0)-CG projection (walled box, [`grid3d::Cavity3d`]), [`grid3d::NavierStokes3d`] (RK4, projection per stage), the ABC exact solution |
//! | [`error`] | [`Error`], [`Result`] |
//! | [`diagnostics`] | kinetic energy, relative divergence, Strouhal number by zero crossings ([`diagnostics::strouhal_zero_crossings`]) or spectral peak ([`diagnostics::strouhal_spectral_peak`], [`diagnostics::dominant_frequency`]), [`diagnostics::track_invariants`] (first step at which an invariant breaks) |
//! | [`validation`] | published reference data: Ghia et al. (1982) cavity centrelines ([`validation::GhiaTable`], [`validation::cavity_centrelines`]) |
//!
//! Conventions: tensors `[batch, channel, ny, nx]`, x fastest, `f32` or `f64`. A MAC velocity has
//! two channels, `u` on x-faces at `((i+1) dx, (j+1/2) dy)` and `v` on y-faces at
//! `((i+1/2) dx, (j+1) dy)` (see [`boundary`] for boundary faces).
//!
//! ```
//! use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig};
//! let grid = Grid::square(32, 2.0 * std::f64::consts::PI)?;
//! let u = MacField::from_fn(grid, Boundaries::periodic(), candle_core::DType::F64, |x, y| {
//!     [x.sin() * y.cos(), -x.cos() * y.sin()]
//! })?;
//! let ns = NavierStokes::new(grid, Boundaries::periodic(), NavierStokesConfig { nu: 0.01, dt: 0.05, scheme: Default::default() })?;
//! let u1 = ns.step(&u)?;
//! assert!(pbdl_grid::fd::divergence(&u1)?.values().abs()?.max_all()?.to_scalar::<f64>()? < 1e-10);
//! # Ok::<(), pbdl_grid::Error>(())
//! ```
#![warn(missing_docs)]

pub mod advect;
pub mod boundary;
pub mod diagnostics;
pub mod diffuse;
pub mod domain;
pub mod error;
pub mod fd;
pub mod field;
mod float;
pub mod fluid;
pub mod forces;
pub mod forcing;
pub mod grid3d;
mod laplacian_matrix;
pub mod navier_stokes;
pub mod obstacle;
mod pad;
pub mod pressure;
pub mod scalar_law;
pub mod scene;
mod scratch;
pub mod spectral;
pub mod stability;
pub mod time_stepping;
pub mod validation;

pub use boundary::{Bc, Boundaries, ScalarBc, ScalarBoundaries};
pub use domain::Grid;
pub use error::{Error, Result};
pub use field::{Centered, CenteredField, Field, Mac, MacField, Staggering};
pub use fluid::{Fluid, FluidConfig, FluidState};
pub use navier_stokes::{NavierStokes, NavierStokesConfig};
pub use obstacle::{Obstacle, ObstacleMask};
pub use pressure::PressureSolver;
pub use time_stepping::{ButcherTableau, Scheme};
