//! The orthogonality baseline of the racecar paper: `0.1 sigma_max(W^T W - I)^2` per weight
//! matrix, with `sigma_max` from one power-iteration step per training step.
//!
//! The official code draws a fresh random start vector at every step; here the vector persists
//! between steps (as in spectral normalisation), so the estimate converges to `sigma_max` while
//! the weights change slowly. The vectors are constants for the gradient: with converged
//! singular vectors `u`, `v`, `d sigma / dM = u v^T` either way.

use candle_core::{DType, Device, Tensor};

/// The persistent vector of one weight matrix's power iteration.
#[derive(Clone, Debug)]
pub struct PowerIteration {
    u: Tensor,
}

impl PowerIteration {
    /// A seeded random unit start vector for `W: [in, out]` (`W^T W - I` is `out x out`).
    pub fn new(out: usize, seed: u64) -> candle_core::Result<Self> {
        let u = pbdl_core::seed::randn(&[out, 1], 0.0, 1.0, DType::F64, &Device::Cpu, seed)
            .map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        Ok(Self { u: unit(&u)? })
    }

    /// One power-iteration step on `M = W^T W - I` (`w: [in, out]`), then
    /// `sigma = u^T M v`: differentiable in `w`, with `u`, `v` held constant.
    pub fn sigma(&mut self, w: &Tensor) -> candle_core::Result<Tensor> {
        let out = w.dim(1)?;
        let eye = Tensor::eye(out, w.dtype(), w.device())?;
        let m = (w.t()?.matmul(w)? - eye)?;
        let md = m.detach();
        let u0 = self.u.to_dtype(w.dtype())?;
        let v = unit(&md.t()?.matmul(&u0)?)?;
        let u = unit(&md.matmul(&v)?)?;
        self.u = u.to_dtype(DType::F64)?;
        u.t()?.matmul(&m.matmul(&v)?)?.reshape(())
    }

    /// The orthogonality loss term `factor * sigma_max(W^T W - I)^2` (the paper: factor 0.1).
    pub fn penalty(&mut self, w: &Tensor, factor: f64) -> candle_core::Result<Tensor> {
        self.sigma(w)?.sqr()? * factor
    }
}

/// `x / ||x||` (a zero vector stays zero).
fn unit(x: &Tensor) -> candle_core::Result<Tensor> {
    let n = x.sqr()?.sum_all()?.sqrt()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
    if n > 0.0 {
        x / n
    } else {
        Ok(x.clone())
    }
}
