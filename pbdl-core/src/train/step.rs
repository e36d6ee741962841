//! One guarded optimisation step: backward, clip, check, update.

use super::{ClipConfig, NanGuard};
use crate::Result;
use candle_core::{Tensor, Var};
use candle_nn::Optimizer;

/// What [`train_step`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepInfo {
    /// The step.
    pub step: u64,
    /// The loss value.
    pub loss: f64,
    /// The global gradient norm before clipping.
    pub grad_norm: f64,
    /// The learning rate the update used.
    pub lr: f64,
}

/// Runs one step on `loss`: backward, gradient clipping of `vars` as configured, the
/// [`NanGuard`] checks of loss and gradient norm, and only then the optimiser update. On a
/// non-finite loss or norm it returns `Error::Diverged` and leaves the parameters untouched.
///
/// Set the step's learning rate first, e.g. with [`super::LrScheduler::apply`].
///
/// ```
/// use candle_core::{Device, Var};
/// use pbdl_core::train::{train_step, ClipConfig, NanGuard, OptimizerConfig, SgdConfig};
///
/// let x = Var::new(&[2.0f64], &Device::Cpu)?;
/// let vars = vec![x.clone()];
/// let mut opt = OptimizerConfig::Sgd(SgdConfig { lr: 0.25, ..Default::default() }).build(vars.clone())?;
/// let mut guard = NanGuard::new();
/// let clip = ClipConfig::Norm { max_norm: 1.0 };
/// let info = train_step(0, &x.as_tensor().sqr()?.sum_all()?, &mut opt, &vars, &clip, &mut guard)?;
/// assert_eq!((info.loss, info.grad_norm), (4.0, 4.0)); // gradient 2x = 4, clipped to 1
/// assert_eq!(x.as_tensor().to_vec1::<f64>()?, [1.75]);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn train_step<O: Optimizer>(
    step: u64,
    loss: &Tensor,
    opt: &mut O,
    vars: &[Var],
    clip: &ClipConfig,
    guard: &mut NanGuard,
) -> Result<StepInfo> {
    // Check the loss before spending a backward pass on it.
    let loss_value = guard.check_tensor(step, "loss", loss)?;
    let mut grads = loss.backward()?;
    let grad_norm = clip.apply(&mut grads, vars)?;
    guard.check(step, loss_value, Some(grad_norm))?;
    opt.step(&grads)?;
    Ok(StepInfo { step, loss: loss_value, grad_norm, lr: opt.learning_rate() })
}
