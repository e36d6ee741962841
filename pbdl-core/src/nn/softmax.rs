//! Softmax and log-softmax over a chosen dim, with a backward.

use crate::Result;
use candle_core::{shape::Dim, Tensor};

/// `x - max(x)` along `dim`. The shift cancels exactly in (log-)softmax, so it is detached:
/// the gradient is unchanged and does not have to flow through (and split at ties of) the max.
fn shifted(x: &Tensor, dim: usize) -> Result<Tensor> {
    Ok(x.broadcast_sub(&x.max_keepdim(dim)?.detach())?)
}

/// Softmax of `x` along `dim`: `exp(x_i) / sum_j exp(x_j)`, computed on `x - max(x)` so large
/// inputs do not overflow. Differentiable, unlike `candle_nn::ops::softmax_last_dim`.
///
/// `dim` is an index or `candle_core::D::Minus1`-style position.
///
/// ```
/// use candle_core::{Device, Tensor, D};
/// let x = Tensor::new(&[[1.0f64, 2.0, 3.0], [1000.0, 1000.0, 1000.0]], &Device::Cpu)?;
/// let p = pbdl_core::nn::softmax(&x, D::Minus1)?.to_vec2::<f64>()?;
/// let z = 1f64.exp() + 2f64.exp() + 3f64.exp();
/// assert!((p[0][2] - 3f64.exp() / z).abs() < 1e-15);
/// assert!(p[1].iter().all(|v| (v - 1.0 / 3.0).abs() < 1e-15)); // no overflow at 1000
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn softmax<D: Dim>(x: &Tensor, dim: D) -> Result<Tensor> {
    let dim = dim.to_index(x.shape(), "softmax")?;
    let e = shifted(x, dim)?.exp()?;
    let sum = e.sum_keepdim(dim)?;
    Ok(e.broadcast_div(&sum)?)
}

/// Log-softmax of `x` along `dim`: `x_i - log(sum_j exp(x_j))`, stable for large and very
/// negative inputs (no `log(0)`). Use it with a negative log-likelihood rather than taking the
/// log of [`softmax`].
///
/// ```
/// use candle_core::{Device, Tensor};
/// let x = Tensor::new(&[0.0f64, -800.0], &Device::Cpu)?;
/// let l = pbdl_core::nn::log_softmax(&x, 0)?.to_vec1::<f64>()?;
/// assert_eq!(l, [0.0, -800.0]); // log(softmax) would give -inf for the second entry
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn log_softmax<D: Dim>(x: &Tensor, dim: D) -> Result<Tensor> {
    let dim = dim.to_index(x.shape(), "log_softmax")?;
    let s = shifted(x, dim)?;
    let log_sum = s.exp()?.sum_keepdim(dim)?.log()?;
    Ok(s.broadcast_sub(&log_sum)?)
}
