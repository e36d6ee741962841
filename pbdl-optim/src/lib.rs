//! # pbdl-optim
//!
//! Optimisers for learning through differentiable physics.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`hig`] | half-inverse gradients (HIG) and Gauss-Newton from one SVD solve ([`hig::HalfInverse`]), trainers ([`hig::HigTrainer`], [`hig::AdamTrainer`]) for any [`hig::JacobianModel`] (the [`mlp::Mlp`], or any candle model through [`hig::CandleModel`]), loss-vs-wall-clock runs |
//! | [`mlp`] | a dense `f64` network with exact per-sample Jacobian rows ([`mlp::Mlp`]) |
//! | [`physics`] | (also [`physics::StepperPhysics`]: HIG on any differentiable tensor stepper, Jacobians by backprop) the [`physics::Physics`] trait (forward + exact Jacobian) and the experiments' physics: linear chain, nonlinear oscillators (RK4), Poisson 8x8, quantum dipole (Crank-Nicolson) |
//! | [`bptt`] | stabilized BPTT: gradient modes F, P, S, C for any candle rollout, with value / global-norm clipping, and the Adam training loop the experiments share ([`bptt::train`]) |
//! | [`cartpole`] | cart-pole with 1..N poles, differentiable in candle, and the stabilized-BPTT training run on it; [`cartpole::adjoint`]: the same run with a hand-written `f64` adjoint (paper-length runs) |
//! | [`controller`] | [`controller::DenseController`]: the dense tanh controller of the BPTT experiments |
//! | [`guidance`] | guidance by repulsion (drivers herd evaders), differentiable in candle, and its stabilized-BPTT run |
//! | [`quantum_control`] | a particle in a box steered into eigenstate 3-5 (Crank-Nicolson custom op with adjoint), and its stabilized-BPTT run |
//! | [`racecar`] | the racecar reverse-pass reconstruction loss (transposed shared weights) for dense nets, BN + ReLU nets ([`racecar::bn_mlp`]) and conv nets ([`racecar::conv_net`]), the orthogonality baseline ([`racecar::ortho`]), procedural peak images and the SVD alignment analysis ([`racecar::svd`], [`racecar::peak_experiment`]) |
//! | [`error`] | the crate's [`Error`] |
//!
//! ```
//! use pbdl_optim::hig::{evaluate, HigConfig, HigTrainer};
//! use pbdl_optim::mlp::{Activation, Mlp};
//! use pbdl_optim::physics::{Dataset, Oscillators};
//!
//! // The pbdl-book linear chain: bring two coupled oscillators back to their start in 24 RK4 steps.
//! let physics = Oscillators::linear_chain();
//! let data = Dataset::return_to_start(256, 4, 0);
//! let mut net = Mlp::new(&[4, 20, 20, 20, 24], Activation::Tanh, 0)?;
//! let before = evaluate(&net, &physics, &data)?;
//! let mut hig = HigTrainer::new(HigConfig::hig(1.0, 1e-10))?;
//! for step in 0..8 {
//!     hig.step(&mut net, &physics, data.batch(32 * step, 32))?;
//! }
//! let after = evaluate(&net, &physics, &data)?;
//! assert!(after < 0.1 * before, "{before} -> {after}");
//! # Ok::<(), pbdl_optim::Error>(())
//! ```
#![warn(missing_docs)]

pub mod bptt;
pub mod cartpole;
pub mod controller;
pub mod error;
pub mod guidance;
pub mod hig;
pub mod mlp;
pub mod physics;
pub mod quantum_control;
pub mod racecar;

pub use error::{Error, Result};
