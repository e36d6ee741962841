//! The half-inverse solve `dtheta = V diag(s^-kappa, truncated) U^T g` with reusable buffers.

use crate::error::{check_len, Error, Result};
use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::svd::{self, ComputeSvdVectors};
use faer::{Mat, MatRef, Par};
use serde::{Deserialize, Serialize};

/// Settings of a HIG (or Gauss-Newton) step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct HigConfig {
    /// Learning rate `eta` of the plain SGD step `theta -= eta dtheta`. Default `1.0`.
    pub eta: f64,
    /// Relative truncation: singular values with `s_i <= tau * s_max` are dropped (strict
    /// comparison, as in the paper). Must be `> 0`. Default `1e-6`.
    pub tau: f64,
    /// `kappa` in `s_i^-kappa`: `0.5` is HIG, `1.0` Gauss-Newton (the truncated pseudo-inverse),
    /// `0` a projected gradient. Default `0.5`.
    pub exponent: f64,
}

impl Default for HigConfig {
    fn default() -> Self {
        Self { eta: 1.0, tau: 1e-6, exponent: 0.5 }
    }
}

impl HigConfig {
    /// Half-inverse gradients with learning rate `eta` and truncation `tau`.
    pub fn hig(eta: f64, tau: f64) -> Self {
        Self { eta, tau, exponent: 0.5 }
    }

    /// The Gauss-Newton baseline (exponent 1) with the same code path.
    pub fn gauss_newton(eta: f64, tau: f64) -> Self {
        Self { eta, tau, exponent: 1.0 }
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<()> {
        if !(self.tau.is_finite() && self.tau > 0.0) {
            return Err(Error::InvalidTau { tau: self.tau });
        }
        if !(self.eta.is_finite() && self.eta > 0.0) {
            return Err(Error::InvalidConfig {
                name: "eta",
                value: self.eta,
                hint: "use a finite learning rate > 0 (HIG: typically 1)",
            });
        }
        if !(self.exponent.is_finite() && self.exponent >= 0.0) {
            return Err(Error::InvalidConfig {
                name: "exponent",
                value: self.exponent,
                hint: "use 0.5 for HIG or 1 for Gauss-Newton",
            });
        }
        Ok(())
    }
}

/// What one solve found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveInfo {
    /// Number of singular values kept (`s_i > tau * s_max`).
    pub rank: usize,
    /// Largest singular value.
    pub s_max: f64,
    /// Smallest singular value kept (0 when none is).
    pub s_min_kept: f64,
}

/// Computes `V diag(s_i^-kappa if s_i > tau s_max else 0) U^T g` from a thin SVD `J = U S V^T`
/// in `f64`. The SVD output and faer's workspace are kept between calls, so repeated solves of
/// the same shape do not allocate.
pub struct HalfInverse {
    rows: usize,
    cols: usize,
    s: Diag<f64>,
    u: Mat<f64>,
    v: Mat<f64>,
    c: Vec<f64>,
    mem: MemBuffer,
    par: Par,
}

impl std::fmt::Debug for HalfInverse {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HalfInverse").field("rows", &self.rows).field("cols", &self.cols).finish()
    }
}

impl HalfInverse {
    /// Buffers for `rows x cols` Jacobians, using `par` for faer (e.g. `Par::rayon(0)` for the
    /// global rayon pool, `Par::Seq` for one thread).
    pub fn new(rows: usize, cols: usize, par: Par) -> Self {
        let mut h = Self {
            rows: 0,
            cols: 0,
            s: Diag::zeros(0),
            u: Mat::zeros(0, 0),
            v: Mat::zeros(0, 0),
            c: Vec::new(),
            mem: MemBuffer::new(faer::dyn_stack::StackReq::EMPTY),
            par,
        };
        h.reshape(rows, cols);
        h
    }

    fn reshape(&mut self, rows: usize, cols: usize) {
        if (rows, cols) == (self.rows, self.cols) {
            return;
        }
        let k = rows.min(cols);
        self.rows = rows;
        self.cols = cols;
        self.s = Diag::zeros(k);
        self.u = Mat::zeros(rows, k);
        self.v = Mat::zeros(cols, k);
        self.c = vec![0.0; k];
        let req = svd::svd_scratch::<f64>(
            rows,
            cols,
            ComputeSvdVectors::Thin,
            ComputeSvdVectors::Thin,
            self.par,
            Default::default(),
        );
        self.mem = MemBuffer::new(req);
    }

    /// The singular values of the last solve, non-increasing.
    pub fn singular_values(&self) -> Vec<f64> {
        let s = self.s.column_vector();
        (0..s.nrows()).map(|i| s[i]).collect()
    }

    /// Left singular vectors `U` (`rows x k`) of the last solve.
    pub fn u(&self) -> MatRef<'_, f64> {
        self.u.as_ref()
    }

    /// Right singular vectors `V` (`cols x k`) of the last solve.
    pub fn v(&self) -> MatRef<'_, f64> {
        self.v.as_ref()
    }

    /// Writes `V diag(s_i^-exponent, truncated) U^T g` into `out` (length `cols`).
    ///
    /// Errors: `tau <= 0` ([`Error::InvalidTau`]), lengths that do not fit `j`
    /// ([`Error::ShapeMismatch`]), NaN/Inf in `j` or `g` ([`Error::NonFinite`]).
    pub fn solve(&mut self, cfg: &HigConfig, j: MatRef<'_, f64>, g: &[f64], out: &mut [f64]) -> Result<SolveInfo> {
        cfg.validate()?;
        let (rows, cols) = j.shape();
        check_len("loss gradient length (Jacobian rows)", rows, g.len())?;
        check_len("update length (Jacobian columns)", cols, out.len())?;
        for c in 0..cols {
            for r in 0..rows {
                let x = j[(r, c)];
                if !x.is_finite() {
                    return Err(Error::NonFinite { what: "Jacobian", row: r, col: c, value: x });
                }
            }
        }
        crate::error::check_finite("loss gradient", g, 1)?;
        self.reshape(rows, cols);
        let stack = MemStack::new(&mut self.mem);
        svd::svd(j, self.s.as_mut(), Some(self.u.as_mut()), Some(self.v.as_mut()), self.par, stack, Default::default())
            .map_err(|_| Error::SvdNoConvergence { rows, cols })?;
        let k = rows.min(cols);
        let s = self.s.column_vector();
        let s_max = (0..k).map(|i| s[i]).fold(0.0, f64::max);
        let cutoff = cfg.tau * s_max;
        let mut rank = 0;
        let mut s_min_kept = 0.0;
        for i in 0..k {
            let si = s[i];
            self.c[i] = if si > cutoff && si > 0.0 {
                rank += 1;
                s_min_kept = si;
                // c_i = s_i^-kappa (u_i . g)
                let ui = self.u.col(i);
                let dot: f64 = (0..rows).map(|r| ui[r] * g[r]).sum();
                dot * si.powf(-cfg.exponent)
            } else {
                0.0
            };
        }
        // out = V c
        out.fill(0.0);
        for i in 0..k {
            let ci = self.c[i];
            if ci != 0.0 {
                let vi = self.v.col(i);
                for (r, o) in out.iter_mut().enumerate() {
                    *o += vi[r] * ci;
                }
            }
        }
        Ok(SolveInfo { rank, s_max, s_min_kept })
    }
}
