//! The 2D convolutional network of the observation predictors and the control force
//! estimator: a small U-Net on pbdl-core's `conv2d` (im2col + gemm) with zero padding (the box
//! is closed).

use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::conv::{Conv2d, Conv2dParams, ConvLayerConfig};
use pbdl_core::nn::Activation;
use serde::{Deserialize, Serialize};

/// Size of a [`ConvNet2d`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ConvNet2dConfig {
    /// Feature channels at every level. Default 8.
    pub width: usize,
    /// Resolution levels (each halves the grid by 2x2 averaging). Default 4 (32, 16, 8, 4).
    pub levels: usize,
    /// Kernel size (odd). Default 3.
    pub kernel: usize,
    /// Activation after every hidden convolution. Default GELU (smooth, so finite-difference
    /// checks see no kinks).
    pub activation: Activation,
}

impl Default for ConvNet2dConfig {
    fn default() -> Self {
        Self { width: 8, levels: 4, kernel: 3, activation: Activation::Gelu }
    }
}

impl ConvNet2dConfig {
    /// Checks the sizes against an `cells x cells` grid.
    pub fn validate(&self, cells: usize) -> Result<()> {
        const C: &str = "ConvNet2dConfig";
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
        if cells % div != 0 || cells / div < 2 {
            return Err(Error::invalid(
                C,
                "levels",
                format!(
                    "{} levels need cells divisible by {div} with at least 2 cells on the coarsest level; got {cells}",
                    self.levels
                ),
            ));
        }
        Ok(())
    }
}

/// A 2D U-Net `[batch, in, n, n] -> [batch, out, n, n]`: two convolutions per level on the way
/// down (2x2 averaging between levels) and on the way up (nearest-neighbour upsampling,
/// concatenated with the skip connection), then a 1x1 output convolution.
#[derive(Clone, Debug)]
pub struct ConvNet2d {
    down: Vec<[Conv2d; 2]>,
    up: Vec<[Conv2d; 2]>,
    out: Conv2d,
    act: Activation,
}

impl ConvNet2d {
    /// Creates the network, its variables under `vb`.
    pub fn new(
        in_channels: usize,
        out_channels: usize,
        cfg: &ConvNet2dConfig,
        cells: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        cfg.validate(cells)?;
        if in_channels == 0 || out_channels == 0 {
            return Err(Error::invalid("ConvNet2d::new", "channels", "in and out channels must be at least 1"));
        }
        let p = Conv2dParams::default().padding(cfg.kernel / 2);
        let conv = |i: usize, o: usize, name: String| -> Result<Conv2d> {
            Ok(ConvLayerConfig::new(i, o, [cfg.kernel, cfg.kernel]).with_params(p).init(vb.pp(name))?)
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
        let out = ConvLayerConfig::new(w, out_channels, [1, 1]).init(vb.pp("out"))?;
        Ok(Self { down, up, out, act: cfg.activation })
    }

    /// Applies the network to `x` `[batch, in, n, n]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut skips = Vec::new();
        let mut h = x.clone();
        for (l, [a, b]) in self.down.iter().enumerate() {
            if l > 0 {
                let (n, c, hh, ww) = h.dims4()?;
                h = h.reshape((n, c, hh / 2, 2, ww / 2, 2))?.mean(5)?.mean(3)?;
            }
            h = b.forward_act(&a.forward_act(&h, self.act)?, self.act)?;
            skips.push(h.clone());
        }
        skips.pop();
        for (l, [a, b]) in self.up.iter().enumerate().rev() {
            let (n, c, hh, ww) = h.dims4()?;
            h = h.reshape((n, c, hh, 1, ww, 1))?.broadcast_as((n, c, hh, 2, ww, 2))?.reshape((n, c, 2 * hh, 2 * ww))?;
            let skip =
                skips.pop().ok_or_else(|| Error::invalid("ConvNet2d", "levels", format!("no skip at level {l}")))?;
            h = Tensor::cat(&[&h, &skip], 1)?;
            h = b.forward_act(&a.forward_act(&h, self.act)?, self.act)?;
        }
        Ok(self.out.forward_act(&h, Activation::Identity)?)
    }
}
