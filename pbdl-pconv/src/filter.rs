//! The continuous filter: [`FilterSpec`] (basis, terms per axis, coordinate map, window,
//! support radius, antisymmetry) and the per-pair evaluation of its `K = n^d` separable
//! basis values `a(|s|) Π_a b_{k_a}(m(s)_a)` with their gradients with respect to the offset.
//!
//! ```
//! use pbdl_pconv::{basis::Basis, filter::FilterSpec};
//!
//! let cconv = FilterSpec::cconv(3, 4, 0.1125);
//! assert_eq!(cconv.filter_size(), 64);
//! let mut eval = cconv.evaluator::<f64>();
//! let mut values = vec![0.0; 64];
//! eval.values(&[0.01, -0.02, 0.03], &mut values);
//! // Linear interpolation weights times the window: they sum to the window value.
//! let r2: f64 = (0.01f64.powi(2) + 0.02f64.powi(2) + 0.03f64.powi(2)) / 0.1125f64.powi(2);
//! assert!((values.iter().sum::<f64>() - (1.0 - r2).powi(3)).abs() < 1e-12);
//! # let _ = Basis::Linear;
//! ```

use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::mapping::CoordinateMap;
use crate::window::Window;
use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// What a continuous convolution's filter is made of.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterSpec {
    /// Spatial dimension, 1 to 3.
    pub dim: usize,
    /// The 1D basis family of each axis.
    pub basis: Basis,
    /// Basis functions per axis `n`; the filter has `n^dim` weights per channel pair.
    pub terms: usize,
    /// Offset-to-filter coordinate map.
    pub map: CoordinateMap,
    /// Radial window.
    pub window: Window,
    /// Support radius `R`: offsets are divided by it, pairs farther apart are not neighbours.
    pub radius: f64,
    /// Antisymmetric filter `g(s) - g(-s)` applied to `f_i + f_j` (DMCF): each pair's two
    /// contributions cancel, so `Σ_i out_i = 0`. Needs senders = receivers.
    pub antisymmetric: bool,
}

impl FilterSpec {
    /// CConv's filter: linear interpolation of an `n^dim` grid, ball-to-cube map, poly6 window.
    pub fn cconv(dim: usize, n: usize, radius: f64) -> Self {
        FilterSpec {
            dim,
            basis: Basis::Linear,
            terms: n,
            map: CoordinateMap::BallToCube,
            window: Window::Poly6,
            radius,
            antisymmetric: false,
        }
    }

    /// An SFBC filter: `n` functions of `basis` per axis, Cartesian coordinates, no window.
    pub fn sfbc(dim: usize, basis: Basis, n: usize, radius: f64) -> Self {
        FilterSpec {
            dim,
            basis,
            terms: n,
            map: CoordinateMap::Cartesian,
            window: Window::None,
            radius,
            antisymmetric: false,
        }
    }

    /// The same filter made antisymmetric.
    pub fn antisymmetric(mut self) -> Self {
        self.antisymmetric = true;
        self
    }

    /// Weights per channel pair, `terms^dim`.
    pub fn filter_size(&self) -> usize {
        self.terms.pow(self.dim as u32)
    }

    /// Checks the fields; the error names the one to change.
    pub fn validate(&self) -> Result<()> {
        if !(1..=3).contains(&self.dim) {
            return Err(Error::Config { field: "dim", reason: format!("{}; use 1, 2 or 3", self.dim) });
        }
        let min = self.basis.min_terms();
        if self.terms < min || self.terms > 64 {
            return Err(Error::Config {
                field: "terms",
                reason: format!("{} functions of basis {}; use {min} to 64", self.terms, self.basis.name()),
            });
        }
        if !(self.radius > 0.0 && self.radius.is_finite()) {
            return Err(Error::Config {
                field: "radius",
                reason: format!("{}; must be positive and finite", self.radius),
            });
        }
        Ok(())
    }

    /// A reusable evaluator (scratch buffers inside) for pairs in precision `T`.
    pub fn evaluator<T: Real>(&self) -> PairFilter<T> {
        let n = self.terms;
        PairFilter {
            spec: *self,
            inv_radius: T::c(1.0 / self.radius),
            b: vec![T::zero(); 3 * n],
            db: vec![T::zero(); 3 * n],
            bn: vec![T::zero(); 3 * n],
            dbn: vec![T::zero(); 3 * n],
        }
    }
}

/// Evaluates a filter's `K` basis values (and gradients) for one offset at a time.
pub struct PairFilter<T> {
    spec: FilterSpec,
    inv_radius: T,
    // Per-axis basis values and derivatives at q (b, db) and at -q (bn, dbn), axis-major.
    b: Vec<T>,
    db: Vec<T>,
    bn: Vec<T>,
    dbn: Vec<T>,
}

impl<T: Real> PairFilter<T> {
    /// The spec this evaluator was made from.
    pub fn spec(&self) -> &FilterSpec {
        &self.spec
    }

    /// The `K` values `v_k(d)` for the offset `d = x_j - x_i` (unscaled, `dim` components).
    pub fn values(&mut self, d: &[T], values: &mut [T]) {
        self.eval(d, values, None);
    }

    /// Values and their gradients `grads[k * dim + a] = ∂v_k/∂d_a`.
    pub fn values_and_grads(&mut self, d: &[T], values: &mut [T], grads: &mut [T]) {
        self.eval(d, values, Some(grads));
    }

    fn eval(&mut self, d: &[T], values: &mut [T], mut grads: Option<&mut [T]>) {
        let dim = self.spec.dim;
        let n = self.spec.terms;
        let mut s = [T::zero(); 3];
        for a in 0..dim {
            s[a] = d[a] * self.inv_radius;
        }
        let r2 = s.iter().fold(T::zero(), |acc, &v| acc + v * v);
        let (w, dw_over_r) = self.spec.window.eval(r2.sqrt());
        let (q, jac) = self.spec.map.apply(dim, s);
        let basis = self.spec.basis;
        for a in 0..dim {
            basis.eval(q[a], &mut self.b[a * n..(a + 1) * n], &mut self.db[a * n..(a + 1) * n]);
            if self.spec.antisymmetric {
                basis.eval(-q[a], &mut self.bn[a * n..(a + 1) * n], &mut self.dbn[a * n..(a + 1) * n]);
            }
        }
        let k_total = n.pow(dim as u32);
        for k in 0..k_total {
            // Multi-index of k in a row-major [n; dim] grid (the last axis fastest).
            let mut idx = [0usize; 3];
            let mut rest = k;
            for a in (0..dim).rev() {
                idx[a] = rest % n;
                rest /= n;
            }
            let (phi, dphi) = product(&self.b, &self.db, &idx, dim, n);
            let (value, dq) = if self.spec.antisymmetric {
                // psi(s) = phi(m(s)) - phi(-m(s)); d/dq of phi(-q) is -(∇phi)(-q).
                let (phin, dphin) = product(&self.bn, &self.dbn, &idx, dim, n);
                (phi - phin, std::array::from_fn::<T, 3, _>(|a| dphi[a] + dphin[a]))
            } else {
                (phi, dphi)
            };
            values[k] = w * value;
            if let Some(g) = grads.as_deref_mut() {
                for b in 0..dim {
                    // ∂v/∂s_b = a'(r) s_b / r * psi + a * Σ_a ∂psi/∂q_a ∂q_a/∂s_b; then 1/R.
                    let mut acc = dw_over_r * s[b] * value;
                    for a in 0..dim {
                        acc += w * dq[a] * jac[a][b];
                    }
                    g[k * dim + b] = acc * self.inv_radius;
                }
            }
        }
    }
}

/// `Π_a b_a[idx_a]` and its gradient over the `dim` axes.
#[inline]
fn product<T: Real>(b: &[T], db: &[T], idx: &[usize; 3], dim: usize, n: usize) -> (T, [T; 3]) {
    let mut value = T::one();
    let mut grad = [T::one(); 3];
    for a in 0..dim {
        let v = b[a * n + idx[a]];
        value *= v;
        for (c, g) in grad.iter_mut().enumerate().take(dim) {
            *g *= if c == a { db[a * n + idx[a]] } else { v };
        }
    }
    (value, grad)
}
