//! The dense tanh controller of the stabilized-BPTT experiments (cart-pole, guidance).

use crate::error::Result;
use candle_core::{DType, Device, Tensor, Var};
use rand::Rng;

/// A dense controller `inputs -> width -> width -> outputs` in f64, tanh hidden layers,
/// Glorot-uniform weights from a seed and zero biases.
#[derive(Clone, Debug)]
pub struct DenseController {
    vars: Vec<Var>,
}

impl DenseController {
    /// All weights Glorot-uniform (as in the official guidance run).
    pub fn new(inputs: usize, width: usize, outputs: usize, seed: u64) -> Result<Self> {
        Self::build(inputs, width, outputs, seed, false)
    }

    /// Hidden weights Glorot-uniform, the last layer zero (as the official cart-pole scripts
    /// effectively start), so training starts from a zero control.
    pub fn with_zero_last_layer(inputs: usize, width: usize, outputs: usize, seed: u64) -> Result<Self> {
        Self::build(inputs, width, outputs, seed, true)
    }

    fn build(inputs: usize, width: usize, outputs: usize, seed: u64, zero_last: bool) -> Result<Self> {
        let mut rng = pbdl_core::seed::rng(seed);
        let mut glorot = |a: usize, b: usize| -> Result<Var> {
            let lim = (6.0 / (a + b) as f64).sqrt();
            let v: Vec<f64> = (0..a * b).map(|_| rng.random_range(-lim..lim)).collect();
            Ok(Var::from_tensor(&Tensor::from_vec(v, (a, b), &Device::Cpu)?)?)
        };
        let zeros = |a: usize, b: usize| -> Result<Var> { Ok(Var::zeros((a, b), DType::F64, &Device::Cpu)?) };
        let w0 = glorot(inputs, width)?;
        let w1 = glorot(width, width)?;
        let w2 = if zero_last { zeros(width, outputs)? } else { glorot(width, outputs)? };
        let vars = vec![w0, zeros(1, width)?, w1, zeros(1, width)?, w2, zeros(1, outputs)?];
        Ok(Self { vars })
    }

    /// The trainable variables.
    pub fn vars(&self) -> &[Var] {
        &self.vars
    }

    /// The controls `[b, outputs]` for inputs `[b, inputs]`.
    pub fn forward(&self, s: &Tensor) -> candle_core::Result<Tensor> {
        let v = &self.vars;
        let h = s.matmul(v[0].as_tensor())?.broadcast_add(v[1].as_tensor())?.tanh()?;
        let h = h.matmul(v[2].as_tensor())?.broadcast_add(v[3].as_tensor())?.tanh()?;
        h.matmul(v[4].as_tensor())?.broadcast_add(v[5].as_tensor())
    }
}
