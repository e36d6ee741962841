//! Dropout with a seeded mask (inverted dropout, as `torch.nn.Dropout`).
//!
//! In training every element is kept with probability `1 - p` and scaled by `1 / (1 - p)`, so
//! the expected output equals the input; in evaluation the layer is the identity. PyTorch draws
//! the mask from its global generator; here the caller passes a `seed`, so the same seed gives
//! the same mask (pick a new seed per step, e.g. `base_seed + step`, to get fresh masks). The
//! mask is drawn as uniforms `u` in `[0, 1)` from [`pbdl_core::seed::rand_uniform`] and an
//! element is kept where `u >= p`; the masks are not PyTorch's numbers, only its distribution.
//! The gradient is the same mask times the same scale.

use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Inverted dropout with drop probability `p` (PyTorch's `nn.Dropout(p)`; PyTorch's default is
/// `p = 0.5`, see [`Dropout::default`]).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use pbdl_nets::dropout::Dropout;
///
/// let drop = Dropout::new(0.25)?;
/// let x = Tensor::ones((4, 100), DType::F32, &Device::Cpu)?;
/// let y = drop.forward(&x, true, 7)?;
/// // Kept elements are scaled by 1 / (1 - p), dropped ones are zero.
/// let v = y.flatten_all()?.to_vec1::<f32>()?;
/// assert!(v.iter().all(|&e| e == 0.0 || (e - 4.0 / 3.0).abs() < 1e-6));
/// // Same seed, same mask; evaluation is the identity.
/// assert_eq!(drop.forward(&x, true, 7)?.flatten_all()?.to_vec1::<f32>()?, v);
/// assert_eq!(drop.forward(&x, false, 7)?.flatten_all()?.to_vec1::<f32>()?, vec![1.0; 400]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dropout {
    p: f64,
}

impl Default for Dropout {
    /// `p = 0.5`, PyTorch's default.
    fn default() -> Self {
        Self { p: 0.5 }
    }
}

impl Dropout {
    /// Dropout that zeroes each element with probability `p` in training.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] unless `0 <= p < 1` (`p = 1` would drop everything and divide
    /// by zero; PyTorch returns zeros there).
    pub fn new(p: f64) -> Result<Self> {
        if !(0.0..1.0).contains(&p) {
            return Err(Error::InvalidConfig {
                name: "dropout probability p",
                value: p.to_string(),
                hint: "use a drop probability in [0, 1)",
            });
        }
        Ok(Self { p })
    }

    /// The drop probability.
    pub fn p(&self) -> f64 {
        self.p
    }

    /// The scaled keep mask for a tensor like `x`: `1 / (1 - p)` where kept, `0` where dropped,
    /// in `x`'s dtype and on its device. `x`'s values are not read.
    ///
    /// # Errors
    /// candle's errors (e.g. an integer dtype).
    pub fn mask(&self, x: &Tensor, seed: u64) -> Result<Tensor> {
        let u = pbdl_core::seed::rand_uniform(x.shape(), 0.0, 1.0, DType::F64, x.device(), seed)?;
        let keep = u.ge(self.p)?.to_dtype(DType::F64)?;
        Ok(keep.affine(1.0 / (1.0 - self.p), 0.0)?.to_dtype(x.dtype())?)
    }

    /// `x * mask(x, seed)` when `train`, else `x` itself. With `p = 0` training is the identity
    /// too (no mask is drawn).
    ///
    /// # Errors
    /// candle's errors (e.g. an integer dtype).
    pub fn forward(&self, x: &Tensor, train: bool, seed: u64) -> Result<Tensor> {
        if !train || self.p == 0.0 {
            return Ok(x.clone());
        }
        Ok(x.mul(&self.mask(x, seed)?)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use pbdl_core::{check_grad, grad_check::GradCheckOptions, tolerance::GRAD_CHECK_F64};

    fn to_vec(t: &Tensor) -> Vec<f64> {
        t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap()
    }

    /// On `n` elements the dropped fraction has mean `p` and standard deviation
    /// `sqrt(p (1 - p) / n)`; the output mean of an all-ones input has mean 1 and standard
    /// deviation `sqrt(p / ((1 - p) n))`. Both are asserted within 5 standard deviations
    /// (a false failure has probability below 1e-6).
    #[test]
    fn drop_fraction_and_mean_match_p_within_five_sigma() {
        let n = 200_000usize;
        for p in [0.1, 0.3, 0.5, 0.8] {
            let x = Tensor::ones(n, DType::F32, &Device::Cpu).unwrap();
            let y = to_vec(&Dropout::new(p).unwrap().forward(&x, true, 11).unwrap());
            let dropped = y.iter().filter(|&&v| v == 0.0).count() as f64 / n as f64;
            let sd = (p * (1.0 - p) / n as f64).sqrt();
            assert!((dropped - p).abs() < 5.0 * sd, "p {p}: dropped {dropped}, 5 sd = {}", 5.0 * sd);
            let mean = y.iter().sum::<f64>() / n as f64;
            let sd_mean = (p / ((1.0 - p) * n as f64)).sqrt();
            assert!((mean - 1.0).abs() < 5.0 * sd_mean, "p {p}: mean {mean}, 5 sd = {}", 5.0 * sd_mean);
            let scale = 1.0 / (1.0 - p);
            assert!(y.iter().all(|&v| v == 0.0 || (v - scale).abs() < 1e-6 * scale));
        }
    }

    #[test]
    fn same_seed_same_mask_other_seed_other_mask_and_dtypes_agree() {
        let d = Dropout::new(0.5).unwrap();
        let x = pbdl_core::seed::randn((3, 4, 8, 8), 0.0, 1.0, DType::F64, &Device::Cpu, 1).unwrap();
        assert_eq!(to_vec(&d.forward(&x, true, 3).unwrap()), to_vec(&d.forward(&x, true, 3).unwrap()));
        assert_ne!(to_vec(&d.forward(&x, true, 3).unwrap()), to_vec(&d.forward(&x, true, 4).unwrap()));
        // The mask does not depend on the dtype: f32 and f64 drop the same elements.
        let a = to_vec(&d.forward(&x.to_dtype(DType::F32).unwrap(), true, 3).unwrap());
        let b = to_vec(&d.forward(&x, true, 3).unwrap());
        assert!(a.iter().zip(&b).all(|(u, v)| (u - v).abs() <= 1e-6 * v.abs().max(1.0)));
    }

    #[test]
    fn identity_in_eval_and_with_p_zero_and_errors() {
        let x = pbdl_core::seed::randn((2, 50), 0.0, 1.0, DType::F32, &Device::Cpu, 2).unwrap();
        assert_eq!(to_vec(&Dropout::new(0.7).unwrap().forward(&x, false, 1).unwrap()), to_vec(&x));
        assert_eq!(to_vec(&Dropout::new(0.0).unwrap().forward(&x, true, 1).unwrap()), to_vec(&x));
        assert_eq!(Dropout::default().p(), 0.5);
        for p in [1.0, -0.1, f64::NAN, 2.0] {
            assert!(matches!(Dropout::new(p), Err(Error::InvalidConfig { .. })), "p = {p}");
        }
    }

    /// The gradient of `sum(y * r)` is exactly `r * mask` (the mask values are 0 or the scale,
    /// and the product with the cotangent is exact in f64): no tolerance.
    #[test]
    fn gradient_is_mask_times_scale_exactly_and_matches_finite_differences() {
        let d = Dropout::new(0.4).unwrap();
        let x =
            Var::from_tensor(&pbdl_core::seed::randn((5, 40), 0.0, 1.0, DType::F64, &Device::Cpu, 3).unwrap()).unwrap();
        let r = pbdl_core::seed::randn((5, 40), 0.0, 1.0, DType::F64, &Device::Cpu, 4).unwrap();
        let y = d.forward(x.as_tensor(), true, 9).unwrap();
        let grads = y.mul(&r).unwrap().sum_all().unwrap().backward().unwrap();
        let g = to_vec(grads.get(x.as_tensor()).unwrap());
        let expect = to_vec(&d.mask(x.as_tensor(), 9).unwrap().mul(&r).unwrap());
        assert_eq!(g, expect);
        let mask = to_vec(&d.mask(x.as_tensor(), 9).unwrap());
        assert!(mask.iter().all(|&m| m == 0.0 || m == 1.0 / 0.6));
        let f = |v: &[Tensor]| d.forward(&v[0], true, 9).map_err(candle_core::Error::wrap);
        let rep = check_grad(f, &[x.as_tensor().clone()], &GradCheckOptions::default()).unwrap();
        rep.ensure(GRAD_CHECK_F64).unwrap();
        eprintln!("dropout FD rel error {:e}", rep.max_rel_error);
    }
}
