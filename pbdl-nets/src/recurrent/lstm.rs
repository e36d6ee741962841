//! The LSTM cell on `[batch, features]` and the (stacked) LSTM layer over batch-first
//! sequences, in PyTorch's layout.

use super::{lstm_update, LstmState};
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use candle_nn::{Init, VarBuilder};
use serde::{Deserialize, Serialize};

/// Configuration of an [`Lstm`] layer (PyTorch's `nn.LSTM` with `batch_first=True`).
///
/// Not supported (PyTorch options): `dropout` between layers, `bidirectional`, `proj_size`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LstmConfig {
    /// Features of the input `x_t`.
    pub input_size: usize,
    /// Features of the hidden and cell states.
    pub hidden_size: usize,
    /// Stacked cells; layer `k > 0` reads the hidden states of layer `k - 1`. Default 1.
    #[serde(default = "one")]
    pub num_layers: usize,
    /// Whether the cells have the biases `b_ih`, `b_hh`. Default `true`.
    #[serde(default = "yes")]
    pub bias: bool,
}

fn one() -> usize {
    1
}

fn yes() -> bool {
    true
}

impl LstmConfig {
    /// One layer `input_size -> hidden_size` with biases.
    pub fn new(input_size: usize, hidden_size: usize) -> Self {
        Self { input_size, hidden_size, num_layers: 1, bias: true }
    }

    /// The same with `num_layers` stacked cells.
    pub fn num_layers(mut self, num_layers: usize) -> Self {
        self.num_layers = num_layers;
        self
    }

    /// The same without biases (PyTorch's `bias=False`).
    pub fn without_bias(mut self) -> Self {
        self.bias = false;
        self
    }
}

/// An LSTM cell (PyTorch's `nn.LSTMCell`): one step `(x, (h, c)) -> (h', c')` on `x`
/// `[batch, input]` and `h`, `c` `[batch, hidden]`, with gate pre-activations
/// `x W_ih^T + b_ih + h W_hh^T + b_hh` in the order i, f, g, o (see [`crate::recurrent`]).
///
/// Variables (PyTorch's names and shapes): `weight_ih` `[4 hidden, input]`, `weight_hh`
/// `[4 hidden, hidden]`, `bias_ih` and `bias_hh` `[4 hidden]`; an [`Lstm`] layer names them
/// `weight_ih_l{k}` etc. like `nn.LSTM`. Initialisation as PyTorch: all four uniform in
/// `±1/sqrt(hidden)` (the bound depends on the hidden size, not on the fan-in), drawn by the
/// `VarBuilder` from candle's unseeded generator. For reproducible runs set the variables from
/// `pbdl_core::seed::rand_uniform`; [`crate::seeded_init`] does not know these names yet: it
/// would draw `weight_ih` in `±1/sqrt(input)` and set `bias_ih` and `bias_hh` to 1.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::recurrent::LstmCell;
///
/// let varmap = VarMap::new();
/// let cell = LstmCell::new(3, 8, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
/// let mut state = cell.zero_state(2)?;
/// for _ in 0..6 {
///     let x = Tensor::ones((2, 3), DType::F32, &Device::Cpu)?;
///     state = cell.forward_step(&x, &state)?;
/// }
/// assert_eq!(state.h.dims(), &[2, 8]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct LstmCell {
    weight_ih: Tensor,
    weight_hh: Tensor,
    bias_ih: Option<Tensor>,
    bias_hh: Option<Tensor>,
    input_size: usize,
    hidden_size: usize,
}

impl LstmCell {
    /// A cell `input_size -> hidden_size` with biases, its variables under `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a zero size; a candle error if `vb` holds variables of
    /// other shapes.
    pub fn new(input_size: usize, hidden_size: usize, vb: VarBuilder) -> Result<Self> {
        Self::with_names(input_size, hidden_size, true, "", vb)
    }

    /// A cell whose variable names end in `suffix` (`"_l0"` in an [`Lstm`]).
    pub(crate) fn with_names(
        input_size: usize,
        hidden_size: usize,
        bias: bool,
        suffix: &str,
        vb: VarBuilder,
    ) -> Result<Self> {
        if input_size == 0 || hidden_size == 0 {
            return Err(Error::InvalidConfig {
                name: "LSTM input_size / hidden_size",
                value: format!("{input_size} / {hidden_size}"),
                hint: "use at least one input and one hidden feature",
            });
        }
        let k = 1.0 / (hidden_size as f64).sqrt();
        let init = Init::Uniform { lo: -k, up: k };
        let g = 4 * hidden_size;
        let weight_ih = vb.get_with_hints((g, input_size), &format!("weight_ih{suffix}"), init)?;
        let weight_hh = vb.get_with_hints((g, hidden_size), &format!("weight_hh{suffix}"), init)?;
        let (bias_ih, bias_hh) = if bias {
            (
                Some(vb.get_with_hints(g, &format!("bias_ih{suffix}"), init)?),
                Some(vb.get_with_hints(g, &format!("bias_hh{suffix}"), init)?),
            )
        } else {
            (None, None)
        };
        Ok(Self { weight_ih, weight_hh, bias_ih, bias_hh, input_size, hidden_size })
    }

    /// Features of the input.
    pub fn input_size(&self) -> usize {
        self.input_size
    }

    /// Features of the hidden and cell states.
    pub fn hidden_size(&self) -> usize {
        self.hidden_size
    }

    /// `W_ih`, `[4 hidden, input]` (rows: blocks i, f, g, o).
    pub fn weight_ih(&self) -> &Tensor {
        &self.weight_ih
    }

    /// `W_hh`, `[4 hidden, hidden]`.
    pub fn weight_hh(&self) -> &Tensor {
        &self.weight_hh
    }

    /// `b_ih`, `[4 hidden]`, if the cell has biases.
    pub fn bias_ih(&self) -> Option<&Tensor> {
        self.bias_ih.as_ref()
    }

    /// `b_hh`, `[4 hidden]`, if the cell has biases.
    pub fn bias_hh(&self) -> Option<&Tensor> {
        self.bias_hh.as_ref()
    }

    /// The zero state for `batch` sequences, in the weights' dtype and device.
    ///
    /// # Errors
    /// A candle error if the tensors cannot be allocated.
    pub fn zero_state(&self, batch: usize) -> Result<LstmState> {
        LstmState::zeros((batch, self.hidden_size), self.weight_hh.dtype(), self.weight_hh.device())
    }

    /// `b_ih + b_hh`, if any.
    fn bias(&self) -> Result<Option<Tensor>> {
        Ok(match (&self.bias_ih, &self.bias_hh) {
            (Some(a), Some(b)) => Some((a + b)?),
            _ => None,
        })
    }

    fn check_state(&self, state: &LstmState, batch: usize) -> Result<()> {
        let want = [batch, self.hidden_size];
        for (name, t) in [("h", &state.h), ("c", &state.c)] {
            if t.dims() != want {
                return Err(Error::shape(format!("LSTM state {name} ([batch, hidden])"), want, t.dims()));
            }
        }
        Ok(())
    }

    /// One step: the new state from `x` `[batch, input]` and `state` (`h`, `c` `[batch, hidden]`).
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for other shapes; a candle error for mixed dtypes or devices.
    pub fn forward_step(&self, x: &Tensor, state: &LstmState) -> Result<LstmState> {
        if x.rank() != 2 || x.dim(1)? != self.input_size {
            return Err(Error::shape(
                "LSTM input x ([batch, input])",
                ["batch", &self.input_size.to_string()],
                x.dims(),
            ));
        }
        self.check_state(state, x.dim(0)?)?;
        let gates = pbdl_core::nn::linear(x, &self.weight_ih, self.bias()?.as_ref())?;
        let gates = (gates + pbdl_core::nn::linear(&state.h, &self.weight_hh, None)?)?;
        lstm_update(&gates, &state.c)
    }

    /// Unrolls the cell over `x` `[batch, time, input]` from `state` (zeros if `None`); returns
    /// the hidden states of all steps `[batch, time, hidden]` and the last state.
    ///
    /// The input projection `x W_ih^T + b_ih + b_hh` of all steps is one matrix product; each
    /// step adds `h W_hh^T` and applies the gates. On the CPU in `f32`/`f64` the steps run as
    /// one fused op with a hand-written backward through time; its gradients cannot be
    /// differentiated again (an error): for second derivatives run inside
    /// `pbdl_core::nn::with_composed`, which uses the composed candle ops.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong input or state shape, or an empty sequence.
    pub fn forward_sequence(&self, x: &Tensor, state: Option<&LstmState>) -> Result<(Tensor, LstmState)> {
        let (b, t) = match x.dims() {
            &[b, t, i] if i == self.input_size && t > 0 => (b, t),
            _ => {
                return Err(Error::shape(
                    "LSTM input sequence ([batch, time >= 1, input])",
                    ["batch", "time", &self.input_size.to_string()],
                    x.dims(),
                ))
            }
        };
        let mut state = match state {
            Some(s) => {
                self.check_state(s, b)?;
                s.clone()
            }
            None => self.zero_state(b)?,
        };
        // One op for all steps (candle's matmul of a transposed weight accumulates its gradient
        // through a strided view: 35 ms instead of 16 at hidden 1024).
        let xp = pbdl_core::nn::linear(x, &self.weight_ih, self.bias()?.as_ref())?;
        if pbdl_core::nn::fusion_enabled() && x.device().is_cpu() && matches!(x.dtype(), DType::F32 | DType::F64) {
            // The whole recurrence as one op with a hand-written backward through time.
            let h = self.hidden_size;
            let s0 = Tensor::cat(&[&state.h, &state.c], 1)?;
            let hc = super::fused::lstm_sequence(&xp, &self.weight_hh, &s0)?;
            let last = hc.narrow(1, t - 1, 1)?.squeeze(1)?;
            let state = LstmState::new(last.narrow(1, 0, h)?, last.narrow(1, h, h)?);
            return Ok((hc.narrow(2, 0, h)?, state));
        }
        let w_hh_t = self.weight_hh.t()?;
        let mut hs = Vec::with_capacity(t);
        for step in 0..t {
            let gates = (xp.narrow(1, step, 1)?.squeeze(1)? + state.h.matmul(&w_hh_t)?)?;
            state = lstm_update(&gates, &state.c)?;
            hs.push(state.h.clone());
        }
        Ok((Tensor::stack(&hs, 1)?, state))
    }
}

/// What an [`Lstm`] returns.
#[derive(Clone, Debug)]
pub struct LstmOutput {
    /// Hidden states of the last layer at every step, `[batch, time, hidden]` (PyTorch's
    /// `output` with `batch_first=True`).
    pub output: Tensor,
    /// The last state of each layer, first layer first (PyTorch's `(h_n, c_n)` split by layer).
    pub states: Vec<LstmState>,
}

/// An LSTM layer over batch-first sequences (PyTorch's `nn.LSTM(batch_first=True)`): `x`
/// `[batch, time, input]` -> hidden states `[batch, time, hidden]` and the last `(h, c)` of each
/// of the `num_layers` stacked [`LstmCell`]s.
///
/// Variables of layer `k`: `weight_ih_l{k}` `[4 hidden, input or hidden]`, `weight_hh_l{k}`,
/// `bias_ih_l{k}`, `bias_hh_l{k}`, as in a PyTorch `state_dict`; initialisation uniform in
/// `±1/sqrt(hidden)` (see [`LstmCell`]).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::recurrent::{Lstm, LstmConfig};
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let lstm = Lstm::new(LstmConfig::new(5, 7), vb)?;
/// let x = Tensor::ones((2, 3, 5), DType::F32, &Device::Cpu)?;
/// let out = lstm.forward(&x, None)?;
/// // The last step's output is the last hidden state.
/// let last = out.output.narrow(1, 2, 1)?.squeeze(1)?;
/// assert_eq!(last.to_vec2::<f32>()?, out.states[0].h.to_vec2::<f32>()?);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Lstm {
    cells: Vec<LstmCell>,
    config: LstmConfig,
}

impl Lstm {
    /// The layer of `config`, its variables under `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for zero sizes or layers; a candle error if `vb` holds
    /// variables of other shapes.
    pub fn new(config: LstmConfig, vb: VarBuilder) -> Result<Self> {
        if config.num_layers == 0 {
            return Err(Error::InvalidConfig {
                name: "LstmConfig::num_layers",
                value: "0".into(),
                hint: "use at least one layer",
            });
        }
        let cells = (0..config.num_layers)
            .map(|k| {
                let input = if k == 0 { config.input_size } else { config.hidden_size };
                LstmCell::with_names(input, config.hidden_size, config.bias, &format!("_l{k}"), vb.clone())
            })
            .collect::<Result<_>>()?;
        Ok(Self { cells, config })
    }

    /// The configuration.
    pub fn config(&self) -> &LstmConfig {
        &self.config
    }

    /// The stacked cells, first layer first.
    pub fn cells(&self) -> &[LstmCell] {
        &self.cells
    }

    /// Zero states of all layers for `batch` sequences.
    ///
    /// # Errors
    /// A candle error if the tensors cannot be allocated.
    pub fn zero_states(&self, batch: usize) -> Result<Vec<LstmState>> {
        self.cells.iter().map(|c| c.zero_state(batch)).collect()
    }

    /// Runs the layer over `x` `[batch, time, input]` from `states` (one per layer; zeros if
    /// `None`).
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong input shape, an empty sequence, or a wrong number
    /// or shape of initial states.
    pub fn forward(&self, x: &Tensor, states: Option<&[LstmState]>) -> Result<LstmOutput> {
        if let Some(s) = states {
            if s.len() != self.cells.len() {
                return Err(Error::shape("LSTM initial states (one per layer)", self.cells.len(), s.len()));
            }
        }
        let mut seq = x.clone();
        let mut last = Vec::with_capacity(self.cells.len());
        for (k, cell) in self.cells.iter().enumerate() {
            let (out, state) = cell.forward_sequence(&seq, states.map(|s| &s[k]))?;
            seq = out;
            last.push(state);
        }
        Ok(LstmOutput { output: seq, states: last })
    }
}
