//! Activations with a backward that is exact to `f64` round-off.
//!
//! All of candle's elementwise activations have a backward, but two need care:
//!
//! * `Tensor::gelu` (tanh approximation) and `Tensor::gelu_erf` differentiate with constants
//!   rounded to 6 digits (`0.797885`, `0.398942`, ...), so their gradients are off by ~2e-7
//!   relative (measured in `tests/nn_tests.rs`; ours: < 1e-9). [`gelu`] here is composed from
//!   exact ops instead, and [`gelu_erf`] is a fused CPU kernel with a hand-written backward
//!   in full-precision constants ([`gelu_erf_composed`] elsewhere); their values equal candle's.
//! * `candle_nn::ops::mish` computes `log(1 + exp(x))`: `exp` overflows for `x > 88` in `f32`
//!   (`x > 709` in `f64`) and the gradient becomes NaN. [`softplus`] and [`mish`] here use the
//!   stable form `relu(x) + log(1 + exp(-|x|))`.
//!
//! The others wrap candle directly: [`relu`] (gradient 1 at 0), [`silu`], [`elu`],
//! [`sigmoid`] (candle-nn's kernel, whose backward only uses the output), [`tanh`], and
//! [`leaky_relu`] (the gradient at exactly 0 is the mean of both slopes).
//!
//! ```
//! use candle_core::{Device, Module, Tensor};
//! use pbdl_core::nn::Activation;
//!
//! let act: Activation = serde_json::from_str(r#"{"leaky_relu":{"negative_slope":0.1}}"#).unwrap();
//! let y = act.forward(&Tensor::new(&[-2.0f32, 3.0], &Device::Cpu)?)?;
//! assert_eq!(y.to_vec1::<f32>()?, [-0.2, 3.0]);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::Result;
use candle_core::Tensor;
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_2_SQRT_PI, SQRT_2};

/// `max(x, 0)`. A fused CPU kernel for `f32`/`f64` (one pass each way; same values and
/// gradients as candle's `Tensor::relu`, gradient 1 at 0), otherwise candle's.
pub fn relu(x: &Tensor) -> Result<Tensor> {
    if super::fused::fusable(x) {
        return Ok(super::fused::relu(x)?);
    }
    Ok(x.relu()?)
}

/// GELU, tanh approximation: `0.5 x (1 + tanh(sqrt(2/pi) (x + 0.044715 x^3)))`.
///
/// Composed from `tanh`, so its gradient is exact (candle's fused `gelu` backward is not; see
/// the module docs).
pub fn gelu(x: &Tensor) -> Result<Tensor> {
    // sqrt(2 / pi) = (2 / sqrt(pi)) / sqrt(2)
    let k = FRAC_2_SQRT_PI / SQRT_2;
    let inner = ((x.sqr()? * 0.044715)? + 1.0)?.mul(x)?;
    let t = (inner * k)?.tanh()?;
    Ok(((t + 1.0)? * x)?.affine(0.5, 0.0)?)
}

/// GELU with the exact normal CDF: `0.5 x (1 + erf(x / sqrt(2)))`.
///
/// On the CPU in `f32` and `f64` this is one fused custom op whose backward,
/// `0.5 (1 + erf(x / sqrt 2)) + x exp(-x^2 / 2) / sqrt(2 pi)`, uses full-precision constants
/// (candle's fused `gelu_erf` does not); other dtypes and devices use [`gelu_erf_composed`].
pub fn gelu_erf(x: &Tensor) -> Result<Tensor> {
    if super::fused::fusable(x) {
        return Ok(super::fused::gelu_erf(x)?);
    }
    gelu_erf_composed(x)
}

/// [`gelu_erf`] composed from `erf` and arithmetic (exact backward, any dtype and device, and
/// twice differentiable); the reference the fused CPU kernel is tested against.
pub fn gelu_erf_composed(x: &Tensor) -> Result<Tensor> {
    let cdf = ((x / SQRT_2)?.erf()? + 1.0)?;
    Ok((cdf * x)?.affine(0.5, 0.0)?)
}

/// SiLU (swish): `x * sigmoid(x)`.
pub fn silu(x: &Tensor) -> Result<Tensor> {
    Ok(x.silu()?)
}

/// ELU: `x` for `x > 0`, `alpha (exp(x) - 1)` otherwise.
pub fn elu(x: &Tensor, alpha: f64) -> Result<Tensor> {
    Ok(x.elu(alpha)?)
}

/// Leaky ReLU: `x` for `x > 0`, `negative_slope * x` otherwise. A fused CPU kernel for
/// `f32`/`f64` (one pass each way; same values and gradients as [`leaky_relu_composed`]),
/// otherwise the composed version.
pub fn leaky_relu(x: &Tensor, negative_slope: f64) -> Result<Tensor> {
    if super::fused::fusable(x) {
        return Ok(super::fused::leaky_relu(x, negative_slope)?);
    }
    leaky_relu_composed(x, negative_slope)
}

/// [`leaky_relu`] composed from candle ops (`max(x, 0) + slope min(x, 0)`; any dtype and
/// device); the reference the fused kernel is tested against.
pub fn leaky_relu_composed(x: &Tensor, negative_slope: f64) -> Result<Tensor> {
    Ok(candle_nn::ops::leaky_relu(x, negative_slope)?)
}

/// Logistic sigmoid `1 / (1 + exp(-x))`; saturates cleanly at both ends.
pub fn sigmoid(x: &Tensor) -> Result<Tensor> {
    Ok(candle_nn::ops::sigmoid(x)?)
}

/// Hyperbolic tangent.
pub fn tanh(x: &Tensor) -> Result<Tensor> {
    Ok(x.tanh()?)
}

/// Softplus `log(1 + exp(x))`, as `relu(x) + log(1 + exp(-|x|))` so it neither overflows nor
/// gives a NaN gradient for large `|x|`. Its derivative is `sigmoid(x)`.
pub fn softplus(x: &Tensor) -> Result<Tensor> {
    let tail = (x.abs()?.neg()?.exp()? + 1.0)?.log()?;
    Ok((x.relu()? + tail)?)
}

/// Mish `x * tanh(softplus(x))`, with the stable [`softplus`].
pub fn mish(x: &Tensor) -> Result<Tensor> {
    Ok((softplus(x)?.tanh()? * x)?)
}

/// A serde-configurable activation, usable as a `candle_core::Module`.
///
/// Serialised in snake case: `"relu"`, `"gelu"`, `{"elu": {"alpha": 1.0}}`,
/// `{"leaky_relu": {"negative_slope": 0.01}}`. The default is [`Activation::Gelu`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// The identity (no activation).
    Identity,
    /// [`relu`].
    Relu,
    /// [`gelu`] (tanh approximation).
    #[default]
    Gelu,
    /// [`gelu_erf`] (exact normal CDF).
    GeluErf,
    /// [`silu`].
    Silu,
    /// [`tanh`].
    Tanh,
    /// [`sigmoid`].
    Sigmoid,
    /// [`softplus`].
    Softplus,
    /// [`mish`].
    Mish,
    /// [`elu`].
    Elu {
        /// Scale of the negative branch (PyTorch default 1.0).
        alpha: f64,
    },
    /// [`leaky_relu`].
    LeakyRelu {
        /// Slope for negative inputs (PyTorch default 0.01).
        negative_slope: f64,
    },
}

impl Activation {
    /// Applies the activation; the same as `Module::forward` but with pbdl's error type.
    pub fn apply(&self, x: &Tensor) -> Result<Tensor> {
        match *self {
            Activation::Identity => Ok(x.clone()),
            Activation::Relu => relu(x),
            Activation::Gelu => gelu(x),
            Activation::GeluErf => gelu_erf(x),
            Activation::Silu => silu(x),
            Activation::Tanh => tanh(x),
            Activation::Sigmoid => sigmoid(x),
            Activation::Softplus => softplus(x),
            Activation::Mish => mish(x),
            Activation::Elu { alpha } => elu(x, alpha),
            Activation::LeakyRelu { negative_slope } => leaky_relu(x, negative_slope),
        }
    }
}

impl candle_core::Module for Activation {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Ok(self.apply(x)?)
    }
}
