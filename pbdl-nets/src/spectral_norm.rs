//! Spectral normalisation of a weight (Miyato et al. 2018), as `torch.nn.utils.spectral_norm`.
//!
//! The weight `W` is viewed as a matrix `[h, rest]` (axis `dim` first, the others flattened;
//! `dim = 0` is the output channel of a convolution or linear layer). A persistent unit vector
//! `u` (length `h`) and `v` (length `rest`) estimate its leading singular vectors; each training
//! call first runs `n_power_iterations` updates on the detached matrix,
//!
//! ```text
//! v <- normalise(W^T u),   u <- normalise(W v),   normalise(a) = a / max(|a|, eps)
//! ```
//!
//! then returns `W / sigma` with `sigma = u^T W v`. The gradient flows through `W` and `sigma`
//! but not through `u` and `v` (PyTorch's semantics). In evaluation no iteration runs and the
//! stored `u`, `v` are used. Each power iteration contracts the error of `u` by
//! `sigma_2 / sigma_1`; the estimate `sigma` errs by its square. One iteration per training step
//! suffices because the weight changes slowly (Miyato et al.).
//!
//! Differences from PyTorch: `u` and `v` are drawn from a `seed` ([`pbdl_core::seed::randn`],
//! `u` first, then `v`) instead of the global generator, so the numbers differ but the
//! distribution (normalised standard normals) does not. The old `torch.nn.utils.spectral_norm`
//! starts from these random vectors; the newer `torch.nn.utils.parametrizations.spectral_norm`
//! first runs 15 power iterations: call [`SpectralNorm::power_iterate`] with 15 for that.

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_core::conv::{Conv, ConvParams};
use serde::{Deserialize, Serialize};

/// Settings of [`SpectralNorm`] (PyTorch's arguments of `spectral_norm`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpectralNormConfig {
    /// Power iterations per training call. Default 1.
    pub n_power_iterations: usize,
    /// Floor of the norm in the vector normalisation. Default `1e-12`.
    pub eps: f64,
    /// The weight axis that becomes the matrix rows. Default 0 (use 1 for a transposed
    /// convolution's `[in, out, k..]` weight, as PyTorch does).
    pub dim: usize,
}

impl Default for SpectralNormConfig {
    fn default() -> Self {
        Self { n_power_iterations: 1, eps: 1e-12, dim: 0 }
    }
}

/// The state of spectral normalisation of one weight: its shape, the vectors `u` and `v`, and
/// the [`SpectralNormConfig`].
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use pbdl_nets::spectral_norm::{SpectralNorm, SpectralNormConfig};
///
/// // diag(3, 2, 1): largest singular value 3.
/// let w = Tensor::new(&[[3f64, 0., 0.], [0., 2., 0.], [0., 0., 1.]], &Device::Cpu)?;
/// let mut sn = SpectralNorm::new(w.dims(), SpectralNormConfig::default(), 0, DType::F64, &Device::Cpu)?;
/// sn.power_iterate(&w, 60)?;
/// assert!((sn.sigma(&w)?.to_scalar::<f64>()? - 3.0).abs() < 1e-9);
/// let w_sn = sn.normalise(&w, true)?; // one more iteration, then W / sigma
/// assert!((w_sn.get(0)?.get(0)?.to_scalar::<f64>()? - 1.0).abs() < 1e-9);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct SpectralNorm {
    shape: Vec<usize>,
    config: SpectralNormConfig,
    u: Tensor,
    v: Tensor,
}

impl SpectralNorm {
    /// The state for a weight of shape `weight_shape`, with `u` and `v` drawn from `seed` as
    /// normalised standard normals of `dtype` on `device`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for `config.dim` outside the weight's axes, an empty weight or
    /// a non-positive `eps`.
    pub fn new(
        weight_shape: &[usize],
        config: SpectralNormConfig,
        seed: u64,
        dtype: DType,
        device: &Device,
    ) -> Result<Self> {
        if config.dim >= weight_shape.len() {
            return Err(Error::InvalidConfig {
                name: "spectral norm dim",
                value: format!("{} for a weight of shape {weight_shape:?}", config.dim),
                hint: "pick a weight axis (0 for conv / linear weights, 1 for transposed conv weights)",
            });
        }
        if weight_shape.contains(&0) {
            return Err(Error::InvalidConfig {
                name: "spectral norm weight shape",
                value: format!("{weight_shape:?}"),
                hint: "spectral normalisation needs a non-empty weight",
            });
        }
        if !(config.eps > 0.0 && config.eps.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "spectral norm eps",
                value: config.eps.to_string(),
                hint: "use a small positive floor such as 1e-12",
            });
        }
        let h = weight_shape[config.dim];
        let rest = weight_shape.iter().product::<usize>() / h;
        let uv = pbdl_core::seed::randn(h + rest, 0.0, 1.0, DType::F64, device, seed)?;
        let u = normalised(&uv.narrow(0, 0, h)?, config.eps)?.to_dtype(dtype)?;
        let v = normalised(&uv.narrow(0, h, rest)?, config.eps)?.to_dtype(dtype)?;
        Ok(Self { shape: weight_shape.to_vec(), config, u, v })
    }

    /// The settings.
    pub fn config(&self) -> &SpectralNormConfig {
        &self.config
    }

    /// The left singular vector estimate `u`, `[h]`.
    pub fn u(&self) -> &Tensor {
        &self.u
    }

    /// The right singular vector estimate `v`, `[rest]`.
    pub fn v(&self) -> &Tensor {
        &self.v
    }

    /// `W` as the matrix `[h, rest]`: axis `dim` first, the others flattened in order.
    fn matrix(&self, w: &Tensor) -> Result<Tensor> {
        if w.dims() != self.shape.as_slice() {
            return Err(Error::shape("spectral norm weight", &self.shape, w.dims()));
        }
        let dim = self.config.dim;
        let h = self.shape[dim];
        let w = if dim == 0 {
            w.clone()
        } else {
            let order: Vec<usize> = std::iter::once(dim).chain((0..w.rank()).filter(|&d| d != dim)).collect();
            w.permute(order)?.contiguous()?
        };
        Ok(w.reshape((h, ()))?)
    }

    /// Runs `n` power iterations on `w` (detached) and stores the new `u` and `v`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] if `w` does not have the shape given to [`SpectralNorm::new`].
    pub fn power_iterate(&mut self, w: &Tensor, n: usize) -> Result<()> {
        let m = self.matrix(&w.detach())?;
        let eps = self.config.eps;
        let (mut u, mut v) = (self.u.to_dtype(w.dtype())?.unsqueeze(1)?, self.v.to_dtype(w.dtype())?.unsqueeze(1)?);
        for _ in 0..n {
            v = normalised(&m.t()?.matmul(&u)?, eps)?;
            u = normalised(&m.matmul(&v)?, eps)?;
        }
        self.u = u.squeeze(1)?;
        self.v = v.squeeze(1)?;
        Ok(())
    }

    /// The estimate `sigma = u^T W v` (a scalar tensor) with the stored `u`, `v`; differentiable
    /// in `w`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] if `w` does not have the shape given to [`SpectralNorm::new`].
    pub fn sigma(&self, w: &Tensor) -> Result<Tensor> {
        let m = self.matrix(w)?;
        let u = self.u.to_dtype(w.dtype())?.unsqueeze(0)?;
        let v = self.v.to_dtype(w.dtype())?.unsqueeze(1)?;
        Ok(u.matmul(&m)?.matmul(&v)?.squeeze(1)?.squeeze(0)?)
    }

    /// `W / sigma` with the stored `u`, `v` and no power iteration (evaluation mode; also what a
    /// finite-difference check of the training gradient holds fixed).
    ///
    /// # Errors
    /// As [`SpectralNorm::sigma`].
    pub fn normalise_fixed(&self, w: &Tensor) -> Result<Tensor> {
        Ok(w.broadcast_div(&self.sigma(w)?)?)
    }

    /// The spectrally normalised weight `W / sigma`. In training (`train`) it first runs
    /// `n_power_iterations` power iterations and stores `u`, `v`; otherwise it is
    /// [`SpectralNorm::normalise_fixed`].
    ///
    /// # Errors
    /// As [`SpectralNorm::sigma`].
    pub fn normalise(&mut self, w: &Tensor, train: bool) -> Result<Tensor> {
        if train {
            self.power_iterate(w, self.config.n_power_iterations)?;
        }
        self.normalise_fixed(w)
    }
}

/// `a / max(|a|, eps)`.
fn normalised(a: &Tensor, eps: f64) -> Result<Tensor> {
    let norm = a.sqr()?.sum_all()?.sqrt()?.maximum(eps)?;
    Ok(a.broadcast_div(&norm)?)
}

/// A convolution layer whose weight is spectrally normalised on every call, as
/// `spectral_norm(nn.Conv2d(..))` in a GAN discriminator. The bias is not normalised.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_core::conv::ConvLayerConfig;
/// use pbdl_nets::spectral_norm::{SpectralNormConfig, SpectralNormConv2d};
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let conv = ConvLayerConfig::new(3, 8, [3, 3]).init(vb.pp("d1"))?;
/// let mut layer = SpectralNormConv2d::new(conv, SpectralNormConfig::default(), 0)?;
/// let x = Tensor::ones((2, 3, 16, 16), DType::F32, &Device::Cpu)?;
/// assert_eq!(layer.forward(&x, true)?.dims(), &[2, 8, 14, 14]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct SpectralNormConv<const N: usize> {
    conv: Conv<N>,
    norm: SpectralNorm,
}

/// A 2D [`SpectralNormConv`].
pub type SpectralNormConv2d = SpectralNormConv<2>;

impl<const N: usize> SpectralNormConv<N> {
    /// Wraps `conv` (its weight stays a variable of its `VarMap`, so optimiser updates are seen);
    /// `u`, `v` are drawn from `seed` in the weight's dtype and device.
    ///
    /// # Errors
    /// As [`SpectralNorm::new`].
    pub fn new(conv: Conv<N>, config: SpectralNormConfig, seed: u64) -> Result<Self> {
        let w = conv.weight();
        let norm = SpectralNorm::new(w.dims(), config, seed, w.dtype(), w.device())?;
        Ok(Self { conv, norm })
    }

    /// The wrapped convolution (its raw weight, bias and parameters).
    pub fn conv(&self) -> &Conv<N> {
        &self.conv
    }

    /// The spectral normalisation state.
    pub fn spectral_norm(&self) -> &SpectralNorm {
        &self.norm
    }

    /// The convolution parameters.
    pub fn params(&self) -> &ConvParams<N> {
        self.conv.params()
    }

    /// The normalised weight: see [`SpectralNorm::normalise`].
    ///
    /// # Errors
    /// As [`SpectralNorm::normalise`].
    pub fn weight(&mut self, train: bool) -> Result<Tensor> {
        self.norm.normalise(self.conv.weight(), train)
    }

    /// `conv(x, W / sigma) + bias`; in training (`train`) the power iteration advances first.
    ///
    /// # Errors
    /// pbdl-core's convolution errors for a wrong input shape or dtype.
    pub fn forward(&mut self, x: &Tensor, train: bool) -> Result<Tensor> {
        let w = self.weight(train)?;
        Ok(pbdl_core::conv::conv(x, &w, self.conv.bias(), self.conv.params())?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Var;
    use pbdl_core::{check_grad, grad_check::GradCheckOptions, tolerance::GRAD_CHECK_F64};

    /// The `n x n` identity.
    fn identity(n: usize) -> Vec<Vec<f64>> {
        (0..n).map(|i| (0..n).map(|j| f64::from(u8::from(i == j))).collect()).collect()
    }

    /// An `n x n` rotation by `angle` in the plane of axes `(a, b)`, `a != b`.
    fn givens(n: usize, a: usize, b: usize, angle: f64) -> Vec<Vec<f64>> {
        let mut g = identity(n);
        let (c, s) = (angle.cos(), angle.sin());
        g[a][a] = c;
        g[b][b] = c;
        g[a][b] = -s;
        g[b][a] = s;
        g
    }

    fn matmul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
        (0..a.len()).map(|i| (0..b[0].len()).map(|j| (0..b.len()).map(|k| a[i][k] * b[k][j]).sum()).collect()).collect()
    }

    /// An orthogonal `n x n` matrix: a product of rotations in every axis pair.
    fn orthogonal(n: usize, seed: f64) -> Vec<Vec<f64>> {
        let mut q = identity(n);
        for a in 0..n {
            for b in a + 1..n {
                q = matmul(&q, &givens(n, a, b, seed + 0.7 * a as f64 + 1.3 * b as f64));
            }
        }
        q
    }

    /// `U S V^T` with orthogonal `U` (`h x h`), `V` (`w x w`) and `S` `h x w` with `s` on the
    /// diagonal: singular values exactly `s`.
    fn with_singular_values(h: usize, w: usize, s: &[f64]) -> Vec<f64> {
        let (u, v) = (orthogonal(h, 0.3), orthogonal(w, 1.1));
        let mut us = vec![vec![0.0; w]; h];
        for i in 0..h {
            for (k, sk) in s.iter().enumerate() {
                us[i][k] = u[i][k] * sk;
            }
        }
        let vt: Vec<Vec<f64>> = (0..w).map(|i| (0..w).map(|j| v[j][i]).collect()).collect();
        matmul(&us, &vt).into_iter().flatten().collect()
    }

    fn scalar(t: &Tensor) -> f64 {
        t.to_dtype(DType::F64).unwrap().to_scalar().unwrap()
    }

    /// A conv weight `[3, 2, 2, 2]` whose `[3, 8]` matrix has singular values 3, 2, 1: after
    /// enough iterations sigma is 3 and the normalised weight has spectral norm 1 (measured
    /// by a fresh estimator run to convergence). Convergence rate (2/3)^2 per iteration.
    #[test]
    fn sigma_converges_to_the_largest_singular_value_and_normalised_norm_is_one() {
        let w = Tensor::from_vec(with_singular_values(3, 8, &[3.0, 2.0, 1.0]), (3, 2, 2, 2), &Device::Cpu).unwrap();
        let cfg = SpectralNormConfig::default();
        let mut sn = SpectralNorm::new(w.dims(), cfg, 5, DType::F64, &Device::Cpu).unwrap();
        let first = scalar(&sn.sigma(&w).unwrap());
        assert!(first < 3.0, "a random u, v gives sigma {first} below the top singular value");
        for _ in 0..100 {
            sn.normalise(&w, true).unwrap();
        }
        let sigma = scalar(&sn.sigma(&w).unwrap());
        assert!((sigma - 3.0).abs() < 1e-12, "sigma {sigma}");
        let w_sn = sn.normalise(&w, false).unwrap();
        let mut check = SpectralNorm::new(w.dims(), cfg, 99, DType::F64, &Device::Cpu).unwrap();
        check.power_iterate(&w_sn, 200).unwrap();
        let norm = scalar(&check.sigma(&w_sn).unwrap());
        assert!((norm - 1.0).abs() < 1e-12, "spectral norm of W_sn {norm}");
        // u and v stay unit vectors.
        for t in [sn.u(), sn.v()] {
            assert!((scalar(&t.sqr().unwrap().sum_all().unwrap()) - 1.0).abs() < 1e-12);
        }
        // f32 agrees with f64 on the converged estimate.
        let mut sn32 = SpectralNorm::new(w.dims(), cfg, 5, DType::F32, &Device::Cpu).unwrap();
        let w32 = w.to_dtype(DType::F32).unwrap();
        sn32.power_iterate(&w32, 100).unwrap();
        assert!((scalar(&sn32.sigma(&w32).unwrap()) - 3.0).abs() < 1e-5);
    }

    /// diag(3, 2, 1) rotated on both sides, with `dim = 1` (a transposed-conv layout): the
    /// matrix of `W.permute(1, 0)` has the same singular values.
    #[test]
    fn dim_one_and_a_square_matrix() {
        let m = with_singular_values(3, 3, &[3.0, 2.0, 1.0]);
        let w = Tensor::from_vec(m, (3, 3), &Device::Cpu).unwrap();
        let cfg = SpectralNormConfig { n_power_iterations: 80, dim: 1, ..Default::default() };
        let mut sn = SpectralNorm::new(w.dims(), cfg, 1, DType::F64, &Device::Cpu).unwrap();
        let w_sn = sn.normalise(&w, true).unwrap();
        assert!((scalar(&sn.sigma(&w).unwrap()) - 3.0).abs() < 1e-12);
        let a: Vec<f64> = w_sn.flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f64> = (w / 3.0).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    /// The gradient of `W / (u^T W v)` with u, v fixed, against finite differences, and the
    /// training path's gradient equals the fixed one once u, v are stored (no gradient through
    /// the power iteration).
    #[test]
    fn gradient_through_sigma_and_w_matches_finite_differences() {
        let w = pbdl_core::seed::randn((4, 2, 3, 3), 0.0, 1.0, DType::F64, &Device::Cpu, 3).unwrap();
        let mut sn = SpectralNorm::new(w.dims(), SpectralNormConfig::default(), 2, DType::F64, &Device::Cpu).unwrap();
        sn.power_iterate(&w, 3).unwrap();
        let frozen = sn.clone();
        let f = |v: &[Tensor]| frozen.normalise_fixed(&v[0]).map_err(candle_core::Error::wrap);
        let rep = check_grad(f, std::slice::from_ref(&w), &GradCheckOptions::default()).unwrap();
        rep.ensure(GRAD_CHECK_F64).unwrap();
        eprintln!("spectral norm FD rel error {:e}", rep.max_rel_error);

        // Training call: one iteration from the state before, then the same gradient as the
        // fixed call with the resulting u, v.
        let r = pbdl_core::seed::randn(w.dims(), 0.0, 1.0, DType::F64, &Device::Cpu, 4).unwrap();
        let var = Var::from_tensor(&w).unwrap();
        let mut train = sn.clone();
        // The gradient of sum(y r) with respect to the weight.
        let grad = |y: Tensor| -> Vec<f64> {
            let g = y.mul(&r).unwrap().sum_all().unwrap().backward().unwrap();
            g.get(var.as_tensor()).unwrap().flatten_all().unwrap().to_vec1().unwrap()
        };
        let g1 = grad(train.normalise(var.as_tensor(), true).unwrap());
        let g2 = grad(train.normalise_fixed(var.as_tensor()).unwrap());
        assert_eq!(g1, g2);
        assert_ne!(train.u().to_vec1::<f64>().unwrap(), sn.u().to_vec1::<f64>().unwrap());
    }

    #[test]
    fn seeded_reproducibility_eval_mode_and_errors() {
        let w = pbdl_core::seed::randn((5, 3, 3, 3), 0.0, 1.0, DType::F32, &Device::Cpu, 7).unwrap();
        let run = |seed| {
            let mut sn =
                SpectralNorm::new(w.dims(), SpectralNormConfig::default(), seed, DType::F32, &Device::Cpu).unwrap();
            let mut out = Vec::new();
            for _ in 0..3 {
                out.push(sn.normalise(&w, true).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap());
            }
            (out, sn)
        };
        let ((a, sn), (b, _), (c, _)) = (run(1), run(1), run(2));
        assert_eq!(a, b);
        assert_ne!(a[0], c[0]);
        // Evaluation does not move u.
        let mut sn = sn;
        let u0 = sn.u().to_vec1::<f32>().unwrap();
        sn.normalise(&w, false).unwrap();
        assert_eq!(sn.u().to_vec1::<f32>().unwrap(), u0);

        let cfg = SpectralNormConfig::default();
        let bad_dim = SpectralNormConfig { dim: 4, ..cfg };
        assert!(matches!(
            SpectralNorm::new(&[2, 3], bad_dim, 0, DType::F32, &Device::Cpu),
            Err(Error::InvalidConfig { .. })
        ));
        assert!(matches!(
            SpectralNorm::new(&[0, 3], cfg, 0, DType::F32, &Device::Cpu),
            Err(Error::InvalidConfig { .. })
        ));
        let bad_eps = SpectralNormConfig { eps: 0.0, ..cfg };
        assert!(matches!(
            SpectralNorm::new(&[2, 3], bad_eps, 0, DType::F32, &Device::Cpu),
            Err(Error::InvalidConfig { .. })
        ));
        let mut sn = SpectralNorm::new(&[2, 3], cfg, 0, DType::F32, &Device::Cpu).unwrap();
        let other = Tensor::zeros((3, 2), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(sn.normalise(&other, true), Err(Error::ShapeMismatch { .. })));
    }

    /// The layer equals a plain convolution with the normalised weight, and its weight
    /// variable receives a gradient.
    #[test]
    fn conv_layer_uses_the_normalised_weight_and_trains() {
        let varmap = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu);
        let params = pbdl_core::conv::Conv2dParams::default().padding(1);
        let conv = pbdl_core::conv::ConvLayerConfig::new(2, 4, [3, 3]).with_params(params).init(vb.pp("c")).unwrap();
        crate::seeded_init(&varmap, 3).unwrap();
        let mut layer = SpectralNormConv2d::new(conv.clone(), SpectralNormConfig::default(), 1).unwrap();
        let x = pbdl_core::seed::randn((2, 2, 5, 5), 0.0, 1.0, DType::F64, &Device::Cpu, 8).unwrap();
        let y = layer.forward(&x, true).unwrap();
        let w_sn = layer.spectral_norm().normalise_fixed(conv.weight()).unwrap();
        let expect = pbdl_core::conv::conv2d(&x, &w_sn, conv.bias(), &params).unwrap();
        let d = (&y - &expect).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
        assert!(d < 1e-12, "{d}");
        let grads = y.sqr().unwrap().sum_all().unwrap().backward().unwrap();
        pbdl_core::grad_check::assert_varmap_has_grads(&varmap, &grads).unwrap();
    }
}
