//! # pbdl-sol
//!
//! Learning through the differentiable grid solver (pbdl-grid's steppers and their adjoints):
//! - **Solver-in-the-Loop** (Um et al., NeurIPS 2020): a correction network applied after each
//!   coarse solver step, trained on precomputed data (PRE), through one solver step (NON) or
//!   through `m` unrolled steps (SOL-m);
//! - **PDE control** (Holl et al., ICLR 2020): observation predictors and a control force
//!   estimator trained end to end through the solver, against direct per-scene optimisation.
//!
//! No solver code lives here: every physics step is a pbdl-grid stepper.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`control`] | PDE control (Holl et al. 2020) of forced 1D Burgers: observation predictors + CFE ([`control::Controller`]), supervised and end-to-end training, the direct-optimisation baseline |
//! | [`sil`] | Solver-in-the-Loop (Um et al. 2020): cylinder-wake source/reference data ([`sil::generate`]), the correction ResNet ([`sil::Corrector`]), PRE / NON / SOL-m training ([`sil::train()`]), corrected rollouts and MAE ([`sil::evaluate`]) |
//! | [`smoke_control`] | PDE control (Holl et al. 2020) of 2D incompressible smoke shape transitions through pbdl-grid's fluid operators: seeded shape pairs, observation predictors + CFE ([`smoke_control::SmokeController`]), supervised (on optimised trajectories) and end-to-end training, the direct-optimisation baseline |
//! | [`error`] | [`Error`], [`Result`] |
#![warn(missing_docs)]

pub mod control;
pub mod error;
pub mod sil;
pub mod smoke_control;

pub use error::{Error, Result};
