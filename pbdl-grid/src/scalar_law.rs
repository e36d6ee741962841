//! Periodic scalar conservation laws in 1D and 2D: viscous Burgers and advection-diffusion.
//!
//! `dc/dt + d/dx F(c) + d/dy G(c) = nu lap c` with `F(c) = a_x c + b_x c^2 / 2` (and `G` alike)
//! on a periodic grid of cell averages `[batch, channels, ny, nx]` (`ny = 1` for 1D). The
//! semi-discrete scheme is conservative (a face flux is added to one cell and taken from its
//! neighbour) and second order:
//!
//! `F_{i+1/2} = a (c_i + c_{i+1}) / 2 + b (c_i^2 + c_i c_{i+1} + c_{i+1}^2) / 6 - nu (c_{i+1} - c_i) / dx`.
//!
//! The quadratic part is the skew-symmetric (energy-conserving) Burgers flux: without viscosity
//! the discrete energy `sum c^2` is exactly conserved by the semi-discrete system, so the scheme
//! adds no numerical diffusion and the only dissipation is the physical `nu`. Like every central
//! scheme it needs a resolved front (cell Peclet number `|c| dx / nu` below about 2) and a time
//! integrator whose stability region covers the imaginary axis (RK4, SSP-RK3).
//!
//! [`ScalarLaw::rhs`] is a custom op with a hand-written adjoint (finite-difference checked in
//! `tests/burgers.rs`). [`cole_hopf_sine`] is the exact solution of 1D Burgers from
//! `u0 = -sin(pi x)` on `[-1, 1]` for the accuracy test.

use crate::time_stepping::{projected_runge_kutta, ButcherTableau};
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel2, Kernel1, Kernel2, Op1};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// A periodic scalar conservation law `c_t + div(a c + b c^2 / 2) = nu lap c`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScalarLaw {
    /// Cell width along x.
    pub dx: f64,
    /// Cell width along y (ignored when the field has one row).
    pub dy: f64,
    /// Constant advection velocity `a = [a_x, a_y]`.
    pub velocity: [f64; 2],
    /// Burgers coefficients `b = [b_x, b_y]` (`[1, 0]`: 1D Burgers `u_t + u u_x`).
    pub burgers: [f64; 2],
    /// Diffusivity (>= 0).
    pub nu: f64,
}

impl ScalarLaw {
    /// 1D viscous Burgers `u_t + (u^2/2)_x = nu u_xx` on `n` cells of a periodic interval of
    /// length `l` (fields `[batch, 1, 1, n]`).
    pub fn burgers_1d(n: usize, l: f64, nu: f64) -> Result<Self> {
        let law = Self { dx: l / n as f64, dy: 1.0, velocity: [0.0; 2], burgers: [1.0, 0.0], nu };
        law.validate()?;
        Ok(law)
    }

    /// Checks the parameters; errors name the bad one.
    pub fn validate(&self) -> Result<()> {
        if !(self.nu >= 0.0 && self.nu.is_finite()) {
            return Err(Error::Invalid { field: "nu", reason: format!("must be finite and >= 0, got {}", self.nu) });
        }
        for (field, d) in [("dx", self.dx), ("dy", self.dy)] {
            if !(d > 0.0 && d.is_finite()) {
                return Err(Error::Invalid { field, reason: format!("cell width must be positive, got {d}") });
            }
        }
        if !self.velocity.iter().chain(&self.burgers).all(|v| v.is_finite()) {
            return Err(Error::Invalid { field: "velocity", reason: "coefficients must be finite".into() });
        }
        Ok(())
    }

    /// The operators this law evaluates (for a stepper's operator list).
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = Vec::new();
        if self.velocity.iter().any(|&a| a != 0.0) {
            ops.push("advect.central_flux");
        }
        if self.burgers.iter().any(|&b| b != 0.0) {
            ops.push("advect.burgers_flux");
        }
        if self.nu > 0.0 {
            ops.push("diffuse.explicit");
        }
        ops
    }

    /// The tendency `-div F(c) + nu lap c` of `c` (`[batch, channels, ny, nx]`, periodic).
    /// Differentiable (custom op with a hand-written adjoint).
    pub fn rhs(&self, c: &Tensor) -> Result<Tensor> {
        if c.rank() != 4 {
            return Err(Error::Shape {
                op: "ScalarLaw::rhs",
                arg: "c",
                expected: "[batch, channels, ny, nx]".into(),
                got: c.dims().to_vec(),
            });
        }
        Ok(apply1(c, *self)?)
    }

    /// The largest stable time step of `tableau` for fields with `max |c| <= max_abs` on a grid
    /// with `ny` rows (the eigenvalue bound of [`crate::stability`]: advection on the imaginary
    /// axis, diffusion on the real axis).
    pub fn stable_time_step(&self, max_abs: f64, ny: usize, tableau: &ButcherTableau) -> f64 {
        let axes: &[(f64, f64, f64)] = &[
            (self.velocity[0], self.burgers[0], self.dx),
            (if ny > 1 { self.velocity[1] } else { 0.0 }, if ny > 1 { self.burgers[1] } else { 0.0 }, self.dy),
        ];
        let mut adv = 0.0;
        let mut diff = 0.0;
        for (k, &(a, b, d)) in axes.iter().enumerate() {
            adv += (a.abs() + b.abs() * max_abs) / d;
            if k == 0 || ny > 1 {
                diff += self.nu * 4.0 / (d * d);
            }
        }
        let s = adv / tableau.imag_limit.max(f64::MIN_POSITIVE) + diff / tableau.real_limit;
        if s > 0.0 {
            1.0 / s
        } else {
            f64::INFINITY
        }
    }

    /// One Runge-Kutta step of size `dt` (no stability check; see [`ScalarLaw::stable_time_step`]).
    pub fn step(&self, c: &Tensor, dt: f64, tableau: &ButcherTableau) -> Result<Tensor> {
        projected_runge_kutta(c, dt, tableau, |x| self.rhs(x), |x| Ok(x.clone()))
    }

    fn coef<T: Real>(&self) -> [T; 8] {
        [
            T::c(self.velocity[0] * 0.5),
            T::c(self.burgers[0] / 6.0),
            T::c(self.nu / self.dx),
            T::c(1.0 / self.dx),
            T::c(self.velocity[1] * 0.5),
            T::c(self.burgers[1] / 6.0),
            T::c(self.nu / self.dy),
            T::c(1.0 / self.dy),
        ]
    }
}

/// Flux between `l` and `r`, with its partial derivatives.
#[inline]
fn flux<T: Real>(l: T, r: T, ha: T, b6: T, nud: T) -> T {
    ha * (l + r) + b6 * (l * l + l * r + r * r) - nud * (r - l)
}

#[inline]
fn flux_grad<T: Real>(l: T, r: T, ha: T, b6: T, nud: T) -> (T, T) {
    let two = T::c(2.0);
    (ha + b6 * (two * l + r) + nud, ha + b6 * (l + two * r) - nud)
}

impl Kernel1 for ScalarLaw {
    fn name(&self) -> &'static str {
        "scalar_law_rhs"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (_, _, ny, nx) = s.dims4()?;
        let [hax, bx, nux, idx, hay, by, nuy, idy] = self.coef::<T>();
        out.iter_mut().for_each(|o| *o = T::zero());
        for (cb, ob) in x.chunks(nx * ny).zip(out.chunks_mut(nx * ny)) {
            for j in 0..ny {
                let jn = (j + 1) % ny;
                for i in 0..nx {
                    let inx = (i + 1) % nx;
                    let c = cb[j * nx + i];
                    // x-face i+1/2: out of cell i, into cell i+1.
                    let fx = flux(c, cb[j * nx + inx], hax, bx, nux) * idx;
                    ob[j * nx + i] -= fx;
                    ob[j * nx + inx] += fx;
                    if ny > 1 {
                        let fy = flux(c, cb[jn * nx + i], hay, by, nuy) * idy;
                        ob[j * nx + i] -= fy;
                        ob[jn * nx + i] += fy;
                    }
                }
            }
        }
        Ok(())
    }
}

impl Op1 for ScalarLaw {
    fn backward(&self, x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, gy, ScalarLawAdjoint(*self))
    }
}

/// `(dR/dc)^T g` at `c`: each face passes `(g_right - g_left) / dx` back through its flux.
struct ScalarLawAdjoint(ScalarLaw);

impl Kernel2 for ScalarLawAdjoint {
    fn name(&self) -> &'static str {
        "scalar_law_rhs_adjoint"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        if a != b {
            candle_core::bail!("scalar_law_rhs_adjoint: shapes differ: {a:?} {b:?}");
        }
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, x: &[T], s: &Shape, g: &[T], _gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (_, _, ny, nx) = s.dims4()?;
        let [hax, bx, nux, idx, hay, by, nuy, idy] = self.0.coef::<T>();
        out.iter_mut().for_each(|o| *o = T::zero());
        let n = nx * ny;
        for ((cb, gb), ob) in x.chunks(n).zip(g.chunks(n)).zip(out.chunks_mut(n)) {
            for j in 0..ny {
                let jn = (j + 1) % ny;
                for i in 0..nx {
                    let (k, kx) = (j * nx + i, j * nx + (i + 1) % nx);
                    let gf = (gb[kx] - gb[k]) * idx;
                    let (dl, dr) = flux_grad(cb[k], cb[kx], hax, bx, nux);
                    ob[k] += gf * dl;
                    ob[kx] += gf * dr;
                    if ny > 1 {
                        let ky = jn * nx + i;
                        let gf = (gb[ky] - gb[k]) * idy;
                        let (dl, dr) = flux_grad(cb[k], cb[ky], hay, by, nuy);
                        ob[k] += gf * dl;
                        ob[ky] += gf * dr;
                    }
                }
            }
        }
        Ok(())
    }
}

/// The exact (Cole-Hopf) solution of `u_t + u u_x = nu u_xx` on the periodic interval `[-1, 1]`
/// from `u(x, 0) = -sin(pi x)`:
///
/// `u(x, t) = -int sin(pi (x - s)) f(x - s) exp(-s^2 / (4 nu t)) ds / int f(x - s) exp(-s^2 / (4 nu t)) ds`
/// with `f(y) = exp(-cos(pi y) / (2 pi nu))`, evaluated by the trapezoidal rule over
/// `s = sqrt(4 nu t) z`, `|z| <= 9` (3,600 points; the integrand is smooth, the rule is
/// accurate to round-off) with the exponents shifted by their maximum (so `nu = 0.01/pi` does not
/// overflow).
pub fn cole_hopf_sine(x: f64, t: f64, nu: f64) -> f64 {
    use std::f64::consts::PI;
    if t <= 0.0 {
        return -(PI * x).sin();
    }
    let (m, zmax) = (3600usize, 9.0);
    let h = 2.0 * zmax / m as f64;
    let scale = (4.0 * nu * t).sqrt();
    let expo = |z: f64| -(PI * (x - scale * z)).cos() / (2.0 * PI * nu) - z * z;
    let emax = (0..=m).map(|k| expo(-zmax + k as f64 * h)).fold(f64::NEG_INFINITY, f64::max);
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..=m {
        let z = -zmax + k as f64 * h;
        let w = if k == 0 || k == m { 0.5 } else { 1.0 } * (expo(z) - emax).exp();
        num += w * (PI * (x - scale * z)).sin();
        den += w;
    }
    -num / den
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inviscid_burgers_conserves_mass_and_energy_semi_discretely() {
        let law = ScalarLaw::burgers_1d(32, 2.0, 0.0).unwrap();
        let c: Vec<f64> = (0..32).map(|i| (0.3 * i as f64).sin() + 0.2).collect();
        let t = Tensor::from_vec(c.clone(), (1, 1, 1, 32), &candle_core::Device::Cpu).unwrap();
        let r = law.rhs(&t).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let mass: f64 = r.iter().sum();
        let energy: f64 = r.iter().zip(&c).map(|(r, c)| r * c).sum();
        assert!(mass.abs() < 1e-12 && energy.abs() < 1e-12, "d mass {mass:e}, d energy {energy:e}");
    }

    #[test]
    fn cole_hopf_matches_the_initial_condition_and_decays() {
        let nu = 0.05 / std::f64::consts::PI;
        let u = cole_hopf_sine(-0.5, 1e-6, nu);
        assert!((u - 1.0).abs() < 1e-4, "{u}");
        assert!(cole_hopf_sine(0.0, 0.5, nu).abs() < 1e-12);
    }
}
