//! Advection.
//!
//! * [`flux_form`]: second-order, energy-conserving central flux form
//!   `-(d(uu)/dx + d(vu)/dy, d(uv)/dx + d(vv)/dy)` with linear interpolation to the flux points.
//!   Central fluxes add no numerical diffusion; step them with a Runge-Kutta scheme whose
//!   stability region covers the imaginary axis (RK4, SSP-RK3), never forward Euler.
//! * [`semi_lagrangian`]: backtrace and bilinear interpolation, for centred scalars (density,
//!   smoke) and MAC velocities ([`Advected`]). Unconditionally stable (no time-step limit: the
//!   result is a convex combination of old values), first order, diffusive.
//! * [`mac_cormack`]: a semi-Lagrangian predictor, a backward corrector and the limiter of Selle
//!   et al. (2008), which clamps to the extrema of the values the predictor interpolated from, so
//!   it creates no new extrema. Second order where smooth; as stable as semi-Lagrangian. Neither
//!   conserves mass: interpolation moves no fluxes (the shipped smoke plume ends with 11% more
//!   density than its source injected).
//! * [`conservative()`]: finite-volume flux form for centred scalars with Zalesak's flux-corrected
//!   transport (upwind + Lax-Wendroff fluxes, limited): mass conserved to round-off, no new
//!   extrema for a divergence-free velocity, second order where smooth, sub-cycled to outflow
//!   CFL <= 1 (see [`conservative`](mod@conservative)).
//!
//! All are differentiable in the advected field and in the velocity (hand-written adjoints).

pub mod conservative;
mod flux_form;
mod mac_cormack;
mod semi_lagrangian;

pub use conservative::conservative;
pub use flux_form::flux_form;
pub(crate) use flux_form::MomentumRhs;
pub use mac_cormack::mac_cormack;
pub use semi_lagrangian::Layout;
pub(crate) use semi_lagrangian::{Loc, SemiLagrangian};

use crate::field::{CenteredField, MacField};
use crate::{Bc, Error, Result, ScalarBc};
use candle_core::Tensor;

/// A field that can be advected by a MAC velocity: cell-centred scalars (every channel) and MAC
/// velocities (each component at its own faces, fixed boundary faces kept).
pub trait Advected: Sized {
    /// Where each channel's samples sit and how its ghosts are filled.
    fn advection_layout(&self) -> Layout;
    /// The same field with new values (shape unchanged by construction).
    fn with_advected(&self, values: Tensor) -> Self;
    /// The values.
    fn advected_values(&self) -> &Tensor;
    /// The grid.
    fn advected_grid(&self) -> &crate::Grid;
}

impl Advected for CenteredField {
    fn advection_layout(&self) -> Layout {
        let g = self.grid();
        let gh = self.bc().ghosts(g.nx, g.ny);
        Layout {
            chans: vec![(Loc::Centre, gh); self.values().dims()[1]],
            periodic: [self.bc().x_lo == ScalarBc::Periodic, self.bc().y_lo == ScalarBc::Periodic],
            u_fixed: None,
            v_fixed: None,
        }
    }
    fn with_advected(&self, values: Tensor) -> Self {
        CenteredField::from_parts(values, *self.grid(), *self.bc())
    }
    fn advected_values(&self) -> &Tensor {
        self.values()
    }
    fn advected_grid(&self) -> &crate::Grid {
        self.grid()
    }
}

impl Advected for MacField {
    fn advection_layout(&self) -> Layout {
        let g = self.grid();
        let mg = self.bc().mac_ghosts(g.nx, g.ny);
        Layout {
            chans: vec![(Loc::UFace, mg.u), (Loc::VFace, mg.v)],
            periodic: [self.bc().x_lo == Bc::Periodic, self.bc().y_lo == Bc::Periodic],
            u_fixed: mg.u_fixed,
            v_fixed: mg.v_fixed,
        }
    }
    fn with_advected(&self, values: Tensor) -> Self {
        MacField::from_parts(values, *self.grid(), *self.bc())
    }
    fn advected_values(&self) -> &Tensor {
        self.values()
    }
    fn advected_grid(&self) -> &crate::Grid {
        self.grid()
    }
}

/// The semi-Lagrangian op for `q` moved by `velocity` over `dt`, after checking that they match.
pub(crate) fn sl_op<F: Advected>(q: &F, velocity: &MacField, dt: f64) -> Result<SemiLagrangian> {
    if q.advected_grid() != velocity.grid() {
        return Err(Error::Invalid {
            field: "velocity",
            reason: format!("lives on {:?}, the advected field on {:?}", velocity.grid(), q.advected_grid()),
        });
    }
    if !dt.is_finite() {
        return Err(Error::Invalid { field: "dt", reason: format!("must be finite, got {dt}") });
    }
    if q.advected_values().dims()[0] != velocity.batch() {
        return Err(Error::Shape {
            op: "advect",
            arg: "velocity",
            expected: format!("batch {} (the advected field's)", q.advected_values().dims()[0]),
            got: velocity.values().dims().to_vec(),
        });
    }
    let g = *velocity.grid();
    Ok(SemiLagrangian { grid: g, vel: velocity.bc().mac_ghosts(g.nx, g.ny), layout: q.advection_layout(), dt })
}

/// One semi-Lagrangian step: `q1(x) = q0(x - dt u(x))`, bilinear, first-order backtrace.
///
/// Works for a [`CenteredField`] (density, smoke; every channel) and for a [`MacField`] (a
/// velocity advected by itself or by another). No time-step limit (unconditionally stable), but
/// first-order accurate. Differentiable in `q` and `velocity`.
pub fn semi_lagrangian<F: Advected>(q: &F, velocity: &MacField, dt: f64) -> Result<F> {
    let op = sl_op(q, velocity, dt)?;
    Ok(q.with_advected(op.apply(q.advected_values(), velocity.values())?))
}
