//! Incompressible flow on periodic 3D grids: the 3D counterpart of the 2D solver, self-contained.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`domain`] | [`Grid3d`]: cells, extent, spacing |
//! | [`field`] | [`MacField3d`]: a periodic staggered velocity `[batch, 3, nz, ny, nx]` |
//! | [`fd`] | [`fd::divergence`], [`fd::gradient`] (each the other's negative adjoint) |
//! | [`momentum`] | [`momentum::flux_form`] (second-order central flux-form advection), [`momentum::viscous`], [`momentum::momentum_rhs`]: one fused custom op with a hand-written adjoint |
//! | [`pressure`] | [`PoissonFft3d`] (planned once), [`pressure::make_incompressible`] (self-adjoint), [`pressure::solve_poisson`] |
//! | [`stability`] | [`stability::stable_time_step`], [`stability::check_time_step`] in 3D |
//! | [`navier_stokes`] | [`NavierStokes3d`]: RK4 (or SSP-RK3) with a projection per stage, listing its operators |
//! | [`abc`] | [`abc::abc_flow`]: the Arnold-Beltrami-Childress exact solution, for accuracy tests |
//! | [`walls`] | [`CavityWalls`]: a closed box with no-slip walls and a sliding lid; ghost rules; [`walls::momentum_rhs_walls`] |
//! | [`cg`] | [`CgBox3d`]: MIC(0)-preconditioned CG on the seven-point Neumann Laplacian (cold or warm start), [`cg::make_incompressible_walls`] |
//! | [`cholesky`] | [`CholeskyBox3d`]: the same matrix factored once (faer sparse Cholesky, nested-dissection order) |
//! | [`box_pressure`] | [`BoxPressure`] (the solver choice), [`BoxSolver`], [`box_pressure::make_incompressible_box`] (self-adjoint) |
//! | [`cavity`] | [`Cavity3d`]: the lid-driven cavity stepper (walled right-hand side, projection per stage) |
//! | [`advect`] | semi-Lagrangian and MacCormack (Selle limiter) advection of cell-centred scalars and of the no-slip box velocity ([`Advection3d`]); hand-written adjoints |
//! | [`conservative`] | [`Conservative3d`]: finite-volume flux form with Zalesak's FCT for cell-centred scalars (walls or periodic per axis): mass conserved to round-off, no new extrema, second order where smooth; forward only |
//! | [`smoke`] | [`Smoke3d`]: the buoyant smoke plume (density advection, sphere inflow, velocity self-advection, Boussinesq buoyancy, optional viscosity, box projection), listing its operators; its pressure split ([`Smoke3d::step_unprojected`], [`Smoke3d::project_keep_pressure`], [`Smoke3d::correct_with_pressure`]) for latent-space physics |
//!
//! Conventions: tensors `[batch, channel, nz, ny, nx]`, x fastest, `f32` or `f64`, CPU. The
//! periodic solver ([`NavierStokes3d`]) treats every face of the box as periodic; the cavity
//! ([`Cavity3d`]) keeps the last face of each component along its own axis as a wall face.
//! Time schemes are the 2D ones ([`crate::ButcherTableau`]).
//!
//! The smoke box takes per-face walls ([`Walls3d`]: no-slip, free-slip, periodic pairs,
//! outflow on upper faces), static obstacles and an inflow patch ([`Smoke3dBoundaries`]).
//!
//! Not here yet: moving walls other than the cavity's lid, CG for periodic / open / obstacle
//! topologies (the sparse Cholesky factor assembles them), the adjoint of the conservative scalar
//! transport, a fused stage update for the cavity, and a warm start of CG
//! across time steps inside the steppers.
//!
//! ```
//! use pbdl_grid::grid3d::{abc::abc_flow, fd, Grid3d, NavierStokes3d, NavierStokes3dConfig};
//! let grid = Grid3d::cube(8, 2.0 * std::f64::consts::PI)?;
//! let u = abc_flow(grid, [1.0, 1.0, 1.0], 0.01, 0.0, candle_core::DType::F64)?;
//! let ns = NavierStokes3d::new(grid, NavierStokes3dConfig { nu: 0.01, dt: 0.1, scheme: Default::default() })?;
//! let u1 = ns.step(&u)?;
//! assert!(fd::divergence(&u1)?.abs()?.max_all()?.to_scalar::<f64>()? < 1e-12);
//! # Ok::<(), pbdl_grid::Error>(())
//! ```

pub mod abc;
pub mod advect;
pub mod box_pressure;
pub mod cavity;
pub mod cg;
pub mod cholesky;
pub mod conservative;
pub mod domain;
pub mod fd;
mod fft;
pub mod field;
pub mod momentum;
pub mod navier_stokes;
mod periodic;
pub mod pressure;
pub mod smoke;
pub mod stability;
pub mod walls;

pub use advect::Advection3d;
pub use box_pressure::{BoxPressure, BoxSolver, BoxTopology};
pub use cavity::Cavity3d;
pub use cg::CgBox3d;
pub use cholesky::CholeskyBox3d;
pub use conservative::{AxisFaces3d, Conservative3d};
pub use domain::Grid3d;
pub use field::MacField3d;
pub use navier_stokes::{NavierStokes3d, NavierStokes3dConfig};
pub use pressure::PoissonFft3d;
pub use smoke::{
    InflowFace3d, InflowPatch3d, MassBalance3d, Obstacle3d, PatchShape3d, Smoke3d, Smoke3dBoundaries, Smoke3dConfig,
    Smoke3dState, SphereSource, Viscosity3d,
};
pub use walls::{CavityWalls, Face3d, Walls3d};
