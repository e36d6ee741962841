//! SPH smoothing kernels in 1D, 2D and 3D with their radial derivatives and gradients.
//!
//! Every kernel is `W(r, h) = sigma_d / h^d * f(q)`, `q = r / h`, with compact support
//! `q < k` ([`KernelKind::support_factor`]):
//!
//! | kernel | `f(q)` | support `k` | `sigma_1, sigma_2, sigma_3` |
//! |---|---|---|---|
//! | cubic spline (M4) | `1 - 3/2 q^2 + 3/4 q^3` (q < 1), `1/4 (2 - q)^3` (q < 2) | 2 | `2/3, 10/(7 pi), 1/pi` |
//! | quintic spline (M6) | `(3-q)^5 - 6 (2-q)^5 + 15 (1-q)^5` (terms where positive) | 3 | `1/120, 7/(478 pi), 1/(120 pi)` |
//! | Wendland C2 | 1D `(1-q/2)^3 (3q/2+1)`, 2D/3D `(1-q/2)^4 (2q+1)` | 2 | `5/8, 7/(4 pi), 21/(16 pi)` |
//! | Wendland C4 | 1D `(1-q/2)^5 (2q^2+5q/2+1)`, 2D/3D `(1-q/2)^6 (35/12 q^2+3q+1)` | 2 | `3/4, 9/(4 pi), 495/(256 pi)` |
//! | poly6 | `(1-q^2)^3` | 1 | `35/32, 4/pi, 315/(64 pi)` |
//! | spiky | `(1-q)^3` | 1 | `2, 10/pi, 15/pi` |
//!
//! `∫ W dV = 1` in each dimension (tested numerically). The gradient with respect to the first
//! particle is `∇_i W(x_i - x_j) = dW/dr * (x_i - x_j) / r`, antisymmetric in `i, j`.

use crate::error::{Error, Result};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Which kernel function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KernelKind {
    /// Monaghan's cubic B-spline (M4), support `2h`.
    CubicSpline,
    /// The quintic B-spline (M6), support `3h`.
    Quintic,
    /// Wendland C2, support `2h`.
    WendlandC2,
    /// Wendland C4, support `2h`.
    WendlandC4,
    /// Müller's poly6 (density kernel of PBF/SPH games), support `h`.
    Poly6,
    /// Desbrun's spiky kernel (non-vanishing gradient at 0), support `h`.
    Spiky,
}

impl KernelKind {
    /// Every kernel, for tests and sweeps.
    pub const ALL: [KernelKind; 6] = [
        KernelKind::CubicSpline,
        KernelKind::Quintic,
        KernelKind::WendlandC2,
        KernelKind::WendlandC4,
        KernelKind::Poly6,
        KernelKind::Spiky,
    ];

    /// Support radius in units of `h`.
    pub fn support_factor(self) -> f64 {
        match self {
            KernelKind::CubicSpline | KernelKind::WendlandC2 | KernelKind::WendlandC4 => 2.0,
            KernelKind::Quintic => 3.0,
            KernelKind::Poly6 | KernelKind::Spiky => 1.0,
        }
    }

    /// The normalisation constant `sigma_d` (without the `h^-d`).
    pub fn sigma(self, dim: usize) -> f64 {
        let s = match self {
            KernelKind::CubicSpline => [2.0 / 3.0, 10.0 / (7.0 * PI), 1.0 / PI],
            KernelKind::Quintic => [1.0 / 120.0, 7.0 / (478.0 * PI), 1.0 / (120.0 * PI)],
            KernelKind::WendlandC2 => [5.0 / 8.0, 7.0 / (4.0 * PI), 21.0 / (16.0 * PI)],
            KernelKind::WendlandC4 => [3.0 / 4.0, 9.0 / (4.0 * PI), 495.0 / (256.0 * PI)],
            KernelKind::Poly6 => [35.0 / 32.0, 4.0 / PI, 315.0 / (64.0 * PI)],
            KernelKind::Spiky => [2.0, 10.0 / PI, 15.0 / PI],
        };
        s[dim - 1]
    }

    /// `(f(q), f'(q))` of the kernel's shape function in dimension `dim`; zero outside support.
    #[inline]
    pub fn shape<T: Real>(self, dim: usize, q: T) -> (T, T) {
        let c = |v: f64| T::c(v);
        let zero = T::zero();
        let one = T::one();
        match self {
            KernelKind::CubicSpline => {
                if q < one {
                    (one - c(1.5) * q * q + c(0.75) * q * q * q, q * (c(2.25) * q - c(3.0)))
                } else if q < c(2.0) {
                    let t = c(2.0) - q;
                    (c(0.25) * t * t * t, c(-0.75) * t * t)
                } else {
                    (zero, zero)
                }
            }
            KernelKind::Quintic => {
                let (mut f, mut df) = (zero, zero);
                for (a, w) in [(3.0, 1.0), (2.0, -6.0), (1.0, 15.0)] {
                    let t = c(a) - q;
                    if t > zero {
                        let t2 = t * t;
                        let t4 = t2 * t2;
                        f += c(w) * t4 * t;
                        df -= c(5.0 * w) * t4;
                    }
                }
                (f, df)
            }
            KernelKind::WendlandC2 => {
                if q >= c(2.0) {
                    return (zero, zero);
                }
                let t = one - c(0.5) * q;
                if dim == 1 {
                    (t * t * t * (c(1.5) * q + one), c(-3.0) * q * t * t)
                } else {
                    let t3 = t * t * t;
                    (t3 * t * (c(2.0) * q + one), c(-5.0) * q * t3)
                }
            }
            KernelKind::WendlandC4 => {
                if q >= c(2.0) {
                    return (zero, zero);
                }
                let t = one - c(0.5) * q;
                let t2 = t * t;
                let t4 = t2 * t2;
                if dim == 1 {
                    (t4 * t * (c(2.0) * q * q + c(2.5) * q + one), c(-3.5) * q * (one + c(2.0) * q) * t4)
                } else {
                    let t5 = t4 * t;
                    (t5 * t * (c(35.0 / 12.0) * q * q + c(3.0) * q + one), c(-14.0 / 3.0) * q * (one + c(2.5) * q) * t5)
                }
            }
            KernelKind::Poly6 => {
                if q >= one {
                    return (zero, zero);
                }
                let t = one - q * q;
                (t * t * t, c(-6.0) * q * t * t)
            }
            KernelKind::Spiky => {
                if q >= one {
                    return (zero, zero);
                }
                let t = one - q;
                (t * t * t, c(-3.0) * t * t)
            }
        }
    }
}

/// A kernel of a given kind, dimension and smoothing length, with its constants precomputed.
///
/// ```
/// use pbdl_particles::{Kernel, KernelKind};
/// let w = Kernel::<f64>::new(KernelKind::CubicSpline, 2, 0.1)?;
/// assert_eq!(w.support(), 0.2);
/// assert!(w.w(0.05) > w.w(0.1));
/// # Ok::<(), pbdl_particles::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kernel<T: Real> {
    kind: KernelKind,
    dim: usize,
    h: T,
    inv_h: T,
    norm: T,
    dnorm: T,
    support: T,
}

impl<T: Real> Kernel<T> {
    /// A kernel of `kind` in `dim` dimensions (1, 2 or 3) with smoothing length `h > 0`.
    pub fn new(kind: KernelKind, dim: usize, h: T) -> Result<Self> {
        if !(1..=3).contains(&dim) {
            return Err(Error::invalid("dim", format!("{dim}; kernels exist in 1, 2 and 3 dimensions")));
        }
        let hf = h.to_f64();
        if !(hf > 0.0 && hf.is_finite()) {
            return Err(Error::invalid("h", format!("{hf}; the smoothing length must be positive and finite")));
        }
        let norm = kind.sigma(dim) / hf.powi(dim as i32);
        Ok(Kernel {
            kind,
            dim,
            h,
            inv_h: T::c(1.0 / hf),
            norm: T::c(norm),
            dnorm: T::c(norm / hf),
            support: T::c(kind.support_factor() * hf),
        })
    }

    /// The kernel kind.
    pub fn kind(&self) -> KernelKind {
        self.kind
    }

    /// The dimension.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The smoothing length `h`.
    pub fn h(&self) -> T {
        self.h
    }

    /// The support radius (`W = 0` for `r >= support`).
    pub fn support(&self) -> T {
        self.support
    }

    /// `W(r)`.
    #[inline]
    pub fn w(&self, r: T) -> T {
        self.norm * self.kind.shape(self.dim, r * self.inv_h).0
    }

    /// `dW/dr (r)`.
    #[inline]
    pub fn dw_dr(&self, r: T) -> T {
        self.dnorm * self.kind.shape(self.dim, r * self.inv_h).1
    }

    /// `(W(r), dW/dr(r))` in one evaluation.
    #[inline]
    pub fn w_dw(&self, r: T) -> (T, T) {
        let (f, df) = self.kind.shape(self.dim, r * self.inv_h);
        (self.norm * f, self.dnorm * df)
    }

    /// `∇ W` at the offset `d = x_i - x_j` (gradient with respect to `x_i`); zero at `d = 0`.
    #[inline]
    pub fn grad<const D: usize>(&self, d: [T; D]) -> [T; D] {
        let r2 = d.iter().fold(T::zero(), |a, &x| a + x * x);
        if r2 <= T::zero() {
            return [T::zero(); D];
        }
        let r = r2.sqrt();
        let s = self.dw_dr(r) / r;
        d.map(|x| s * x)
    }
}
