//! Layers with PyTorch's layout and initialisation: a linear layer, and the convolution and
//! transposed-convolution layers the networks are built from.

use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::{Init, VarBuilder};
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

    /// `x W^T + b` for `x` of shape `[batch, in]` (one op: [`pbdl_core::nn::linear`]).
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(pbdl_core::nn::linear(x, &self.weight, Some(&self.bias))?)
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
