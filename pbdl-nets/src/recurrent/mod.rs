//! Recurrent cells: an LSTM over vectors (the latent-space LSTM of Wiewel et al.) and a
//! convolutional LSTM over fields (Shi et al. 2015), both with PyTorch's gate layout.
//!
//! Both cells carry a state `(h, c)` ([`LstmState`]) and update it from the gate
//! pre-activations `z = [z_i, z_f, z_g, z_o]` (four blocks of `hidden` along axis 1, in this
//! order, as PyTorch's `nn.LSTM` / `nn.LSTMCell`):
//!
//! ```text
//! i = sigmoid(z_i)   f = sigmoid(z_f)   g = tanh(z_g)   o = sigmoid(z_o)
//! c' = f * c + i * g
//! h' = o * tanh(c')
//! ```
//!
//! * [`LstmCell`] / [`Lstm`]: `z = x W_ih^T + b_ih + h W_hh^T + b_hh` on `[batch, features]`;
//!   [`Lstm`] unrolls one or more stacked cells over a batch-first sequence
//!   `[batch, time, input]`. Over a sequence the input projection of all time steps is one matrix
//!   product up front; each step then costs one `[batch, hidden] x [hidden, 4 hidden]` product.
//! * [`ConvLstmCell`]: `z = conv(concat(x, h))` on `[batch, channel, y, x]` fields, a
//!   size-preserving convolution with `4 hidden` output channels and zero or periodic padding
//!   ([`crate::Padding`]); no peephole terms (Shi et al.'s `W_c * c` products are left out, as
//!   in most ConvLSTM code).
//!
//! Backpropagation through time is candle's autograd over the unrolled steps; the integration
//! tests check every gradient (inputs, initial state, all weights) against finite differences
//! in `f64` over 4-step unrolls.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_nets::recurrent::{Lstm, LstmConfig};
//!
//! let varmap = VarMap::new();
//! let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
//! let lstm = Lstm::new(LstmConfig::new(16, 32).num_layers(2), vb)?;
//! let x = Tensor::zeros((4, 6, 16), DType::F32, &Device::Cpu)?; // [batch, time, input]
//! let out = lstm.forward(&x, None)?;
//! assert_eq!(out.output.dims(), &[4, 6, 32]); // h of the last layer at every step
//! assert_eq!(out.states[1].h.dims(), &[4, 32]); // last (h, c) of each layer
//! # Ok::<(), pbdl_nets::Error>(())
//! ```

mod conv_lstm;
mod fused;
mod lstm;

pub use conv_lstm::{ConvLstmCell, ConvLstmConfig};
pub use lstm::{Lstm, LstmCell, LstmConfig, LstmOutput};

use crate::Result;
use candle_core::{DType, Device, Shape, Tensor};

/// The state `(h, c)` of an LSTM cell: hidden state `h` (the cell's output) and cell state `c`,
/// of one shape: `[batch, hidden]` for [`LstmCell`], `[batch, hidden, y, x]` for
/// [`ConvLstmCell`].
#[derive(Clone, Debug)]
pub struct LstmState {
    /// Hidden state, the output of the step.
    pub h: Tensor,
    /// Cell state.
    pub c: Tensor,
}

impl LstmState {
    /// A state from `(h, c)`.
    pub fn new(h: Tensor, c: Tensor) -> Self {
        Self { h, c }
    }

    /// The zero state of the given shape (PyTorch's default initial state).
    ///
    /// # Errors
    /// A candle error if the tensors cannot be allocated.
    pub fn zeros(shape: impl Into<Shape>, dtype: DType, device: &Device) -> Result<Self> {
        let z = Tensor::zeros(shape, dtype, device)?;
        Ok(Self { h: z.clone(), c: z })
    }
}

/// The LSTM update from gate pre-activations `gates` (`[batch, 4 hidden, ..]`, order i, f, g, o
/// along axis 1) and the cell state `c` (`[batch, hidden, ..]`).
///
/// One sigmoid over all four blocks (the g block's is unused: one op instead of two narrows
/// and two sigmoids), one tanh over the g block.
pub(crate) fn lstm_update(gates: &Tensor, c: &Tensor) -> Result<LstmState> {
    let n = c.dim(1)?;
    let s = pbdl_core::nn::activation::sigmoid(gates)?;
    let i = s.narrow(1, 0, n)?;
    let f = s.narrow(1, n, n)?;
    let o = s.narrow(1, 3 * n, n)?;
    let g = gates.narrow(1, 2 * n, n)?.tanh()?;
    let c_new = ((f * c)? + (i * g)?)?;
    let h_new = (o * c_new.tanh()?)?;
    Ok(LstmState { h: h_new, c: c_new })
}
