//! Normalisation modules with learnable affine parameters, built from a `VarBuilder`.
//!
//! Parameters are named `weight` (initialised to 1) and `bias` (initialised to 0), as in
//! PyTorch and candle-nn, so existing checkpoints load into them.

use super::norm::{check_eps, layer_norm, rms_norm};
use super::Activation;
use crate::{Error, Result};
use candle_core::{Module, Tensor};
use candle_nn::{Init, VarBuilder};
use serde::{Deserialize, Serialize};

/// Configuration of [`LayerNorm`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LayerNormConfig {
    /// Added to the variance before the square root. Default `1e-5` (PyTorch's).
    pub eps: f64,
    /// Learn an elementwise `weight` (init 1) and `bias` (init 0). Default `true`.
    pub affine: bool,
}

impl Default for LayerNormConfig {
    fn default() -> Self {
        Self { eps: 1e-5, affine: true }
    }
}

/// Layer normalisation over the trailing dims `normalized_shape`, with a backward
/// (unlike `candle_nn::LayerNorm` on contiguous input). See [`layer_norm`].
#[derive(Clone, Debug)]
pub struct LayerNorm {
    normalized_shape: Vec<usize>,
    weight: Option<Tensor>,
    bias: Option<Tensor>,
    eps: f64,
}

impl LayerNorm {
    /// Creates the layer; with `config.affine` its `weight` and `bias` of shape
    /// `normalized_shape` come from `vb`.
    ///
    /// ```
    /// use candle_core::{DType, Device, Module};
    /// use candle_nn::{VarBuilder, VarMap};
    /// use pbdl_core::nn::{LayerNorm, LayerNormConfig};
    ///
    /// let varmap = VarMap::new();
    /// let vb = VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu);
    /// let ln = LayerNorm::new(&[8], LayerNormConfig::default(), vb.pp("ln"))?;
    /// let x = pbdl_core::seed::randn((4, 8), 0.0, 1.0, DType::F64, &Device::Cpu, 0)?;
    /// let grads = ln.forward(&x)?.sqr()?.sum_all()?.backward()?;
    /// pbdl_core::assert_varmap_has_grads(&varmap, &grads)?; // ln.weight and ln.bias
    /// # Ok::<(), pbdl_core::Error>(())
    /// ```
    pub fn new(normalized_shape: &[usize], config: LayerNormConfig, vb: VarBuilder) -> Result<Self> {
        check_eps("LayerNorm", config.eps)?;
        if normalized_shape.is_empty() {
            return Err(Error::invalid(
                "LayerNorm",
                "normalized_shape",
                "is empty; give the trailing dims, e.g. &[channels]",
            ));
        }
        let (weight, bias) = if config.affine {
            let w = vb.get_with_hints(normalized_shape, "weight", Init::Const(1.0))?;
            let b = vb.get_with_hints(normalized_shape, "bias", Init::Const(0.0))?;
            (Some(w), Some(b))
        } else {
            (None, None)
        };
        Ok(Self { normalized_shape: normalized_shape.to_vec(), weight, bias, eps: config.eps })
    }

    /// The elementwise weight, if affine.
    pub fn weight(&self) -> Option<&Tensor> {
        self.weight.as_ref()
    }

    /// The elementwise bias, if affine.
    pub fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    /// The trailing dims normalised over.
    pub fn normalized_shape(&self) -> &[usize] {
        &self.normalized_shape
    }

    /// The variance offset.
    pub fn eps(&self) -> f64 {
        self.eps
    }

    /// The forward pass with pbdl's error type (shape errors name the layer and dims).
    pub fn apply(&self, x: &Tensor) -> Result<Tensor> {
        layer_norm(x, &self.normalized_shape, self.weight.as_ref(), self.bias.as_ref(), self.eps)
    }
}

impl Module for LayerNorm {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Ok(self.apply(x)?)
    }
}

/// Configuration of [`GroupNorm`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GroupNormConfig {
    /// Added to the variance before the square root. Default `1e-5` (PyTorch's).
    pub eps: f64,
    /// Learn a per-channel `weight` (init 1) and `bias` (init 0). Default `true`.
    pub affine: bool,
}

impl Default for GroupNormConfig {
    fn default() -> Self {
        Self { eps: 1e-5, affine: true }
    }
}

/// Group normalisation of `[batch, channel, ..]` tensors; see [`group_norm`].
#[derive(Clone, Debug)]
pub struct GroupNorm {
    num_groups: usize,
    num_channels: usize,
    weight: Option<Tensor>,
    bias: Option<Tensor>,
    eps: f64,
}

impl GroupNorm {
    /// Creates the layer for `num_channels` channels in `num_groups` groups (which must divide
    /// `num_channels`); with `config.affine` its `weight` and `bias` of shape `[num_channels]`
    /// come from `vb`.
    pub fn new(num_groups: usize, num_channels: usize, config: GroupNormConfig, vb: VarBuilder) -> Result<Self> {
        check_eps("GroupNorm", config.eps)?;
        if num_groups == 0 || num_channels % num_groups != 0 {
            return Err(Error::invalid(
                "GroupNorm",
                "num_groups",
                format!("{num_groups} does not divide num_channels = {num_channels}; use a divisor of it"),
            ));
        }
        let (weight, bias) = if config.affine {
            let w = vb.get_with_hints(num_channels, "weight", Init::Const(1.0))?;
            let b = vb.get_with_hints(num_channels, "bias", Init::Const(0.0))?;
            (Some(w), Some(b))
        } else {
            (None, None)
        };
        Ok(Self { num_groups, num_channels, weight, bias, eps: config.eps })
    }

    /// The per-channel weight, if affine.
    pub fn weight(&self) -> Option<&Tensor> {
        self.weight.as_ref()
    }

    /// The per-channel bias, if affine.
    pub fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    /// Number of groups.
    pub fn num_groups(&self) -> usize {
        self.num_groups
    }

    /// Number of channels.
    pub fn num_channels(&self) -> usize {
        self.num_channels
    }

    /// The variance offset.
    pub fn eps(&self) -> f64 {
        self.eps
    }

    /// The forward pass with pbdl's error type.
    pub fn apply(&self, x: &Tensor) -> Result<Tensor> {
        self.apply_act(x, Activation::Identity)
    }

    /// `act(self.apply(x))`, fused into the norm kernel for ReLU and LeakyReLU (see
    /// [`group_norm_act`](super::group_norm_act)).
    pub fn apply_act(&self, x: &Tensor, act: Activation) -> Result<Tensor> {
        if x.rank() < 2 || x.dims()[1] != self.num_channels {
            return Err(Error::Shape {
                op: "GroupNorm",
                arg: "x",
                expected: format!("[batch, {}, ..]", self.num_channels),
                got: x.dims().to_vec(),
            });
        }
        super::group_norm_act(x, self.num_groups, self.weight.as_ref(), self.bias.as_ref(), self.eps, act)
    }
}

impl Module for GroupNorm {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Ok(self.apply(x)?)
    }
}

/// Configuration of [`RmsNorm`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RmsNormConfig {
    /// Added to the mean square before the square root. Default `1e-5` (candle-nn's).
    pub eps: f64,
    /// Learn an elementwise `weight` (init 1). Default `true`.
    pub affine: bool,
}

impl Default for RmsNormConfig {
    fn default() -> Self {
        Self { eps: 1e-5, affine: true }
    }
}

/// RMS normalisation over the trailing dims, with a backward (unlike `candle_nn::RmsNorm`);
/// see [`rms_norm`].
#[derive(Clone, Debug)]
pub struct RmsNorm {
    normalized_shape: Vec<usize>,
    weight: Option<Tensor>,
    eps: f64,
}

impl RmsNorm {
    /// Creates the layer; with `config.affine` its `weight` of shape `normalized_shape` comes
    /// from `vb`.
    pub fn new(normalized_shape: &[usize], config: RmsNormConfig, vb: VarBuilder) -> Result<Self> {
        check_eps("RmsNorm", config.eps)?;
        if normalized_shape.is_empty() {
            return Err(Error::invalid(
                "RmsNorm",
                "normalized_shape",
                "is empty; give the trailing dims, e.g. &[channels]",
            ));
        }
        let weight =
            if config.affine { Some(vb.get_with_hints(normalized_shape, "weight", Init::Const(1.0))?) } else { None };
        Ok(Self { normalized_shape: normalized_shape.to_vec(), weight, eps: config.eps })
    }

    /// The elementwise weight, if affine.
    pub fn weight(&self) -> Option<&Tensor> {
        self.weight.as_ref()
    }

    /// The trailing dims normalised over.
    pub fn normalized_shape(&self) -> &[usize] {
        &self.normalized_shape
    }

    /// The mean-square offset.
    pub fn eps(&self) -> f64 {
        self.eps
    }

    /// The forward pass with pbdl's error type.
    pub fn apply(&self, x: &Tensor) -> Result<Tensor> {
        rms_norm(x, &self.normalized_shape, self.weight.as_ref(), self.eps)
    }
}

impl Module for RmsNorm {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Ok(self.apply(x)?)
    }
}
