//! Explicit Runge-Kutta time stepping with a projection after every stage.
//!
//! Schemes are data ([`ButcherTableau`]), each carrying the extent of its stability region along
//! the imaginary axis (central advection) and the negative real axis (diffusion), so every
//! scheme can say its stable time step ([`crate::stability`]).
//! The 2D and 3D Navier-Stokes steppers share one fused stage update (`fused`: each stage's
//! combination and its projection in one op, over any projection that implements its trait).

pub(crate) mod fused;
mod runge_kutta;
mod tableau;

pub use runge_kutta::projected_runge_kutta;
pub use tableau::{ButcherTableau, Scheme};
