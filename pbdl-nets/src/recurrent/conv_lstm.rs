//! The convolutional LSTM cell (Shi et al. 2015, without peepholes) on `[batch, channel, y, x]`
//! fields.

use super::{lstm_update, LstmState};
use crate::padding::{PaddedConv2d, Padding};
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

/// Configuration of a [`ConvLstmCell`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConvLstmConfig {
    /// Channels of the input `x_t`.
    pub input_channels: usize,
    /// Channels of the hidden and cell states.
    pub hidden_channels: usize,
    /// Odd, square kernel size of the gate convolution. Default 3.
    #[serde(default = "three")]
    pub kernel_size: usize,
    /// What the gate convolution sees beyond the border. Default [`Padding::Zeros`].
    #[serde(default)]
    pub padding: Padding,
}

fn three() -> usize {
    3
}

impl ConvLstmConfig {
    /// A `3 x 3` cell `input_channels -> hidden_channels` with zero padding.
    pub fn new(input_channels: usize, hidden_channels: usize) -> Self {
        Self { input_channels, hidden_channels, kernel_size: 3, padding: Padding::Zeros }
    }

    /// The same with another (odd) kernel size.
    pub fn kernel_size(mut self, kernel_size: usize) -> Self {
        self.kernel_size = kernel_size;
        self
    }

    /// The same with another padding.
    pub fn padding(mut self, padding: Padding) -> Self {
        self.padding = padding;
        self
    }
}

/// A convolutional LSTM cell: the gate pre-activations are one size-preserving convolution of
/// `concat(x, h)` along channels, `4 hidden` output channels in the order i, f, g, o (see
/// [`crate::recurrent`]); `x` is `[batch, input, y, x]`, `h` and `c` are `[batch, hidden, y, x]`.
///
/// Variables: `weight` `[4 hidden, input + hidden, k, k]` (input channels first, then hidden)
/// and `bias` `[4 hidden]`, initialised like PyTorch's `nn.Conv2d` (uniform in
/// `±1/sqrt((input + hidden) k^2)`, as the common PyTorch ConvLSTM code does;
/// [`crate::seeded_init`] reproduces this from a seed).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::recurrent::{ConvLstmCell, ConvLstmConfig};
/// use pbdl_nets::Padding;
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let cell = ConvLstmCell::new(ConvLstmConfig::new(2, 8).padding(Padding::Periodic), vb)?;
/// pbdl_nets::seeded_init(&varmap, 0)?;
/// let x = Tensor::ones((1, 5, 2, 16, 16), DType::F32, &Device::Cpu)?; // [batch, time, c, y, x]
/// let (hs, last) = cell.forward_sequence(&x, None)?;
/// assert_eq!(hs.dims(), &[1, 5, 8, 16, 16]);
/// assert_eq!(last.c.dims(), &[1, 8, 16, 16]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct ConvLstmCell {
    conv: PaddedConv2d,
    config: ConvLstmConfig,
}

impl ConvLstmCell {
    /// The cell of `config`, its variables under `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for zero channels or an even kernel; a candle error if `vb`
    /// holds variables of other shapes.
    pub fn new(config: ConvLstmConfig, vb: VarBuilder) -> Result<Self> {
        let (ci, ch) = (config.input_channels, config.hidden_channels);
        if ci == 0 || ch == 0 {
            return Err(Error::InvalidConfig {
                name: "ConvLstmConfig input_channels / hidden_channels",
                value: format!("{ci} / {ch}"),
                hint: "use at least one input and one hidden channel",
            });
        }
        let conv = PaddedConv2d::same(ci + ch, 4 * ch, config.kernel_size, config.padding, vb)?;
        Ok(Self { conv, config })
    }

    /// The configuration.
    pub fn config(&self) -> &ConvLstmConfig {
        &self.config
    }

    /// The gate convolution (`weight` `[4 hidden, input + hidden, k, k]`, `bias`).
    pub fn conv(&self) -> &PaddedConv2d {
        &self.conv
    }

    /// The zero state for `batch` fields of `y x x` cells, in the weights' dtype and device.
    ///
    /// # Errors
    /// A candle error if the tensors cannot be allocated.
    pub fn zero_state(&self, batch: usize, y: usize, x: usize) -> Result<LstmState> {
        let w = self.conv.conv().weight();
        LstmState::zeros((batch, self.config.hidden_channels, y, x), w.dtype(), w.device())
    }

    fn check_state(&self, state: &LstmState, batch: usize, y: usize, x: usize) -> Result<()> {
        let want = [batch, self.config.hidden_channels, y, x];
        for (name, t) in [("h", &state.h), ("c", &state.c)] {
            if t.dims() != want {
                return Err(Error::shape(format!("ConvLSTM state {name} ([batch, hidden, y, x])"), want, t.dims()));
            }
        }
        Ok(())
    }

    /// One step: the new state from `x` `[batch, input, y, x]` and `state` (`h`, `c`
    /// `[batch, hidden, y, x]`), with one convolution of `concat(x, h)`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for other shapes; a candle error for mixed dtypes or devices.
    pub fn forward_step(&self, x: &Tensor, state: &LstmState) -> Result<LstmState> {
        let (b, yy, xx) = match x.dims() {
            &[b, c, y, w] if c == self.config.input_channels => (b, y, w),
            _ => {
                return Err(Error::shape(
                    "ConvLSTM input x ([batch, input, y, x])",
                    ["batch", &self.config.input_channels.to_string(), "y", "x"],
                    x.dims(),
                ))
            }
        };
        self.check_state(state, b, yy, xx)?;
        let gates = self.conv.forward(&Tensor::cat(&[x, &state.h], 1)?)?;
        lstm_update(&gates, &state.c)
    }

    /// Unrolls the cell over `x` `[batch, time, input, y, x]` from `state` (zeros if `None`);
    /// returns the hidden states of all steps `[batch, time, hidden, y, x]` and the last state.
    ///
    /// The convolution is split by input channels: the part of `x` (and the bias) runs once over
    /// all steps, each step convolves only `h`; the result equals [`ConvLstmCell::forward_step`]
    /// step by step up to round-off.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong input or state shape, or an empty sequence.
    pub fn forward_sequence(&self, x: &Tensor, state: Option<&LstmState>) -> Result<(Tensor, LstmState)> {
        let (ci, ch) = (self.config.input_channels, self.config.hidden_channels);
        let (b, t, yy, xx) = match x.dims() {
            &[b, t, c, y, w] if c == ci && t > 0 => (b, t, y, w),
            _ => {
                return Err(Error::shape(
                    "ConvLSTM input sequence ([batch, time >= 1, input, y, x])",
                    ["batch", "time", &ci.to_string(), "y", "x"],
                    x.dims(),
                ))
            }
        };
        let mut state = match state {
            Some(s) => {
                self.check_state(s, b, yy, xx)?;
                s.clone()
            }
            None => self.zero_state(b, yy, xx)?,
        };
        let conv = self.conv.conv();
        let weight = conv.weight();
        let w_x = weight.narrow(1, 0, ci)?.contiguous()?;
        let w_h = weight.narrow(1, ci, ch)?.contiguous()?;
        let xp = self.conv_part(&x.reshape((b * t, ci, yy, xx))?, &w_x, conv.bias())?;
        let xp = xp.reshape((b, t, 4 * ch, yy, xx))?;
        let mut hs = Vec::with_capacity(t);
        for step in 0..t {
            let gates = (xp.narrow(1, step, 1)?.squeeze(1)? + self.conv_part(&state.h, &w_h, None)?)?;
            state = lstm_update(&gates, &state.c)?;
            hs.push(state.h.clone());
        }
        Ok((Tensor::stack(&hs, 1)?, state))
    }

    /// The gate convolution restricted to some input channels (`weight` the matching slice).
    fn conv_part(&self, x: &Tensor, weight: &Tensor, bias: Option<&Tensor>) -> Result<Tensor> {
        // The layer's parameters carry the padding, periodic x included.
        Ok(pbdl_core::conv::conv2d(x, weight, bias, self.conv.conv().params())?)
    }
}
