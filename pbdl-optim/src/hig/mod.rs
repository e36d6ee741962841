//! Half-inverse gradients (Schnell, Holl & Thuerey, ICLR 2022) and the Gauss-Newton baseline.
//!
//! For a batch of `b` samples with network outputs `u_s = f(i_s; theta)` and physics outcomes
//! `y_s = P(x_s; u_s)`, stack the per-sample output Jacobians into
//! `J = d y / d theta` (`b * dim(y)` rows, `|theta|` columns), computed exactly as
//! `J_s = J_phys,s J_net,s` ([`composed_jacobian`]). With the loss gradient
//! `g = d(L / b)/dy` (least squares: `2 (y - y*) / b`; other per-sample losses: [`Loss`]) and
//! the thin SVD `J = U S V^T`:
//!
//! ```text
//! dtheta = V diag(s_i^-kappa if s_i > tau * s_max else 0) U^T g,   theta <- theta - eta dtheta
//! ```
//!
//! `kappa = 1/2` is HIG, `kappa = 1` Gauss-Newton (the truncated pseudo-inverse). The
//! truncation is relative to the largest singular value and strict. `c = U^T g` is scaled and
//! mapped back by `V`; the (half-)inverse matrix is never formed.
//!
//! On a linear model `y = A theta`, one step maps each residual mode `u_i^T r` (kept by the
//! truncation) to `(1 - 2 eta s_i^(1 - kappa) / b) u_i^T r`: for HIG `1 - 2 eta sqrt(s_i) / b`.
//!
//! | file | gives you |
//! |---|---|
//! | [`loss`] | [`Loss`]: the per-sample loss and its gradient (least squares, state infidelity) |
//! | [`solve`] | [`HigConfig`], [`HalfInverse`]: the SVD solve with buffers kept between steps |
//! | [`train`] | [`HigTrainer`], [`AdamTrainer`], [`evaluate`], [`run_curve`] (loss vs wall-clock), `*_with_loss` variants |

pub mod loss;
pub mod solve;
pub mod train;

pub use loss::Loss;
pub use solve::{Decomposition, HalfInverse, HigConfig, SolveInfo};
pub use train::{
    composed_jacobian, evaluate, evaluate_with_loss, run_curve, run_curve_with_loss, AdamTrainer, Budget, Curve,
    HigTrainer, Method, StepInfo,
};
