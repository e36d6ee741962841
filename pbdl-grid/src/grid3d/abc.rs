//! The Arnold-Beltrami-Childress (ABC) flow, an exact solution of the 3D incompressible
//! Navier-Stokes equations on `[0, 2 pi]^3`:
//!
//! `u = (A sin z + C cos y, B sin x + A cos z, C sin y + B cos x) e^{-nu t}`.
//!
//! It is a Beltrami field (`curl u = u`), so `u x curl u = 0` and the nonlinear term
//! `(u . grad) u = grad(|u|^2 / 2)` is a pure gradient that the pressure absorbs; each component
//! is an eigenfunction of the Laplacian with eigenvalue -1, which gives the decay. On the MAC
//! grid each component depends only on the two other coordinates, so the sampled field is
//! discretely divergence-free as well.

use super::{Grid3d, MacField3d};
use crate::Result;
use candle_core::DType;

/// Coefficients `[A, B, C]` of an ABC flow.
pub type AbcCoefficients = [f64; 3];

/// The exact ABC velocity at `(x, y, z)` and time `t`, viscosity `nu`.
pub fn abc_velocity(coef: AbcCoefficients, nu: f64, t: f64, x: f64, y: f64, z: f64) -> [f64; 3] {
    let [a, b, c] = coef;
    let decay = (-nu * t).exp();
    [(a * z.sin() + c * y.cos()) * decay, (b * x.sin() + a * z.cos()) * decay, (c * y.sin() + b * x.cos()) * decay]
}

/// The ABC flow sampled at each component's faces (batch 1). Use a grid on `[0, 2 pi]^3`.
pub fn abc_flow(grid: Grid3d, coef: AbcCoefficients, nu: f64, t: f64, dtype: DType) -> Result<MacField3d> {
    MacField3d::from_fn(grid, dtype, |x, y, z| abc_velocity(coef, nu, t, x, y, z))
}
