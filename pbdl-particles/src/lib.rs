//! # pbdl-particles
//!
//! Particle simulation for physics-based deep learning: fast fixed-radius neighbour search,
//! SPH kernels and validated SPH solvers that generate data for particle networks.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`neighbors`] | [`CellList`] (counting sort on cell keys, 1D/2D/3D, periodic or bounded, rayon), CSR [`NeighborList`] and pair lists, [`neighbors::brute_force`] |
//! | [`kernels`] | [`Kernel`]: cubic spline, quintic, Wendland C2/C4, poly6, spiky in 1D/2D/3D with gradients |
//! | [`riemann`] | exact Riemann solver of the 1D Euler equations ([`riemann::solve`], [`GasState`]) |
//! | [`hll`] | first-order HLL finite-volume reference for shock tubes ([`hll::solve`], Toro's pressure-based wave speeds, transmissive ends) |
//! | [`sph1d`] | [`Sph1d`]: compressible 1D SPH (grad-h; Monaghan viscosity with the Morris & Monaghan switch, Price's artificial conductivity), [`ShockTube`] (any left/right states, moving ends; Sod by default; `build_as::<f32>` for single precision), periodic boxes |
//! | [`wcsph`] | [`Wcsph`]: 2D weakly compressible SPH (Tait, Monaghan viscosity, δ-SPH, extrapolated wall particles), [`DamBreak`] (Martin & Moyce; [`DamBreak::build_as`] picks `f32` or `f64`) |
//! | [`wcsph3d`] | [`wcsph3d::Wcsph3d`]: 3D weakly compressible SPH (Tait, Monaghan viscosity, δ-SPH, wall particles of [`walls`]), [`wcsph3d::DamBreak3d`] (quasi-2D Martin & Moyce column spanning the tank's depth; [`wcsph3d::DamBreak3d::build_dfsph`] for 3D DFSPH), [`wcsph3d::BlockDrop3d`] (blocks and balls dropped into a box) |
//! | [`liquid3d`] | CConv-style 3D liquid data: [`liquid3d::Liquid3dConfig`] draws seeded block-drop scenes and writes per-scene `.npz` (`pos`, `vel` per frame, `box`, `box_normals`) plus a JSON sidecar |
//! | [`iisph`] | [`Iisph`]: 2D implicit incompressible SPH (relaxed-Jacobi pressure solve to a stated density tolerance, wall particles), [`DamBreak::build_iisph`] / [`DamBreak::build_iisph_as`] |
//! | [`dfsph`] | [`dfsph::Dfsph`]: divergence-free SPH in 2D or 3D (`Dfsph<T, D>`; Bender & Koschier: divergence-free solve + constant-density solve with the α factors, warm start; the wall particles of [`walls`]), [`DamBreak::build_dfsph`] / [`DamBreak::build_dfsph_as`], in 3D [`wcsph3d::DamBreak3d::build_dfsph`] / [`wcsph3d::DamBreak3d::build_dfsph_as`] with [`dfsph::DfsphParams::default_3d`] |
//! | [`walls`] | wall particles shared by WCSPH, IISPH and DFSPH in 2D and by 3D WCSPH and DFSPH (generic over the dimension): Adami, Hu & Adams (2012) pressure extrapolation with the hydrostatic term and no-slip wall velocity ([`walls::WallStencil`]), the impermeable-container fallback and leak/front diagnostics |
//! | [`render`] | particles splatted into pixel fields for PNG/GIF ([`render::scatter`]) |
//! | [`scene`] | [`scene::Scene`]: TOML scenes (`precision = "f32"` or `"f64"`) (shock tube, dam break WCSPH/IISPH/DFSPH, 3D dam break WCSPH/DFSPH, 3D block drop, periodic 1D noisy density, periodic 2D noisy velocity) building a [`scene::Stepper`]; `.npz` trajectories and PNG/GIF renders |
//! | [`Evolve`] | the one solver trait (re-exported from [`pbdl_core::stepper`]): [`Sph1d`], [`Wcsph`], [`Iisph`] and [`scene::Stepper`] step in place with an adaptive stable step; [`Evolve::run_until`] (IISPH in equal steps, the others with a shortened last step) |
//! | [`validation`] | [`validation::martin_moyce_1952`]: the measured dam-break surge front (embedded) |
//! | [`error`] | [`Error`], [`Result`] |
//!
//! Conventions: positions are slices of `[T; D]` (`T` = `f32` or `f64`); every solver is generic
//! over `T` with `f64` as the default type (parameters, time and step sizes stay `f64`; sums such
//! as momentum and mass are accumulated in `f64`); neighbour lists exclude the particle itself.
//!
//! Every solver advances through [`Evolve`]; bring it into scope to call `run_until`:
//!
//! ```
//! use pbdl_particles::{Evolve, ShockTube, Sph1dParams};
//!
//! let mut sim = ShockTube::sod().build(100, Sph1dParams::default())?;
//! let steps = sim.run_until(0.01)?;
//! assert!(steps > 0 && (sim.time() - 0.01).abs() < 1e-12);
//! assert_eq!(sim.run_until(0.01)?, 0); // already there
//! # Ok::<(), pbdl_particles::Error>(())
//! ```
#![warn(missing_docs)]

pub mod dfsph;
pub mod error;
pub mod hll;
pub mod iisph;
pub mod kernels;
pub mod liquid3d;
pub mod neighbors;
pub mod render;
pub mod riemann;
pub mod scene;
pub mod sph1d;
pub mod validation;
pub mod walls;
pub mod wcsph;
pub mod wcsph3d;

pub use error::{Error, Result};
pub use iisph::{Iisph, IisphParams};
pub use kernels::{Kernel, KernelKind};
pub use neighbors::{CellList, Domain, NeighborList};
pub use pbdl_core::stepper::Evolve;
pub use riemann::GasState;
pub use sph1d::{ShockTube, Sph1d, Sph1dParams};
pub use wcsph::{DamBreak, Wcsph, WcsphParams};

/// Largest smoothing length over particle spacing (`h_over_dx`, 1D `eta`) any solver accepts:
/// beyond it every particle has thousands of neighbours, and walls and ghost layers (as thick as
/// the kernel support) grow without bound (found by fuzzing the scene files: a huge value hung
/// the wall construction or overflowed an index).
pub const MAX_H_OVER_DX: f64 = 8.0;

/// Smallest smoothing length over particle spacing any solver accepts: below it the kernel's
/// support holds no neighbour, and the neighbour grid's cells (sized by the support) become so
/// many that a small tank allocates gigabytes (found by fuzzing: `h_over_dx = 0.005`).
pub const MIN_H_OVER_DX: f64 = 0.5;
