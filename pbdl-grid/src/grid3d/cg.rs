//! Pressure projection in the closed box ([`super::walls`]) by MIC(0)-preconditioned conjugate
//! gradients on the seven-point Neumann Laplacian: the 3D extension of
//! [`crate::pressure::CgPressureSolver`]'s method, on a structured matrix (never assembled).
//!
//! `A = G^T G = -D G` over all cells (a neighbour across a wall is dropped: zero normal velocity,
//! Neumann pressure), symmetric positive semi-definite with the constants as null space: the
//! right-hand side and each preconditioned residual are projected onto zero mean.
//! MIC(0) is Bridson's `M = (E + L) E^-1 (E + L)^T`, compensation `tau`, pivot floor
//! `0.25 A_ii`, in lexicographic order (x fastest).
//!
//! On the interior faces `D = -G^T`, so the projection `u - G A^+ (-D u)` is symmetric and its
//! backward is one more projection of the cotangent (with the same tolerance); the projection
//! itself lives in [`super::box_pressure`], shared with the Cholesky solver. The recursive CG
//! residual is exactly the divergence left behind: `||D P u||_2 <= rel_tol ||D u||_2`.

use super::box_pressure::{make_incompressible_box, project_box_slice, BoxSolver};
use super::field::MacField3d;
use super::walls::WallGeom;
use super::{CavityWalls, Grid3d};
use crate::pressure::cg::{dot, pcg, remove_mean};
use crate::pressure::{CgPreconditioner, CgSettings, CgStats};
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use std::sync::Arc;

/// The pivot floor of MIC(0), as a fraction of the diagonal (as in 2D).
const PIVOT_FLOOR: f64 = 0.25;

/// The Neumann pressure solve of a closed 3D box by preconditioned CG; build once, share.
#[derive(Debug)]
pub struct CgBox3d {
    grid: Grid3d,
    settings: CgSettings,
    /// `1 / h^2` per axis.
    w: [f64; 3],
    diag: Vec<f64>,
    inv_pivot: Vec<f64>,
}

impl CgBox3d {
    /// Sets up the matrix diagonal and the preconditioner for `grid`.
    pub fn new(grid: Grid3d, settings: CgSettings) -> Result<Arc<Self>> {
        grid.validate()?;
        settings.validate("1e-8")?;
        let w = grid.spacing().map(|h| 1.0 / (h * h));
        let mut s = Self { grid, settings, w, diag: Vec::new(), inv_pivot: Vec::new() };
        let geo = s.geo();
        s.diag = (0..grid.cells())
            .map(|m| {
                let p = geo.pos(m);
                (0..3).map(|a| w[a] * ((p[a] > 0) as usize + (p[a] + 1 < geo.n[a] as isize) as usize) as f64).sum()
            })
            .collect();
        s.inv_pivot = s.pivots();
        Ok(Arc::new(s))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The settings.
    pub fn settings(&self) -> &CgSettings {
        &self.settings
    }

    fn geo(&self) -> WallGeom {
        WallGeom::new(&self.grid, &CavityWalls { lid_velocity: 0.0 })
    }

    /// Flat strides of the axes.
    fn strides(&self) -> [usize; 3] {
        [1, self.grid.nx, self.grid.nx * self.grid.ny]
    }

    fn pivots(&self) -> Vec<f64> {
        let (geo, st, n) = (self.geo(), self.strides(), self.grid.cells());
        let tau = match self.settings.preconditioner {
            CgPreconditioner::Jacobi => return self.diag.iter().map(|d| 1.0 / d).collect(),
            CgPreconditioner::Mic0 { tau } => tau,
        };
        // Upper off-diagonal row sums `sum_{k > m} A_mk`.
        let upper_sum: Vec<f64> = (0..n)
            .map(|m| {
                let p = geo.pos(m);
                -(0..3).filter(|&a| p[a] + 1 < geo.n[a] as isize).map(|a| self.w[a]).sum::<f64>()
            })
            .collect();
        let mut inv = vec![0.0; n];
        for m in 0..n {
            let p = geo.pos(m);
            let mut e = self.diag[m];
            for a in (0..3).filter(|&a| p[a] > 0) {
                let (j, v) = (m - st[a], -self.w[a]);
                e -= v * v * inv[j];
                e -= tau * v * (upper_sum[j] - v) * inv[j];
            }
            if e < PIVOT_FLOOR * self.diag[m] {
                e = self.diag[m];
            }
            inv[m] = 1.0 / e;
        }
        inv
    }

    fn matvec(&self, x: &[f64], y: &mut [f64]) {
        let (geo, st) = (self.geo(), self.strides());
        for (m, ym) in y.iter_mut().enumerate() {
            let p = geo.pos(m);
            let mut s = self.diag[m] * x[m];
            for a in 0..3 {
                if p[a] > 0 {
                    s -= self.w[a] * x[m - st[a]];
                }
                if p[a] + 1 < geo.n[a] as isize {
                    s -= self.w[a] * x[m + st[a]];
                }
            }
            *ym = s;
        }
    }

    fn precondition(&self, r: &[f64], z: &mut [f64]) {
        let (geo, st) = (self.geo(), self.strides());
        match self.settings.preconditioner {
            CgPreconditioner::Jacobi => {
                for ((zi, ri), d) in z.iter_mut().zip(r).zip(&self.inv_pivot) {
                    *zi = ri * d;
                }
            }
            CgPreconditioner::Mic0 { .. } => {
                // (E + L) y = r, then (E + L)^T z = E y.
                for m in 0..z.len() {
                    let p = geo.pos(m);
                    let mut s = r[m];
                    for a in (0..3).filter(|&a| p[a] > 0) {
                        s += self.w[a] * z[m - st[a]];
                    }
                    z[m] = s * self.inv_pivot[m];
                }
                for m in (0..z.len()).rev() {
                    let p = geo.pos(m);
                    let mut s = 0.0;
                    for a in (0..3).filter(|&a| p[a] + 1 < geo.n[a] as isize) {
                        s += self.w[a] * z[m + st[a]];
                    }
                    z[m] += s * self.inv_pivot[m];
                }
            }
        }
        remove_mean(z);
    }

    /// `x = A^+ b` from a zero start (`b`'s mean is removed first; `x` has zero mean).
    /// Non-convergence within `max_iter` is an [`Error::Solver`] naming the residual reached.
    pub fn solve(&self, b: &mut [f64], x: &mut [f64]) -> Result<CgStats> {
        x.fill(0.0);
        self.solve_from(b, x)
    }

    /// [`Self::solve`] from the start `x` (warm start: the previous pressure).
    pub fn solve_from(&self, b: &mut [f64], x: &mut [f64]) -> Result<CgStats> {
        let n = self.grid.cells();
        if b.len() != n || x.len() != n {
            return Err(Error::Shape {
                op: "CgBox3d::solve",
                arg: "b/x",
                expected: format!("{n} values each (nz * ny * nx)"),
                got: vec![b.len(), x.len()],
            });
        }
        remove_mean(b);
        let bnorm = dot(b, b).sqrt();
        if bnorm == 0.0 {
            x.fill(0.0);
            return Ok(CgStats { iterations: 0, rel_residual: 0.0 });
        }
        let stats = pcg(b, x, bnorm, &self.settings, |v, out| self.matvec(v, out), |r, z| self.precondition(r, z))
            .map_err(|(it, rel, hint)| self.not_converged(it, rel, hint))?;
        remove_mean(x);
        Ok(stats)
    }

    fn not_converged(&self, iterations: usize, rel: f64, hint: &str) -> Error {
        Error::Solver {
            solver: "grid3d box pressure cg",
            reason: format!(
                "not converged after {iterations} iterations: relative residual {rel:.3e} > rel_tol {:.1e}; {hint}",
                self.settings.rel_tol
            ),
        }
    }

    /// The projection of [`make_incompressible_walls`] with a warm start (forward only,
    /// computed in f64, returned in `u`'s dtype): `pressure` is the start, `batch * cells`
    /// values (resized to zeros when it has another length), and receives the pressures.
    /// Returns the largest iteration count and residual over the batch.
    pub fn project(&self, u: &MacField3d, pressure: &mut Vec<f64>) -> Result<(MacField3d, CgStats)> {
        if u.grid() != &self.grid {
            return Err(Error::Invalid {
                field: "solver",
                reason: format!("built for {:?}, the field lives on {:?}", self.grid, u.grid()),
            });
        }
        let n = self.grid.cells();
        if pressure.len() != u.batch() * n {
            *pressure = vec![0.0; u.batch() * n];
        }
        let mut w: Vec<f64> = u.values().to_dtype(DType::F64)?.flatten_all()?.to_vec1()?;
        let mut worst = CgStats { iterations: 0, rel_residual: 0.0 };
        for (ub, p) in w.chunks_mut(3 * n).zip(pressure.chunks_mut(n)) {
            project_box_slice(&self.grid, ub, p, |b, x| {
                let st = self.solve_from(b, x)?;
                worst.iterations = worst.iterations.max(st.iterations);
                worst.rel_residual = worst.rel_residual.max(st.rel_residual);
                Ok(())
            })?;
        }
        let t = Tensor::from_vec(w, u.values().shape(), u.values().device())?.to_dtype(u.values().dtype())?;
        Ok((MacField3d::from_parts(t, self.grid), worst))
    }
}

/// Projects `u` in the closed box onto discretely divergence-free fields with zero normal
/// velocity on the walls (wall faces set to 0), by CG. Differentiable (the backward is the same
/// projection of the cotangent). Non-convergence of CG is an error. The same as
/// [`make_incompressible_box`] with [`BoxSolver::Cg`].
pub fn make_incompressible_walls(u: &MacField3d, solver: &Arc<CgBox3d>) -> Result<MacField3d> {
    make_incompressible_box(u, &BoxSolver::Cg(solver.clone()))
}
