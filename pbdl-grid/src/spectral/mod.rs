//! Pseudo-spectral solvers for periodic boxes: [`SpectralNavierStokes`] (2D, vorticity form) and
//! [`SpectralNavierStokes3d`] (3D, velocity form).
//!
//! | module | what it gives you |
//! |---|---|
//! | [`imex`] | [`ImexScheme`]: the low-storage IMEX Runge-Kutta schemes (CN-RK4 Carpenter-Kennedy, CN-RK3 Williamson) and their stability limits |
//! | [`ns3d`] | [`SpectralNavierStokes3d`]: 3D Navier-Stokes, rotational form with Leray projection, 2/3 dealiasing, implicit viscosity, f32/f64, fast and differentiable paths |
//! | [`ns2d`] | [`SpectralNavierStokes`]: 2D Navier-Stokes, 2/3 dealiasing, implicit viscosity, f32/f64, a fast path and a differentiable path |
//!
//! On smooth periodic flows the error is set by the time step alone (spectral accuracy in
//! space): on the Taylor-Green vortex the solution equals the scheme's own Crank-Nicolson decay
//! to round-off at any resolution that holds its mode.

mod engine2d;
mod engine3d;
pub mod imex;
pub mod ns2d;
pub mod ns3d;
mod tensor2d;
mod tensor3d;

pub use imex::ImexScheme;
pub use ns2d::{KolmogorovForcing, SpectralConfig, SpectralNavierStokes, SpectralState};
pub use ns3d::{SpectralNavierStokes3d, SpectralState3d};
