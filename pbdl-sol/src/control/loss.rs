//! The control objective: effort plus weighted target deviation, per scene.

use crate::Result;
use candle_core::{Tensor, D};

/// Control effort per scene, `sum_t ||u_{t+1} - P(u_t)||^2 = dt^2 sum_t sum_x F_t(x)^2`
/// (`forces`: each `[batch, 1, 1, cells]`); returns `[batch]`.
pub fn effort(forces: &[Tensor], dt: f64) -> Result<Tensor> {
    let mut acc: Option<Tensor> = None;
    for f in forces {
        let e = f.affine(dt, 0.0)?.sqr()?.flatten_from(1)?.sum(D::Minus1)?;
        acc = Some(match acc {
            None => e,
            Some(a) => (a + e)?,
        });
    }
    match acc {
        Some(a) => Ok(a),
        None => Err(crate::Error::invalid("control::effort", "forces", "no forces given")),
    }
}

/// Target deviation per scene, `||u_T - u*||^2` (summed over cells); returns `[batch]`.
pub fn target_error(final_state: &Tensor, target: &Tensor) -> Result<Tensor> {
    Ok((final_state - target)?.sqr()?.flatten_from(1)?.sum(D::Minus1)?)
}

/// `effort + target_weight * target_error`, per scene (`[batch]`).
pub fn combined(
    forces: &[Tensor],
    dt: f64,
    final_state: &Tensor,
    target: &Tensor,
    target_weight: f64,
) -> Result<Tensor> {
    Ok((effort(forces, dt)? + target_error(final_state, target)?.affine(target_weight, 0.0)?)?)
}

/// The three numbers of one evaluation, averaged over scenes.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ControlScore {
    /// Mean effort.
    pub effort: f64,
    /// Mean target deviation.
    pub target_error: f64,
    /// Mean `effort + target_weight * target_error`.
    pub combined: f64,
}

impl ControlScore {
    /// Scores forces and their final state against the targets.
    pub fn of(forces: &[Tensor], dt: f64, final_state: &Tensor, target: &Tensor, target_weight: f64) -> Result<Self> {
        let e = effort(forces, dt)?.to_dtype(candle_core::DType::F64)?.mean_all()?.to_scalar::<f64>()?;
        let t = target_error(final_state, target)?.to_dtype(candle_core::DType::F64)?.mean_all()?.to_scalar::<f64>()?;
        Ok(Self { effort: e, target_error: t, combined: e + target_weight * t })
    }
}
