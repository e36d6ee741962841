//! [`JacobianModel`]: what HIG needs from a network, so that any model can be trained by it.
//!
//! HIG builds `J = J_phys J_net` row by row: every row is the network's vector-Jacobian product
//! with one row of the physics Jacobian as the cotangent. A model therefore has to give
//!
//! - its flat `f64` parameter vector `theta` (read, write, and the update `theta -= eta delta`),
//! - a forward pass of a batch `[b, in_dim] -> [b, out_dim]` whose intermediate results it
//!   keeps in a [`JacobianModel::Cache`] owned by the caller,
//! - exact per-row VJPs ([`JacobianModel::jacobian_rows`]) and the batch-summed gradient
//!   ([`JacobianModel::gradient`], for Adam).
//!
//! Implemented by the hand-written [`crate::mlp::Mlp`] and by [`super::CandleModel`] (any candle
//! model given as `Var`s and a forward closure).

use crate::error::{check_len, Result};

/// A differentiable model `u = f(i; theta)` with exact per-row Jacobians, trainable by
/// [`super::HigTrainer`] and [`super::AdamTrainer`].
///
/// Parameters are one flat `f64` vector of length [`JacobianModel::n_params`]; the model defines
/// its order, and every method uses the same one.
pub trait JacobianModel {
    /// What a forward pass keeps for the backward passes (activations, a candle graph). Owned by
    /// the caller and reused across calls, so a model can keep its buffers between steps.
    type Cache: Default + Send + 'static;

    /// Width of one input sample.
    fn in_dim(&self) -> usize;

    /// Width of one output sample (the physics control length).
    fn out_dim(&self) -> usize;

    /// Number of parameters `|theta|`.
    fn n_params(&self) -> usize;

    /// Copies `theta` into `out` (length [`JacobianModel::n_params`]).
    fn read_params(&self, out: &mut [f64]) -> Result<()>;

    /// Replaces `theta` by `params` (length [`JacobianModel::n_params`]).
    fn write_params(&mut self, params: &[f64]) -> Result<()>;

    /// The plain SGD step `theta -= eta * delta` of HIG / Gauss-Newton. The default reads,
    /// updates and writes back the parameter vector; models that own it update in place.
    fn apply_update(&mut self, eta: f64, delta: &[f64]) -> Result<()> {
        check_len("update length (n_params)", self.n_params(), delta.len())?;
        let mut theta = vec![0.0; self.n_params()];
        self.read_params(&mut theta)?;
        theta.iter_mut().zip(delta).for_each(|(t, d)| *t -= eta * d);
        self.write_params(&theta)
    }

    /// Forward pass of `batch` samples `x: [batch, in_dim]` (row-major), keeping the output
    /// and whatever the backward passes need in `cache`.
    fn forward(&self, x: &[f64], batch: usize, cache: &mut Self::Cache) -> Result<()>;

    /// The output `[batch, out_dim]` of the last [`JacobianModel::forward`] into `cache`.
    fn output<'c>(&self, cache: &'c Self::Cache) -> &'c [f64];

    /// Exact Jacobian rows: row `r` (sample `r / rows_per_sample`) is
    /// `cot[r]^T d out_s / d theta` for the cotangent `cot[r]` (length `out_dim`), written into
    /// `out` as `[rows, n_params]` row-major, `rows = batch * rows_per_sample`.
    fn jacobian_rows(&self, cache: &Self::Cache, cot: &[f64], rows_per_sample: usize, out: &mut [f64]) -> Result<()>;

    /// The batch-summed gradient `sum_s cot_s^T d out_s / d theta` (`cot: [batch, out_dim]`,
    /// `grad` of length `n_params`). The default sums the rows of
    /// [`JacobianModel::jacobian_rows`] with one row per sample (allocates `batch * n_params`);
    /// models with an ordinary backward pass override it.
    fn gradient(&self, cache: &Self::Cache, cot: &[f64], grad: &mut [f64]) -> Result<()> {
        let p = self.n_params();
        check_len("gradient length (n_params)", p, grad.len())?;
        if p == 0 {
            return Ok(());
        }
        let batch = cot.len() / self.out_dim().max(1);
        let mut rows = vec![0.0; batch * p];
        self.jacobian_rows(cache, cot, 1, &mut rows)?;
        grad.fill(0.0);
        for row in rows.chunks_exact(p) {
            grad.iter_mut().zip(row).for_each(|(g, r)| *g += r);
        }
        Ok(())
    }
}
