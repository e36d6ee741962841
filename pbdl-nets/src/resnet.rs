//! Residual convolution blocks and a ResNet stack `[B, C, H, W] -> [B, C', H, W]` that keeps
//! the resolution, as the WeatherBench ResNet (Rasp and Thuerey 2021) is built.
//!
//! A conv unit is a size-preserving [`PaddedConv2d`], an optional GroupNorm and an
//! activation; their order is the block's [`BlockOrder`]:
//!
//! * [`BlockOrder::PostActivation`]: `u(h) = act(norm(conv(h)))`, WeatherBench's `convblock`
//!   (with the norm in the middle position) and the original ResNet's order.
//! * [`BlockOrder::PreActivation`]: `u(h) = conv(act(norm(h)))` (He et al. 2016, "Identity
//!   mappings in deep residual networks").
//!
//! A [`ResBlock`] is `x + u2(u1(x))`. The [`ResNet`] is an input conv `in -> width`
//! (post-activation: a full unit; pre-activation: the conv alone), `blocks` residual blocks at
//! `width`, (pre-activation: a final norm and activation,) and an output conv `width -> out`
//! without activation. With [`Padding::PeriodicX`] every conv wraps around in x (longitude)
//! and zero-pads in y (latitude), as WeatherBench's `PeriodicConv2D`.
//!
//! Norms are GroupNorms (`norm_groups` groups; 1 group normalises each sample over all
//! channels and pixels): batch norm is not offered, its running statistics do not fit the
//! stateless layers here.

use crate::padding::{PaddedConv2d, Padding};
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::{Activation, GroupNorm, GroupNormConfig};
use serde::{Deserialize, Serialize};

/// Where the activation (and norm) sits relative to the convolution; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BlockOrder {
    /// `conv -> norm -> act` (WeatherBench, original ResNet). The default.
    #[default]
    PostActivation,
    /// `norm -> act -> conv` (identity-mapping ResNet).
    PreActivation,
}

/// Configuration of a [`ResBlock`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResBlockConfig {
    /// Channels in and out.
    pub channels: usize,
    /// Odd kernel size of both convs.
    pub kernel: usize,
    /// Activation of each unit.
    pub activation: Activation,
    /// GroupNorm groups (dividing `channels`), or `None` for no norm.
    pub norm_groups: Option<usize>,
    /// Order of conv, norm and activation.
    pub order: BlockOrder,
    /// Border handling of the convs.
    pub padding: Padding,
}

/// Checks a norm's group count against the width it normalises.
fn check_groups(norm_groups: Option<usize>, channels: usize) -> Result<()> {
    match norm_groups {
        Some(g) if g == 0 || channels % g != 0 => Err(Error::InvalidConfig {
            name: "norm_groups",
            value: format!("{g} for {channels} channels"),
            hint: "use a group count that divides the width (1 normalises over all channels)",
        }),
        _ => Ok(()),
    }
}

fn group_norm(groups: Option<usize>, channels: usize, vb: VarBuilder) -> Result<Option<GroupNorm>> {
    Ok(groups.map(|g| GroupNorm::new(g, channels, GroupNormConfig::default(), vb)).transpose()?)
}

/// One conv unit: conv, optional norm, activation, in the order of a [`BlockOrder`].
#[derive(Clone, Debug)]
struct ConvUnit {
    conv: PaddedConv2d,
    norm: Option<GroupNorm>,
    activation: Activation,
    order: BlockOrder,
}

impl ConvUnit {
    /// Variables: `conv.*` and `norm.*` (the norm over `c_out` post-activation, `c_in` pre).
    fn new(c_in: usize, c_out: usize, cfg: &ResBlockConfig, vb: VarBuilder) -> Result<Self> {
        let norm_width = match cfg.order {
            BlockOrder::PostActivation => c_out,
            BlockOrder::PreActivation => c_in,
        };
        Ok(Self {
            conv: PaddedConv2d::same(c_in, c_out, cfg.kernel, cfg.padding, vb.pp("conv"))?,
            norm: group_norm(cfg.norm_groups, norm_width, vb.pp("norm"))?,
            activation: cfg.activation,
            order: cfg.order,
        })
    }

    /// The norm (if any) and the activation; ReLU/LeakyReLU run inside the norm kernel.
    fn norm_act(&self, h: &Tensor) -> Result<Tensor> {
        Ok(match &self.norm {
            Some(n) => n.apply_act(h, self.activation)?,
            None => self.activation.apply(h)?,
        })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match (self.order, &self.norm) {
            // Without a norm the activation follows the conv directly: fuse it there.
            (BlockOrder::PostActivation, None) => self.conv.forward_act(x, self.activation),
            (BlockOrder::PostActivation, Some(_)) => self.norm_act(&self.conv.forward(x)?),
            (BlockOrder::PreActivation, _) => self.conv.forward(&self.norm_act(x)?),
        }
    }
}

/// A residual block `x + u2(u1(x))` of two conv units (`unit1.*`, `unit2.*`).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::VarBuilder;
/// use pbdl_core::nn::Activation;
/// use pbdl_nets::resnet::{BlockOrder, ResBlock, ResBlockConfig};
/// use pbdl_nets::Padding;
///
/// let cfg = ResBlockConfig {
///     channels: 8,
///     kernel: 3,
///     activation: Activation::Relu,
///     norm_groups: Some(2),
///     order: BlockOrder::PreActivation,
///     padding: Padding::Periodic,
/// };
/// let block = ResBlock::new(cfg, VarBuilder::zeros(DType::F32, &Device::Cpu))?;
/// let x = Tensor::ones((2, 8, 6, 6), DType::F32, &Device::Cpu)?;
/// // Zero weights: the residual branch vanishes and the block is the identity.
/// assert_eq!(block.forward(&x)?.flatten_all()?.to_vec1::<f32>()?, vec![1.0; 2 * 8 * 36]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct ResBlock {
    channels: usize,
    unit1: ConvUnit,
    unit2: ConvUnit,
}

impl ResBlock {
    /// Builds the block, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for zero channels, an even kernel or groups that do not divide
    /// the channels.
    pub fn new(config: ResBlockConfig, vb: VarBuilder) -> Result<Self> {
        check_groups(config.norm_groups, config.channels)?;
        let c = config.channels;
        Ok(Self {
            channels: c,
            unit1: ConvUnit::new(c, c, &config, vb.pp("unit1"))?,
            unit2: ConvUnit::new(c, c, &config, vb.pp("unit2"))?,
        })
    }

    /// `x + u2(u1(x))` for `x` `[batch, channels, y, x]`; same shape out.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong rank or channel count.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        if x.rank() != 4 || x.dim(1)? != self.channels {
            return Err(Error::shape("ResBlock input", format!("[batch, {}, y, x]", self.channels), x.dims()));
        }
        Ok((self.unit2.forward(&self.unit1.forward(x)?)? + x)?)
    }
}

/// Configuration of a [`ResNet`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResNetConfig {
    /// Input channels `C`.
    pub in_channels: usize,
    /// Output channels `C'`.
    pub out_channels: usize,
    /// Width of the residual blocks.
    pub width: usize,
    /// Number of residual blocks.
    pub blocks: usize,
    /// Odd kernel size of every conv.
    pub kernel: usize,
    /// Activation of each unit.
    pub activation: Activation,
    /// GroupNorm groups (dividing `width`), or `None` for no norm.
    pub norm_groups: Option<usize>,
    /// Order of conv, norm and activation.
    pub order: BlockOrder,
    /// Border handling of the convs.
    pub padding: Padding,
}

impl ResNetConfig {
    /// A post-activation ResNet without norm, LeakyReLU (slope 0.3, Keras' default), kernel 3,
    /// zero padding; set `padding: Padding::PeriodicX` for global fields.
    pub fn new(in_channels: usize, out_channels: usize, width: usize, blocks: usize) -> Self {
        Self {
            in_channels,
            out_channels,
            width,
            blocks,
            kernel: 3,
            activation: Activation::LeakyRelu { negative_slope: 0.3 },
            norm_groups: None,
            order: BlockOrder::PostActivation,
            padding: Padding::Zeros,
        }
    }

    fn block(&self) -> ResBlockConfig {
        ResBlockConfig {
            channels: self.width,
            kernel: self.kernel,
            activation: self.activation,
            norm_groups: self.norm_groups,
            order: self.order,
            padding: self.padding,
        }
    }
}

/// A resolution-preserving ResNet (see the module docs). Variables: `input.*`, `blocks.{i}.*`,
/// `final_norm.*` (pre-activation with a norm), `output.*`.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::resnet::{ResNet, ResNetConfig};
/// use pbdl_nets::Padding;
///
/// let varmap = VarMap::new();
/// let cfg = ResNetConfig { padding: Padding::PeriodicX, ..ResNetConfig::new(3, 2, 16, 2) };
/// let net = ResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
/// pbdl_nets::seeded_init(&varmap, 0)?;
/// let x = Tensor::zeros((4, 3, 8, 16), DType::F32, &Device::Cpu)?; // [batch, C, lat, lon]
/// assert_eq!(net.forward(&x)?.dims(), &[4, 2, 8, 16]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct ResNet {
    config: ResNetConfig,
    input: ConvUnit,
    blocks: Vec<ResBlock>,
    final_norm: Option<GroupNorm>,
    output: PaddedConv2d,
}

impl ResNet {
    /// Builds the network, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for zero channels or width, an even kernel, or groups that do
    /// not divide the width.
    pub fn new(config: ResNetConfig, vb: VarBuilder) -> Result<Self> {
        if config.in_channels == 0 || config.out_channels == 0 || config.width == 0 {
            return Err(Error::InvalidConfig {
                name: "ResNetConfig channels",
                value: format!("{} -> {} -> {}", config.in_channels, config.width, config.out_channels),
                hint: "use at least one channel in, in the blocks and out",
            });
        }
        check_groups(config.norm_groups, config.width)?;
        let block = config.block();
        let input = match config.order {
            BlockOrder::PostActivation => ConvUnit::new(config.in_channels, config.width, &block, vb.pp("input"))?,
            // Pre-activation starts with a bare conv: no norm or activation on the raw input.
            BlockOrder::PreActivation => ConvUnit {
                conv: PaddedConv2d::same(
                    config.in_channels,
                    config.width,
                    config.kernel,
                    config.padding,
                    vb.pp("input.conv"),
                )?,
                norm: None,
                activation: Activation::Identity,
                order: BlockOrder::PreActivation,
            },
        };
        let blocks = (0..config.blocks)
            .map(|i| ResBlock::new(block, vb.pp(format!("blocks.{i}"))))
            .collect::<Result<Vec<_>>>()?;
        let final_norm = match config.order {
            BlockOrder::PreActivation => group_norm(config.norm_groups, config.width, vb.pp("final_norm"))?,
            BlockOrder::PostActivation => None,
        };
        let output =
            PaddedConv2d::same(config.width, config.out_channels, config.kernel, config.padding, vb.pp("output"))?;
        Ok(Self { config, input, blocks, final_norm, output })
    }

    /// The configuration.
    pub fn config(&self) -> &ResNetConfig {
        &self.config
    }

    /// The network on `x` `[batch, in_channels, y, x]`; returns `[batch, out_channels, y, x]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong rank or channel count (or, with periodic x padding,
    /// fewer columns than `kernel / 2`).
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let c = self.config.in_channels;
        if x.rank() != 4 || x.dim(1)? != c {
            return Err(Error::shape("ResNet input", format!("[batch, {c}, y, x]"), x.dims()));
        }
        let mut h = self.input.forward(x)?;
        for block in &self.blocks {
            h = block.forward(&h)?;
        }
        if self.config.order == BlockOrder::PreActivation {
            if let Some(n) = &self.final_norm {
                h = n.apply(&h)?;
            }
            h = self.config.activation.apply(&h)?;
        }
        self.output.forward(&h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn shapes_variables_and_errors() {
        for order in [BlockOrder::PostActivation, BlockOrder::PreActivation] {
            let varmap = VarMap::new();
            let cfg = ResNetConfig { order, norm_groups: Some(2), kernel: 5, ..ResNetConfig::new(3, 1, 4, 2) };
            let net = ResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu)).unwrap();
            let y = net.forward(&Tensor::zeros((2, 3, 6, 10), DType::F32, &Device::Cpu).unwrap()).unwrap();
            assert_eq!(y.dims(), &[2, 1, 6, 10]);
            let data = varmap.data().lock().unwrap();
            assert_eq!(data["input.conv.weight"].dims(), &[4, 3, 5, 5]);
            assert_eq!(data["blocks.1.unit2.norm.weight"].dims(), &[4]);
            assert_eq!(data["output.weight"].dims(), &[1, 4, 5, 5]);
            assert_eq!(data.contains_key("input.norm.weight"), order == BlockOrder::PostActivation);
            assert_eq!(data.contains_key("final_norm.weight"), order == BlockOrder::PreActivation);
            let wrong = Tensor::zeros((2, 2, 6, 10), DType::F32, &Device::Cpu).unwrap();
            assert!(matches!(net.forward(&wrong), Err(Error::ShapeMismatch { .. })));
        }
        let vb = VarBuilder::zeros(DType::F32, &Device::Cpu);
        let bad = ResNetConfig { norm_groups: Some(3), ..ResNetConfig::new(3, 1, 4, 2) };
        assert!(matches!(ResNet::new(bad, vb.clone()), Err(Error::InvalidConfig { .. })));
        let bad = ResNetConfig { kernel: 4, ..ResNetConfig::new(3, 1, 4, 2) };
        assert!(matches!(ResNet::new(bad, vb), Err(Error::InvalidConfig { .. })));
    }
}
