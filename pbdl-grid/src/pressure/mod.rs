//! Pressure: Poisson solves and the projection onto divergence-free velocities.
//!
//! The discrete Laplacian is `L = D M G` (divergence of the masked face gradient), with the
//! pressure conditions implied by the velocity's ([`crate::Boundaries::pressure`]). It is
//! symmetric, so the adjoint of a solve is the same solve: gradients never unroll iterations.
//! Closed and periodic domains make `L` singular (constants); solves then use the pseudo-inverse
//! (right-hand side mean removed, solution mean zero).
//!
//! * [`PressureSolver`]: built once per grid and boundaries. Fully periodic domains use a real
//!   FFT (`fft`), anything with walls a sparse Cholesky factor (`cholesky`, faer) that is
//!   factored once and reused every step.
//! * [`make_incompressible`]: `u - M G L^+ D u`, a custom op whose backward is
//!   `g - D^T L^+ (M G)^T g` (one adjoint solve).
//! * [`solve_poisson`]: `L^+ b` as a differentiable op.
//! * [`MaskedPressureSolver`], [`make_incompressible_masked`]: the same with obstacles (solid
//!   cells out of the solve, zero normal velocity on their faces).
//! * [`CgPressureSolver`], [`make_incompressible_masked_cg`]: the same masked system by
//!   preconditioned conjugate gradients (MIC(0) or Jacobi), warm-started, with a relative
//!   tolerance; slower than the factor at 64^2-256^2 (see `benches/pressure.rs`).

pub(crate) mod cg;
mod cholesky;
mod fft;
mod masked;
mod project;
mod solver;

pub use cg::{make_incompressible_masked_cg, CgPreconditioner, CgPressureSolver, CgSettings, CgStats};
pub(crate) use masked::{check_mac_shape, MaskedProjection};
pub use masked::{make_incompressible_masked, MaskedPressureSolver};
pub use project::make_incompressible;
pub(crate) use project::Projection;
pub use solver::{solve_poisson, PressureSolver};
