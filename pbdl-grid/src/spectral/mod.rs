//! Pseudo-spectral solvers for periodic boxes: [`SpectralNavierStokes`] (2D, vorticity form).
//!
//! | module | what it gives you |
//! |---|---|
//! | [`imex`] | [`ImexScheme`]: the low-storage IMEX Runge-Kutta schemes (CN-RK4 Carpenter-Kennedy, CN-RK3 Williamson) and their stability limits |
//! | [`ns2d`] | [`SpectralNavierStokes`]: 2D Navier-Stokes, 2/3 dealiasing, implicit viscosity, f32/f64, a fast path and a differentiable path |
//!
//! On smooth periodic flows the error is set by the time step alone (spectral accuracy in
//! space): on the Taylor-Green vortex the solution equals the scheme's own Crank-Nicolson decay
//! to round-off at any resolution that holds its mode.

mod engine2d;
pub mod imex;
pub mod ns2d;
mod tensor2d;

pub use imex::ImexScheme;
pub use ns2d::{KolmogorovForcing, SpectralConfig, SpectralNavierStokes, SpectralState};
