//! The U-Nets of the diffusion papers, as [`NoisePredictor`](crate::ddpm::NoisePredictor)s.
//!
//! | type | paper | notes |
//! |---|---|---|
//! | [`AcdmUnet`] | ACDM (Kohl et al. 2023) | ConvNeXt blocks, linear attention, full attention in the middle; also the deterministic U-Net baseline (no step embedding) |
//! | [`AifNet`] | airfoil DDPM (Liu and Thuerey 2024) | depthwise-separable residual blocks, self-attention on two levels, space-to-depth down, nearest up, skips x 0.707 |
//!
//! Building blocks: [`ConvNextBlock`], [`Attention`] / [`ResidualAttention`] (full and linear
//! multi-head attention over pixels), [`Linear`], [`sinusoidal_embedding`]. Networks take
//! their variables from a `candle_nn::VarBuilder`; build it over a `VarMap` to train and to
//! save checkpoints with `pbdl_core::io::save_varmap`; [`seeded_init`] gives reproducible
//! weights and [`count_parameters`] counts a `VarMap`'s scalars. [`workload`] is the unit of
//! the benchmarks. Convolutions run on `pbdl_core::conv` (im2col + gemm, with depthwise
//! groups and a differentiable transposed convolution). On narrow feature maps (width up to a
//! quarter of the attention's 4 x 32) linear attention runs as one fused op with its two
//! projections (`linear_attention.rs`), 2.6x less CPU time than composed candle ops at dim 16.

mod acdm;
mod aifnet;
mod attention;
mod layers;
mod linear_attention;
pub mod workload;

pub use acdm::{AcdmUnet, AcdmUnetConfig, ConvNextBlock};
pub use aifnet::{AifNet, AifNetConfig};
pub use attention::{Attention, AttentionKind, ResidualAttention};
pub use layers::{count_parameters, seeded_init, sinusoidal_embedding, Linear};
