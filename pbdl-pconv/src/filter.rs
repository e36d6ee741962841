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
            sparse: self.basis == Basis::Linear && !self.antisymmetric,
            b: vec![T::zero(); 3 * n],
            db: vec![T::zero(); 3 * n],
            bn: vec![T::zero(); 3 * n],
            dbn: vec![T::zero(); 3 * n],
            sel: vec![0; 3 * n],
        }
    }
}

/// Evaluates a filter's `K` basis values (and gradients) for one offset at a time.
pub struct PairFilter<T> {
    spec: FilterSpec,
    inv_radius: T,
    /// Linear basis, not antisymmetric: at most `2^dim` terms are nonzero (the interpolation
    /// corners), and [`PairFilter::terms`] lists only those.
    sparse: bool,
    // Per-axis basis values and derivatives at q (b, db) and at -q (bn, dbn), axis-major.
    b: Vec<T>,
    db: Vec<T>,
    bn: Vec<T>,
    dbn: Vec<T>,
    /// Per axis, the basis indices that take part (axis-major, `n` slots each).
    sel: Vec<usize>,
}

impl<T: Real> PairFilter<T> {
    /// The spec this evaluator was made from.
    pub fn spec(&self) -> &FilterSpec {
        &self.spec
    }

    /// Whether [`PairFilter::terms`] lists only the nonzero terms (a linear basis that is not
    /// antisymmetric) instead of all `K` in order.
    pub fn is_sparse(&self) -> bool {
        self.sparse
    }

    /// The most terms [`PairFilter::terms`] writes: `2^dim` when sparse, else `K`.
    pub fn max_terms(&self) -> usize {
        if self.sparse {
            1 << self.spec.dim
        } else {
            self.spec.filter_size()
        }
    }

    /// The `K` values `v_k(d)` for the offset `d = x_j - x_i` (unscaled, `dim` components).
    pub fn values(&mut self, d: &[T], values: &mut [T]) {
        if self.sparse {
            values[..self.spec.filter_size()].fill(T::zero());
        }
        self.eval(d, false, |k, v, _| values[k] = v);
    }

    /// Values and their gradients `grads[k * dim + a] = ∂v_k/∂d_a`.
    pub fn values_and_grads(&mut self, d: &[T], values: &mut [T], grads: &mut [T]) {
        let dim = self.spec.dim;
        if self.sparse {
            let k = self.spec.filter_size();
            values[..k].fill(T::zero());
            grads[..k * dim].fill(T::zero());
        }
        self.eval(d, true, |k, v, g| {
            values[k] = v;
            for a in 0..dim {
                grads[k * dim + a] = g[a];
            }
        });
    }

    /// The terms of one offset as a list: `idx[t]` the filter index `k`, `values[t]` = `v_k(d)`
    /// and, when asked for, `grads[t * dim + a]` = `∂v_k/∂d_a`; returns the count. All `K`
    /// terms in order (`idx[t] = t`), or only the `2^dim` that can be nonzero when
    /// [`PairFilter::is_sparse`]. Buffers need [`PairFilter::max_terms`] slots.
    pub fn terms(&mut self, d: &[T], idx: &mut [u32], values: &mut [T], grads: Option<&mut [T]>) -> usize {
        let dim = self.spec.dim;
        let mut m = 0;
        match grads {
            None => self.eval(d, false, |k, v, _| {
                idx[m] = k as u32;
                values[m] = v;
                m += 1;
            }),
            Some(grads) => self.eval(d, true, |k, v, g| {
                idx[m] = k as u32;
                values[m] = v;
                for a in 0..dim {
                    grads[m * dim + a] = g[a];
                }
                m += 1;
            }),
        }
        m
    }

    /// Calls `emit(k, v_k, ∇v_k)` for every term (only the possibly nonzero ones when sparse),
    /// `k` ascending. The gradient is left zero unless `want_grads`.
    #[inline(always)]
    fn eval(&mut self, d: &[T], want_grads: bool, mut emit: impl FnMut(usize, T, &[T; 3])) {
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
        let anti = self.spec.antisymmetric;
        let mut count = [n; 3];
        for a in 0..dim {
            basis.eval(q[a], &mut self.b[a * n..(a + 1) * n], &mut self.db[a * n..(a + 1) * n]);
            if anti {
                basis.eval(-q[a], &mut self.bn[a * n..(a + 1) * n], &mut self.dbn[a * n..(a + 1) * n]);
            }
            let sel = &mut self.sel[a * n..(a + 1) * n];
            if self.sparse {
                // An index whose value and derivative are both zero on one axis makes every
                // product through it zero (value and all gradient components): skip it.
                let mut c = 0;
                for m in 0..n {
                    if self.b[a * n + m] != T::zero() || self.db[a * n + m] != T::zero() {
                        sel[c] = m;
                        c += 1;
                    }
                }
                count[a] = c;
            } else {
                for (m, x) in sel.iter_mut().enumerate() {
                    *x = m;
                }
            }
        }
        let (b, db, bn, dbn, sel) = (&self.b, &self.db, &self.bn, &self.dbn, &self.sel);
        let inv_radius = self.inv_radius;
        // One axis of the running products `Π b` and their gradients (the same multiplications
        // in the same order as a product over the axes of one multi-index).
        let step = |a: usize, m: usize, (v, g): (T, [T; 3]), b: &[T], db: &[T]| -> (T, [T; 3]) {
            let bv = b[a * n + m];
            let mut g2 = g;
            for c in 0..dim {
                g2[c] *= if c == a { db[a * n + m] } else { bv };
            }
            (v * bv, g2)
        };
        let mut finish = |k: usize, phi: (T, [T; 3]), phin: (T, [T; 3])| {
            let (value, dq) = if anti {
                // psi(s) = phi(m(s)) - phi(-m(s)); d/dq of phi(-q) is -(∇phi)(-q).
                (phi.0 - phin.0, std::array::from_fn::<T, 3, _>(|a| phi.1[a] + phin.1[a]))
            } else {
                phi
            };
            let mut g = [T::zero(); 3];
            if want_grads {
                for bb in 0..dim {
                    // ∂v/∂s_b = a'(r) s_b / r * psi + a * Σ_a ∂psi/∂q_a ∂q_a/∂s_b; then 1/R.
                    let mut acc = dw_over_r * s[bb] * value;
                    for a in 0..dim {
                        acc += w * dq[a] * jac[a][bb];
                    }
                    g[bb] = acc * inv_radius;
                }
            }
            emit(k, w * value, &g);
        };
        let one = (T::one(), [T::one(); 3]);
        // Multi-index (m0, m1, m2) of a row-major [n; dim] grid, the last axis fastest; axes at
        // and beyond `dim` are one dummy index (stride 1, factor 1), so `finish` has one call
        // site (inlined).
        let stride = |a: usize| if a < dim { n } else { 1 };
        let (n1, n2) = (stride(1), stride(2));
        let axis = |a: usize| if a < dim { &sel[a * n..a * n + count[a]] } else { &[0usize][..] };
        let (sel0, sel1, sel2) = (axis(0), axis(1), axis(2));
        let step_if = |a: usize, m: usize, acc: (T, [T; 3]), b: &[T], db: &[T]| {
            if a < dim {
                step(a, m, acc, b, db)
            } else {
                acc
            }
        };
        for &m0 in sel0 {
            let p0 = step(0, m0, one, b, db);
            let n0 = if anti { step(0, m0, one, bn, dbn) } else { one };
            for &m1 in sel1 {
                let p1 = step_if(1, m1, p0, b, db);
                let q1 = if anti { step_if(1, m1, n0, bn, dbn) } else { one };
                for &m2 in sel2 {
                    let p2 = step_if(2, m2, p1, b, db);
                    let q2 = if anti { step_if(2, m2, q1, bn, dbn) } else { one };
                    finish((m0 * n1 + m1) * n2 + m2, p2, q2);
                }
            }
        }
    }
}
