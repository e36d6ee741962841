//! The frame-recurrent generator G and the combined F + G model.

use super::motion::{MotionNet, MotionNetConfig};
use crate::warp::{backward_warp, upsample_motion};
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::conv::{conv_transpose_act, Conv2dParams};
use pbdl_core::nn::Activation;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_nets::shuffle::pixel_unshuffle;
use pbdl_nets::{PaddedConv2d, Padding};
use serde::{Deserialize, Serialize};

/// Configuration of a [`RecurrentGenerator`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecurrentGeneratorConfig {
    /// Width of the convs (TecoGAN: 64). Default 32.
    pub channels: usize,
    /// Residual blocks at the low resolution (TecoGAN: 16, FRVSR: 10). Default 4.
    pub blocks: usize,
    /// Upscaling factor, a power of two >= 2: `log2(factor)` transposed-conv 2x steps and a
    /// `factor^2`-channel space-to-depth of the recurrent input. Default 4.
    pub factor: usize,
}

impl Default for RecurrentGeneratorConfig {
    fn default() -> Self {
        Self { channels: 32, blocks: 4, factor: 4 }
    }
}

impl RecurrentGeneratorConfig {
    /// Checks the fields ([`Error::Config`] naming the one to change).
    pub fn validate(&self) -> Result<()> {
        if self.factor < 2 || !self.factor.is_power_of_two() {
            return Err(Error::config("generator.factor", format!("{}; use a power of two >= 2", self.factor)));
        }
        if self.channels == 0 {
            return Err(Error::config("generator.channels", "0; use a positive width"));
        }
        Ok(())
    }
}

/// TecoGAN's (FRVSR's) frame-recurrent generator.
///
/// Input: the low-resolution frame `[B, 1, n, m]` and the previous high-resolution output
/// warped to the current frame `[B, 1, f n, f m]`, the latter by space-to-depth
/// (`pixel_unshuffle` by `f`, PyTorch's channel order) turned into `f^2` channels; frame 0 gets
/// zeros. Layout: a 3x3 conv to `channels` + ReLU; `blocks` residual blocks
/// `h + conv(relu(conv(h)))` (TecoGAN's: no activation after the sum); per 2x step a 3x3
/// transposed conv with stride 2 (padding 1, output padding 1, TecoGAN's "same"
/// deconvolution) and a ReLU; a 3x3 conv to 1 channel, added to the bicubic upsample of the low-resolution frame
/// (half-pixel centres, PyTorch's `a = -0.75`). Zero padding throughout. Variables: `input.*`,
/// `blocks.{i}.conv{1,2}.*`, `ups.{l}.weight` `[c, c, 3, 3]` (PyTorch's transposed layout),
/// `ups.{l}.bias`, `output.*`.
#[derive(Clone, Debug)]
pub struct RecurrentGenerator {
    config: RecurrentGeneratorConfig,
    input: PaddedConv2d,
    blocks: Vec<[PaddedConv2d; 2]>,
    ups: Vec<(Tensor, Tensor)>,
    output: PaddedConv2d,
}

impl RecurrentGenerator {
    /// Builds G, taking (or creating) its variables in `vb`.
    pub fn new(config: RecurrentGeneratorConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let (c, f) = (config.channels, config.factor);
        let conv = |i, o, vb| -> Result<PaddedConv2d> { Ok(PaddedConv2d::same(i, o, 3, Padding::Zeros, vb)?) };
        let input = conv(1 + f * f, c, vb.pp("input"))?;
        let blocks = (0..config.blocks)
            .map(|i| {
                Ok([conv(c, c, vb.pp(format!("blocks.{i}.conv1")))?, conv(c, c, vb.pp(format!("blocks.{i}.conv2")))?])
            })
            .collect::<Result<Vec<_>>>()?;
        let bound = 1.0 / ((c * 9) as f64).sqrt();
        let init = candle_nn::Init::Uniform { lo: -bound, up: bound };
        let ups = (0..f.trailing_zeros())
            .map(|l| {
                let vb = vb.pp(format!("ups.{l}"));
                Ok((vb.get_with_hints((c, c, 3, 3), "weight", init)?, vb.get_with_hints(c, "bias", init)?))
            })
            .collect::<Result<Vec<_>>>()?;
        let output = conv(c, 1, vb.pp("output"))?;
        Ok(Self { config, input, blocks, ups, output })
    }

    /// The configuration.
    pub fn config(&self) -> &RecurrentGeneratorConfig {
        &self.config
    }

    /// The high-resolution frame `[B, 1, f n, f m]` of `lr` `[B, 1, n, m]` given the warped
    /// previous output `[B, 1, f n, f m]` (`None`: zeros, as for frame 0).
    pub fn forward(&self, lr: &Tensor, warped_prev: Option<&Tensor>) -> Result<Tensor> {
        let d = lr.dims();
        let f = self.config.factor;
        if d.len() != 4 || d[1] != 1 || d[2] == 0 || d[3] == 0 {
            return Err(Error::input("lr frame", format!("{d:?}: expected [batch, 1, y, x]")));
        }
        let hr_shape = [d[0], 1, d[2] * f, d[3] * f];
        let prev = match warped_prev {
            Some(p) if p.dims() == hr_shape => p.clone(),
            Some(p) => {
                return Err(Error::input("warped previous output", format!("{:?}: expected {hr_shape:?}", p.dims())))
            }
            None => Tensor::zeros(hr_shape.as_slice(), lr.dtype(), lr.device())?,
        };
        let x = Tensor::cat(&[lr, &pixel_unshuffle(&prev, f)?], 1)?;
        let mut h = self.input.forward_act(&x, Activation::Relu)?;
        for [c1, c2] in &self.blocks {
            h = (c2.forward(&c1.forward_act(&h, Activation::Relu)?)? + h)?;
        }
        let params = Conv2dParams::default().stride(2).padding(1);
        for (w, b) in &self.ups {
            h = conv_transpose_act(&h, w, Some(b), &params, [1, 1], Activation::Relu)?;
        }
        let base = resize2d(lr, (hr_shape[2], hr_shape[3]), Resize::Bicubic { align_corners: false })?;
        Ok((self.output.forward(&h)? + base)?)
    }
}

/// Configuration of a [`TecoGan`] (F and G).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TecoGanConfig {
    /// The motion network F.
    pub motion: MotionNetConfig,
    /// The recurrent generator G.
    pub generator: RecurrentGeneratorConfig,
}

impl TecoGanConfig {
    /// Checks both parts.
    pub fn validate(&self) -> Result<()> {
        self.motion.validate()?;
        self.generator.validate()
    }
}

/// What [`TecoGan::run_batch`] returns.
#[derive(Clone, Debug)]
pub struct SequenceOutput {
    /// The generated frames `[B, T, 1, f n, f m]`.
    pub hr: Tensor,
    /// F's low-resolution flows `[B, T - 1, 2, n, m]`: entry `t - 1` warps frame `t - 1` onto
    /// frame `t`. `None` for a one-frame sequence.
    pub lr_flows: Option<Tensor>,
}

/// TecoGAN's F and G: frame `t` is `G(lr_t, backward_warp(g_{t-1}, up(F(lr_{t-1}, lr_t))))`,
/// frame 0 `G(lr_0, 0)`. Variables: `fnet.*` ([`MotionNet`]) and `generator.*`
/// ([`RecurrentGenerator`]).
#[derive(Clone, Debug)]
pub struct TecoGan {
    motion: MotionNet,
    generator: RecurrentGenerator,
}

impl TecoGan {
    /// Builds F and G in `vb` (call [`pbdl_nets::seeded_init`] on the `VarMap` for
    /// reproducible weights).
    pub fn new(config: TecoGanConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            motion: MotionNet::new(config.motion, vb.pp("fnet"))?,
            generator: RecurrentGenerator::new(config.generator, vb.pp("generator"))?,
        })
    }

    /// F.
    pub fn motion(&self) -> &MotionNet {
        &self.motion
    }

    /// G.
    pub fn generator(&self) -> &RecurrentGenerator {
        &self.generator
    }

    /// The upscaling factor.
    pub fn factor(&self) -> usize {
        self.generator.config.factor
    }

    /// Runs F and G over a batch of sequences `lr` `[B, T, 1, n, m]`, keeping the graph (for
    /// training: gradients reach F through the warp of the recurrent input and through the
    /// returned flows). F runs on all `T - 1` pairs at once, G frame by frame.
    pub fn run_batch(&self, lr: &Tensor) -> Result<SequenceOutput> {
        let d = lr.dims();
        if d.len() != 5 || d[1] == 0 || d[2] != 1 {
            return Err(Error::input("lr sequence", format!("{d:?}: expected [batch, frames, 1, y, x]")));
        }
        let (b, t, n, m) = (d[0], d[1], d[3], d[4]);
        let f = self.factor();
        let lr_flows = if t > 1 {
            let prev = lr.narrow(1, 0, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            let cur = lr.narrow(1, 1, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            Some(self.motion.flow(&prev, &cur)?.reshape((b, t - 1, 2, n, m))?)
        } else {
            None
        };
        let mut frames: Vec<Tensor> = Vec::with_capacity(t);
        for i in 0..t {
            let lr_i = lr.narrow(1, i, 1)?.squeeze(1)?;
            let g = match (&lr_flows, frames.last()) {
                (Some(flows), Some(prev)) => {
                    let flow = upsample_motion(&flows.narrow(1, i - 1, 1)?.squeeze(1)?, f)?;
                    self.generator.forward(&lr_i, Some(&backward_warp(prev, &flow)?))?
                }
                _ => self.generator.forward(&lr_i, None)?,
            };
            frames.push(g);
        }
        Ok(SequenceOutput { hr: Tensor::stack(&frames, 1)?, lr_flows })
    }

    /// One sequence `lr` `[T, 1, n, m]` to `[T, 1, f n, f m]` (a batch of one
    /// [`TecoGan::run_batch`]; the graph is kept).
    pub fn run_sequence(&self, lr: &Tensor) -> Result<Tensor> {
        if lr.rank() != 4 {
            return Err(Error::input("lr sequence", format!("{:?}: expected [frames, 1, y, x]", lr.dims())));
        }
        Ok(self.run_batch(&lr.unsqueeze(0)?)?.hr.squeeze(0)?)
    }

    /// [`TecoGan::run_sequence`] without a graph, frame by frame through a [`Rollout`] (memory
    /// independent of the length).
    pub fn infer_sequence(&self, lr: &Tensor) -> Result<Tensor> {
        if lr.rank() != 4 || lr.dim(0)? == 0 {
            return Err(Error::input("lr sequence", format!("{:?}: expected [frames, 1, y, x]", lr.dims())));
        }
        let mut r = Rollout::new(self);
        let out = (0..lr.dim(0)?).map(|t| r.step(&lr.narrow(0, t, 1)?)).collect::<Result<Vec<_>>>()?;
        Ok(Tensor::cat(&out, 0)?)
    }
}

/// Frame-by-frame generation without a graph: each output is detached before it becomes the
/// next recurrent input, so arbitrarily long sequences run in constant memory.
#[derive(Clone, Debug)]
pub struct Rollout<'a> {
    model: &'a TecoGan,
    prev_lr: Option<Tensor>,
    prev_hr: Option<Tensor>,
}

impl<'a> Rollout<'a> {
    /// A rollout at frame 0 (no previous frame).
    pub fn new(model: &'a TecoGan) -> Self {
        Self { model, prev_lr: None, prev_hr: None }
    }

    /// Forgets the previous frame: the next [`Rollout::step`] is a frame 0 again.
    pub fn reset(&mut self) {
        self.prev_lr = None;
        self.prev_hr = None;
    }

    /// The next output `[B, 1, f n, f m]` for the low-resolution frame `lr` `[B, 1, n, m]`.
    pub fn step(&mut self, lr: &Tensor) -> Result<Tensor> {
        let lr = lr.detach();
        let g = match (&self.prev_lr, &self.prev_hr) {
            (Some(pl), Some(ph)) => {
                let flow = upsample_motion(&self.model.motion.flow(pl, &lr)?, self.model.factor())?;
                self.model.generator.forward(&lr, Some(&backward_warp(ph, &flow)?))?
            }
            _ => self.model.generator.forward(&lr, None)?,
        }
        .detach();
        self.prev_lr = Some(lr);
        self.prev_hr = Some(g.clone());
        Ok(g)
    }
}
