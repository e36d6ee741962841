//! # pbdl-core
//!
//! The shared foundation of the pbdl crates: everything a differentiable simulator or a
//! physics-based learning method needs besides its own physics.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`error`] | the crate's [`Error`] enum and shape/dtype/finiteness checks |
//! | [`real`] | the [`Real`] float trait (`f32`, `f64`) that kernels are generic over |
//! | [`op`] | a toolkit for differentiable candle custom ops (forward + backward in one place) |
//! | [`grad_check`] | [`check_grad`] (central finite differences) and gradient-presence checks |
//! | [`seed`] | seeded random tensors: same seed, same numbers |
//!
//! Conventions: tensors are candle `Tensor`s laid out `[batch, channel, (z,) y, x]` with x
//! fastest; `f32` by default, `f64` where an accuracy test needs it.
#![warn(missing_docs)]

pub mod error;
pub mod grad_check;
pub mod op;
pub mod real;
pub mod seed;

pub use error::{Error, Result};
pub use grad_check::{assert_all_have_grads, assert_varmap_has_grads, check_grad, GradCheckOptions, GradCheckReport};
pub use real::Real;
