//! Small building blocks shared by the U-Nets: a linear layer, convolution layers with
//! PyTorch's initialisation, the sinusoidal step embedding and a parameter counter.

use crate::{Error, Result};
use candle_core::{DType, Tensor};
use candle_nn::{Init, VarBuilder, VarMap};
use pbdl_core::conv::{conv_transpose2d, Conv2d, Conv2dParams, ConvLayerConfig};

/// A fully connected layer `y = x W^T + b` on `[batch, in]` inputs, weight `[out, in]`
/// (PyTorch's `nn.Linear` layout and initialisation: uniform in `±1/sqrt(in)`).
#[derive(Clone, Debug)]
pub struct Linear {
    weight: Tensor,
    bias: Tensor,
}

impl Linear {
    /// Creates the layer, taking `weight` and `bias` from `vb`.
    pub fn new(in_features: usize, out_features: usize, vb: VarBuilder) -> Result<Self> {
        if in_features == 0 || out_features == 0 {
            return Err(Error::InvalidConfig {
                name: "Linear features",
                value: format!("{in_features} -> {out_features}"),
                hint: "use at least one input and one output feature",
            });
        }
        let bound = 1.0 / (in_features as f64).sqrt();
        let init = Init::Uniform { lo: -bound, up: bound };
        let weight = vb.get_with_hints((out_features, in_features), "weight", init)?;
        let bias = vb.get_with_hints(out_features, "bias", init)?;
        Ok(Self { weight, bias })
    }

    /// `x W^T + b` for `x` of shape `[batch, in]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(x.matmul(&self.weight.t()?)?.broadcast_add(&self.bias)?)
    }
}

/// A 2D convolution layer `in -> out` with a square kernel, initialised like PyTorch's
/// `nn.Conv2d`.
pub(crate) fn conv2d_layer(
    vb: VarBuilder,
    c_in: usize,
    c_out: usize,
    kernel: usize,
    params: Conv2dParams,
    bias: bool,
) -> Result<Conv2d> {
    let mut cfg = ConvLayerConfig::new(c_in, c_out, [kernel, kernel]).with_params(params);
    if !bias {
        cfg = cfg.without_bias();
    }
    Ok(cfg.init(vb)?)
}

/// A 2D transposed convolution layer with a bias (PyTorch's `nn.ConvTranspose2d`, zero
/// padding, one group): weight `[in, out, k, k]`.
#[derive(Clone, Debug)]
pub(crate) struct ConvTranspose2d {
    weight: Tensor,
    bias: Tensor,
    params: Conv2dParams,
}

impl ConvTranspose2d {
    /// Creates the layer; PyTorch computes its init fan-in from weight dim 1 (`out * k * k`).
    pub fn new(
        vb: VarBuilder,
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
    ) -> Result<Self> {
        let bound = 1.0 / ((c_out * kernel * kernel) as f64).sqrt();
        let init = Init::Uniform { lo: -bound, up: bound };
        let weight = vb.get_with_hints((c_in, c_out, kernel, kernel), "weight", init)?;
        let bias = vb.get_with_hints(c_out, "bias", init)?;
        Ok(Self { weight, bias, params: Conv2dParams::default().stride(stride).padding(padding) })
    }

    /// The transposed convolution of `x` `[batch, in, h, w]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(conv_transpose2d(x, &self.weight, Some(&self.bias), &self.params, [0, 0])?)
    }
}

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

/// Number of scalar parameters held by `varmap` (the sum of its variables' element counts).
pub fn count_parameters(varmap: &VarMap) -> usize {
    varmap.all_vars().iter().map(|v| v.elem_count()).sum()
}

/// Re-initialises every variable of `varmap` like PyTorch's default layer initialisation, but
/// from `seed` (candle's own random init cannot be seeded): a weight of rank >= 2 is uniform
/// in `±1/sqrt(fan_in)` with `fan_in` the product of its dims after the first; a `bias` is
/// uniform with the bound of its sibling `weight`, or 0 when that weight has rank 1 (a norm);
/// other rank-1 variables (norm scales) are 1. Variables are visited in name order, so the
/// same seed and network give the same numbers.
pub fn seeded_init(varmap: &VarMap, seed: u64) -> Result<()> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let fan_bound = |dims: &[usize]| 1.0 / (dims[1..].iter().product::<usize>().max(1) as f64).sqrt();
    for (i, name) in names.into_iter().enumerate() {
        let var = &data[name];
        let dims = var.dims();
        let sibling = name.strip_suffix("bias").and_then(|stem| data.get(&format!("{stem}weight")));
        let bound = match (dims.len(), sibling) {
            (n, _) if n >= 2 => Some(fan_bound(dims)),
            (_, Some(w)) if w.rank() >= 2 => Some(fan_bound(w.dims())),
            _ => None,
        };
        let value = match bound {
            Some(b) => {
                pbdl_core::seed::rand_uniform(dims, -b, b, var.dtype(), var.device(), seed.wrapping_add(i as u64))?
            }
            None if name.ends_with("bias") => var.zeros_like()?,
            None => var.ones_like()?,
        };
        var.set(&value)?;
    }
    Ok(())
}
