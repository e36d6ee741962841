//! MacCormack advection with the limiter of Selle, Fedkiw, Kim, Liu & Rossignac, "An
//! unconditionally stable MacCormack method", J. Sci. Comput. 35 (2008).

use super::semi_lagrangian::Clamp;
use super::{sl_op, Advected, SemiLagrangian};
use crate::field::MacField;
use crate::Result;
use pbdl_core::op::apply3;

/// One MacCormack step: predictor `a = SL(q, dt)`, corrector `b = SL(a, -dt)`,
/// `a + (q - b) / 2`, clamped to the min/max of the four values the predictor interpolated from
/// (so no new extrema, hence as stable as semi-Lagrangian: no time-step limit).
///
/// Composed of differentiable custom ops (semi-Lagrangian, stencil bounds, clamp), so the
/// gradient flows to `q` and `velocity`.
pub fn mac_cormack<F: Advected>(q: &F, velocity: &MacField, dt: f64) -> Result<F> {
    let fwd = sl_op(q, velocity, dt)?;
    let bwd = SemiLagrangian { dt: -dt, ..fwd.clone() };
    let (x, u) = (q.advected_values(), velocity.values());
    let a = fwd.apply(x, u)?;
    let b = bwd.apply(&a, u)?;
    let mc = (&a + ((x - b)? * 0.5)?)?;
    let lo = fwd.bounds(x, u, false)?;
    let hi = fwd.bounds(x, u, true)?;
    Ok(q.with_advected(apply3(&mc, &lo, &hi, Clamp)?))
}
