//! The sinusoidal embedding of a diffusion step (or any scalar per sample).

use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Sinusoidal embedding of the diffusion step (Vaswani et al., as in the annotated diffusion
/// model): for `t` `[batch]` returns `[batch, dim]` = `[sin(t f_0..f_{h-1}), cos(t f_0..f_{h-1})]`
/// with `h = dim / 2` and `f_i = exp(-i ln(10000) / (h - 1))`.
///
/// # Errors
/// [`Error::InvalidConfig`] for `dim < 4` or odd `dim`; [`Error::ShapeMismatch`] if `t` is not
/// rank 1.
pub fn sinusoidal_embedding(t: &Tensor, dim: usize, dtype: DType) -> Result<Tensor> {
    if dim < 4 || dim % 2 != 0 {
        return Err(Error::InvalidConfig {
            name: "time embedding dim",
            value: dim.to_string(),
            hint: "use an even dimension of at least 4",
        });
    }
    if t.rank() != 1 {
        return Err(Error::shape("diffusion step t", "[batch]", t.dims()));
    }
    let half = dim / 2;
    let step = 10000f64.ln() / (half - 1) as f64;
    let freqs: Vec<f64> = (0..half).map(|i| (-(i as f64) * step).exp()).collect();
    let freqs = Tensor::from_vec(freqs, (1, half), t.device())?.to_dtype(dtype)?;
    let args = t.to_dtype(dtype)?.unsqueeze(1)?.broadcast_mul(&freqs)?;
    Ok(Tensor::cat(&[args.sin()?, args.cos()?], 1)?)
}
