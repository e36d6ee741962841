//! # pbdl-diffusion
//!
//! Diffusion models for physics: the DDPM/DDIM core, ACDM (autoregressive conditional diffusion)
//! for flow prediction, SMDP (score matching through differentiable physics) and a diffusion
//! surrogate that predicts mean and spread of an unsteady flow.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`schedule`] | noise schedules: linear, cosine, ACDM's linear schedule scaled to R steps |
//! | [`ddpm`] | the epsilon-prediction objective (MSE / Huber), ancestral DDPM and DDIM samplers, channel-concatenation conditioning |
//! | [`unet`] | the ACDM U-Net (ConvNeXt blocks, linear attention, sinusoidal time embedding) and the airfoil-paper U-Net, from [`pbdl_nets`], as [`ddpm::NoisePredictor`]s; the benchmark workload |
//! | [`smdp`] | score matching through physics: SDE with physics drift, 1-step and multi-step losses, reverse-SDE and probability-flow samplers (graded time grids), time-split expert score networks, toy and heat problems |
//! | [`uncertainty`] | a diffusion surrogate that predicts mean and standard-deviation fields of an unsteady wake from samples |
//! | [`acdm`] | autoregressive conditional diffusion on our own cylinder-flow data, baselines, rollouts and rollout metrics |
//! | [`error`] | [`Error`], [`Result`] |
#![warn(missing_docs)]

pub mod acdm;
pub mod ddpm;
pub mod error;
pub mod schedule;
pub mod smdp;
pub mod uncertainty;
pub mod unet;

pub use error::{Error, Result};
