//! One-dimensional basis functions on `[-1, 1]` whose tensor products make a separable filter.
//!
//! A filter over a `d`-dimensional neighbourhood is `g(q) = Σ_k W_k Π_a b_{k_a}(q_a)` with
//! `n` functions `b_0 .. b_{n-1}` per axis (SFBC's separable formulation). [`Basis::Linear`]
//! (hat functions on `n` evenly spaced nodes) is CConv's multilinear filter interpolation; the
//! Fourier families carry even (cos) and odd (sin) symmetry, which SFBC finds decisive.
//!
//! ```
//! use pbdl_pconv::basis::Basis;
//!
//! let mut v = [0.0f64; 4];
//! let mut dv = [0.0f64; 4];
//! Basis::Linear.eval(0.0, &mut v, &mut dv);
//! // Nodes -1, -1/3, 1/3, 1: the origin lies halfway between the middle two.
//! assert!((v[1] - 0.5).abs() < 1e-15 && (v[2] - 0.5).abs() < 1e-15);
//! Basis::FourierOdd.eval(0.5, &mut v, &mut dv);
//! assert!((v[1] - (std::f64::consts::PI * 0.5).sin() / std::f64::consts::PI.sqrt()).abs() < 1e-15);
//! ```

use pbdl_core::Real;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A family of `n` one-dimensional functions on `[-1, 1]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Basis {
    /// Hat functions on `n >= 2` nodes `linspace(-1, 1, n)`: multilinear interpolation of a
    /// filter grid with aligned corners, as CConv.
    Linear,
    /// Fourier series without `cos(πx)` (SFBC's `fourier`): `1/√(2π)`, then `sin(πx)/√π`,
    /// `cos(2πx)/√π`, `sin(2πx)/√π`, `cos(3πx)/√π`, ...
    Fourier,
    /// The full Fourier series: `1/√(2π)`, `cos(πx)/√π`, `sin(πx)/√π`, `cos(2πx)/√π`, ...
    FourierFull,
    /// Even terms only: `1/√(2π)`, `cos(πx)/√π`, `cos(2πx)/√π`, ...
    FourierEven,
    /// The constant and the odd terms: `1/√(2π)`, `sin(πx)/√π`, `sin(2πx)/√π`, ... (as SFBC's
    /// `fourier odd`, which keeps the constant).
    FourierOdd,
    /// Chebyshev polynomials of the first kind `T_0 .. T_{n-1}`.
    Chebyshev,
    /// Gaussian radial basis functions on the nodes `linspace(-1, 1, n)`,
    /// `exp(-(x - c)² / s²)` with `s` the node spacing (a single function at 0 for `n = 1`).
    Gaussian,
}

impl Basis {
    /// Every basis, for tables and sweeps.
    pub const ALL: [Basis; 7] = [
        Basis::Linear,
        Basis::Fourier,
        Basis::FourierFull,
        Basis::FourierEven,
        Basis::FourierOdd,
        Basis::Chebyshev,
        Basis::Gaussian,
    ];

    /// The name used in scene files and tables.
    pub fn name(self) -> &'static str {
        match self {
            Basis::Linear => "linear",
            Basis::Fourier => "fourier",
            Basis::FourierFull => "fourier_full",
            Basis::FourierEven => "fourier_even",
            Basis::FourierOdd => "fourier_odd",
            Basis::Chebyshev => "chebyshev",
            Basis::Gaussian => "gaussian",
        }
    }

    /// Parses [`Basis::name`].
    pub fn from_name(name: &str) -> Option<Basis> {
        Basis::ALL.into_iter().find(|b| b.name() == name)
    }

    /// The smallest number of functions per axis this basis accepts.
    pub fn min_terms(self) -> usize {
        match self {
            Basis::Linear => 2,
            _ => 1,
        }
    }

    /// Writes `b_k(x)` into `values[k]` and `b_k'(x)` into `derivs[k]` for `k < values.len()`.
    /// `x` is clamped to `[-1, 1]` for [`Basis::Linear`] (CConv clamps its filter coordinate);
    /// the other families are smooth and evaluated as they are.
    #[inline]
    pub fn eval<T: Real>(self, x: T, values: &mut [T], derivs: &mut [T]) {
        let n = values.len();
        debug_assert_eq!(derivs.len(), n);
        match self {
            Basis::Linear => linear(x, values, derivs),
            Basis::Chebyshev => chebyshev(x, values, derivs),
            Basis::Gaussian => gaussian(x, values, derivs),
            Basis::Fourier | Basis::FourierFull | Basis::FourierEven | Basis::FourierOdd => {
                for k in 0..n {
                    let (v, d) = fourier_term(self, k, x);
                    values[k] = v;
                    derivs[k] = d;
                }
            }
        }
    }
}

/// Which Fourier function term `k` of a family is: `(0, _)` the constant, `(m, true)`
/// `cos(mπx)`, `(m, false)` `sin(mπx)`.
fn fourier_index(basis: Basis, k: usize) -> (usize, bool) {
    match basis {
        Basis::FourierFull => {
            if k == 0 {
                (0, true)
            } else {
                (k.div_ceil(2), k % 2 == 1)
            }
        }
        // As the full series with cos(πx) (term 1) left out.
        Basis::Fourier => fourier_index(Basis::FourierFull, if k == 0 { 0 } else { k + 1 }),
        Basis::FourierEven => (k, true),
        Basis::FourierOdd => (k, false),
        _ => unreachable!("fourier_index of a non-Fourier basis"),
    }
}

#[inline]
fn fourier_term<T: Real>(basis: Basis, k: usize, x: T) -> (T, T) {
    match fourier_index(basis, k) {
        (0, _) => (T::c(1.0 / (2.0 * PI).sqrt()), T::zero()),
        (m, cos) => {
            let w = T::c(m as f64 * PI);
            let norm = T::c(1.0 / PI.sqrt());
            let (s, c) = (w * x).sin_cos();
            if cos {
                (norm * c, -norm * w * s)
            } else {
                (norm * s, norm * w * c)
            }
        }
    }
}

fn linear<T: Real>(x: T, values: &mut [T], derivs: &mut [T]) {
    let n = values.len();
    values.fill(T::zero());
    derivs.fill(T::zero());
    // Position in node units, clamped to the grid; i0 and the weight as CConv's interpolation.
    let c = ((x + T::one()) * T::c(0.5) * T::c((n - 1) as f64)).fmax(T::zero()).fmin(T::c((n - 1) as f64));
    let i0 = (c.to_usize().unwrap_or(0)).min(n - 2);
    let a = c - T::c(i0 as f64);
    values[i0] = T::one() - a;
    values[i0 + 1] = a;
    // d c / d x inside the grid; the clamp makes it 0 outside (never reached for |x| < 1).
    let inside = x > -T::one() && x < T::one();
    let dc = if inside { T::c(0.5 * (n - 1) as f64) } else { T::zero() };
    derivs[i0] = -dc;
    derivs[i0 + 1] = dc;
}

fn chebyshev<T: Real>(x: T, values: &mut [T], derivs: &mut [T]) {
    // T_{k+1} = 2x T_k - T_{k-1};  T'_{k+1} = 2 T_k + 2x T'_k - T'_{k-1}.
    let n = values.len();
    values[0] = T::one();
    derivs[0] = T::zero();
    if n > 1 {
        values[1] = x;
        derivs[1] = T::one();
    }
    let two = T::c(2.0);
    for k in 2..n {
        values[k] = two * x * values[k - 1] - values[k - 2];
        derivs[k] = two * values[k - 1] + two * x * derivs[k - 1] - derivs[k - 2];
    }
}

fn gaussian<T: Real>(x: T, values: &mut [T], derivs: &mut [T]) {
    let n = values.len();
    let spacing = if n > 1 { 2.0 / (n - 1) as f64 } else { 1.0 };
    let inv_s2 = T::c(1.0 / (spacing * spacing));
    for k in 0..n {
        let centre = if n > 1 { -1.0 + k as f64 * spacing } else { 0.0 };
        let r = x - T::c(centre);
        let v = (-(r * r) * inv_s2).exp();
        values[k] = v;
        derivs[k] = T::c(-2.0) * r * inv_s2 * v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_central_differences() {
        for basis in Basis::ALL {
            let n = 6;
            let (mut v, mut d) = (vec![0.0f64; n], vec![0.0f64; n]);
            let (mut vp, mut dp, mut vm, mut dm) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            for &x in &[-0.93, -0.41, 0.07, 0.52, 0.88] {
                let h = 1e-6;
                basis.eval(x, &mut v, &mut d);
                basis.eval(x + h, &mut vp, &mut dp);
                basis.eval(x - h, &mut vm, &mut dm);
                for k in 0..n {
                    let fd = (vp[k] - vm[k]) / (2.0 * h);
                    assert!((fd - d[k]).abs() <= 1e-6 * (1.0 + d[k].abs()), "{basis:?} k={k} x={x}: {fd} vs {}", d[k]);
                }
            }
        }
    }

    #[test]
    fn symmetries() {
        let n = 5;
        let (mut a, mut da, mut b, mut db) = (vec![0.0f64; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for &x in &[0.13, 0.6, 0.97] {
            Basis::FourierEven.eval(x, &mut a, &mut da);
            Basis::FourierEven.eval(-x, &mut b, &mut db);
            assert!(a.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-15));
            Basis::FourierOdd.eval(x, &mut a, &mut da);
            Basis::FourierOdd.eval(-x, &mut b, &mut db);
            assert_eq!(a[0], b[0]);
            assert!(a[1..].iter().zip(&b[1..]).all(|(p, q)| (p + q).abs() < 1e-15));
        }
        // Partition of unity of the hat functions.
        let mut v = vec![0.0; 4];
        let mut d = vec![0.0; 4];
        for &x in &[-1.0, -0.77, 0.0, 0.31, 1.0] {
            Basis::Linear.eval(x, &mut v, &mut d);
            assert!((v.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn fourier_orders() {
        assert_eq!(fourier_index(Basis::FourierFull, 1), (1, true));
        assert_eq!(fourier_index(Basis::FourierFull, 2), (1, false));
        assert_eq!(fourier_index(Basis::Fourier, 1), (1, false));
        assert_eq!(fourier_index(Basis::Fourier, 2), (2, true));
        assert_eq!(fourier_index(Basis::FourierOdd, 0), (0, false));
        assert_eq!(fourier_index(Basis::FourierOdd, 1), (1, false));
    }
}
