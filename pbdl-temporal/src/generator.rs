//! The per-frame fluid generator (after tempoGAN): a low-resolution density (optionally with
//! the low-resolution velocity) in, a `factor`-times finer density out.
//!
//! Layout: a 3x3 conv to `channels` + ReLU and a residual block at the low resolution; per 2x
//! step a nearest-neighbour 2x upsample, a 3x3 conv + ReLU and a residual block (tempoGAN's
//! two nearest upsamples with residual blocks between them); a 3x3 conv to one channel, added
//! to the bicubic upsample of the input density (the residual formulation of TecoGAN's
//! generator, so an untrained network starts at bicubic). Residual blocks are
//! `x + relu(conv(relu(conv(x))))` (pbdl-nets post-activation blocks, no norm). Kernels are
//! 3x3 instead of tempoGAN's 5x5 and the widths are narrower, for CPU training.
//!
//! The same generator serves the temporal GAN, the per-frame GAN and the non-adversarial
//! baseline, so their scores compare training objectives, not networks.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_temporal::generator::{FrameGenerator, GeneratorConfig};
//!
//! let varmap = VarMap::new();
//! let g = FrameGenerator::new(GeneratorConfig::default(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
//! let lr = Tensor::zeros((2, 1, 16, 16), DType::F32, &Device::Cpu)?;
//! assert_eq!(g.forward(&lr, None)?.dims(), [2, 1, 64, 64]);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::Activation;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_nets::resample::upsample_nearest2;
use pbdl_nets::resnet::{BlockOrder, ResBlock, ResBlockConfig};
use pbdl_nets::{PaddedConv2d, Padding};
use serde::{Deserialize, Serialize};

/// Configuration of a [`FrameGenerator`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeneratorConfig {
    /// Upscaling factor, a power of two >= 2. Default 4.
    pub factor: usize,
    /// Feed the low-resolution velocity (2 more input channels) besides the density.
    /// Default false: density only, so any density sequence can be upscaled.
    pub use_velocity: bool,
    /// Width of the convs. Default 32.
    pub channels: usize,
}

impl Default for GeneratorConfig {
    fn default() -> Self {
        Self { factor: 4, use_velocity: false, channels: 32 }
    }
}

impl GeneratorConfig {
    /// Input channels: 1 (density) or 3 (density, velocity x, velocity y).
    pub fn in_channels(&self) -> usize {
        if self.use_velocity {
            3
        } else {
            1
        }
    }

    /// Checks the fields.
    pub fn validate(&self) -> Result<()> {
        if self.factor < 2 || !self.factor.is_power_of_two() {
            return Err(Error::config("factor", format!("{}; use a power of two >= 2", self.factor)));
        }
        if self.channels == 0 {
            return Err(Error::config("channels", "0; use a positive width"));
        }
        Ok(())
    }
}

/// The per-frame generator (see the module docs).
#[derive(Clone, Debug)]
pub struct FrameGenerator {
    config: GeneratorConfig,
    input: PaddedConv2d,
    blocks: Vec<ResBlock>,
    ups: Vec<PaddedConv2d>,
    output: PaddedConv2d,
}

fn block(channels: usize, vb: VarBuilder) -> Result<ResBlock> {
    let cfg = ResBlockConfig {
        channels,
        kernel: 3,
        activation: Activation::Relu,
        norm_groups: None,
        order: BlockOrder::PostActivation,
        padding: Padding::Zeros,
    };
    Ok(ResBlock::new(cfg, vb)?)
}

impl FrameGenerator {
    /// Builds the generator, taking (or creating) its variables in `vb` (`input.*`,
    /// `blocks.{i}.*`, `ups.{i}.*`, `output.*`).
    pub fn new(config: GeneratorConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let c = config.channels;
        let input = PaddedConv2d::same(config.in_channels(), c, 3, Padding::Zeros, vb.pp("input"))?;
        let levels = config.factor.trailing_zeros() as usize;
        let mut blocks = vec![block(c, vb.pp("blocks.0"))?];
        let mut ups = Vec::with_capacity(levels);
        for l in 0..levels {
            ups.push(PaddedConv2d::same(c, c, 3, Padding::Zeros, vb.pp(format!("ups.{l}")))?);
            blocks.push(block(c, vb.pp(format!("blocks.{}", l + 1)))?);
        }
        let output = PaddedConv2d::same(c, 1, 3, Padding::Zeros, vb.pp("output"))?;
        Ok(Self { config, input, blocks, ups, output })
    }

    /// The configuration.
    pub fn config(&self) -> &GeneratorConfig {
        &self.config
    }

    /// The high-resolution density `[B, 1, f y, f x]` of `density` `[B, 1, y, x]` (and
    /// `velocity` `[B, 2, y, x]` when the generator takes it).
    pub fn forward(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor> {
        let d = density.dims();
        if d.len() != 4 || d[1] != 1 || d[2] == 0 || d[3] == 0 {
            return Err(Error::input("density", format!("{d:?}: expected [batch, 1, y, x]")));
        }
        let x = match (self.config.use_velocity, velocity) {
            (true, Some(v)) => {
                let vd = v.dims();
                if vd.len() != 4 || vd[0] != d[0] || vd[1] != 2 || vd[2] != d[2] || vd[3] != d[3] {
                    return Err(Error::input(
                        "velocity",
                        format!("{vd:?}: expected [{}, 2, {}, {}] next to the density", d[0], d[2], d[3]),
                    ));
                }
                Tensor::cat(&[density, v], 1)?
            }
            (true, None) => {
                return Err(Error::input(
                    "velocity",
                    "missing: this generator was trained with the low-resolution velocity",
                ))
            }
            (false, _) => density.clone(),
        };
        let mut h = self.input.forward_act(&x, Activation::Relu)?;
        h = self.blocks[0].forward(&h)?;
        for (up, blk) in self.ups.iter().zip(&self.blocks[1..]) {
            h = up.forward_act(&upsample_nearest2(&h)?, Activation::Relu)?;
            h = blk.forward(&h)?;
        }
        let f = self.config.factor;
        let base = resize2d(density, (d[2] * f, d[3] * f), Resize::Bicubic { align_corners: false })?;
        Ok((self.output.forward(&h)? + base)?)
    }
}
