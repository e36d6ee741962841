//! Autoregressive conditional diffusion (ACDM) for flow prediction on our own cylinder-flow
//! data, with U-Net baselines, rollouts and rollout metrics.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | the "Inc" geometry simulated with `pbdl_grid::Fluid`, normalisation, `.npz` cache |
//! | [`model`] | ACDM / ACDM_ncn and the U-Net baselines (one-step, unrolled, training noise) on one U-Net |
//! | [`train`] | random windows, Adam, clipping, NaN guard, progress bar, resumable checkpoints |
//! | [`rollout`] | the [`rollout::FramePredictor`] trait and autoregressive rollouts with the Re channel reset |
//! | [`benchmark`] | [`benchmark::Benchmark`]: cached data + models trained or resumed under `target/pbdl/acdm/runs/` |
//! | [`eval`] | [`eval::evaluate`]: a rollout scored against held-out truth (MSE, LSiM, stability, Strouhal, spread) |
//! | [`metrics`] | MSE, temporal stability, probe spectrum / Strouhal number, sample spread |
pub mod benchmark;
pub mod data;
pub mod eval;
pub mod metrics;
pub mod model;
pub mod rollout;
pub mod train;
