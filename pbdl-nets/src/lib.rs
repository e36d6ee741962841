//! # pbdl-nets
//!
//! The neural networks that pbdl's methods share, on candle tensors with `pbdl_core::conv`
//! convolutions and `pbdl_core::nn` norms and activations. Every network takes its variables
//! from a `candle_nn::VarBuilder` (build it over a `VarMap` to train, and save the map with
//! `pbdl_core::io::save_varmap`); [`seeded_init`] re-initialises a `VarMap` reproducibly.
//! Image-like tensors are `[batch, channel, y, x]`.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`unet`] | the ACDM U-Net (ConvNeXt blocks, linear attention, sinusoidal step embedding) and the airfoil-paper U-Net (AifNet) |
//! | [`attention`] | multi-head self-attention over pixels: full and linear (fused CPU kernel on narrow maps), residual pre-norm wrapper |
//! | [`mlp`] | a multilayer perceptron with configurable widths and activations |
//! | [`resnet`] | residual conv blocks (pre- or post-activation, optional GroupNorm) and a ResNet stack `[B, C, H, W] -> [B, C', H, W]` |
//! | [`encoder_decoder`] | a strided conv encoder to a latent map and a transposed-conv or upsampling decoder back |
//! | [`discriminator`] | a conv discriminator: per-sample logits and the intermediate features, for GAN losses |
//! | [`padding`] | [`Padding`] (zeros, periodic, periodic in x only as WeatherBench) and the [`PaddedConv2d`] layer |
//! | [`layers`] | [`Linear`] (PyTorch layout and init) |
//! | [`resample`] | space-to-depth and nearest 2x upsampling |
//! | [`embedding`] | [`sinusoidal_embedding`] of the diffusion step |
//! | [`init`] | [`seeded_init`], [`count_parameters`] |
//! | [`error`] | [`Error`], [`Result`] |
#![warn(missing_docs)]

pub mod attention;
pub mod discriminator;
pub mod embedding;
pub mod encoder_decoder;
pub mod error;
pub mod init;
pub mod layers;
pub mod mlp;
pub mod padding;
pub mod resample;
pub mod resnet;
pub mod unet;

pub use embedding::sinusoidal_embedding;
pub use error::{Error, Result};
pub use init::{count_parameters, seeded_init};
pub use layers::Linear;
pub use padding::{PaddedConv2d, Padding};
