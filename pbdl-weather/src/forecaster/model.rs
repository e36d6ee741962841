//! The Rasp & Thuerey (2021) ResNet: periodic-in-longitude convolutions, LeakyReLU,
//! BatchNorm, dropout and residual blocks at constant resolution.
//!
//! A conv block is `periodic conv -> LeakyReLU(0.3) -> BatchNorm -> Dropout`; the network is
//! one block at `first_kernel` (7x7) from the inputs to `width` channels, `blocks` residual
//! blocks `x + block(block(x))` at 3x3, and a final periodic 3x3 conv to the outputs (no
//! activation). The full-size network (117 inputs, width 128, 19 residual blocks, 3 outputs)
//! has 6,365,571 parameters as Keras counts them (BatchNorm's running mean and variance
//! included), 6,371,843 with the continuous lead-time channel: [`ResNetConfig::full_size`].

use crate::error::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::{Activation, BatchNorm2d, BatchNormConfig};
use pbdl_nets::dropout::Dropout;
use pbdl_nets::{PaddedConv2d, Padding};
use serde::{Deserialize, Serialize};

/// Shape and regularisation of the ResNet.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResNetConfig {
    /// Input channels (variables x past times + constants [+ lead time]).
    pub in_channels: usize,
    /// Output channels (the predicted variables).
    pub out_channels: usize,
    /// Channels of every hidden layer.
    pub width: usize,
    /// Residual blocks.
    pub blocks: usize,
    /// Kernel of the first conv (7 in the paper).
    pub first_kernel: usize,
    /// Kernel of the other convs (3).
    pub kernel: usize,
    /// Dropout probability after every block's norm (0.1 in the paper's best model).
    pub dropout: f64,
    /// Negative slope of the LeakyReLU (0.3, Keras' default).
    pub leaky_slope: f64,
}

impl ResNetConfig {
    /// The paper's network: width 128, 19 residual blocks, kernels 7 and 3, dropout 0.1.
    /// `in_channels` = 117 (38 channels at t, t-6h, t-12h plus 3 constants) or 118 with the
    /// continuous lead time; 3 outputs (z500, t850, t2m).
    pub fn full_size(in_channels: usize, out_channels: usize) -> Self {
        Self {
            in_channels,
            out_channels,
            width: 128,
            blocks: 19,
            first_kernel: 7,
            kernel: 3,
            dropout: 0.1,
            leaky_slope: 0.3,
        }
    }

    /// A network that trains on two CPU cores in minutes: width 32, 4 residual blocks.
    pub fn cpu_size(in_channels: usize, out_channels: usize) -> Self {
        Self { width: 32, blocks: 4, ..Self::full_size(in_channels, out_channels) }
    }

    fn check(&self) -> Result<()> {
        let odd = |k: usize| k % 2 == 1;
        if self.in_channels == 0 || self.out_channels == 0 || self.width == 0 {
            return Err(Error::InvalidArgument(format!("ResNet channels must be positive: {self:?}")));
        }
        if !odd(self.first_kernel) || !odd(self.kernel) {
            return Err(Error::InvalidArgument(format!(
                "ResNet kernels must be odd to keep the grid size (got {} and {})",
                self.first_kernel, self.kernel
            )));
        }
        if !(0.0..1.0).contains(&self.dropout) || self.leaky_slope.is_nan() || self.leaky_slope <= 0.0 {
            return Err(Error::InvalidArgument(format!(
                "dropout must be in [0, 1) and the LeakyReLU slope positive (got {}, {})",
                self.dropout, self.leaky_slope
            )));
        }
        Ok(())
    }
}

/// `periodic conv -> LeakyReLU -> BatchNorm -> Dropout`.
#[derive(Clone, Debug)]
struct ConvBlock {
    conv: PaddedConv2d,
    norm: BatchNorm2d,
    dropout: Dropout,
    activation: Activation,
}

impl ConvBlock {
    fn new(c_in: usize, c_out: usize, kernel: usize, cfg: &ResNetConfig, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            conv: PaddedConv2d::same(c_in, c_out, kernel, Padding::PeriodicX, vb.pp("conv")).map_err(nets_err)?,
            norm: BatchNorm2d::new(c_out, BatchNormConfig { momentum: 0.01, ..Default::default() }, vb.pp("bn"))
                .map_err(core_err)?,
            dropout: Dropout::new(cfg.dropout).map_err(nets_err)?,
            activation: Activation::LeakyRelu { negative_slope: cfg.leaky_slope },
        })
    }

    fn forward(&self, x: &Tensor, train: bool, seed: u64) -> Result<Tensor> {
        let h = self.conv.forward_act(x, self.activation).map_err(nets_err)?;
        let h = self.norm.forward(&h, train).map_err(core_err)?;
        if self.dropout.p() > 0.0 && train {
            self.dropout.forward(&h, true, seed).map_err(nets_err)
        } else {
            Ok(h)
        }
    }
}

pub(crate) fn nets_err(e: pbdl_nets::Error) -> Error {
    Error::Model(e.to_string())
}

pub(crate) fn core_err(e: impl std::fmt::Display) -> Error {
    Error::Model(e.to_string())
}

/// The WeatherBench ResNet `[B, in, lat, lon] -> [B, out, lat, lon]`.
#[derive(Clone, Debug)]
pub struct WeatherResNet {
    config: ResNetConfig,
    input: ConvBlock,
    blocks: Vec<(ConvBlock, ConvBlock)>,
    output: PaddedConv2d,
}

impl WeatherResNet {
    /// Builds the network's variables under `vb` (`in.*`, `block<i>.a.*`, `block<i>.b.*`, `out.*`).
    pub fn new(config: ResNetConfig, vb: VarBuilder) -> Result<Self> {
        config.check()?;
        let input = ConvBlock::new(config.in_channels, config.width, config.first_kernel, &config, vb.pp("in"))?;
        let blocks = (0..config.blocks)
            .map(|i| {
                let b = vb.pp(format!("block{i}"));
                Ok((
                    ConvBlock::new(config.width, config.width, config.kernel, &config, b.pp("a"))?,
                    ConvBlock::new(config.width, config.width, config.kernel, &config, b.pp("b"))?,
                ))
            })
            .collect::<Result<_>>()?;
        let output =
            PaddedConv2d::same(config.width, config.out_channels, config.kernel, Padding::PeriodicX, vb.pp("out"))
                .map_err(nets_err)?;
        Ok(Self { config, input, blocks, output })
    }

    /// The configuration.
    pub fn config(&self) -> &ResNetConfig {
        &self.config
    }

    /// The forecast; `train` uses batch statistics (and updates the running ones) and dropout
    /// with masks drawn from `seed`.
    pub fn forward(&self, x: &Tensor, train: bool, seed: u64) -> Result<Tensor> {
        let c = x.dims().get(1).copied().unwrap_or(0);
        if x.rank() != 4 || c != self.config.in_channels {
            return Err(Error::InvalidArgument(format!(
                "ResNet input must be [batch, {}, lat, lon], got {:?}",
                self.config.in_channels,
                x.dims()
            )));
        }
        let mut h = self.input.forward(x, train, seed)?;
        for (i, (a, b)) in self.blocks.iter().enumerate() {
            let s = seed.wrapping_add(2 * i as u64 + 1).wrapping_mul(0x9E37_79B9);
            let r = b.forward(&a.forward(&h, train, s)?, train, s ^ 0x5555)?;
            h = (h + r).map_err(core_err)?;
        }
        self.output.forward(&h).map_err(nets_err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn full_size_parameter_counts_equal_the_papers() {
        // Keras counts BatchNorm's moving mean and variance as (non-trainable) parameters;
        // the VarMap holds them too, so its total is comparable.
        for (inputs, published) in [(117, 6_365_571), (118, 6_371_843)] {
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
            WeatherResNet::new(ResNetConfig::full_size(inputs, 3), vb).unwrap();
            assert_eq!(pbdl_nets::count_parameters(&varmap), published, "{inputs} inputs");
        }
    }

    #[test]
    fn the_network_commutes_with_rolls_in_longitude() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = WeatherResNet::new(ResNetConfig { width: 8, blocks: 2, ..ResNetConfig::cpu_size(3, 2) }, vb).unwrap();
        pbdl_nets::seeded_init(&varmap, 3).unwrap();
        let x = pbdl_core::seed::randn((2, 3, 8, 16), 0.0, 1.0, DType::F32, &Device::Cpu, 4).unwrap();
        let roll = |t: &Tensor, n: usize| {
            Tensor::cat(&[t.narrow(3, 16 - n, n).unwrap(), t.narrow(3, 0, 16 - n).unwrap()], 3).unwrap()
        };
        let y = net.forward(&x, false, 0).unwrap();
        for n in [1, 5, 8] {
            let a = net.forward(&roll(&x, n), false, 0).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let b = roll(&y, n).flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert_eq!(a, b, "roll by {n}");
        }
    }
}
