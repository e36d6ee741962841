//! The convolutional autoencoder of a field (pressure by default) to a flat latent code.
//!
//! Latent-space physics (Wiewel et al. 2019) compresses a 64^2 pressure field 16-fold to a
//! 256-vector with strided 4x4 / 2x2 convolutions, leaky ReLU (0.2) and batch norm, and mirrors
//! it with transposed convolutions. Here the encoder is pbdl-nets' strided-conv
//! [`ConvEncoder`](pbdl_nets::encoder_decoder::ConvEncoder) (4x4 stride-2 convs, leaky ReLU 0.2,
//! no norm: the code of a frame must not depend on its batch) down to a small map, flattened to
//! the code; the decoder mirrors it with 4x4 stride-2 transposed convs and ends linear.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::VarMap;
//! use pbdl_latent::autoencoder::{AutoencoderConfig, LatentAutoencoder};
//!
//! let cfg = AutoencoderConfig { resolution: 16, widths: vec![8, 16], latent_channels: 4, ..AutoencoderConfig::default() };
//! let varmap = VarMap::new();
//! let ae = LatentAutoencoder::new(cfg, &varmap, 0)?;
//! assert_eq!(ae.code_size(), 4 * 4 * 4);
//! let p = Tensor::zeros((3, 1, 16, 16), DType::F32, &Device::Cpu)?;
//! let z = ae.encode(&p)?;
//! assert_eq!(z.dims(), [3, 64]);
//! assert_eq!(ae.decode(&z)?.dims(), [3, 1, 16, 16]);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::nn::Activation;
use pbdl_nets::encoder_decoder::{Autoencoder, EncoderDecoderConfig, Upsampling};
use pbdl_nets::Padding;
use serde::{Deserialize, Serialize};

/// Layout of a [`LatentAutoencoder`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AutoencoderConfig {
    /// Channels of the field (1 for the pressure). Default 1.
    pub channels: usize,
    /// Cells per side of the (square) input; a multiple of `2^levels`. Default 32.
    pub resolution: usize,
    /// Widths of the stride-2 levels (their count halves the side that often). Default
    /// `[16, 32, 64]`: 32^2 -> 4^2.
    pub widths: Vec<usize>,
    /// Channels of the latent map; the code has `latent_channels * (resolution / 2^levels)^2`
    /// entries. Default 8 (a 128-code at 32^2: 8x compression).
    pub latent_channels: usize,
}

impl Default for AutoencoderConfig {
    fn default() -> Self {
        Self { channels: 1, resolution: 32, widths: vec![16, 32, 64], latent_channels: 8 }
    }
}

impl AutoencoderConfig {
    /// The layout for an `n x n` field down to a `4 x 4` map: one stride-2 level per halving,
    /// widths 16, 32, 64, 128, 128, ... and `latent_channels` channels in the map.
    pub fn for_resolution(n: usize, latent_channels: usize) -> Self {
        let levels = (n / 4).max(1).ilog2() as usize;
        let widths = (0..levels).map(|l| 16usize << l.min(3)).collect();
        Self { resolution: n, widths, latent_channels, ..Self::default() }
    }

    /// Side of the latent map.
    pub fn latent_side(&self) -> usize {
        self.resolution >> self.widths.len()
    }

    /// Entries of the flat code.
    pub fn code_size(&self) -> usize {
        self.latent_channels * self.latent_side() * self.latent_side()
    }

    /// Checks the layout (typed [`Error::Config`]).
    pub fn validate(&self) -> Result<()> {
        let m = 1usize << self.widths.len();
        if self.widths.is_empty() || self.resolution == 0 || self.resolution % m != 0 {
            return Err(Error::config(
                "resolution / widths",
                format!(
                    "{} with {} levels; the side must be a positive multiple of 2^levels = {m}",
                    self.resolution,
                    self.widths.len()
                ),
            ));
        }
        if self.channels == 0 || self.latent_channels == 0 || self.widths.contains(&0) {
            return Err(Error::config("channels / latent_channels / widths", "use positive sizes"));
        }
        Ok(())
    }

    fn nets_config(&self) -> EncoderDecoderConfig {
        EncoderDecoderConfig {
            in_channels: self.channels,
            out_channels: self.channels,
            widths: self.widths.clone(),
            latent_channels: self.latent_channels,
            activation: Activation::LeakyRelu { negative_slope: 0.2 },
            norm_groups: None,
            upsampling: Upsampling::Transposed,
            padding: Padding::Zeros,
        }
    }
}

/// Encoder and decoder of one field (see the module docs).
#[derive(Clone, Debug)]
pub struct LatentAutoencoder {
    net: Autoencoder,
    config: AutoencoderConfig,
}

impl LatentAutoencoder {
    /// Builds the network with its variables in `varmap` (f32), initialised from `seed`.
    pub fn new(config: AutoencoderConfig, varmap: &VarMap, seed: u64) -> Result<Self> {
        config.validate()?;
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let net = Autoencoder::new(config.nets_config(), vb)?;
        pbdl_nets::seeded_init(varmap, seed)?;
        Ok(Self { net, config })
    }

    /// The layout.
    pub fn config(&self) -> &AutoencoderConfig {
        &self.config
    }

    /// Entries of the flat code.
    pub fn code_size(&self) -> usize {
        self.config.code_size()
    }

    /// `[B, channels, n, n]` -> codes `[B, code_size]`.
    pub fn encode(&self, x: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = x.dims();
        if d.len() != 4 || d[1] != c.channels || d[2] != c.resolution || d[3] != c.resolution {
            return Err(Error::Shape {
                what: "autoencoder input",
                expected: format!("[batch, {}, {}, {}]", c.channels, c.resolution, c.resolution),
                got: d.to_vec(),
            });
        }
        Ok(self.net.encoder().forward(x)?.flatten_from(1)?)
    }

    /// Codes `[B, code_size]` -> fields `[B, channels, n, n]`.
    pub fn decode(&self, z: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = z.dims();
        if d.len() != 2 || d[1] != c.code_size() {
            return Err(Error::Shape {
                what: "latent code",
                expected: format!("[batch, {}]", c.code_size()),
                got: d.to_vec(),
            });
        }
        let s = c.latent_side();
        Ok(self.net.decoder().forward(&z.reshape((d[0], c.latent_channels, s, s))?)?)
    }

    /// `decode(encode(x))`.
    pub fn reconstruct(&self, x: &Tensor) -> Result<Tensor> {
        self.decode(&self.encode(x)?)
    }
}
