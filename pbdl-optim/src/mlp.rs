//! A small dense network in `f64` with exact per-sample Jacobian rows.
//!
//! HIG needs the Jacobian of every output component of every sample with respect to all
//! parameters (one row each), not the batch-summed gradient that autodiff gives. For a dense
//! net a row is one backward pass with a cotangent `c` (the row of the physics Jacobian):
//! `dW_l = delta_l a_{l-1}^T`, `db_l = delta_l`, `delta_{l-1} = act'(a_{l-1}) (W_l^T delta_l)`,
//! starting from `delta_L = c`. [`Mlp::jacobian_rows`] runs these passes in parallel over rows
//! and writes each row contiguously (as one column of `J^T`, the layout faer's SVD wants).
//!
//! Parameter layout (flat, layer after layer): `W_l` as `[out, in]` row-major, then `b_l`.
//! Weights start Glorot-uniform from a seed (Keras' default), biases at zero; the last layer
//! is linear.

use crate::error::{check_len, Result};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Activation of the hidden layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// `tanh(z)`; derivative `1 - a^2`.
    Tanh,
    /// `max(z, 0)`; derivative `1` where `a > 0`, else `0`.
    Relu,
}

impl Activation {
    #[inline]
    fn apply(self, z: f64) -> f64 {
        match self {
            Activation::Tanh => z.tanh(),
            Activation::Relu => z.max(0.0),
        }
    }

    /// Derivative expressed through the activation's output `a`.
    #[inline]
    fn deriv_from_output(self, a: f64) -> f64 {
        match self {
            Activation::Tanh => 1.0 - a * a,
            Activation::Relu => {
                if a > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }
}

/// A dense network `sizes[0] -> sizes[1] -> ... -> sizes[L]` with flat `f64` parameters.
#[derive(Clone, Debug)]
pub struct Mlp {
    sizes: Vec<usize>,
    activation: Activation,
    params: Vec<f64>,
    /// Offset of `W_l` in `params`; `b_l` follows it.
    offsets: Vec<usize>,
}

/// The activations of one forward pass, kept for the backward passes.
#[derive(Clone, Debug, Default)]
pub struct MlpCache {
    batch: usize,
    /// `acts[l]` is layer `l`'s input `[batch, sizes[l]]`; the last entry is the output.
    acts: Vec<Vec<f64>>,
}

impl MlpCache {
    /// The network output `[batch, out_dim]` of the last forward pass.
    pub fn output(&self) -> &[f64] {
        self.acts.last().map(|v| v.as_slice()).unwrap_or(&[])
    }

    /// Batch size of the last forward pass.
    pub fn batch(&self) -> usize {
        self.batch
    }
}

impl Mlp {
    /// A network with the given layer sizes (at least input and output) and hidden activation,
    /// Glorot-uniform weights drawn from `seed` and zero biases.
    pub fn new(sizes: &[usize], activation: Activation, seed: u64) -> Result<Self> {
        if sizes.len() < 2 || sizes.contains(&0) {
            return Err(crate::Error::shape("Mlp layer sizes", "at least two sizes, all > 0", format!("{sizes:?}")));
        }
        let mut offsets = Vec::with_capacity(sizes.len() - 1);
        let mut n = 0;
        for w in sizes.windows(2) {
            offsets.push(n);
            n += w[0] * w[1] + w[1];
        }
        let mut params = vec![0.0; n];
        let mut rng = pbdl_core::seed::rng(seed);
        for (l, w) in sizes.windows(2).enumerate() {
            let limit = (6.0 / (w[0] + w[1]) as f64).sqrt();
            for p in &mut params[offsets[l]..offsets[l] + w[0] * w[1]] {
                *p = rng.random_range(-limit..limit);
            }
        }
        Ok(Self { sizes: sizes.to_vec(), activation, params, offsets })
    }

    /// Activation of the hidden layers.
    pub fn activation(&self) -> Activation {
        self.activation
    }

    /// Layer sizes, input first.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// Input width.
    pub fn in_dim(&self) -> usize {
        self.sizes[0]
    }

    /// Output width.
    pub fn out_dim(&self) -> usize {
        *self.sizes.last().expect("at least two sizes")
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.params.len()
    }

    /// The flat parameters.
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// The flat parameters, to update in place.
    pub fn params_mut(&mut self) -> &mut [f64] {
        &mut self.params
    }

    /// Replaces the parameters.
    pub fn set_params(&mut self, p: &[f64]) -> Result<()> {
        check_len("Mlp parameter count", self.params.len(), p.len())?;
        self.params.copy_from_slice(p);
        Ok(())
    }

    /// A forward pass over `batch` samples `x: [batch, in_dim]`; the output and the
    /// activations are kept in `cache` (its buffers are reused across calls).
    pub fn forward(&self, x: &[f64], batch: usize, cache: &mut MlpCache) -> Result<()> {
        check_len("Mlp input length (batch * in_dim)", batch * self.in_dim(), x.len())?;
        let n_layers = self.sizes.len();
        cache.acts.resize_with(n_layers, Vec::new);
        cache.batch = batch;
        cache.acts[0].clear();
        cache.acts[0].extend_from_slice(x);
        for l in 0..n_layers - 1 {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let (head, tail) = cache.acts.split_at_mut(l + 1);
            let a_in = &head[l];
            let a_out = &mut tail[0];
            a_out.resize(batch * n_out, 0.0);
            let w = &self.params[self.offsets[l]..self.offsets[l] + n_in * n_out];
            let b = &self.params[self.offsets[l] + n_in * n_out..self.offsets[l] + n_in * n_out + n_out];
            let last = l + 2 == n_layers;
            let act = self.activation;
            a_out.par_chunks_mut(n_out).zip(a_in.par_chunks(n_in)).for_each(|(o, i)| {
                for r in 0..n_out {
                    let wr = &w[r * n_in..(r + 1) * n_in];
                    let z = b[r] + wr.iter().zip(i).map(|(p, q)| p * q).sum::<f64>();
                    o[r] = if last { z } else { act.apply(z) };
                }
            });
        }
        Ok(())
    }

    /// One backward pass for sample `s` with output cotangent `cot`, writing the parameter
    /// gradient into `out` (length `n_params`) and using `delta`/`delta_prev` as scratch.
    fn backward_one(
        &self,
        cache: &MlpCache,
        s: usize,
        cot: &[f64],
        out: &mut [f64],
        delta: &mut Vec<f64>,
        prev: &mut Vec<f64>,
    ) {
        delta.clear();
        delta.extend_from_slice(cot);
        for l in (0..self.sizes.len() - 1).rev() {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let a_in = &cache.acts[l][s * n_in..(s + 1) * n_in];
            let off = self.offsets[l];
            let (gw, rest) = out[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
            for r in 0..n_out {
                let d = delta[r];
                for (g, a) in gw[r * n_in..(r + 1) * n_in].iter_mut().zip(a_in) {
                    *g = d * a;
                }
            }
            rest.copy_from_slice(&delta[..n_out]);
            if l > 0 {
                let w = &self.params[off..off + n_in * n_out];
                prev.clear();
                prev.resize(n_in, 0.0);
                for r in 0..n_out {
                    let d = delta[r];
                    for (p, wv) in prev.iter_mut().zip(&w[r * n_in..(r + 1) * n_in]) {
                        *p += wv * d;
                    }
                }
                for (p, a) in prev.iter_mut().zip(a_in) {
                    *p *= self.activation.deriv_from_output(*a);
                }
                std::mem::swap(delta, prev);
            }
        }
    }

    /// Exact Jacobian rows: row `r` (sample `r / rows_per_sample`) is `cot[r]^T d out / d theta`
    /// for the cotangent `cot[r]` (length `out_dim`). `out` is `[rows, n_params]` row-major.
    pub fn jacobian_rows(&self, cache: &MlpCache, cot: &[f64], rows_per_sample: usize, out: &mut [f64]) -> Result<()> {
        let rows = cache.batch * rows_per_sample;
        check_len("cotangent length (batch * rows_per_sample * out_dim)", rows * self.out_dim(), cot.len())?;
        check_len("Jacobian buffer length (rows * n_params)", rows * self.n_params(), out.len())?;
        let (p, m) = (self.n_params(), self.out_dim());
        out.par_chunks_mut(p).enumerate().for_each_init(
            || (Vec::new(), Vec::new()),
            |(d, q), (r, row)| self.backward_one(cache, r / rows_per_sample, &cot[r * m..(r + 1) * m], row, d, q),
        );
        Ok(())
    }

    /// The batch-summed gradient `sum_s cot_s^T d out_s / d theta` (ordinary backprop), for
    /// first-order optimisers. `cot` is `[batch, out_dim]`; `grad` has length `n_params`.
    pub fn gradient(&self, cache: &MlpCache, cot: &[f64], grad: &mut [f64]) -> Result<()> {
        check_len("cotangent length (batch * out_dim)", cache.batch * self.out_dim(), cot.len())?;
        check_len("gradient length (n_params)", self.n_params(), grad.len())?;
        let (p, m) = (self.n_params(), self.out_dim());
        let total = (0..cache.batch)
            .into_par_iter()
            .fold(
                || (vec![0.0; p], vec![0.0; p], Vec::new(), Vec::new()),
                |(mut acc, mut row, mut d, mut q), s| {
                    self.backward_one(cache, s, &cot[s * m..(s + 1) * m], &mut row, &mut d, &mut q);
                    acc.iter_mut().zip(&row).for_each(|(a, r)| *a += r);
                    (acc, row, d, q)
                },
            )
            .map(|t| t.0)
            .reduce(
                || vec![0.0; p],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        grad.copy_from_slice(&total);
        Ok(())
    }
}

/// HIG's model interface, delegating to the inherent methods (same numbers, parameters
/// updated in place).
impl crate::hig::JacobianModel for Mlp {
    type Cache = MlpCache;

    fn in_dim(&self) -> usize {
        Mlp::in_dim(self)
    }

    fn out_dim(&self) -> usize {
        Mlp::out_dim(self)
    }

    fn n_params(&self) -> usize {
        Mlp::n_params(self)
    }

    fn read_params(&self, out: &mut [f64]) -> Result<()> {
        check_len("parameter buffer length (Mlp parameter count)", self.params.len(), out.len())?;
        out.copy_from_slice(&self.params);
        Ok(())
    }

    fn write_params(&mut self, params: &[f64]) -> Result<()> {
        self.set_params(params)
    }

    fn apply_update(&mut self, eta: f64, delta: &[f64]) -> Result<()> {
        check_len("update length (Mlp parameter count)", self.params.len(), delta.len())?;
        self.params.iter_mut().zip(delta).for_each(|(t, d)| *t -= eta * d);
        Ok(())
    }

    fn forward(&self, x: &[f64], batch: usize, cache: &mut MlpCache) -> Result<()> {
        Mlp::forward(self, x, batch, cache)
    }

    fn output<'c>(&self, cache: &'c MlpCache) -> &'c [f64] {
        cache.output()
    }

    fn jacobian_rows(&self, cache: &MlpCache, cot: &[f64], rows_per_sample: usize, out: &mut [f64]) -> Result<()> {
        Mlp::jacobian_rows(self, cache, cot, rows_per_sample, out)
    }

    fn gradient(&self, cache: &MlpCache, cot: &[f64], grad: &mut [f64]) -> Result<()> {
        Mlp::gradient(self, cache, cot, grad)
    }
}
