//! The U-Nets of the diffusion papers, as [`NoisePredictor`]s. The networks live in
//! [`pbdl_nets`] and are re-exported here; this module adds the trait impls, the conversion of
//! [`pbdl_nets::Error`] into this crate's [`Error`], and the benchmark [`workload`].
//!
//! | type | paper | notes |
//! |---|---|---|
//! | [`AcdmUnet`] | ACDM (Kohl et al. 2023) | ConvNeXt blocks, linear attention, full attention in the middle; also the deterministic U-Net baseline (no step embedding) |
//! | [`AifNet`] | airfoil DDPM (Liu and Thuerey 2024) | depthwise-separable residual blocks, self-attention on two levels, space-to-depth down, nearest up, skips x 0.707 |
//!
//! Building blocks (also from [`pbdl_nets`]): [`ConvNextBlock`], [`Attention`] /
//! [`ResidualAttention`] (full and linear multi-head attention over pixels), [`Linear`],
//! [`sinusoidal_embedding`]; [`seeded_init`] gives reproducible weights and
//! [`count_parameters`] counts a `VarMap`'s scalars.

pub mod workload;

use crate::ddpm::NoisePredictor;
use crate::{Error, Result};
use candle_core::Tensor;

pub use pbdl_nets::attention::{Attention, AttentionKind, ResidualAttention};
pub use pbdl_nets::unet::{AcdmUnet, AcdmUnetConfig, AifNet, AifNetConfig, ConvNextBlock};
pub use pbdl_nets::{count_parameters, seeded_init, sinusoidal_embedding, Linear};

impl NoisePredictor for AcdmUnet {
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor> {
        Ok(self.forward(x, Some(t))?)
    }
}

impl NoisePredictor for AifNet {
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor> {
        Ok(self.forward(x, t)?)
    }
}

/// Variant for variant: the networks' invalid settings and shape mismatches stay
/// [`Error::InvalidConfig`] and [`Error::ShapeMismatch`] here.
impl From<pbdl_nets::Error> for Error {
    fn from(e: pbdl_nets::Error) -> Self {
        match e {
            pbdl_nets::Error::InvalidConfig { name, value, hint } => Error::InvalidConfig { name, value, hint },
            pbdl_nets::Error::ShapeMismatch { what, expected, got } => Error::ShapeMismatch { what, expected, got },
            pbdl_nets::Error::Candle(e) => Error::Candle(e),
            pbdl_nets::Error::Core(e) => Error::Core(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::{VarBuilder, VarMap};

    /// The trait is the inherent forward pass of both nets, and network errors keep their kind.
    #[test]
    fn noise_predictor_is_the_forward_pass_and_errors_keep_their_kind() {
        let varmap = VarMap::new();
        let net = AcdmUnet::new(AcdmUnetConfig::acdm(8, 3), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))
            .unwrap();
        seeded_init(&varmap, 3).unwrap();
        let x = pbdl_core::seed::randn((1, 3, 8, 8), 0.0, 1.0, DType::F32, &Device::Cpu, 4).unwrap();
        let t = Tensor::new(&[5f32], &Device::Cpu).unwrap();
        let a: Vec<f32> = net.predict(&x, &t).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f32> = net.forward(&x, Some(&t)).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(a, b);
        let varmap = VarMap::new();
        let cfg = AifNetConfig {
            dim_basic: 4,
            dim_multipliers: vec![1, 2],
            attention_layers: vec![1],
            ..AifNetConfig::airfoil_32()
        };
        let aif = AifNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu)).unwrap();
        seeded_init(&varmap, 5).unwrap();
        let x6 = pbdl_core::seed::randn((1, 6, 8, 8), 0.0, 1.0, DType::F32, &Device::Cpu, 6).unwrap();
        let a: Vec<f32> = aif.predict(&x6, &t).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f32> = aif.forward(&x6, &t).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(a, b);
        let wrong = Tensor::zeros((1, 4, 8, 8), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(net.predict(&wrong, &t), Err(Error::ShapeMismatch { .. })));
        let bad = AcdmUnetConfig { dim_mults: vec![], ..AcdmUnetConfig::acdm(8, 3) };
        let err: Error = AcdmUnet::new(bad, VarBuilder::zeros(DType::F32, &Device::Cpu)).unwrap_err().into();
        assert!(matches!(err, Error::InvalidConfig { name: "dim_mults", .. }));
    }
}
