//! The half-inverse solve `dtheta = V diag(s^-kappa, truncated) U^T g` with reusable buffers.

use crate::error::{check_len, Error, Result};
use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{self, ComputeEigenvectors};
use faer::linalg::matmul::matmul;
use faer::linalg::svd::{self, ComputeSvdVectors};
use faer::{Accum, Mat, MatRef, Par};
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
    /// How `U`, `S` (and the map back to parameter space) are obtained. Default
    /// [`Decomposition::Svd`].
    pub decomposition: Decomposition,
}

/// Which factorisation a [`HalfInverse`] solve uses. Both give the same update (up to
/// rounding) as long as the kept singular values are well above `sqrt(f64::EPSILON) * s_max`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decomposition {
    /// Thin SVD `J = U S V^T` of the `rows x cols` Jacobian (faer), then `V diag(s^-kappa) U^T g`.
    #[default]
    Svd,
    /// Eigendecomposition of the Gram matrix `J J^T = U diag(lambda) U^T` (`rows x rows`,
    /// `lambda_i = s_i^2`), then `J^T U diag(lambda^(-(kappa + 1) / 2)) U^T g`, keeping
    /// `lambda_i > tau^2 lambda_max` (the same cut as `s_i > tau s_max`). Cheaper when
    /// `rows << cols`, but eigenvalues carry an absolute error `~ eps * lambda_max`, so singular
    /// values below `~1e-7 s_max` lose relative accuracy.
    Eigen,
}

impl Default for HigConfig {
    fn default() -> Self {
        Self { eta: 1.0, tau: 1e-6, exponent: 0.5, decomposition: Decomposition::Svd }
    }
}

impl HigConfig {
    /// Half-inverse gradients with learning rate `eta` and truncation `tau`.
    pub fn hig(eta: f64, tau: f64) -> Self {
        Self { eta, tau, exponent: 0.5, decomposition: Decomposition::Svd }
    }

    /// The Gauss-Newton baseline (exponent 1) with the same code path.
    pub fn gauss_newton(eta: f64, tau: f64) -> Self {
        Self { eta, tau, exponent: 1.0, decomposition: Decomposition::Svd }
    }

    /// The same settings solved with `decomposition`.
    pub fn with_decomposition(mut self, decomposition: Decomposition) -> Self {
        self.decomposition = decomposition;
        self
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
    decomposition: Decomposition,
    /// Eigen path: the Gram matrix `J J^T`, its eigenvalues (ascending) and `U c`.
    gram: Mat<f64>,
    lambda: Diag<f64>,
    w: Vec<f64>,
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
            decomposition: Decomposition::Svd,
            gram: Mat::zeros(0, 0),
            lambda: Diag::zeros(0),
            w: Vec::new(),
        };
        h.reshape(rows, cols, Decomposition::Svd);
        h
    }

    fn reshape(&mut self, rows: usize, cols: usize, decomposition: Decomposition) {
        if (rows, cols, decomposition) == (self.rows, self.cols, self.decomposition) {
            return;
        }
        self.rows = rows;
        self.cols = cols;
        self.decomposition = decomposition;
        if decomposition == Decomposition::Eigen {
            self.s = Diag::zeros(0);
            self.u = Mat::zeros(rows, rows);
            self.v = Mat::zeros(0, 0);
            self.gram = Mat::zeros(rows, rows);
            self.lambda = Diag::zeros(rows);
            self.c = vec![0.0; rows];
            self.w = vec![0.0; rows];
            let req =
                evd::self_adjoint_evd_scratch::<f64>(rows, ComputeEigenvectors::Yes, self.par, Default::default());
            self.mem = MemBuffer::new(req);
            return;
        }
        self.gram = Mat::zeros(0, 0);
        self.lambda = Diag::zeros(0);
        self.w = Vec::new();
        let k = rows.min(cols);
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

    /// The singular values of the last solve, non-increasing (on the eigen path
    /// `sqrt(max(lambda_i, 0))`, `rows` of them).
    pub fn singular_values(&self) -> Vec<f64> {
        if self.decomposition == Decomposition::Eigen {
            let l = self.lambda.column_vector();
            return (0..l.nrows()).rev().map(|i| l[i].max(0.0).sqrt()).collect();
        }
        let s = self.s.column_vector();
        (0..s.nrows()).map(|i| s[i]).collect()
    }

    /// Left singular vectors `U` (`rows x k`) of the last solve. On the eigen path: the
    /// eigenvectors of `J J^T` (`rows x rows`) in *ascending* order of their eigenvalues.
    pub fn u(&self) -> MatRef<'_, f64> {
        self.u.as_ref()
    }

    /// Right singular vectors `V` (`cols x k`) of the last SVD solve (empty on the eigen path,
    /// which never forms `V`).
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
        self.reshape(rows, cols, cfg.decomposition);
        if cfg.decomposition == Decomposition::Eigen {
            return self.solve_eigen(cfg, j, g, out);
        }
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

    /// The eigen path: `out = J^T U diag(lambda^(-(kappa+1)/2), truncated) U^T g`.
    fn solve_eigen(&mut self, cfg: &HigConfig, j: MatRef<'_, f64>, g: &[f64], out: &mut [f64]) -> Result<SolveInfo> {
        let (rows, cols) = j.shape();
        matmul(self.gram.as_mut(), Accum::Replace, j, j.transpose(), 1.0, self.par);
        let stack = MemStack::new(&mut self.mem);
        evd::self_adjoint_evd(
            self.gram.as_ref(),
            self.lambda.as_mut(),
            Some(self.u.as_mut()),
            self.par,
            stack,
            Default::default(),
        )
        .map_err(|_| Error::SvdNoConvergence { rows, cols })?;
        let l = self.lambda.column_vector();
        let l_max = (0..rows).map(|i| l[i]).fold(0.0, f64::max);
        let cutoff = cfg.tau * cfg.tau * l_max;
        let power = -0.5 * (cfg.exponent + 1.0);
        let (mut rank, mut l_min_kept) = (0, f64::INFINITY);
        for i in 0..rows {
            let li = l[i];
            self.c[i] = if li > cutoff && li > 0.0 {
                rank += 1;
                l_min_kept = l_min_kept.min(li);
                let ui = self.u.col(i);
                let dot: f64 = (0..rows).map(|r| ui[r] * g[r]).sum();
                dot * li.powf(power)
            } else {
                0.0
            };
        }
        // w = U c, then out = J^T w (row after row of J).
        self.w.fill(0.0);
        for i in 0..rows {
            let ci = self.c[i];
            if ci != 0.0 {
                let ui = self.u.col(i);
                for (r, w) in self.w.iter_mut().enumerate() {
                    *w += ui[r] * ci;
                }
            }
        }
        let wm = MatRef::from_column_major_slice(&self.w, rows, 1);
        let mut o = faer::MatMut::from_column_major_slice_mut(out, cols, 1);
        matmul(o.as_mut(), Accum::Replace, j.transpose(), wm, 1.0, self.par);
        let s_min_kept = if rank > 0 { l_min_kept.sqrt() } else { 0.0 };
        Ok(SolveInfo { rank, s_max: l_max.max(0.0).sqrt(), s_min_kept })
    }
}
