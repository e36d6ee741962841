//! Coordinate maps from the unit ball of neighbour offsets to the filter's cube `[-1, 1]^d`,
//! with their Jacobians.
//!
//! [`CoordinateMap::BallToCube`] is CConv's volume-preserving map (Ummenhofer et al. 2020, after
//! Griepentrog et al.): in 3D the ball goes to a cylinder and the cylinder to the cube; in 2D
//! the disc goes to the square; in 1D it is the identity. Both maps are odd
//! (`m(-s) = -m(s)` exactly in floating point), which the antisymmetric convolution needs.
//!
//! The Jacobian is carried by forward-mode dual numbers ([`Dual`]), so the map is written once
//! and its derivative cannot drift from it.
//!
//! ```
//! use pbdl_pconv::mapping::CoordinateMap;
//!
//! // A point on the unit circle lands on the boundary of the square.
//! let (q, _jac) = CoordinateMap::BallToCube.apply::<f64>(2, [0.6, 0.8, 0.0]);
//! assert!((q[0].abs().max(q[1].abs()) - 1.0).abs() < 1e-12);
//! ```

use pbdl_core::Real;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// How a scaled offset `s = (x_j - x_i) / R` (with `|s| < 1`) becomes the filter coordinate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CoordinateMap {
    /// `q = s`: the ball is a subset of the cube, the cube's corners are never reached.
    Cartesian,
    /// CConv's volume-preserving ball-to-cube map (identity in 1D).
    BallToCube,
}

impl CoordinateMap {
    /// The name used in configs and tables.
    pub fn name(self) -> &'static str {
        match self {
            CoordinateMap::Cartesian => "cartesian",
            CoordinateMap::BallToCube => "ball_to_cube",
        }
    }

    /// Maps the first `dim` components of `s`; returns `q` and the Jacobian `jac[a][b] = ∂q_a/∂s_b`
    /// (unused components are zero).
    pub fn apply<T: Real>(self, dim: usize, s: [T; 3]) -> ([T; 3], [[T; 3]; 3]) {
        let var = |a: usize| {
            let mut g = [T::zero(); 3];
            g[a] = T::one();
            Dual { v: s[a], g }
        };
        let x = [var(0), var(1), var(2)];
        let q = match (self, dim) {
            (CoordinateMap::Cartesian, _) | (CoordinateMap::BallToCube, 1) => x,
            (CoordinateMap::BallToCube, 2) => {
                let (a, b) = disc_to_square(x[0], x[1]);
                [a, b, Dual::constant(T::zero())]
            }
            (CoordinateMap::BallToCube, _) => ball_to_cube(x[0], x[1], x[2]),
        };
        let mut jac = [[T::zero(); 3]; 3];
        let mut out = [T::zero(); 3];
        for a in 0..dim {
            out[a] = q[a].v;
            for b in 0..dim {
                jac[a][b] = q[a].g[b];
            }
        }
        (out, jac)
    }
}

/// The smallest radius (in units of the support) below which a point maps to the origin, as in
/// CConv (the maps are not differentiable at 0).
const ORIGIN: f64 = 1e-6;

/// 3D: ball to cylinder, then cylinder to cube.
fn ball_to_cube<T: Real>(x: Dual<T>, y: Dual<T>, z: Dual<T>) -> [Dual<T>; 3] {
    let n2 = x * x + y * y + z * z;
    if n2.v < T::c(ORIGIN * ORIGIN) {
        return [Dual::constant(T::zero()); 3];
    }
    let n = n2.sqrt();
    let xy2 = x * x + y * y;
    let (cx, cy, cz) = if T::c(1.25) * z.v * z.v > xy2.v {
        // Near the poles: the cap goes onto the cylinder's end disc.
        let f = (n * T::c(3.0) / (n + z.abs())).sqrt();
        (x * f, y * f, n.with_sign_of(z.v))
    } else {
        // Near the equator: radial push onto the mantle, z stretched by 3/2.
        let g = n / xy2.sqrt();
        (x * g, y * g, z * T::c(1.5))
    };
    let (a, b) = disc_to_square(cx, cy);
    [a, b, cz]
}

/// 2D (and the cylinder's cross-section): disc to square, area-preserving up to the constant 4/π.
fn disc_to_square<T: Real>(x: Dual<T>, y: Dual<T>) -> (Dual<T>, Dual<T>) {
    let r2 = x * x + y * y;
    if r2.v < T::c(ORIGIN * ORIGIN) {
        return (Dual::constant(T::zero()), Dual::constant(T::zero()));
    }
    let r = r2.sqrt();
    let k = T::c(4.0 / PI);
    if y.v.abs() <= x.v.abs() {
        let s = r.with_sign_of(x.v);
        (s, s * (y / x).atan() * k)
    } else {
        let s = r.with_sign_of(y.v);
        (s * (x / y).atan() * k, s)
    }
}

/// A value with its gradient over (up to) three inputs: forward-mode differentiation.
#[derive(Clone, Copy, Debug)]
pub struct Dual<T> {
    /// The value.
    pub v: T,
    /// Its partial derivatives.
    pub g: [T; 3],
}

impl<T: Real> Dual<T> {
    /// A constant (zero gradient).
    pub fn constant(v: T) -> Self {
        Dual { v, g: [T::zero(); 3] }
    }

    fn chain(self, v: T, dv: T) -> Self {
        Dual { v, g: [self.g[0] * dv, self.g[1] * dv, self.g[2] * dv] }
    }

    /// Square root (derivative infinite at 0; callers stay away from it).
    pub fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, T::c(0.5) / r)
    }

    /// Arc tangent.
    pub fn atan(self) -> Self {
        self.chain(self.v.atan(), T::one() / (T::one() + self.v * self.v))
    }

    /// Absolute value (derivative sign, 1 at 0).
    pub fn abs(self) -> Self {
        if self.v < T::zero() {
            -self
        } else {
            self
        }
    }

    /// `self` (taken non-negative) with the sign of `sign` (`+` for 0): `sign(x)|v|`.
    pub fn with_sign_of(self, sign: T) -> Self {
        if sign < T::zero() {
            -self
        } else {
            self
        }
    }
}

impl<T: Real> Add for Dual<T> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Dual { v: self.v + o.v, g: [self.g[0] + o.g[0], self.g[1] + o.g[1], self.g[2] + o.g[2]] }
    }
}

impl<T: Real> Sub for Dual<T> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Dual { v: self.v - o.v, g: [self.g[0] - o.g[0], self.g[1] - o.g[1], self.g[2] - o.g[2]] }
    }
}

impl<T: Real> Neg for Dual<T> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual { v: -self.v, g: [-self.g[0], -self.g[1], -self.g[2]] }
    }
}

// The product rule adds: clippy flags `+` inside `Mul`.
#[allow(clippy::suspicious_arithmetic_impl)]
impl<T: Real> Mul for Dual<T> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        let g = std::array::from_fn(|a| self.g[a] * o.v + self.v * o.g[a]);
        Dual { v: self.v * o.v, g }
    }
}

impl<T: Real> Mul<T> for Dual<T> {
    type Output = Self;
    fn mul(self, c: T) -> Self {
        Dual { v: self.v * c, g: [self.g[0] * c, self.g[1] * c, self.g[2] * c] }
    }
}

impl<T: Real> Add<T> for Dual<T> {
    type Output = Self;
    fn add(self, c: T) -> Self {
        Dual { v: self.v + c, g: self.g }
    }
}

#[allow(clippy::suspicious_arithmetic_impl)]
impl<T: Real> Div for Dual<T> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let inv = T::one() / o.v;
        let v = self.v * inv;
        let g = std::array::from_fn(|a| (self.g[a] - v * o.g[a]) * inv);
        Dual { v, g }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_matches_central_differences() {
        let pts: [[f64; 3]; 5] =
            [[0.3, -0.2, 0.5], [0.05, 0.04, -0.9], [-0.6, 0.3, 0.1], [0.2, -0.7, 0.05], [-0.1, 0.15, 0.2]];
        for map in [CoordinateMap::Cartesian, CoordinateMap::BallToCube] {
            for dim in 1..=3 {
                for p in pts {
                    let (_, jac) = map.apply(dim, p);
                    for b in 0..dim {
                        let h = 1e-7;
                        let (mut pp, mut pm) = (p, p);
                        pp[b] += h;
                        pm[b] -= h;
                        let (qp, _) = map.apply(dim, pp);
                        let (qm, _) = map.apply(dim, pm);
                        for a in 0..dim {
                            let fd = (qp[a] - qm[a]) / (2.0 * h);
                            assert!((fd - jac[a][b]).abs() < 1e-6 * (1.0 + fd.abs()), "{map:?} d{dim} {p:?} {a}{b}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn odd_exactly() {
        for dim in 1..=3 {
            for p in [[0.31f64, -0.27, 0.55], [0.05, 0.04, -0.9], [-0.6, 0.6, 0.1]] {
                let (q, _) = CoordinateMap::BallToCube.apply(dim, p);
                let (qm, _) = CoordinateMap::BallToCube.apply(dim, [-p[0], -p[1], -p[2]]);
                for a in 0..dim {
                    assert_eq!(q[a], -qm[a]);
                }
            }
        }
    }
}
