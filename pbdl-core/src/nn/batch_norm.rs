//! Batch normalisation ([`BatchNorm2d`]) with PyTorch's semantics, fused on the CPU.
//!
//! For `x` of shape `[batch, channel, ..]` (`[b, c]`, `[b, c, l]`, `[b, c, h, w]` or
//! `[b, c, d, h, w]`: PyTorch's `BatchNorm1d`/`2d`/`3d` in one type), per channel over the
//! `n = batch * spatial` values of that channel:
//!
//! * **train mode**: `y = (x - mean) / sqrt(var + eps) * weight + bias` with the batch `mean`
//!   and the *biased* batch variance `var = sum((x - mean)^2) / n`; the running statistics are
//!   then updated with the *unbiased* batch variance, as `torch.nn.BatchNorm2d` does:
//!
//!   ```text
//!   running_mean <- (1 - momentum) * running_mean + momentum * mean
//!   running_var  <- (1 - momentum) * running_var  + momentum * var * n / (n - 1)
//!   ```
//!
//!   (`n = 1` is an error in train mode, as in PyTorch);
//! * **eval mode**: the same map with `running_mean` and `running_var` in place of the batch
//!   statistics (constants: no gradient flows into them).
//!
//! Defaults are PyTorch's ([`BatchNormConfig`]): `eps = 1e-5`, `momentum = 0.1`, affine
//! `weight` initialised to 1 and `bias` to 0, `running_mean = 0`, `running_var = 1`.
//! What differs: `momentum = None` (PyTorch's cumulative average) and
//! `track_running_stats = false` are not offered, and `num_batches_tracked` is not stored (a
//! PyTorch state dict that has it still loads: [`crate::io::load_varmap`] ignores extra
//! tensors).
//!
//! # Where the running statistics live, and why they are not trained
//!
//! `running_mean` and `running_var` are variables of the layer's `VarBuilder`, named like
//! PyTorch's state dict (`<prefix>.running_mean`, `<prefix>.running_var`). So a checkpoint of
//! the `VarMap` ([`crate::io::save_varmap`], and the checkpoints of
//! [`crate::train::TrainLoop::resume`]) keeps them and a resumed run reloads them, with nothing
//! to remember. The layer updates them in place (`Var::set`) in train mode.
//!
//! They are never trained, although `VarMap::all_vars` (the variable list of
//! [`crate::train::TrainLoop::resume`]) includes them: the layer only ever reads them
//! detached, so no backward pass produces a gradient for them, and every optimiser in pbdl
//! (candle-nn's Adam/AdamW, including AdamW's weight decay, and [`crate::train::Sgd`]) and
//! the gradient clipping skip variables without a gradient. The alternatives were worse: a
//! second `VarMap` for the statistics would need a second checkpoint per run, and plain tensors
//! behind a `Mutex` would drop out of every checkpoint unless each method saved them by hand.
//! Code that treats *every* variable as a parameter (a flattened parameter vector, a
//! Jacobian over all weights) should filter them out: [`BatchNorm2d::trainable_vars`] lists a
//! layer's trainable variables, [`trainable_vars`] those of a whole `VarMap` (sorted by name),
//! and [`is_running_stat`] tells the names apart.
//!
//! # Fused kernel
//!
//! On the CPU in `f32`/`f64`, [`batch_norm_train`] and [`batch_norm_eval`] run one custom op
//! (normalisation, affine map and an activation among identity, ReLU and leaky ReLU, with a
//! hand-written backward; see `batch_norm_fused.rs`). Other activations follow as a separate
//! op; other dtypes and devices, and `PBDL_NN_COMPOSED=1`, use the composed versions
//! ([`batch_norm_train_composed`], [`batch_norm_eval_composed`]), which are the reference the
//! fused kernel is tested against.
//!
//! ```
//! use candle_core::{DType, Device};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_core::nn::{Activation, BatchNorm2d, BatchNormConfig};
//!
//! let dev = Device::Cpu;
//! let varmap = VarMap::new();
//! let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
//! let bn = BatchNorm2d::new(4, BatchNormConfig::default(), vb.pp("bn"))?;
//! let x = pbdl_core::seed::randn((8, 4, 6, 6), 3.0, 2.0, DType::F32, &dev, 0)?;
//!
//! // Train mode: batch statistics (output mean 0, variance 1 per channel), running stats move.
//! let y = bn.forward_with(&x, true, Activation::LeakyRelu { negative_slope: 0.3 })?;
//! let grads = y.sqr()?.sum_all()?.backward()?;
//! assert!(grads.get(bn.weight().unwrap()).is_some());
//! let (mean, _var) = bn.running_stats()?;
//! let m = mean.to_vec1::<f32>()?;
//! assert!(m.iter().all(|&m| (m - 0.3).abs() < 0.1)); // 0.9 * 0 + 0.1 * (about 3)
//!
//! // The running stats are in the VarMap (checkpoints keep them) but get no gradient.
//! assert!(grads.get(&varmap.data().lock().unwrap()["bn.running_mean"]).is_none());
//! assert_eq!(pbdl_core::nn::batch_norm::trainable_vars(&varmap).len(), 2); // bn.bias, bn.weight
//!
//! // Eval mode: the running statistics.
//! let y_eval = bn.forward(&x, false)?;
//! assert_eq!(y_eval.dims(), [8, 4, 6, 6]);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use super::batch_norm_fused::{self as fused, BatchNormOp};
use super::epilogue::Epilogue;
use super::norm::check_eps;
use super::Activation;
use crate::{Error, Result};
use candle_core::{DType, ModuleT, Tensor, Var};
use candle_nn::{Init, VarBuilder, VarMap};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, OnceLock};

/// The state-dict names of the running statistics (the last component of a variable's name).
pub const RUNNING_STAT_NAMES: [&str; 2] = ["running_mean", "running_var"];

/// Whether the variable name `name` (e.g. `"block3.bn.running_var"`) is a running statistic of
/// a batch norm (`running_mean`, `running_var`, or PyTorch's `num_batches_tracked`) rather
/// than a trainable parameter.
pub fn is_running_stat(name: &str) -> bool {
    let last = name.rsplit('.').next().unwrap_or(name);
    RUNNING_STAT_NAMES.contains(&last) || last == "num_batches_tracked"
}

/// The variables of `varmap` that are not batch-norm running statistics ([`is_running_stat`]),
/// sorted by name (a fixed order, as [`crate::train::TrainLoop::in_memory`] wants).
pub fn trainable_vars(varmap: &VarMap) -> Vec<Var> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut named: Vec<(&String, &Var)> = data.iter().filter(|(n, _)| !is_running_stat(n)).collect();
    named.sort_by(|a, b| a.0.cmp(b.0));
    named.into_iter().map(|(_, v)| v.clone()).collect()
}

/// Configuration of [`BatchNorm2d`]; the defaults are PyTorch's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BatchNormConfig {
    /// Added to the variance before the square root. Default `1e-5`.
    pub eps: f64,
    /// Weight of the new batch statistic in the running averages, in `[0, 1]`. Default `0.1`.
    pub momentum: f64,
    /// Learn a per-channel `weight` (init 1) and `bias` (init 0). Default `true`.
    pub affine: bool,
}

impl Default for BatchNormConfig {
    fn default() -> Self {
        Self { eps: 1e-5, momentum: 0.1, affine: true }
    }
}

/// The statistics of one training batch, per channel, in `f64`.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchStats {
    /// The batch mean of each channel.
    pub mean: Vec<f64>,
    /// The biased batch variance of each channel (divided by `count`), the one normalised with.
    pub var: Vec<f64>,
    /// Values per channel, `n = batch * spatial`.
    pub count: usize,
}

impl BatchStats {
    /// The unbiased variance `var * n / (n - 1)`, the one the running variance averages.
    pub fn unbiased_var(&self) -> Vec<f64> {
        let f = self.count as f64 / (self.count.max(2) - 1) as f64;
        self.var.iter().map(|v| v * f).collect()
    }
}

/// `x` read as `[batch, channel, spatial]`: its channel count and that 3-D view.
fn view3(op: &'static str, x: &Tensor) -> Result<(usize, Tensor)> {
    let d = x.dims();
    if d.len() < 2 {
        return Err(Error::Shape { op, arg: "x", expected: "[batch, channel, ..]".into(), got: d.to_vec() });
    }
    let spatial: usize = d[2..].iter().product();
    Ok((d[1], x.reshape((d[0], d[1], spatial))?))
}

/// Checks an optional per-channel parameter's shape and dtype.
fn check_channel_param(op: &'static str, arg: &'static str, p: Option<&Tensor>, c: usize, x: &Tensor) -> Result<()> {
    let Some(p) = p else { return Ok(()) };
    if p.dims() != [c] {
        return Err(Error::Shape { op, arg, expected: format!("[{c}]"), got: p.dims().to_vec() });
    }
    if p.dtype() != x.dtype() {
        return Err(Error::invalid(
            op,
            arg,
            format!("has dtype {:?} but x has {:?}; convert one with `.to_dtype(..)`", p.dtype(), x.dtype()),
        ));
    }
    Ok(())
}

fn check_train_count(op: &'static str, x: &Tensor) -> Result<usize> {
    let d = x.dims();
    let n = d[0] * d[2..].iter().product::<usize>();
    if n < 2 && d[1] > 0 {
        return Err(Error::invalid(
            op,
            "x",
            format!(
                "training mode needs more than one value per channel (batch x spatial), got shape {d:?}; \
                 use a batch of 2 or more, or eval mode"
            ),
        ));
    }
    Ok(n)
}

/// The weight and bias for the fused op: missing ones become ones / zeros.
fn params_or_default(x: &Tensor, c: usize, weight: Option<&Tensor>, bias: Option<&Tensor>) -> Result<(Tensor, Tensor)> {
    let w = match weight {
        Some(w) => w.clone(),
        None => Tensor::ones(c, x.dtype(), x.device())?,
    };
    let b = match bias {
        Some(b) => b.clone(),
        None => Tensor::zeros(c, x.dtype(), x.device())?,
    };
    Ok((w, b))
}

/// `y * weight + bias` on a `[b, c, s]` view with `[c]` parameters.
fn affine3(y: Tensor, c: usize, weight: Option<&Tensor>, bias: Option<&Tensor>) -> Result<Tensor> {
    let y = match weight {
        Some(w) => y.broadcast_mul(&w.reshape((1, c, 1))?)?,
        None => y,
    };
    Ok(match bias {
        Some(b) => y.broadcast_add(&b.reshape((1, c, 1))?)?,
        None => y,
    })
}

/// A `[c]` tensor as `f64` values.
fn to_f64s(t: &Tensor) -> Result<Vec<f64>> {
    Ok(t.detach().flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
}

/// Train-mode batch norm of `x` (`[batch, channel, ..]`) with optional per-channel `weight`
/// and `bias`, followed by `activation`: `act((x - mean) / sqrt(var + eps) * weight + bias)`
/// with the batch mean and biased variance over all dims but the channel. Returns the output
/// and the batch statistics (from which [`BatchNorm2d`] updates its running averages).
///
/// Differentiable in `x`, `weight` and `bias` (the statistics are functions of `x`). On the CPU
/// in `f32`/`f64` a fused op (the activation inside when it is identity, ReLU or leaky ReLU);
/// otherwise [`batch_norm_train_composed`].
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_core::nn::{batch_norm_train, Activation};
/// // One channel, values 1, 2, 3, 6: mean 3, biased variance 3.5.
/// let x = Tensor::new(&[1.0f64, 2.0, 3.0, 6.0], &Device::Cpu)?.reshape((4, 1))?;
/// let (y, stats) = batch_norm_train(&x, None, None, 0.0, Activation::Identity)?;
/// assert_eq!((stats.mean[0], stats.var[0]), (3.0, 3.5));
/// assert!((stats.unbiased_var()[0] - 14.0 / 3.0).abs() < 1e-15); // var n / (n - 1)
/// let s = 3.5f64.sqrt();
/// for (a, b) in y.flatten_all()?.to_vec1::<f64>()?.iter().zip([-2.0 / s, -1.0 / s, 0.0, 3.0 / s]) {
///     assert!((a - b).abs() < 1e-15);
/// }
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn batch_norm_train(
    x: &Tensor,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    activation: Activation,
) -> Result<(Tensor, BatchStats)> {
    const OP: &str = "batch_norm_train";
    if !super::fused::fusable(x) {
        return batch_norm_train_composed(x, weight, bias, eps, activation);
    }
    let (c, _) = view3(OP, x)?;
    check_eps(OP, eps)?;
    check_channel_param(OP, "weight", weight, c, x)?;
    check_channel_param(OP, "bias", bias, c, x)?;
    let count = check_train_count(OP, x)?;
    let (w, b) = params_or_default(x, c, weight, bias)?;
    let epilogue = Epilogue::of_with_pre_activation(activation);
    let batch = Arc::new(OnceLock::new());
    let op = BatchNormOp::train(eps, epilogue.unwrap_or(Epilogue::Identity), batch.clone());
    let y = fused::apply(x, &w, &b, op)?;
    let y = if epilogue.is_some() { y } else { activation.apply(&y)? };
    let stats = batch.get().cloned().unwrap_or_else(|| vec![[0.0, 1.0]; c]);
    let (mean, var) = stats.into_iter().map(|[m, v]| (m, v)).unzip();
    Ok((y, BatchStats { mean, var, count }))
}

/// [`batch_norm_train`] composed from candle ops (any float dtype and device, twice
/// differentiable): the reference of the fused kernel.
pub fn batch_norm_train_composed(
    x: &Tensor,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    activation: Activation,
) -> Result<(Tensor, BatchStats)> {
    const OP: &str = "batch_norm_train";
    let (c, x3) = view3(OP, x)?;
    check_eps(OP, eps)?;
    check_channel_param(OP, "weight", weight, c, x)?;
    check_channel_param(OP, "bias", bias, c, x)?;
    let count = check_train_count(OP, x)?;
    let mean = x3.mean_keepdim((0, 2))?;
    let centred = x3.broadcast_sub(&mean)?;
    let var = centred.sqr()?.mean_keepdim((0, 2))?;
    let xhat = centred.broadcast_div(&(&var + eps)?.sqrt()?)?;
    let y = activation.apply(&affine3(xhat, c, weight, bias)?)?.reshape(x.shape())?;
    Ok((y, BatchStats { mean: to_f64s(&mean)?, var: to_f64s(&var)?, count }))
}

/// Eval-mode batch norm: `act((x - mean) / sqrt(var + eps) * weight + bias)` with given
/// per-channel `mean` and `var` (`[channel]`, e.g. running statistics), differentiable in `x`,
/// `weight` and `bias`. Fused on the CPU in `f32`/`f64` when `mean` and `var` carry no gradient
/// (they are constants of the kernel); otherwise, or elsewhere, [`batch_norm_eval_composed`],
/// which also differentiates in `mean` and `var`.
pub fn batch_norm_eval(
    x: &Tensor,
    mean: &Tensor,
    var: &Tensor,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    activation: Activation,
) -> Result<Tensor> {
    const OP: &str = "batch_norm_eval";
    if !super::fused::fusable(x) || mean.track_op() || var.track_op() {
        return batch_norm_eval_composed(x, mean, var, weight, bias, eps, activation);
    }
    let (c, _) = view3(OP, x)?;
    check_eps(OP, eps)?;
    for (arg, p) in [("mean", mean), ("var", var)] {
        if p.dims() != [c] {
            return Err(Error::Shape { op: OP, arg, expected: format!("[{c}]"), got: p.dims().to_vec() });
        }
    }
    check_channel_param(OP, "weight", weight, c, x)?;
    check_channel_param(OP, "bias", bias, c, x)?;
    let (w, b) = params_or_default(x, c, weight, bias)?;
    let stats = to_f64s(mean)?.into_iter().zip(to_f64s(var)?).map(|(m, v)| [m, v]).collect();
    let epilogue = Epilogue::of_with_pre_activation(activation);
    let op = BatchNormOp::eval(eps, epilogue.unwrap_or(Epilogue::Identity), stats);
    let y = fused::apply(x, &w, &b, op)?;
    if epilogue.is_some() {
        Ok(y)
    } else {
        activation.apply(&y)
    }
}

/// [`batch_norm_eval`] composed from candle ops (any float dtype and device).
pub fn batch_norm_eval_composed(
    x: &Tensor,
    mean: &Tensor,
    var: &Tensor,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    activation: Activation,
) -> Result<Tensor> {
    const OP: &str = "batch_norm_eval";
    let (c, x3) = view3(OP, x)?;
    check_eps(OP, eps)?;
    for (arg, p) in [("mean", mean), ("var", var)] {
        check_channel_param(OP, arg, Some(p), c, x)?;
    }
    check_channel_param(OP, "weight", weight, c, x)?;
    check_channel_param(OP, "bias", bias, c, x)?;
    let rstd = (var + eps)?.sqrt()?.recip()?.reshape((1, c, 1))?;
    let xhat = x3.broadcast_sub(&mean.reshape((1, c, 1))?)?.broadcast_mul(&rstd)?;
    Ok(activation.apply(&affine3(xhat, c, weight, bias)?)?.reshape(x.shape())?)
}

/// Batch normalisation of `[batch, channel, ..]` tensors with running statistics, as
/// `torch.nn.BatchNorm2d` (and `1d`/`3d`); see the [module docs](self) for the maths, the
/// defaults and how the running statistics are stored and kept out of training.
///
/// A clone shares its parameters and running statistics with the original (like a PyTorch
/// module used twice).
#[derive(Clone, Debug)]
pub struct BatchNorm2d {
    num_features: usize,
    weight: Option<Tensor>,
    bias: Option<Tensor>,
    running_mean: Var,
    running_var: Var,
    config: BatchNormConfig,
}

impl BatchNorm2d {
    /// Creates the layer for `num_features` channels: `running_mean` (init 0) and
    /// `running_var` (init 1), and with `config.affine` its `weight` (init 1) and `bias`
    /// (init 0), all of shape `[num_features]`, come from `vb`. With a `VarBuilder` that is not
    /// backed by a `VarMap` (weights loaded for inference) the layer keeps its own copy of the
    /// running statistics.
    pub fn new(num_features: usize, config: BatchNormConfig, vb: VarBuilder) -> Result<Self> {
        const OP: &str = "BatchNorm2d";
        check_eps(OP, config.eps)?;
        if num_features == 0 {
            return Err(Error::invalid(OP, "num_features", "is 0; give the channel count of the input"));
        }
        if !(0.0..=1.0).contains(&config.momentum) {
            return Err(Error::invalid(
                OP,
                "momentum",
                format!("must be in [0, 1] (PyTorch's default is 0.1), got {}", config.momentum),
            ));
        }
        let (weight, bias) = if config.affine {
            let w = vb.get_with_hints(num_features, "weight", Init::Const(1.0))?;
            let b = vb.get_with_hints(num_features, "bias", Init::Const(0.0))?;
            (Some(w), Some(b))
        } else {
            (None, None)
        };
        // `Var::from_tensor` shares a VarMap variable (so `Var::set` updates what the VarMap
        // saves) and copies anything else.
        let running_mean = Var::from_tensor(&vb.get_with_hints(num_features, "running_mean", Init::Const(0.0))?)?;
        let running_var = Var::from_tensor(&vb.get_with_hints(num_features, "running_var", Init::Const(1.0))?)?;
        Ok(Self { num_features, weight, bias, running_mean, running_var, config })
    }

    /// Normalises `x` (`[batch, num_features, ..]`): with batch statistics and a running-stats
    /// update when `train`, with the running statistics otherwise.
    pub fn forward(&self, x: &Tensor, train: bool) -> Result<Tensor> {
        self.forward_with(x, train, Activation::Identity)
    }

    /// [`BatchNorm2d::forward`] followed by `activation`, fused into one kernel on the CPU for
    /// identity, ReLU and leaky ReLU (the GAN generators' `BN -> ReLU`).
    pub fn forward_with(&self, x: &Tensor, train: bool, activation: Activation) -> Result<Tensor> {
        if x.rank() < 2 || x.dims()[1] != self.num_features {
            return Err(Error::Shape {
                op: "BatchNorm2d",
                arg: "x",
                expected: format!("[batch, {}, ..]", self.num_features),
                got: x.dims().to_vec(),
            });
        }
        let (w, b, eps) = (self.weight.as_ref(), self.bias.as_ref(), self.config.eps);
        if !train {
            let (m, v) = self.running_stats()?;
            let (m, v) = (m.to_dtype(x.dtype())?, v.to_dtype(x.dtype())?);
            return batch_norm_eval(x, &m, &v, w, b, eps, activation);
        }
        let (y, stats) = batch_norm_train(x, w, b, eps, activation)?;
        self.update_running_stats(&stats)?;
        Ok(y)
    }

    /// Folds one batch's statistics into the running averages (what train mode does after the
    /// normalisation); see the module docs for the formula.
    pub fn update_running_stats(&self, stats: &BatchStats) -> Result<()> {
        if stats.mean.len() != self.num_features || stats.var.len() != self.num_features {
            return Err(Error::Shape {
                op: "BatchNorm2d::update_running_stats",
                arg: "stats",
                expected: format!("{} channels", self.num_features),
                got: vec![stats.mean.len(), stats.var.len()],
            });
        }
        let m = self.config.momentum;
        let blend = |var: &Var, batch: &[f64]| -> Result<()> {
            let old = to_f64s(var.as_tensor())?;
            let new: Vec<f64> = old.iter().zip(batch).map(|(o, b)| (1.0 - m) * o + m * b).collect();
            let t = Tensor::from_vec(new, self.num_features, var.device())?.to_dtype(var.dtype())?;
            Ok(var.set(&t)?)
        };
        blend(&self.running_mean, &stats.mean)?;
        blend(&self.running_var, &stats.unbiased_var())
    }

    /// Detached copies of `(running_mean, running_var)`, `[num_features]` each.
    pub fn running_stats(&self) -> Result<(Tensor, Tensor)> {
        Ok((self.running_mean.as_tensor().detach().copy()?, self.running_var.as_tensor().detach().copy()?))
    }

    /// Sets the running statistics (`[num_features]` each; converted to the layer's dtype and
    /// device), e.g. from a foreign checkpoint.
    pub fn load_running_stats(&self, mean: &Tensor, var: &Tensor) -> Result<()> {
        for (arg, t) in [("mean", mean), ("var", var)] {
            if t.dims() != [self.num_features] {
                return Err(Error::Shape {
                    op: "BatchNorm2d::load_running_stats",
                    arg,
                    expected: format!("[{}]", self.num_features),
                    got: t.dims().to_vec(),
                });
            }
        }
        let conv = |v: &Var, t: &Tensor| -> Result<()> {
            Ok(v.set(&t.detach().to_dtype(v.dtype())?.to_device(v.device())?.copy()?)?)
        };
        conv(&self.running_mean, mean)?;
        conv(&self.running_var, var)
    }

    /// The layer's trainable variables, `[weight, bias]` (empty without affine parameters, or
    /// when the `VarBuilder` was not backed by a `VarMap`). Never the running statistics.
    pub fn trainable_vars(&self) -> Vec<Var> {
        [&self.weight, &self.bias]
            .into_iter()
            .flatten()
            .filter(|t| t.is_variable())
            .filter_map(|t| Var::from_tensor(t).ok())
            .collect()
    }

    /// The per-channel weight, if affine.
    pub fn weight(&self) -> Option<&Tensor> {
        self.weight.as_ref()
    }

    /// The per-channel bias, if affine.
    pub fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    /// Number of channels.
    pub fn num_features(&self) -> usize {
        self.num_features
    }

    /// The configuration.
    pub fn config(&self) -> BatchNormConfig {
        self.config
    }
}

impl ModuleT for BatchNorm2d {
    fn forward_t(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        Ok(self.forward(x, train)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::{F32_AGREEMENT, GRAD_CHECK_F64};
    use crate::{check_grad, GradCheckOptions};
    use candle_core::Device;
    use candle_nn::Optimizer;

    type TrainFn = fn(&Tensor, Option<&Tensor>, Option<&Tensor>, f64, Activation) -> Result<(Tensor, BatchStats)>;

    const LEAKY: Activation = Activation::LeakyRelu { negative_slope: 0.3 };

    fn randn(shape: &[usize], dtype: DType, seed: u64) -> Tensor {
        crate::seed::randn(shape, 0.5, 1.5, dtype, &Device::Cpu, seed).unwrap()
    }

    fn vals(t: &Tensor) -> Vec<f64> {
        t.flatten_all().unwrap().to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
    }

    /// `max |a - b| / max |b|`, and `max |a - b|`.
    fn rel_diff(a: &Tensor, b: &Tensor) -> (f64, f64) {
        let (a, b) = (vals(a), vals(b));
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        let d = a.iter().zip(&b).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        (d / scale, d)
    }

    fn layer(c: usize, dtype: DType) -> (VarMap, BatchNorm2d) {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, dtype, &Device::Cpu);
        let bn = BatchNorm2d::new(c, BatchNormConfig::default(), vb.pp("bn")).unwrap();
        (varmap, bn)
    }

    /// The 2x2x2x2 case by hand. Channel 0 holds 1..8: mean 4.5, squared deviations
    /// 2 (3.5^2 + 2.5^2 + 1.5^2 + 0.5^2) = 42, biased variance 42 / 8 = 5.25, unbiased
    /// 42 / 7 = 6. Channel 1 holds -1, 1, -1, 1, ..: mean 0, biased variance 1, unbiased 8 / 7.
    /// After one step with momentum 0.1: running_mean = (0.45, 0),
    /// running_var = (0.9 + 0.6, 0.9 + 0.8 / 7) = (1.5, 1.0142857..); after a second step with
    /// the same batch: (0.855, 0), (1.95, 0.9 * 1.0142857.. + 0.8 / 7).
    #[test]
    fn hand_computed_two_by_two_case() {
        let data = [1.0, 2.0, 3.0, 4.0, -1.0, 1.0, -1.0, 1.0, 5.0, 6.0, 7.0, 8.0, -1.0, 1.0, -1.0, 1.0];
        let x = Tensor::new(&data, &Device::Cpu).unwrap().reshape((2, 2, 2, 2)).unwrap();
        let eps = 1e-5;
        let norm = |v: f64, ch: usize, m: [f64; 2], s2: [f64; 2]| (v - m[ch]) / (s2[ch] + eps).sqrt();
        let expect = |m: [f64; 2], s2: [f64; 2]| -> Vec<f64> {
            data.iter().enumerate().map(|(i, &v)| norm(v, (i / 4) % 2, m, s2)).collect()
        };
        let close = |got: &[f64], want: &[f64], what: &str| {
            for (g, w) in got.iter().zip(want) {
                assert!((g - w).abs() < 1e-14, "{what}: {got:?} vs {want:?}");
            }
        };
        for dtype in [DType::F64, DType::F32] {
            let tol = if dtype == DType::F64 { 1e-14 } else { 1e-6 };
            let xd = x.to_dtype(dtype).unwrap();
            let (_vm, bn) = layer(2, dtype);
            let y = bn.forward(&xd, true).unwrap();
            let want = expect([4.5, 0.0], [5.25, 1.0]);
            for (g, w) in vals(&y).iter().zip(&want) {
                assert!((g - w).abs() < tol * 10.0, "{dtype:?} train: {g} vs {w}");
            }
            let (rm, rv) = bn.running_stats().unwrap();
            let rv1 = 0.9 + 0.1 * 8.0 / 7.0;
            for (g, w) in vals(&rm).iter().zip([0.45, 0.0]).chain(vals(&rv).iter().zip([1.5, rv1])) {
                assert!((g - w).abs() < tol, "{dtype:?} running stats: {g} vs {w}");
            }
            let ye = bn.forward(&xd, false).unwrap();
            for (g, w) in vals(&ye).iter().zip(&expect([0.45, 0.0], [1.5, rv1])) {
                assert!((g - w).abs() < tol * 10.0, "{dtype:?} eval: {g} vs {w}");
            }
            bn.forward(&xd, true).unwrap();
            let (rm, rv) = bn.running_stats().unwrap();
            let rv2 = 0.9 * rv1 + 0.1 * 8.0 / 7.0;
            for (g, w) in vals(&rm).iter().zip([0.855, 0.0]).chain(vals(&rv).iter().zip([1.95, rv2])) {
                assert!((g - w).abs() < tol * 4.0, "{dtype:?} second step: {g} vs {w}");
            }
        }
        // The functional forms, fused and composed, with an affine map, in f64.
        let w = Tensor::new(&[2.0f64, 0.5], &Device::Cpu).unwrap();
        let b = Tensor::new(&[1.0f64, -1.0], &Device::Cpu).unwrap();
        let want: Vec<f64> = expect([4.5, 0.0], [5.25, 1.0])
            .iter()
            .enumerate()
            .map(|(i, v)| if (i / 4) % 2 == 0 { 2.0 * v + 1.0 } else { 0.5 * v - 1.0 })
            .collect();
        for f in [batch_norm_train, batch_norm_train_composed] {
            let (y, stats) = f(&x, Some(&w), Some(&b), eps, Activation::Identity).unwrap();
            close(&vals(&y), &want, "affine train");
            close(&stats.mean, &[4.5, 0.0], "mean");
            close(&stats.var, &[5.25, 1.0], "var");
            close(&stats.unbiased_var(), &[6.0, 8.0 / 7.0], "unbiased var");
            assert_eq!(stats.count, 8);
        }
    }

    fn fd_opts() -> GradCheckOptions {
        GradCheckOptions { max_probes: 40, ..Default::default() }
    }

    #[test]
    fn composed_train_and_eval_pass_gradient_check() {
        let x = randn(&[3, 2, 4, 3], DType::F64, 1);
        let w = randn(&[2], DType::F64, 2);
        let b = randn(&[2], DType::F64, 3);
        for act in [Activation::Identity, LEAKY] {
            let r = check_grad(
                |v| Ok(batch_norm_train_composed(&v[0], Some(&v[1]), Some(&v[2]), 1e-5, act)?.0),
                &[x.clone(), w.clone(), b.clone()],
                &fd_opts(),
            )
            .unwrap();
            eprintln!("composed train {act:?}: FD max rel error {:.2e} {:?}", r.max_rel_error, r.per_input);
            r.ensure(GRAD_CHECK_F64).unwrap();
        }
        let (m, v) = (randn(&[2], DType::F64, 4), randn(&[2], DType::F64, 5).abs().unwrap());
        let r = check_grad(
            |t| {
                batch_norm_eval_composed(&t[0], &t[3], &t[4], Some(&t[1]), Some(&t[2]), 1e-5, LEAKY).map_err(Into::into)
            },
            &[x, w, b, m, v],
            &fd_opts(),
        )
        .unwrap();
        eprintln!("composed eval: FD max rel error {:.2e} {:?}", r.max_rel_error, r.per_input);
        r.ensure(GRAD_CHECK_F64).unwrap();
    }

    #[test]
    fn fused_train_and_eval_pass_gradient_check() {
        let x = randn(&[3, 2, 4, 3], DType::F64, 11);
        let w = randn(&[2], DType::F64, 12);
        let b = randn(&[2], DType::F64, 13);
        for act in [Activation::Identity, Activation::Relu, LEAKY] {
            let r = check_grad(
                |v| Ok(batch_norm_train(&v[0], Some(&v[1]), Some(&v[2]), 1e-5, act)?.0),
                &[x.clone(), w.clone(), b.clone()],
                &fd_opts(),
            )
            .unwrap();
            eprintln!("fused train {act:?}: FD max rel error {:.2e} {:?}", r.max_rel_error, r.per_input);
            r.ensure(GRAD_CHECK_F64).unwrap();
        }
        let (m, v) = (randn(&[2], DType::F64, 14), randn(&[2], DType::F64, 15).abs().unwrap());
        let r = check_grad(
            |t| batch_norm_eval(&t[0], &m, &v, Some(&t[1]), Some(&t[2]), 1e-5, LEAKY).map_err(Into::into),
            &[x.clone(), w, b],
            &fd_opts(),
        )
        .unwrap();
        eprintln!("fused eval: FD max rel error {:.2e} {:?}", r.max_rel_error, r.per_input);
        r.ensure(GRAD_CHECK_F64).unwrap();
        // Without affine parameters, and on a [b, c] input.
        let x2 = randn(&[5, 3], DType::F64, 16);
        let r = check_grad(|v| Ok(batch_norm_train(&v[0], None, None, 1e-5, LEAKY)?.0), &[x2], &fd_opts()).unwrap();
        eprintln!("fused train [b, c], no affine: FD max rel error {:.2e}", r.max_rel_error);
        r.ensure(GRAD_CHECK_F64).unwrap();
    }

    /// Fused and composed in f32: outputs, all three gradients and the batch statistics.
    fn compare_fused_composed(shape: &[usize], act: Activation, seed: u64) -> f64 {
        let c = shape[1];
        let x = Var::from_tensor(&randn(shape, DType::F32, seed)).unwrap();
        let w = Var::from_tensor(&randn(&[c], DType::F32, seed + 1)).unwrap();
        let b = Var::from_tensor(&randn(&[c], DType::F32, seed + 2)).unwrap();
        let r = randn(shape, DType::F32, seed + 3);
        let run = |f: TrainFn| {
            let (y, stats) = f(x.as_tensor(), Some(w.as_tensor()), Some(b.as_tensor()), 1e-5, act).unwrap();
            let g = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let gs: Vec<Tensor> = [&x, &w, &b].iter().map(|v| g.get(v.as_tensor()).unwrap().clone()).collect();
            (y, gs, stats)
        };
        let (yf, gf, sf) = run(batch_norm_train);
        let (yc, gc, sc) = run(batch_norm_train_composed);
        let mut worst = 0.0f64;
        for (what, a, b) in [("y", &yf, &yc), ("dx", &gf[0], &gc[0]), ("dw", &gf[1], &gc[1]), ("db", &gf[2], &gc[2])] {
            let (rel, abs) = rel_diff(a, b);
            eprintln!("{shape:?} {act:?} {what}: max |fused - composed| = {abs:.2e} (relative {rel:.2e})");
            assert!(rel < F32_AGREEMENT, "{shape:?} {what}: relative difference {rel:e}");
            worst = worst.max(rel);
        }
        assert_eq!(sf.count, sc.count);
        for (a, b) in sf.mean.iter().zip(&sc.mean).chain(sf.var.iter().zip(&sc.var)) {
            assert!((a - b).abs() <= 1e-5 * b.abs().max(1.0), "stats {a} vs {b}");
        }
        worst
    }

    #[test]
    fn fused_equals_composed_in_f32() {
        compare_fused_composed(&[4, 8, 12, 10], Activation::Identity, 20);
        compare_fused_composed(&[4, 8, 12, 10], Activation::Relu, 30);
        compare_fused_composed(&[6, 5], LEAKY, 40);
        compare_fused_composed(&[3, 4, 17], LEAKY, 50);
        // Large enough to take the rayon path (when the machine has 2+ threads).
        compare_fused_composed(&[4, 16, 48, 48], LEAKY, 60);
    }

    #[test]
    fn other_activations_strided_input_and_f32_vs_f64() {
        // GELU is not fused: batch norm, then the activation.
        let x = randn(&[3, 4, 5, 6], DType::F32, 70);
        let (a, _) = batch_norm_train(&x, None, None, 1e-5, Activation::Gelu).unwrap();
        let (b, _) = batch_norm_train_composed(&x, None, None, 1e-5, Activation::Gelu).unwrap();
        assert!(rel_diff(&a, &b).0 < F32_AGREEMENT);
        // A non-contiguous view is read through its layout.
        let base = randn(&[4, 3, 5, 6], DType::F32, 71);
        let view = base.transpose(0, 1).unwrap();
        assert!(!view.is_contiguous());
        let (a, _) = batch_norm_train(&view, None, None, 1e-5, LEAKY).unwrap();
        let (b, _) = batch_norm_train(&view.contiguous().unwrap(), None, None, 1e-5, LEAKY).unwrap();
        assert_eq!(vals(&a), vals(&b));
        // f32 against f64 of the fused kernel.
        let x64 = randn(&[4, 3, 7, 5], DType::F64, 72);
        let (a, _) = batch_norm_train(&x64.to_dtype(DType::F32).unwrap(), None, None, 1e-5, LEAKY).unwrap();
        let (b, _) = batch_norm_train(&x64, None, None, 1e-5, LEAKY).unwrap();
        let (rel, _) = rel_diff(&a, &b);
        assert!(rel < F32_AGREEMENT, "f32 vs f64: {rel:e}");
        // Eval mode, fused and composed.
        let (m, v) = (randn(&[3], DType::F64, 73), randn(&[3], DType::F64, 74).abs().unwrap());
        let a = batch_norm_eval(&x64, &m, &v, None, None, 1e-5, LEAKY).unwrap();
        let b = batch_norm_eval_composed(&x64, &m, &v, None, None, 1e-5, LEAKY).unwrap();
        assert!(rel_diff(&a, &b).0 < 1e-14);
    }

    #[test]
    fn running_stats_update_identically_fused_and_composed() {
        let x = randn(&[5, 3, 6, 4], DType::F32, 80);
        let (_, sf) = batch_norm_train(&x, None, None, 1e-5, Activation::Identity).unwrap();
        let (_, sc) = batch_norm_train_composed(&x, None, None, 1e-5, Activation::Identity).unwrap();
        let (_v1, l1) = layer(3, DType::F32);
        let (_v2, l2) = layer(3, DType::F32);
        l1.update_running_stats(&sf).unwrap();
        l2.update_running_stats(&sc).unwrap();
        // The layer's own train step takes the fused path.
        let (_v3, l3) = layer(3, DType::F32);
        l3.forward(&x, true).unwrap();
        let (a, b, c) = (l1.running_stats().unwrap(), l2.running_stats().unwrap(), l3.running_stats().unwrap());
        assert_eq!(vals(&a.0), vals(&c.0));
        assert_eq!(vals(&a.1), vals(&c.1));
        let (dm, dv) = (rel_diff(&a.0, &b.0).1, rel_diff(&a.1, &b.1).1);
        eprintln!("running stats, fused vs composed: max diff mean {dm:.2e}, var {dv:.2e}");
        assert!(dm < 1e-6 && dv < 1e-6);
    }

    /// AdamW with weight decay over `VarMap::all_vars` (what `TrainLoop::resume` trains) moves
    /// the weight but leaves the running statistics to the layer's own update; a checkpoint keeps
    /// them.
    #[test]
    fn optimiser_skips_running_stats_and_checkpoint_keeps_them() {
        let (varmap, bn) = layer(2, DType::F32);
        let x = randn(&[4, 2, 3, 3], DType::F32, 90);
        let (_, stats) = batch_norm_train(&x, None, None, 1e-5, Activation::Identity).unwrap();
        let params = candle_nn::ParamsAdamW { lr: 0.1, weight_decay: 0.5, ..Default::default() };
        let mut opt = candle_nn::AdamW::new(varmap.all_vars(), params).unwrap();
        let y = bn.forward_with(&x, true, LEAKY).unwrap();
        let grads = (y.sqr().unwrap() * 0.5).unwrap().sum_all().unwrap().backward().unwrap();
        for name in ["bn.running_mean", "bn.running_var"] {
            assert!(grads.get(&varmap.data().lock().unwrap()[name]).is_none(), "{name} got a gradient");
        }
        opt.step(&grads).unwrap();
        let (rm, rv) = bn.running_stats().unwrap();
        let want_m: Vec<f64> = stats.mean.iter().map(|m| 0.1 * m).collect();
        let want_v: Vec<f64> = stats.unbiased_var().iter().map(|v| 0.9 + 0.1 * v).collect();
        for (g, w) in vals(&rm).iter().zip(&want_m).chain(vals(&rv).iter().zip(&want_v)) {
            assert!((g - w).abs() < 1e-6, "running stat {g} vs {w}");
        }
        assert!(vals(bn.weight().unwrap()).iter().all(|w| (w - 1.0).abs() > 1e-3), "the weight trains");
        assert_eq!(bn.trainable_vars().len(), 2);
        let names: Vec<String> = {
            let tv = trainable_vars(&varmap);
            let data = varmap.data().lock().unwrap();
            tv.iter()
                .map(|v| data.iter().find(|(_, d)| d.as_tensor().id() == v.as_tensor().id()).unwrap().0.clone())
                .collect()
        };
        assert_eq!(names, ["bn.bias", "bn.weight"]);
        assert!(is_running_stat("a.b.running_var") && is_running_stat("num_batches_tracked"));
        assert!(!is_running_stat("bn.weight") && !is_running_stat("my_running_var_weight"));

        // Checkpoint round trip.
        let dir = std::env::temp_dir().join(format!("pbdl_bn_ckpt_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bn");
        crate::io::save_varmap(&path, &varmap, &crate::io::CheckpointMeta::at(1)).unwrap();
        let (fresh_map, fresh) = layer(2, DType::F32);
        crate::io::load_varmap(&path, &fresh_map).unwrap();
        let (fm, fv) = fresh.running_stats().unwrap();
        assert_eq!(vals(&fm), vals(&rm));
        assert_eq!(vals(&fv), vals(&rv));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let (_vm, bn) = layer(3, DType::F32);
        // One value per channel in train mode (PyTorch refuses it too); eval mode is fine.
        let one = randn(&[1, 3, 1, 1], DType::F32, 1);
        let err = bn.forward(&one, true).unwrap_err().to_string();
        assert!(err.contains("more than one value per channel"), "{err}");
        assert!(batch_norm_train_composed(&one, None, None, 1e-5, Activation::Identity).is_err());
        bn.forward(&one, false).unwrap();
        let err = bn.forward(&randn(&[2, 4, 3, 3], DType::F32, 2), true).unwrap_err().to_string();
        assert!(err.contains("[batch, 3, ..]"), "{err}");
        assert!(bn.forward(&randn(&[6], DType::F32, 2), true).is_err());
        let err = bn.forward(&randn(&[2, 3, 3], DType::F64, 2), true).unwrap_err().to_string();
        assert!(err.contains("to_dtype"), "{err}");
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let cfg = BatchNormConfig { momentum: 1.5, ..Default::default() };
        assert!(BatchNorm2d::new(3, cfg, vb.clone()).unwrap_err().to_string().contains("momentum"));
        let cfg = BatchNormConfig { eps: -1.0, ..Default::default() };
        assert!(BatchNorm2d::new(3, cfg, vb.clone()).is_err());
        assert!(BatchNorm2d::new(0, BatchNormConfig::default(), vb).is_err());
        assert!(bn
            .load_running_stats(
                &Tensor::zeros(2, DType::F32, &Device::Cpu).unwrap(),
                &Tensor::ones(3, DType::F32, &Device::Cpu).unwrap()
            )
            .is_err());
        let cfg: BatchNormConfig = serde_json::from_str(r#"{"momentum": 0.01}"#).unwrap();
        assert_eq!(cfg, BatchNormConfig { momentum: 0.01, ..Default::default() });
    }

    #[test]
    fn without_affine_and_load_running_stats() {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F64, &Device::Cpu);
        let bn = BatchNorm2d::new(2, BatchNormConfig { affine: false, ..Default::default() }, vb).unwrap();
        assert!(bn.weight().is_none() && bn.trainable_vars().is_empty());
        assert_eq!(vm.all_vars().len(), 2);
        let m = Tensor::new(&[1.0f32, -1.0], &Device::Cpu).unwrap();
        let v = Tensor::new(&[4.0f32, 0.25], &Device::Cpu).unwrap();
        bn.load_running_stats(&m, &v).unwrap();
        let x = Tensor::new(&[3.0f64, 0.0], &Device::Cpu).unwrap().reshape((1, 2)).unwrap();
        let y = vals(&bn.forward(&x, false).unwrap());
        assert!((y[0] - 2.0 / (4.0f64 + 1e-5).sqrt()).abs() < 1e-12);
        assert!((y[1] - 1.0 / (0.25f64 + 1e-5).sqrt()).abs() < 1e-12);
    }
}

#[cfg(test)]
mod timing {
    use super::*;
    use candle_core::Device;

    /// Forward + backward of the WeatherBench ResNet's batch norm ([8, 128, 32, 64], leaky ReLU
    /// 0.3), fused against composed: `cargo test -p pbdl-core --lib batch_norm_timing -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn batch_norm_timing() {
        let x = Var::from_tensor(&crate::seed::randn((8, 128, 32, 64), 0.0, 1.0, DType::F32, &Device::Cpu, 0).unwrap())
            .unwrap();
        let w = Var::ones(128, DType::F32, &Device::Cpu).unwrap();
        let b = Var::zeros(128, DType::F32, &Device::Cpu).unwrap();
        let act = Activation::LeakyRelu { negative_slope: 0.3 };
        type TrainFn = fn(&Tensor, Option<&Tensor>, Option<&Tensor>, f64, Activation) -> Result<(Tensor, BatchStats)>;
        let fns: [(&str, TrainFn); 2] = [("fused", batch_norm_train), ("composed", batch_norm_train_composed)];
        for (name, f) in fns {
            let mut best = (f64::MAX, f64::MAX);
            for _ in 0..5 {
                let t0 = std::time::Instant::now();
                let (y, _) = f(x.as_tensor(), Some(w.as_tensor()), Some(b.as_tensor()), 1e-5, act).unwrap();
                let t1 = t0.elapsed().as_secs_f64();
                let _ = y.sum_all().unwrap().backward().unwrap();
                best = (best.0.min(t1), best.1.min(t0.elapsed().as_secs_f64()));
            }
            eprintln!("{name}: forward {:.2} ms, forward+backward {:.2} ms", best.0 * 1e3, best.1 * 1e3);
        }
    }
}
