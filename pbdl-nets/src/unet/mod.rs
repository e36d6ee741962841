//! The U-Nets of the diffusion papers. Each has an inherent `forward(x, t)`: the noisy input
//! and the diffusion step in, the predicted noise out; `pbdl_diffusion` implements its
//! `NoisePredictor` on them.
//!
//! | type | paper | notes |
//! |---|---|---|
//! | [`AcdmUnet`] | ACDM (Kohl et al. 2023) | ConvNeXt blocks, linear attention, full attention in the middle; also the deterministic U-Net baseline (no step embedding) |
//! | [`AifNet`] | airfoil DDPM (Liu and Thuerey 2024) | depthwise-separable residual blocks, self-attention on two levels, space-to-depth down, nearest up, skips x 0.707 |
//!
//! Building blocks: [`ConvNextBlock`], [`crate::attention`] (full and linear multi-head
//! attention over pixels), [`crate::Linear`], [`crate::sinusoidal_embedding`]. Networks take
//! their variables from a `candle_nn::VarBuilder`; build it over a `VarMap` to train and to
//! save checkpoints with `pbdl_core::io::save_varmap`; [`crate::seeded_init`] gives
//! reproducible weights and [`crate::count_parameters`] counts a `VarMap`'s scalars.
//! Convolutions run on `pbdl_core::conv` (im2col + gemm, with depthwise groups and a
//! differentiable transposed convolution).

mod acdm;
mod aifnet;

pub use acdm::{AcdmUnet, AcdmUnetConfig, ConvNextBlock};
pub use aifnet::{AifNet, AifNetConfig};
