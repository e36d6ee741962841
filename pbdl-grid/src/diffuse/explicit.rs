//! Explicit viscous diffusion: the tendency `nu * lap(u)` on the faces of a MAC velocity.

use crate::advect::MomentumRhs;
use crate::field::MacField;
use crate::{Error, Result};

/// The diffusive tendency `nu * lap(u)` (fixed boundary faces get 0). `nu` must be >= 0.
pub fn explicit(u: &MacField, nu: f64) -> Result<MacField> {
    if !(nu >= 0.0 && nu.is_finite()) {
        return Err(Error::Invalid { field: "nu", reason: format!("viscosity must be finite and >= 0, got {nu}") });
    }
    let rhs = MomentumRhs::new(u, false, nu);
    u.with_values(rhs.apply(u.values())?)
}
