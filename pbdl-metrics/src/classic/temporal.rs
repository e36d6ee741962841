//! Temporal stability of a rollout: how much the state changes per unit time.
//!
//! For states `s_0, ..., s_(T-1)` (time is the first axis), the change per step is
//! `mean |s_t - s_(t-1)| / dt` over all other axes; the stability measure is its mean over the
//! `T - 1` steps. A rollout that settles has a decaying curve; one that blows up or jitters
//! shows it as growth.

use crate::classic::pointwise::per_sample_mean;
use crate::{check, Error, Result};
use candle_core::{DType, Tensor};

/// The change per step, `mean |s_t - s_(t-1)| / dt` for `t = 1 .. T`; `[T - 1]`.
///
/// `states` is `[time, ...]` with any number of further axes (e.g. `[T, batch, channel, y, x]`),
/// `f32` or `f64`; the result is differentiable. Errors: fewer than 2 time steps, a non-positive
/// `dt`, non-float, empty or non-finite states.
pub fn temporal_change(states: &Tensor, dt: f64) -> Result<Tensor> {
    const OP: &str = "temporal_change";
    check::float(OP, "states", states)?;
    check::non_empty(OP, "states", states)?;
    if states.rank() < 1 || states.dim(0)? < 2 {
        return Err(Error::Shape {
            op: OP,
            arg: "states",
            expected: "[time, ...] with at least 2 time steps".into(),
            got: states.dims().to_vec(),
        });
    }
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(Error::invalid(OP, "dt", format!("must be positive and finite, got {dt}")));
    }
    check::finite(OP, "states", states)?;
    let t = states.dim(0)?;
    let states = if states.rank() == 1 { states.unsqueeze(1)? } else { states.clone() };
    let diff = (states.narrow(0, 1, t - 1)? - states.narrow(0, 0, t - 1)?)?.abs()?;
    Ok((per_sample_mean(&diff)? / dt)?)
}

/// The temporal stability measure: the mean of [`temporal_change`] over all steps.
pub fn temporal_stability(states: &Tensor, dt: f64) -> Result<f64> {
    Ok(temporal_change(states, dt)?.to_dtype(DType::F64)?.mean_all()?.to_scalar::<f64>()?)
}
