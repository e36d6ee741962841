//! Batch normalisation for the racecar nets, and how the reverse pass reuses it.
//!
//! Training-mode batch norm, per channel: `y = gamma (x - mean) / sqrt(var + eps) + beta`, with
//! the biased mean and variance over every axis but the channel axis 1 (`[batch, channel]` or
//! `[batch, channel, y, x]`). `eps = 1e-3` as the racecar code (TensorFlow's `batch_norm`).
//!
//! In the reverse pass, layer `m`'s reconstruction goes through the batch norm of the layer
//! that produced `d_m` again, with the *same* `gamma` and `beta`. Which mean and variance it
//! uses is [`ReverseStats`]: the official code calls the shared TensorFlow layer in training
//! mode on the reverse tensor, so it normalises with that tensor's own batch statistics
//! ([`ReverseStats::Own`], our default); [`ReverseStats::Forward`] reuses the statistics of the
//! forward pass instead. Running averages (the inference-mode statistics) are not kept: the
//! racecar experiments here only train and then analyse the weights.

use candle_core::{DType, Device, Tensor, Var};
use serde::{Deserialize, Serialize};

/// Which statistics the reverse pass normalises with (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ReverseStats {
    /// The reverse tensor's own batch mean and variance (as the official racecar code).
    #[default]
    Own,
    /// The mean and variance that the forward pass computed at this layer.
    Forward,
}

/// Per-channel batch mean and (biased) variance, shaped to broadcast against the input
/// (`[1, C]` or `[1, C, 1, 1]`).
#[derive(Clone, Debug)]
pub struct BnStats {
    /// Batch mean per channel.
    pub mean: Tensor,
    /// Biased batch variance per channel.
    pub var: Tensor,
}

/// A batch-norm layer: per-channel scale `gamma` (init 1) and shift `beta` (init 0).
#[derive(Clone, Debug)]
pub struct BatchNorm {
    gamma: Tensor,
    beta: Tensor,
    eps: f64,
}

impl BatchNorm {
    /// `gamma = 1`, `beta = 0`, `eps = 1e-3`, both trainable.
    pub fn new(channels: usize, dtype: DType) -> candle_core::Result<Self> {
        let gamma = Var::ones(channels, dtype, &Device::Cpu)?.as_tensor().clone();
        let beta = Var::zeros(channels, dtype, &Device::Cpu)?.as_tensor().clone();
        Ok(Self { gamma, beta, eps: 1e-3 })
    }

    /// A layer from given `gamma`, `beta` (`[C]` each), e.g. for gradient checks.
    pub fn from_tensors(gamma: Tensor, beta: Tensor, eps: f64) -> Self {
        Self { gamma, beta, eps }
    }

    /// `gamma` and `beta` as variables (they are variables when built by [`BatchNorm::new`]).
    pub fn vars(&self) -> candle_core::Result<Vec<Var>> {
        Ok(vec![Var::from_tensor(&self.gamma)?, Var::from_tensor(&self.beta)?])
    }

    /// Batch statistics of `x` (`[batch, C]` or `[batch, C, ...]`).
    pub fn stats(&self, x: &Tensor) -> candle_core::Result<BnStats> {
        let mean = channel_mean(x)?;
        let var = channel_mean(&x.broadcast_sub(&mean)?.sqr()?)?;
        Ok(BnStats { mean, var })
    }

    /// Normalises `x` with `stats` and applies the affine part.
    pub fn normalize(&self, x: &Tensor, stats: &BnStats) -> candle_core::Result<Tensor> {
        let shape = stats.mean.dims().to_vec();
        let inv = (&stats.var + self.eps)?.sqrt()?.recip()?;
        let xhat = x.broadcast_sub(&stats.mean)?.broadcast_mul(&inv)?;
        xhat.broadcast_mul(&self.gamma.reshape(shape.clone())?)?.broadcast_add(&self.beta.reshape(shape)?)
    }

    /// Training-mode forward: normalises with `x`'s own batch statistics and returns them.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<(Tensor, BnStats)> {
        let stats = self.stats(x)?;
        Ok((self.normalize(x, &stats)?, stats))
    }

    /// The reverse pass through this layer: `x`'s own statistics or `forward`'s, per `mode`.
    pub fn reverse(&self, x: &Tensor, forward: &BnStats, mode: ReverseStats) -> candle_core::Result<Tensor> {
        match mode {
            ReverseStats::Own => Ok(self.forward(x)?.0),
            ReverseStats::Forward => self.normalize(x, forward),
        }
    }
}

/// Mean over every axis but axis 1, keeping the rank.
fn channel_mean(x: &Tensor) -> candle_core::Result<Tensor> {
    let mut m = x.mean_keepdim(0)?;
    for axis in 2..x.rank() {
        m = m.mean_keepdim(axis)?;
    }
    Ok(m)
}
