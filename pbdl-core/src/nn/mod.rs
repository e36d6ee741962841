//! Normalisation layers, pooling, softmax and activations that train: every one has a backward.
//!
//! candle 0.11 has fast fused kernels for `softmax_last_dim`, `layer_norm` and `rms_norm`
//! (and its `LayerNorm` / `RmsNorm` modules use them on contiguous input), but those kernels
//! have **no backward**: `loss.backward()` succeeds and the gradients of the input, the weight
//! and the bias are silently missing. The functions here are composed from differentiable
//! candle ops instead, so they work in training paths; each is checked against central finite
//! differences in `f64` (`tests/nn_tests.rs`).
//!
//! | function | normalises / maps | module |
//! |---|---|---|
//! | [`layer_norm`] | over the trailing `normalized_shape` dims, `(x - mean) / sqrt(var + eps)` | [`LayerNorm`] |
//! | [`group_norm`] | `[batch, channel, ..]` over each group of channels and all spatial dims | [`GroupNorm`] |
//! | [`batch_norm_train`], [`batch_norm_eval`] | `[batch, channel, ..]` per channel over batch and space (batch or running statistics), fused with an activation | [`BatchNorm2d`] |
//! | [`rms_norm`] | over the trailing dims, `x / sqrt(mean(x^2) + eps)` | [`RmsNorm`] |
//! | [`softmax`], [`log_softmax`] | over one chosen dim, shifted by the (detached) max for stability | |
//! | [`max_pool2d`] | `[batch, channel, y, x]`: max over square windows of any kernel and stride (PyTorch's floor mode), with a backward (candle's is missing or wrong) | |
//! | [`linear`] | `x W^T + b` in PyTorch's layout as one op (hand-written backward; [`linear_composed`] is the candle version) | |
//! | [`activation`] | `relu`, `gelu`, `gelu_erf`, `silu`, `elu`, `leaky_relu`, `sigmoid`, `softplus`, `mish`, ... | [`Activation`] |
//!
//! The variance is the biased one (divide by `n`), as in PyTorch. Half-precision inputs are
//! normalised in `f32` and cast back. [`group_norm`] and [`activation::gelu_erf`] (the hot
//! ones of the diffusion U-Nets) are fused CPU kernels with hand-written backward passes in
//! `f32`/`f64`; their composed references stay public ([`group_norm_composed`],
//! [`activation::gelu_erf_composed`]), and [`with_composed`] runs any code with the composed
//! versions (A/B comparisons of whole trainings in one process).
//!
//! ```
//! use candle_core::{DType, Device, Module, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_core::nn::{softmax, GroupNorm, GroupNormConfig};
//!
//! let dev = Device::Cpu;
//! let varmap = VarMap::new();
//! let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
//! let norm = GroupNorm::new(2, 4, GroupNormConfig::default(), vb.pp("norm"))?;
//! let x = pbdl_core::seed::randn((3, 4, 8, 8), 0.0, 2.0, DType::F32, &dev, 0)?;
//! let y = norm.forward(&x)?;
//!
//! // Every parameter gets a gradient (candle_nn::LayerNorm's weight would not).
//! let grads = softmax(&y.flatten_from(1)?, 1)?.sqr()?.sum_all()?.backward()?;
//! pbdl_core::assert_varmap_has_grads(&varmap, &grads)?;
//! # Ok::<(), pbdl_core::Error>(())
//! ```

pub mod activation;
pub mod batch_norm;
mod batch_norm_fused;
pub(crate) mod epilogue;
mod fused;
pub use fused::{fusion_enabled, with_composed};
mod layers;
mod linear;
pub use linear::{linear, linear_composed};
mod norm;
pub mod pool;
mod softmax;

pub use activation::Activation;
pub use batch_norm::{
    batch_norm_eval, batch_norm_eval_composed, batch_norm_train, batch_norm_train_composed, BatchNorm2d,
    BatchNormConfig, BatchStats,
};
pub use layers::{GroupNorm, GroupNormConfig, LayerNorm, LayerNormConfig, RmsNorm, RmsNormConfig};
pub use norm::{group_norm, group_norm_act, group_norm_composed, layer_norm, rms_norm};
pub use pool::max_pool2d;
pub use softmax::{log_softmax, softmax};
