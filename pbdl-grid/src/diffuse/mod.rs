//! Diffusion of MAC velocities and centred scalars.
//!
//! * [`explicit`]: the tendency `nu * lap(u)` (five-point Laplacian per component, walls through
//!   mirrored ghosts). Its stable step is `diffusion_limit / (nu (4/dx^2 + 4/dy^2))` for the
//!   chosen Runge-Kutta scheme; see [`crate::stability`].
//! * [`implicit`] / [`ImplicitDiffusion`]: backward Euler `(I - nu dt L) q1 = q0` with the same
//!   stencil, the matrix factored once (faer sparse Cholesky) and reused; no time-step limit
//!   (unconditionally stable), first order in time; the gradient is the same solve.

mod explicit;
mod implicit;

pub use explicit::explicit;
pub use implicit::{implicit, ImplicitDiffusion};
