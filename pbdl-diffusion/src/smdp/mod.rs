//! Score matching through differentiable physics (SMDP).
//!
//! The physics SDE `dx = P(x) dt + g dW` is simulated forward; a score network `s(x, t)` (which
//! absorbs `g^2`) is trained so that the backward step `x - dt [P(x) - s/2]` retraces the
//! simulated paths. Sampling then runs the reverse SDE `x <- x - dt [P(x) - s] + g sqrt(dt) xi`
//! or the probability-flow ODE `x <- x - dt [P(x) - s/2]`.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`physics`] | the [`PhysicsDrift`] drift trait (candle, differentiable) and the toy drifts |
//! | [`sde`] | the toy SDE and its seeded, batched Euler-Maruyama simulator |
//! | [`analytic`] | closed-form score and posterior of the affine toy; the digest's posterior table |
//! | [`euler_law`] | the exact law of the toy's Euler chain on a grid: score, 1-step loss minimiser, posterior |
//! | [`mlp`] | the toy's `f64` score MLP with hand-written backpropagation, and Adam |
//! | [`loss`] | the 1-step loss (with the regulariser) and the multi-step loss, with gradients |
//! | [`sampler`] | reverse-SDE and probability-flow samplers, posterior and hit-rate evaluation |
//! | [`heat`] | the spectral heat step (differentiable op), random fields, noisy simulation, metrics |
//! | [`heat_net`] | the heat problem's periodic residual conv score network |
//! | [`heat_train`] | heat training (1-step loss), plain/ODE/SDE reconstructions and their metrics |
//! | [`toy`] | training the toy score network (stages, sliding windows); score error vs analytic |
//! | [`experts`] | two score networks split in time, trained for a graded time grid |
pub mod analytic;
pub mod euler_law;
pub mod experts;
pub mod heat;
pub mod heat_net;
pub mod heat_train;
pub mod loss;
pub mod mlp;
pub mod physics;
pub mod sampler;
pub mod sde;
pub mod toy;

pub use physics::{AffineDrift, PhysicsDrift, QuadraticDrift, ScalarDrift, StepperDrift, ToyDrift};
pub use sde::{Paths, ToySde};
