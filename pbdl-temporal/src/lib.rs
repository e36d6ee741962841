//! # pbdl-temporal
//!
//! Temporally coherent GAN super-resolution of fluid flows: tempoGAN (Xie, Franz, Chu,
//! Thuerey 2018) and TecoGAN (Chu, Xie, Mayer, Leal-Taixé, Thuerey 2020) on candle tensors.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | smoke plumes from pbdl-grid at the high resolution (varied sources, buoyancy, inflow noise), box-downsampled for the low-resolution input |
//! | [`warp`] | semi-Lagrangian advection by a known velocity, TecoGAN's backward warp, motion upsampling |
//! | [`generator`] | the per-frame fluid generator (tempoGAN layout, residual on bicubic) shared by all three training modes |
//! | [`eval`] | held-out scores of every model and bicubic: PSNR, SSIM, LSiM, tOF, tLSiM, time per frame vs the solver |
//! | [`gan`] | tempoGAN's spatial and temporal discriminator inputs, losses and the discriminator balance |
//! | [`model`] | a trained generator with its kind, save/load, upscaling of sequences and `.npz` files |
//! | [`tecogan`] | TecoGAN's frame-recurrent generator with its motion network F, the spatio-temporal triplet discriminator, the ping-pong loss, non-adversarial and adversarial (resumable) trainers |
//! | [`train`] | L1 pre-training, then the baseline, per-frame GAN and temporal GAN objectives from the same weights; resumable runs |
//!
//! Image-like tensors are `[batch, channel, y, x]` with row 0 at the bottom (y up).
//!
//! Quick start (toy size; `cargo xtask temporal train` runs the CPU-size experiment, and
//! `cargo xtask temporal upscale --model M --input LR.npz --out HR.npz` applies a model):
//!
//! ```
//! use pbdl_temporal::data::{generate, SmokeData};
//! use pbdl_temporal::generator::GeneratorConfig;
//! use pbdl_temporal::train::{train_all, PhaseSettings, TrainConfig};
//!
//! let data = generate(&SmokeData { lr_resolution: 8, train_scenes: 2, test_scenes: 1, frames: 6, warmup: 16, ..SmokeData::default() })?;
//! let cfg = TrainConfig {
//!     generator: GeneratorConfig { channels: 8, ..GeneratorConfig::default() },
//!     pretrain: PhaseSettings { steps: 5, batch: 4, lr: 1e-3 },
//!     finetune: PhaseSettings { steps: 2, batch: 2, lr: 2e-4 },
//!     discriminator_widths: vec![8, 8],
//!     ..TrainConfig::default()
//! };
//! let models = train_all(&data, &cfg, None)?; // baseline, per-frame GAN, temporal GAN
//! let hr = models[2].0.upscale(&data.test[0].lr_density, None)?;
//! assert_eq!(hr.dims(), [6, 1, 32, 32]);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```
#![warn(missing_docs)]

pub mod data;
pub mod error;
pub mod eval;
pub mod gan;
pub mod generator;
pub mod model;
pub mod tecogan;
pub mod train;
pub mod warp;

pub use error::{Error, Result};
