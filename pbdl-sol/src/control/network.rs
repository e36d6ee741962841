//! The 1D convolutional network of the observation predictors and the control force
//! estimator: a small periodic U-Net (pbdl-core's `conv1d` with circular padding).

use crate::{Error, Result};
use candle_core::{Tensor, D};
use candle_nn::VarBuilder;
use pbdl_core::conv::{Conv1d, Conv1dParams, ConvLayerConfig};
use pbdl_core::nn::Activation;
use serde::{Deserialize, Serialize};

/// Size of a [`ConvNet1d`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ConvNetConfig {
    /// Feature channels at every level. Default 16.
    pub width: usize,
    /// Resolution levels (each halves the grid by averaging pairs). Default 3 (128, 64, 32).
    pub levels: usize,
    /// Kernel size (odd). Default 5.
    pub kernel: usize,
    /// Activation after every hidden convolution. Default ReLU (a smooth one, e.g. GELU,
    /// makes finite-difference checks free of kinks).
    pub activation: Activation,
}

impl Default for ConvNetConfig {
    fn default() -> Self {
        Self { width: 16, levels: 3, kernel: 5, activation: Activation::Relu }
    }
}

impl ConvNetConfig {
    /// Checks the sizes against a grid of `cells` cells.
    pub fn validate(&self, cells: usize) -> Result<()> {
        const C: &str = "ConvNetConfig";
        if self.width == 0 {
            return Err(Error::invalid(C, "width", "must be at least 1"));
        }
        if self.kernel == 0 || self.kernel % 2 == 0 {
            return Err(Error::invalid(C, "kernel", format!("must be odd, got {}", self.kernel)));
        }
        if self.levels == 0 || self.levels > 8 {
            return Err(Error::invalid(C, "levels", format!("must be in 1..=8, got {}", self.levels)));
        }
        let div = 1usize << (self.levels - 1);
        if cells % div != 0 || cells / div < self.kernel {
            return Err(Error::invalid(
                C,
                "levels",
                format!(
                    "{} levels need cells divisible by {div} with at least `kernel` cells left on the coarsest level; got {cells} cells",
                    self.levels
                ),
            ));
        }
        Ok(())
    }
}

/// A periodic 1D U-Net `[batch, in, cells] -> [batch, out, cells]`: two convolutions per
/// level on the way down (pair averaging between levels) and on the way up (nearest-neighbour
/// upsampling, concatenated with the skip connection), a 1x1 output convolution. The
/// activation is [`ConvNetConfig::activation`].
#[derive(Clone, Debug)]
pub struct ConvNet1d {
    down: Vec<[Conv1d; 2]>,
    up: Vec<[Conv1d; 2]>,
    out: Conv1d,
    act: Activation,
}

impl ConvNet1d {
    /// Creates the network, its variables under `vb`.
    pub fn new(
        in_channels: usize,
        out_channels: usize,
        cfg: &ConvNetConfig,
        cells: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        cfg.validate(cells)?;
        if in_channels == 0 || out_channels == 0 {
            return Err(Error::invalid("ConvNet1d::new", "channels", "in and out channels must be at least 1"));
        }
        let p = Conv1dParams::default().padding(cfg.kernel / 2).circular();
        let conv = |i: usize, o: usize, name: String| -> Result<Conv1d> {
            Ok(ConvLayerConfig::new(i, o, [cfg.kernel]).with_params(p).init(vb.pp(name))?)
        };
        let w = cfg.width;
        let mut down = Vec::new();
        for l in 0..cfg.levels {
            let i = if l == 0 { in_channels } else { w };
            down.push([conv(i, w, format!("down{l}.0"))?, conv(w, w, format!("down{l}.1"))?]);
        }
        let mut up = Vec::new();
        for l in 0..cfg.levels - 1 {
            up.push([conv(2 * w, w, format!("up{l}.0"))?, conv(w, w, format!("up{l}.1"))?]);
        }
        let out = ConvLayerConfig::new(w, out_channels, [1]).init(vb.pp("out"))?;
        Ok(Self { down, up, out, act: cfg.activation })
    }

    /// Applies the network to `x` `[batch, in, cells]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut skips = Vec::new();
        let mut h = x.clone();
        for (l, [a, b]) in self.down.iter().enumerate() {
            if l > 0 {
                let (n, c, len) = h.dims3()?;
                h = h.reshape((n, c, len / 2, 2))?.mean(D::Minus1)?;
            }
            h = b.forward_act(&a.forward_act(&h, self.act)?, self.act)?;
            skips.push(h.clone());
        }
        skips.pop();
        for (l, [a, b]) in self.up.iter().enumerate().rev() {
            let (n, c, len) = h.dims3()?;
            h = h.unsqueeze(3)?.broadcast_as((n, c, len, 2))?.reshape((n, c, 2 * len))?;
            let skip =
                skips.pop().ok_or_else(|| Error::invalid("ConvNet1d", "levels", format!("no skip at level {l}")))?;
            h = Tensor::cat(&[&h, &skip], 1)?;
            h = b.forward_act(&a.forward_act(&h, self.act)?, self.act)?;
        }
        Ok(self.out.forward_act(&h, Activation::Identity)?)
    }
}
