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
//! | [`recurrent`] | [`recurrent::LstmCell`] and the stacked batch-first [`recurrent::Lstm`] (PyTorch layout), [`recurrent::ConvLstmCell`] (Shi et al., zero or periodic padding) |
//! | [`resample`] | space-to-depth and nearest 2x upsampling |
//! | [`shuffle`] | [`pixel_shuffle`](shuffle::pixel_shuffle) / [`pixel_unshuffle`](shuffle::pixel_unshuffle) in PyTorch's channel order (sub-pixel upsampling) |
//! | [`pad`] | [`pad_per_axis`](pad::pad_per_axis): zeros / periodic / replicate / reflect per axis, as `numpy.pad` |
//! | [`dropout`] | [`Dropout`](dropout::Dropout), inverted dropout with a seeded mask |
//! | [`spectral_norm`] | [`SpectralNorm`](spectral_norm::SpectralNorm) (power iteration, PyTorch's `spectral_norm`) and [`SpectralNormConv2d`](spectral_norm::SpectralNormConv2d) for discriminators |
//! | [`embedding`] | [`sinusoidal_embedding`] of the diffusion step |
//! | [`init`] | [`seeded_init`], [`count_parameters`] |
//! | [`error`] | [`Error`], [`Result`] |
#![warn(missing_docs)]

pub mod attention;
pub mod discriminator;
pub mod dropout;
pub mod embedding;
pub mod encoder_decoder;
pub mod error;
pub mod init;
pub mod layers;
pub mod mlp;
pub mod pad;
pub mod padding;
pub mod recurrent;
pub mod resample;
pub mod resnet;
pub mod shuffle;
pub mod spectral_norm;
pub mod unet;

pub use embedding::sinusoidal_embedding;
pub use error::{Error, Result};
pub use init::{count_parameters, seeded_init};
pub use layers::Linear;
pub use padding::{PaddedConv2d, Padding};
