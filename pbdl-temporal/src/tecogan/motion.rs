//! The motion network F.

use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::Activation;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_nets::{PaddedConv2d, Padding};
use serde::{Deserialize, Serialize};

const LEAKY: Activation = Activation::LeakyRelu { negative_slope: 0.2 };

/// Configuration of a [`MotionNet`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionNetConfig {
    /// Width of the first encoder level; level `l` has `base_width * 2^l` channels and the
    /// decoder mirrors them at twice the width (TecoGAN: 32). Default 16.
    pub base_width: usize,
    /// Encoder (and decoder) levels, each halving (doubling) the resolution; the input size
    /// must be divisible by `2^levels` (TecoGAN: 3). Default 2, for 16^2 inputs.
    pub levels: usize,
    /// Bound of the flow in low-resolution cells: the output is `tanh(.) * max_flow`
    /// (TecoGAN: 24). Default 4.
    pub max_flow: f64,
}

impl Default for MotionNetConfig {
    fn default() -> Self {
        Self { base_width: 16, levels: 2, max_flow: 4.0 }
    }
}

impl MotionNetConfig {
    /// Checks the fields ([`Error::Config`] naming the one to change).
    pub fn validate(&self) -> Result<()> {
        if self.base_width == 0 {
            return Err(Error::config("motion.base_width", "0; use a positive width"));
        }
        if !(1..=5).contains(&self.levels) {
            return Err(Error::config("motion.levels", format!("{}; use 1 to 5 levels", self.levels)));
        }
        if !(self.max_flow > 0.0 && self.max_flow.is_finite()) {
            return Err(Error::config("motion.max_flow", format!("{}; use a positive finite bound", self.max_flow)));
        }
        Ok(())
    }

    /// The factor by which the input height and width must be divisible (`2^levels`).
    pub fn size_multiple(&self) -> usize {
        1 << self.levels
    }
}

/// TecoGAN's motion network F: `[B, 2, n, m]` (channel 0 the previous low-resolution frame,
/// channel 1 the current one) to the flow `[B, 2, n, m]` in low-resolution cells that warps the
/// previous frame onto the current one (`backward_warp(prev, flow) ~ cur`).
///
/// Layout: per encoder level two 3x3 convs + leaky ReLU 0.2 and a 2x max-pool (pbdl_core::nn's PyTorch-style pool); per decoder
/// level two 3x3 convs + leaky ReLU 0.2 and a bilinear 2x upsample (half-pixel centres); a 3x3
/// conv to `base_width` + leaky ReLU, a 3x3 conv to 2, `tanh * max_flow`. Zero padding.
/// Variables: `enc.{l}.{0,1}.*`, `dec.{l}.{0,1}.*`, `head.{0,1}.*`.
#[derive(Clone, Debug)]
pub struct MotionNet {
    config: MotionNetConfig,
    enc: Vec<[PaddedConv2d; 2]>,
    dec: Vec<[PaddedConv2d; 2]>,
    head: [PaddedConv2d; 2],
}

fn conv(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<PaddedConv2d> {
    Ok(PaddedConv2d::same(c_in, c_out, 3, Padding::Zeros, vb)?)
}

fn pair(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<[PaddedConv2d; 2]> {
    Ok([conv(c_in, c_out, vb.pp("0"))?, conv(c_out, c_out, vb.pp("1"))?])
}

impl MotionNet {
    /// Builds F, taking (or creating) its variables in `vb`.
    pub fn new(config: MotionNetConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let (b, levels) = (config.base_width, config.levels);
        let mut enc = Vec::with_capacity(levels);
        let mut c = 2;
        for l in 0..levels {
            enc.push(pair(c, b << l, vb.pp(format!("enc.{l}")))?);
            c = b << l;
        }
        let mut dec = Vec::with_capacity(levels);
        for l in 0..levels {
            let w = b << (levels - l);
            dec.push(pair(c, w, vb.pp(format!("dec.{l}")))?);
            c = w;
        }
        let head = [conv(c, b, vb.pp("head.0"))?, conv(b, 2, vb.pp("head.1"))?];
        Ok(Self { config, enc, dec, head })
    }

    /// The configuration.
    pub fn config(&self) -> &MotionNetConfig {
        &self.config
    }

    /// The flow `[B, 2, n, m]` (low-resolution cells) of `frames` `[B, 2, n, m]` (previous,
    /// current); `n` and `m` must be divisible by `2^levels`.
    pub fn forward(&self, frames: &Tensor) -> Result<Tensor> {
        let d = frames.dims();
        let k = self.config.size_multiple();
        if d.len() != 4 || d[1] != 2 || d[2] == 0 || d[3] == 0 || d[2] % k != 0 || d[3] % k != 0 {
            return Err(Error::input(
                "motion input",
                format!("{d:?}: expected [batch, 2 (previous, current), y, x] with y and x multiples of {k}"),
            ));
        }
        let mut h = frames.clone();
        for [c0, c1] in &self.enc {
            h = c1.forward_act(&c0.forward_act(&h, LEAKY)?, LEAKY)?;
            // Not candle's `max_pool2d`: its backward (candle 0.11) multiplies the gradient by
            // (ties / 4) instead of dividing by the ties, a 4x too small gradient for F's
            // encoder (caught by the finite-difference test of the ping-pong loss).
            h = pbdl_core::nn::max_pool2d(&h, 2, 2)?;
        }
        for [c0, c1] in &self.dec {
            h = c1.forward_act(&c0.forward_act(&h, LEAKY)?, LEAKY)?;
            let (y, x) = (h.dim(2)?, h.dim(3)?);
            h = resize2d(&h, (2 * y, 2 * x), Resize::Bilinear { align_corners: false })?;
        }
        h = self.head[0].forward_act(&h, LEAKY)?;
        Ok((self.head[1].forward(&h)?.tanh()? * self.config.max_flow)?)
    }

    /// The flow from `prev` to `cur` (both `[B, 1, n, m]`): [`MotionNet::forward`] of their
    /// channel concatenation.
    pub fn flow(&self, prev: &Tensor, cur: &Tensor) -> Result<Tensor> {
        if prev.dims() != cur.dims() || prev.rank() != 4 || prev.dim(1)? != 1 {
            return Err(Error::input(
                "motion frames",
                format!("{:?} and {:?}: expected two [batch, 1, y, x] frames of one shape", prev.dims(), cur.dims()),
            ));
        }
        self.forward(&Tensor::cat(&[prev, cur], 1)?)
    }
}
