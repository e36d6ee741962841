//! The objective: (multi-scale) density deviation at the end plus weighted control effort.

use crate::{Error, Result};
use candle_core::{DType, Tensor, D};

/// Control effort per scene, `sum_t sum_faces F_t^2` (pass the masked forces, as a
/// [`super::Rollout`] holds them); returns `[batch]`.
pub fn effort(forces: &[Tensor]) -> Result<Tensor> {
    let mut acc: Option<Tensor> = None;
    for f in forces {
        let e = f.sqr()?.flatten_from(1)?.sum(D::Minus1)?;
        acc = Some(match acc {
            None => e,
            Some(a) => (a + e)?,
        });
    }
    acc.ok_or_else(|| Error::invalid("smoke_control::effort", "forces", "no forces given"))
}

/// Final-density error per scene, `||rho_T - rho*||^2` summed over cells (the evaluation
/// metric); returns `[batch]`.
pub fn target_error(final_density: &Tensor, target: &Tensor) -> Result<Tensor> {
    Ok((final_density - target)?.sqr()?.flatten_from(1)?.sum(D::Minus1)?)
}

/// Multi-scale density error per scene: `sum_{k < levels} 4^k ||A_k (rho_T - rho*)||^2`,
/// `A_k` the average over `2^k x 2^k` blocks (the squared norm of the block-constant field).
/// Level 0 is [`target_error`]; the coarser levels give a gradient towards a target the
/// density does not overlap yet. Returns `[batch]`.
pub fn multiscale_target_error(final_density: &Tensor, target: &Tensor, levels: usize) -> Result<Tensor> {
    let mut d = (final_density - target)?;
    let mut acc = d.sqr()?.flatten_from(1)?.sum(D::Minus1)?;
    for k in 1..levels {
        let (b, c, h, w) = d.dims4()?;
        if h % 2 != 0 || w % 2 != 0 {
            return Err(Error::invalid(
                "smoke_control::multiscale_target_error",
                "levels",
                format!("{levels} levels need the grid divisible by {}", 1usize << (levels - 1)),
            ));
        }
        d = d.reshape((b, c, h / 2, 2, w / 2, 2))?.mean(5)?.mean(3)?;
        let e = d.sqr()?.flatten_from(1)?.sum(D::Minus1)?.affine(4f64.powi(k as i32), 0.0)?;
        acc = (acc + e)?;
    }
    Ok(acc)
}

/// The training and optimisation objective per scene:
/// `multiscale_target_error(levels) + effort_weight * effort`; returns `[batch]`.
pub fn objective(
    forces: &[Tensor],
    final_density: &Tensor,
    target: &Tensor,
    levels: usize,
    effort_weight: f64,
) -> Result<Tensor> {
    Ok((multiscale_target_error(final_density, target, levels)? + effort(forces)?.affine(effort_weight, 0.0)?)?)
}

fn mean_f64(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(DType::F64)?.mean_all()?.to_scalar::<f64>()?)
}

/// The numbers of one evaluation, averaged over scenes.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SmokeScore {
    /// Mean final-density error `||rho_T - rho*||^2` (the acceptance metric).
    pub target_error: f64,
    /// Mean effort `sum_t ||F_t||^2`.
    pub effort: f64,
    /// Mean objective (`multi-scale target error + effort_weight * effort`).
    pub objective: f64,
}

impl SmokeScore {
    /// Scores (masked) forces and their final density against the targets.
    pub fn of(
        forces: &[Tensor],
        final_density: &Tensor,
        target: &Tensor,
        levels: usize,
        effort_weight: f64,
    ) -> Result<Self> {
        Ok(Self {
            target_error: mean_f64(&target_error(final_density, target)?)?,
            effort: mean_f64(&effort(forces)?)?,
            objective: mean_f64(&objective(forces, final_density, target, levels, effort_weight)?)?,
        })
    }
}
