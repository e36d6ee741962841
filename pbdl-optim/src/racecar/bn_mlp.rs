//! The racecar reverse pass for a dense network with batch norm and ReLU (the paper's peak
//! model `784 -> 128 -> 2`).
//!
//! Forward: `d_{m+1} = ReLU(BN_m(d_m W_m + b_m))` for every layer, the output included (as the
//! official peak model). Reverse, from `d'_L = d_L`: `d'_m = ReLU(BN_{m-1}((d'_{m+1} - b_m)
//! W_m^T))` for `m > 0`, i.e. the shared transposed weights, then the batch norm and the ReLU
//! that produced `d_m`, and `d'_0 = (d'_1 - b_0) W_0^T` for the input. The loss term is
//! `sum_m 1/2 ||d'_m - d_m||^2`, averaged over the batch.

use super::batch_norm::{BatchNorm, BnStats, ReverseStats};
use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use rand::Rng;

/// One forward pass: the layer inputs/outputs and the batch statistics of every batch norm.
#[derive(Clone, Debug)]
pub struct Pass {
    /// `[d_0 = x, d_1, ..., d_L]`.
    pub acts: Vec<Tensor>,
    /// The forward batch statistics of each layer's batch norm.
    pub stats: Vec<BnStats>,
}

/// A dense BN + ReLU network whose weights are shared with its reverse pass.
#[derive(Clone, Debug)]
pub struct BnMlp {
    weights: Vec<Tensor>,
    biases: Vec<Tensor>,
    norms: Vec<BatchNorm>,
}

/// A Glorot-uniform `[rows, cols]` variable with fans `fan_in`, `fan_out`.
pub(crate) fn glorot(
    shape: &[usize],
    fan_in: usize,
    fan_out: usize,
    dtype: DType,
    rng: &mut impl Rng,
) -> candle_core::Result<Tensor> {
    let lim = (6.0 / (fan_in + fan_out) as f64).sqrt();
    let v: Vec<f64> = (0..shape.iter().product()).map(|_| rng.random_range(-lim..lim)).collect();
    let t = Tensor::from_vec(v, shape, &Device::Cpu)?.to_dtype(dtype)?;
    Ok(Var::from_tensor(&t)?.as_tensor().clone())
}

impl BnMlp {
    /// Glorot-uniform weights from `seed`, zero biases, `gamma = 1`, `beta = 0`; `sizes` from
    /// input to output.
    pub fn new(sizes: &[usize], dtype: DType, seed: u64) -> Result<Self> {
        if sizes.len() < 2 || sizes.contains(&0) {
            return Err(Error::shape("racecar layer sizes", "at least two sizes, all > 0", format!("{sizes:?}")));
        }
        let mut rng = pbdl_core::seed::rng(seed);
        let mut net = Self { weights: Vec::new(), biases: Vec::new(), norms: Vec::new() };
        for w in sizes.windows(2) {
            net.weights.push(glorot(&[w[0], w[1]], w[0], w[1], dtype, &mut rng)?);
            net.biases.push(Var::zeros(w[1], dtype, &Device::Cpu)?.as_tensor().clone());
            net.norms.push(BatchNorm::new(w[1], dtype)?);
        }
        Ok(net)
    }

    /// A network from given parameters (`W_m: [in, out]`, `b_m: [out]`), e.g. for gradient checks.
    pub fn from_tensors(weights: Vec<Tensor>, biases: Vec<Tensor>, norms: Vec<BatchNorm>) -> Result<Self> {
        if weights.is_empty() || biases.len() != weights.len() || norms.len() != weights.len() {
            return Err(Error::shape(
                "racecar BN-MLP parameters",
                "equal, non-zero numbers of weights, biases and batch norms",
                format!("{} / {} / {}", weights.len(), biases.len(), norms.len()),
            ));
        }
        Ok(Self { weights, biases, norms })
    }

    /// All trainable variables.
    pub fn vars(&self) -> Result<Vec<Var>> {
        let mut v: Vec<Var> =
            self.weights.iter().chain(&self.biases).map(Var::from_tensor).collect::<candle_core::Result<_>>()?;
        for n in &self.norms {
            v.extend(n.vars()?);
        }
        Ok(v)
    }

    /// Layer `m`'s weights `[in, out]`.
    pub fn weight(&self, m: usize) -> &Tensor {
        &self.weights[m]
    }

    /// Number of layers.
    pub fn layers(&self) -> usize {
        self.weights.len()
    }

    /// The forward pass (training-mode batch norm).
    pub fn forward(&self, x: &Tensor) -> Result<Pass> {
        let mut acts = vec![x.clone()];
        let mut stats = Vec::new();
        for m in 0..self.weights.len() {
            let z = acts[m].matmul(&self.weights[m])?.broadcast_add(&self.biases[m])?;
            let (y, s) = self.norms[m].forward(&z)?;
            acts.push(y.relu()?);
            stats.push(s);
        }
        Ok(Pass { acts, stats })
    }

    /// The reverse pass `[d'_0, ..., d'_{L-1}]` (see the module docs).
    pub fn reverse(&self, pass: &Pass, mode: ReverseStats) -> Result<Vec<Tensor>> {
        let n = self.weights.len();
        let mut rec = pass.acts[n].clone();
        let mut out = vec![rec.clone(); n];
        for m in (0..n).rev() {
            let back = rec.broadcast_sub(&self.biases[m])?.matmul(&self.weights[m].t()?)?;
            rec = if m > 0 { self.norms[m - 1].reverse(&back, &pass.stats[m - 1], mode)?.relu()? } else { back };
            out[m] = rec.clone();
        }
        Ok(out)
    }

    /// `sum_m 1/2 ||d'_m - d_m||^2`, averaged over the batch.
    pub fn reconstruction_loss(&self, pass: &Pass, mode: ReverseStats) -> Result<Tensor> {
        let rec = self.reverse(pass, mode)?;
        reconstruction_sum(&rec, &pass.acts)
    }
}

/// `sum_m 1/2 ||rec_m - acts_m||^2 / batch` over the pairs of `rec` and `acts`.
pub(crate) fn reconstruction_sum(rec: &[Tensor], acts: &[Tensor]) -> Result<Tensor> {
    let batch = acts[0].dim(0)? as f64;
    let mut total = (rec[0].broadcast_sub(&acts[0])?.sqr()?.sum_all()? * (0.5 / batch))?;
    for (r, a) in rec.iter().zip(acts).skip(1) {
        total = (total + (r.broadcast_sub(a)?.sqr()?.sum_all()? * (0.5 / batch))?)?;
    }
    Ok(total)
}
