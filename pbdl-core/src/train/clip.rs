//! Gradient clipping on a candle `GradStore`, by value and by global norm.
//!
//! Only the gradients of the given vars are read and replaced; a var without a gradient is
//! skipped. Norms are accumulated in `f64` whatever the gradients' dtype.
//!
//! ```
//! use candle_core::{Device, Var};
//! use pbdl_core::train::{clip_grad_norm, grad_norm};
//!
//! let a = Var::new(&[3.0f64], &Device::Cpu)?;
//! let b = Var::new(&[4.0f64], &Device::Cpu)?;
//! // loss = 3a + 4b: the gradient is (3, 4), of norm 5.
//! let loss = ((a.as_tensor() * 3.0)? + (b.as_tensor() * 4.0)?)?.sum_all()?;
//! let mut grads = loss.backward()?;
//! let vars = [a.clone(), b.clone()];
//! assert_eq!(clip_grad_norm(&mut grads, &vars, 1.0)?, 5.0); // the norm before clipping
//! assert!((grad_norm(&grads, &vars)? - 1.0).abs() < 1e-15);
//! assert!((grads.get(a.as_tensor()).unwrap().to_vec1::<f64>()?[0] - 0.6).abs() < 1e-15);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{backprop::GradStore, DType, Tensor, Var};
use serde::{Deserialize, Serialize};

/// The global L2 norm of the gradients of `vars`: `sqrt(sum over vars of sum(g^2))`.
/// NaN or infinite when any gradient entry is, finite otherwise (also when squaring the
/// entries would overflow `f64`).
pub fn grad_norm(grads: &GradStore, vars: &[Var]) -> Result<f64> {
    let present: Vec<Tensor> = vars
        .iter()
        .filter_map(|v| grads.get(v.as_tensor()))
        .map(|g| g.to_dtype(DType::F64))
        .collect::<candle_core::Result<_>>()?;
    let mut sum_sq = 0.0f64;
    for g in &present {
        sum_sq += g.sqr()?.sum_all()?.to_scalar::<f64>()?;
    }
    // Squares are >= 0, so a NaN sum means a NaN entry.
    if !sum_sq.is_infinite() {
        return Ok(sum_sq.sqrt());
    }
    // An infinite entry, or finite entries whose squares overflow: rescale by the largest.
    let mut max_abs = 0.0f64;
    for g in &present {
        max_abs = max_abs.max(g.abs()?.max_all()?.to_scalar::<f64>()?);
    }
    if max_abs.is_infinite() {
        return Ok(max_abs);
    }
    let mut scaled = 0.0f64;
    for g in &present {
        scaled += (g / max_abs)?.sqr()?.sum_all()?.to_scalar::<f64>()?;
    }
    Ok(max_abs * scaled.sqrt())
}

/// Scales the gradients of `vars` so that their global norm is at most `max_norm`, and returns
/// the norm *before* clipping (log it; feed it to a [`super::NanGuard`]).
///
/// When the norm exceeds `max_norm` every gradient is multiplied by `max_norm / norm`, so the
/// direction is kept and the new norm is `max_norm` (to round-off). A non-finite norm leaves the
/// gradients untouched: scaling would only turn them into zeros or NaNs, and the caller should
/// stop instead.
pub fn clip_grad_norm(grads: &mut GradStore, vars: &[Var], max_norm: f64) -> Result<f64> {
    if !(max_norm > 0.0 && max_norm.is_finite()) {
        return Err(Error::invalid(
            "clip_grad_norm",
            "max_norm",
            format!("{max_norm} must be finite and > 0, e.g. 1.0"),
        ));
    }
    let norm = grad_norm(grads, vars)?;
    if norm.is_finite() && norm > max_norm {
        let scale = max_norm / norm;
        for var in vars {
            if let Some(g) = grads.get(var.as_tensor()) {
                let scaled = g.affine(scale, 0.0)?;
                grads.insert(var.as_tensor(), scaled);
            }
        }
    }
    Ok(norm)
}

/// Clamps every gradient entry of `vars` to `[-max_value, max_value]`.
///
/// Clamping hides NaNs (a NaN entry may come out as a bound): check [`grad_norm`] first, as
/// [`ClipConfig::apply`] does.
pub fn clip_grad_value(grads: &mut GradStore, vars: &[Var], max_value: f64) -> Result<()> {
    if !(max_value > 0.0 && max_value.is_finite()) {
        return Err(Error::invalid("clip_grad_value", "max_value", format!("{max_value} must be finite and > 0")));
    }
    for var in vars {
        if let Some(g) = grads.get(var.as_tensor()) {
            let clamped = g.clamp(-max_value, max_value)?;
            grads.insert(var.as_tensor(), clamped);
        }
    }
    Ok(())
}

/// Gradient clipping as a serde setting: `{"kind": "norm", "max_norm": 1.0}`,
/// `{"kind": "value", "max_value": 0.5}` or `{"kind": "none"}` (the default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ClipConfig {
    /// No clipping.
    #[default]
    None,
    /// [`clip_grad_value`].
    Value {
        /// Bound on each entry's magnitude.
        max_value: f64,
    },
    /// [`clip_grad_norm`].
    Norm {
        /// Bound on the global norm.
        max_norm: f64,
    },
}

impl ClipConfig {
    /// Clips as configured and returns the global gradient norm before clipping.
    pub fn apply(&self, grads: &mut GradStore, vars: &[Var]) -> Result<f64> {
        match *self {
            ClipConfig::None => grad_norm(grads, vars),
            ClipConfig::Value { max_value } => {
                let norm = grad_norm(grads, vars)?;
                clip_grad_value(grads, vars, max_value)?;
                Ok(norm)
            }
            ClipConfig::Norm { max_norm } => clip_grad_norm(grads, vars, max_norm),
        }
    }
}
