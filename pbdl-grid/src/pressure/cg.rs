//! Preconditioned conjugate gradients for the masked pressure Poisson system: the alternative to
//! the sparse Cholesky factor of [`super::MaskedPressureSolver`], on the very same matrix.
//!
//! The matrix is `A = -L_m` over the fluid cells, assembled by the shared
//! [`Laplacian`](crate::laplacian_matrix::Laplacian) (closed faces at obstacles, pressure ghost
//! rules at the domain edges), symmetric positive semi-definite. Without a Dirichlet face it is
//! singular (constants): the right-hand side and every preconditioned residual are projected onto
//! zero mean and the returned solution has zero mean, which is the pseudo-inverse solution the
//! Cholesky path returns.
//!
//! Preconditioners: Jacobi, or the modified incomplete Cholesky MIC(0) of Bridson's fluid
//! notes, `M = (E + L) E^-1 (E + L)^T` with `L` the strict lower part of `A` and `E` diagonal;
//! `tau = 0` gives plain IC(0), `tau = 1` full row-sum compensation. A pivot below
//! `sigma * A_ii` (`sigma = 0.25`) falls back to `A_ii`, which keeps `M` positive definite.
//!
//! `A` is symmetric, so the adjoint of a solve is the same solve: the gradient of the CG-based
//! projection [`make_incompressible_masked_cg`] is one more CG solve, never unrolled iterations.

use super::masked::check_mac_shape;
use super::project::set_fixed;
use crate::boundary::{Boundaries, Ghosts, MacGhosts};
use crate::fd::{div_padded, div_padded_adjoint, grad_padded, grad_padded_adjoint};
use crate::field::MacField;
use crate::laplacian_matrix::{unknown_index, Excluded, Laplacian, NOT_UNKNOWN};
use crate::obstacle::ObstacleMask;
use crate::pad::{pad, pad_adjoint};
use crate::{Error, Grid, Result};
use candle_core::{DType, Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// The pivot floor of MIC(0), as a fraction of the diagonal (Bridson's `sigma`).
const PIVOT_FLOOR: f64 = 0.25;

/// Which preconditioner the conjugate gradients use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CgPreconditioner {
    /// Diagonal scaling.
    Jacobi,
    /// Modified incomplete Cholesky with compensation `tau` in `[0, 1]` (0: IC(0); 0.97 is the
    /// usual choice for MAC pressure).
    Mic0 {
        /// Fraction of the dropped fill moved onto the diagonal.
        tau: f64,
    },
}

/// Settings of [`CgPressureSolver`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CgSettings {
    /// Stop when `||b - A x||_2 <= rel_tol * ||b||_2` (`b` after mean removal when singular).
    pub rel_tol: f64,
    /// Give up (typed error) after this many iterations.
    pub max_iter: usize,
    /// The preconditioner.
    pub preconditioner: CgPreconditioner,
}

impl Default for CgSettings {
    /// `rel_tol = 1e-6`, `max_iter = 2000`, MIC(0) with `tau = 0.97`.
    fn default() -> Self {
        Self { rel_tol: 1e-6, max_iter: 2000, preconditioner: CgPreconditioner::Mic0 { tau: 0.97 } }
    }
}

impl CgSettings {
    /// Checks the settings (2D and 3D solvers); `suggested_tol` goes into the `rel_tol` message.
    pub(crate) fn validate(&self, suggested_tol: &str) -> Result<()> {
        if !(self.rel_tol > 0.0 && self.rel_tol < 1.0) {
            return Err(Error::Invalid {
                field: "rel_tol",
                reason: format!("{} is not in (0, 1); use e.g. {suggested_tol}", self.rel_tol),
            });
        }
        if self.max_iter == 0 {
            return Err(Error::Invalid { field: "max_iter", reason: "0 iterations; use e.g. 2000".into() });
        }
        if let CgPreconditioner::Mic0 { tau } = self.preconditioner {
            if !(0.0..=1.0).contains(&tau) {
                return Err(Error::Invalid { field: "tau", reason: format!("{tau} is not in [0, 1]; use 0.97") });
            }
        }
        Ok(())
    }
}

/// What one solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CgStats {
    /// Conjugate-gradient iterations (0 when the start already met the tolerance).
    pub iterations: usize,
    /// `||b - A x||_2 / ||b||_2` at the end (the recursively updated residual).
    pub rel_residual: f64,
}

/// The masked pressure solve by preconditioned conjugate gradients: built once per grid,
/// boundaries and mask (assembly and preconditioner set-up are cheap next to a factorisation).
pub struct CgPressureSolver {
    grid: Grid,
    bc: Boundaries,
    mac: MacGhosts,
    p: Ghosts,
    index: Vec<usize>,
    mu: Vec<f64>,
    mv: Vec<f64>,
    singular: bool,
    settings: CgSettings,
    /// `A = -L_m`: its diagonal and its strict lower / upper rows (compressed).
    diag: Vec<f64>,
    lower: Rows,
    upper: Rows,
    /// Jacobi: `1 / A_ii`; MIC(0): `1 / E_ii`.
    inv_pivot: Vec<f64>,
}

impl std::fmt::Debug for CgPressureSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CgPressureSolver")
            .field("grid", &self.grid)
            .field("fluid_cells", &self.fluid_cells())
            .field("settings", &self.settings)
            .finish()
    }
}

impl CgPressureSolver {
    /// Assembles `-L_m` over the fluid cells of `mask` (the matrix the Cholesky path factors)
    /// and sets up the preconditioner.
    pub fn new(grid: Grid, bc: &Boundaries, mask: &ObstacleMask, settings: CgSettings) -> Result<Self> {
        grid.validate()?;
        bc.validate()?;
        if mask.grid() != &grid {
            return Err(Error::Invalid { field: "obstacles", reason: "the mask was built for another grid".into() });
        }
        settings.validate("1e-6")?;
        let (nx, ny) = (grid.nx, grid.ny);
        let pbc = bc.pressure();
        let g = pbc.ghosts(nx, ny);
        let singular = !pbc.has_dirichlet();
        let (index, fluid) = unknown_index(nx * ny, |k| !mask.is_solid(k / nx, k % nx));
        let spec = Laplacian {
            grid: &grid,
            ghosts: g,
            index: &index,
            excluded: Excluded::ClosedFace,
            scale: 1.0,
            shift: 0.0,
            pin_first: false,
        };
        let mat = spec.assemble("masked pressure cg")?;
        // Symmetric: column i holds row i. Split it once so the loops below run over plain slices.
        let (mut diag, mut lower, mut upper) = (vec![0.0; fluid], Rows::new(fluid), Rows::new(fluid));
        for (i, d) in diag.iter_mut().enumerate() {
            for (k, &v) in mat.row_idx_of_col(i).zip(mat.val_of_col(i)) {
                match k.cmp(&i) {
                    std::cmp::Ordering::Less => lower.push(k, v),
                    std::cmp::Ordering::Equal => *d += v,
                    std::cmp::Ordering::Greater => upper.push(k, v),
                }
            }
            lower.end_row();
            upper.end_row();
        }
        let mut s = Self {
            grid,
            bc: *bc,
            mac: bc.mac_ghosts(nx, ny),
            p: g,
            index,
            mu: Vec::new(),
            mv: Vec::new(),
            singular,
            settings,
            diag,
            lower,
            upper,
            inv_pivot: Vec::new(),
        };
        s.inv_pivot = s.pivots()?;
        (s.mu, s.mv) = mask.face_masks(bc);
        Ok(s)
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The velocity boundaries it was built for.
    pub fn bc(&self) -> &Boundaries {
        &self.bc
    }

    /// The settings.
    pub fn settings(&self) -> &CgSettings {
        &self.settings
    }

    /// Number of fluid cells (unknowns).
    pub fn fluid_cells(&self) -> usize {
        self.diag.len()
    }

    /// Inverse pivots of the preconditioner.
    fn pivots(&self) -> Result<Vec<f64>> {
        let n = self.fluid_cells();
        let diag = &self.diag;
        if let Some(i) = diag.iter().position(|&d| d <= 0.0) {
            return Err(Error::Solver {
                solver: "masked pressure cg",
                reason: format!("fluid cell {i} has no open face; remove isolated fluid cells from the mask"),
            });
        }
        let tau = match self.settings.preconditioner {
            CgPreconditioner::Jacobi => return Ok(diag.iter().map(|d| 1.0 / d).collect()),
            CgPreconditioner::Mic0 { tau } => tau,
        };
        // Upper off-diagonal row sums `sum_{k>j} A_jk`, for the dropped-fill compensation.
        let upper_sum: Vec<f64> = (0..n).map(|j| self.upper.row(j).1.iter().sum()).collect();
        let mut inv = vec![0.0; n];
        for i in 0..n {
            let mut e = diag[i];
            let (cols, vals) = self.lower.row(i);
            for (&j, &a) in cols.iter().zip(vals) {
                // IC(0) term, then the fill (i, k) of eliminating j that the pattern drops.
                e -= a * a * inv[j];
                e -= tau * a * (upper_sum[j] - a) * inv[j];
            }
            if e < PIVOT_FLOOR * diag[i] {
                e = diag[i];
            }
            inv[i] = 1.0 / e;
        }
        Ok(inv)
    }

    fn matvec(&self, x: &[f64], y: &mut [f64]) {
        for (i, yi) in y.iter_mut().enumerate() {
            *yi = self.diag[i] * x[i] + self.lower.dot(i, x) + self.upper.dot(i, x);
        }
    }

    fn precondition(&self, r: &[f64], z: &mut [f64]) {
        match self.settings.preconditioner {
            CgPreconditioner::Jacobi => {
                for ((zi, ri), d) in z.iter_mut().zip(r).zip(&self.inv_pivot) {
                    *zi = ri * d;
                }
            }
            CgPreconditioner::Mic0 { .. } => {
                // (E + L) y = r, then (E + L)^T z = E y.
                let n = z.len();
                for i in 0..n {
                    z[i] = (r[i] - self.lower.dot(i, z)) * self.inv_pivot[i];
                }
                for i in (0..n).rev() {
                    z[i] -= self.upper.dot(i, z) * self.inv_pivot[i];
                }
            }
        }
        if self.singular {
            remove_mean(z);
        }
    }

    /// Solves `A x = b` on the unknowns; `x` holds the start and receives the solution.
    fn solve_unknowns(&self, b: &mut [f64], x: &mut [f64]) -> Result<CgStats> {
        if self.singular {
            remove_mean(b);
            remove_mean(x);
        }
        let bnorm = dot(b, b).sqrt();
        if bnorm == 0.0 {
            x.fill(0.0);
            return Ok(CgStats { iterations: 0, rel_residual: 0.0 });
        }
        let stats = pcg(b, x, bnorm, &self.settings, |v, out| self.matvec(v, out), |r, z| self.precondition(r, z))
            .map_err(|(it, rel, hint)| self.not_converged(it, rel, hint))?;
        if self.singular && stats.iterations > 0 {
            remove_mean(x);
        }
        Ok(stats)
    }

    fn not_converged(&self, iterations: usize, rel: f64, hint: &str) -> Error {
        Error::Solver {
            solver: "masked pressure cg",
            reason: format!(
                "not converged after {iterations} iterations: relative residual {rel:.3e} > rel_tol {:.1e}; {hint}",
                self.settings.rel_tol
            ),
        }
    }

    /// `x = L_m^+ rhs` on one `ny x nx` slice (solid cells ignored in `rhs`, 0 in `x`). `x` is
    /// also the start (warm start: pass the previous pressure; cold: zeros). Non-convergence
    /// within `max_iter` is an [`Error::Solver`] that names the residual reached.
    pub fn solve(&self, rhs: &[f64], x: &mut [f64]) -> Result<CgStats> {
        let cells = self.grid.cells();
        if rhs.len() != cells || x.len() != cells {
            return Err(Error::Shape {
                op: "CgPressureSolver::solve",
                arg: "rhs/x",
                expected: format!("{cells} values each (ny * nx)"),
                got: vec![rhs.len(), x.len()],
            });
        }
        let n = self.fluid_cells();
        // The Poisson matrix is -L: solve A p = -rhs.
        let (mut b, mut p) = (vec![0.0; n], vec![0.0; n]);
        for (k, &ix) in self.index.iter().enumerate() {
            if ix != NOT_UNKNOWN {
                b[ix] = -rhs[k];
                p[ix] = x[k];
            }
        }
        let stats = self.solve_unknowns(&mut b, &mut p)?;
        for (k, &ix) in self.index.iter().enumerate() {
            x[k] = if ix == NOT_UNKNOWN { 0.0 } else { p[ix] };
        }
        Ok(stats)
    }

    /// The masked projection of [`super::make_incompressible_masked`] with the pressure solved by
    /// CG (forward only, computed in f64, returned in `u`'s dtype). `pressure` is the warm start,
    /// `batch * ny * nx` values (resized to zeros when it has another length), and receives the
    /// pressures. Returns the largest iteration count and residual over the batch.
    pub fn project(&self, u: &MacField, pressure: &mut Vec<f64>) -> Result<(MacField, CgStats)> {
        if u.grid() != &self.grid || u.bc() != &self.bc {
            return Err(Error::Invalid {
                field: "solver",
                reason: "the CG pressure solver was built for another grid or other boundaries".into(),
            });
        }
        let n = self.grid.cells();
        let batch = u.batch();
        if pressure.len() != batch * n {
            *pressure = vec![0.0; batch * n];
        }
        let mut w: Vec<f64> = u.values().to_dtype(DType::F64)?.flatten_all()?.to_vec1()?;
        let mut worst = CgStats { iterations: 0, rel_residual: 0.0 };
        for (ob, p) in w.chunks_mut(2 * n).zip(pressure.chunks_mut(n)) {
            let st = self.project_slice(ob, p)?;
            worst.iterations = worst.iterations.max(st.iterations);
            worst.rel_residual = worst.rel_residual.max(st.rel_residual);
        }
        let t = Tensor::from_vec(w, u.values().shape(), u.values().device())?.to_dtype(u.values().dtype())?;
        Ok((MacField::from_parts(t, self.grid, self.bc), worst))
    }

    fn fixed(&self) -> (bool, bool) {
        (self.mac.u_fixed.is_some(), self.mac.v_fixed.is_some())
    }

    /// Projects one `[2, ny, nx]` slice in place; `p` is the start and receives the pressure.
    fn project_slice(&self, ob: &mut [f64], p: &mut [f64]) -> Result<CgStats> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        let (idx, idy) = (1.0 / self.grid.dx(), 1.0 / self.grid.dy());
        let (mut a, mut b, mut c) = (vec![0.0; pn], vec![0.0; pn], vec![0.0; pn]);
        let (mut div, mut g) = (vec![0.0; n], vec![0.0; 2 * n]);
        set_fixed(ob, nx, ny, self.mac.u_fixed, self.mac.v_fixed);
        self.mask(ob);
        pad(&ob[..n], nx, ny, &self.mac.u, true, &mut a);
        pad(&ob[n..], nx, ny, &self.mac.v, true, &mut b);
        div_padded(&a, &b, nx, ny, idx, idy, &mut div);
        let st = self.solve(&div, p)?;
        pad(p, nx, ny, &self.p, true, &mut c);
        let (gu, gv) = g.split_at_mut(n);
        grad_padded(&c, nx, ny, idx, idy, self.fixed(), gu, gv);
        self.mask(&mut g);
        for (o, gg) in ob.iter_mut().zip(&g) {
            *o -= gg;
        }
        Ok(st)
    }

    /// The vector-Jacobian product of [`Self::project_slice`] for one cotangent slice
    /// `gb`: `F m (g - D^T L_m^+ G^T (m g))`, one CG solve (from zero).
    fn project_adjoint_slice(&self, gb: &[f64], ob: &mut [f64]) -> Result<CgStats> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        let (idx, idy) = (1.0 / self.grid.dx(), 1.0 / self.grid.dy());
        let (mut a, mut b, mut c) = (vec![0.0; pn], vec![0.0; pn], vec![0.0; pn]);
        let (mut d, mut p) = (vec![0.0; n], vec![0.0; n]);
        let mut h = gb.to_vec();
        self.mask(&mut h);
        grad_padded_adjoint(&h[..n], &h[n..], nx, ny, idx, idy, self.fixed(), &mut c);
        pad_adjoint(&mut c, nx, ny, &self.p, &mut d);
        let st = self.solve(&d, &mut p)?;
        div_padded_adjoint(&p, nx, ny, idx, idy, &mut a, &mut b);
        let (ou, ov) = ob.split_at_mut(n);
        ou.fill(0.0);
        ov.fill(0.0);
        pad_adjoint(&mut a, nx, ny, &self.mac.u, ou);
        pad_adjoint(&mut b, nx, ny, &self.mac.v, ov);
        for (o, &gv) in ob.iter_mut().zip(gb) {
            *o = gv - *o;
        }
        self.mask(ob);
        set_fixed(ob, nx, ny, self.mac.u_fixed.and(Some(0.0)), self.mac.v_fixed.and(Some(0.0)));
        Ok(st)
    }

    /// Zeroes the closed faces of a `[2, ny, nx]` slice.
    fn mask(&self, x: &mut [f64]) {
        let (xu, xv) = x.split_at_mut(self.grid.cells());
        for (e, &m) in xu.iter_mut().zip(&self.mu).chain(xv.iter_mut().zip(&self.mv)) {
            if m == 0.0 {
                *e = 0.0;
            }
        }
    }
}

/// Compressed rows: `ptr[i]..ptr[i + 1]` indexes row `i`'s columns and values.
struct Rows {
    ptr: Vec<usize>,
    col: Vec<usize>,
    val: Vec<f64>,
}

impl Rows {
    fn new(rows: usize) -> Self {
        let mut ptr = Vec::with_capacity(rows + 1);
        ptr.push(0);
        Self { ptr, col: Vec::with_capacity(2 * rows), val: Vec::with_capacity(2 * rows) }
    }

    fn push(&mut self, col: usize, val: f64) {
        self.col.push(col);
        self.val.push(val);
    }

    fn end_row(&mut self) {
        self.ptr.push(self.col.len());
    }

    fn row(&self, i: usize) -> (&[usize], &[f64]) {
        let r = self.ptr[i]..self.ptr[i + 1];
        (&self.col[r.clone()], &self.val[r])
    }

    /// Row `i` times `x`.
    fn dot(&self, i: usize, x: &[f64]) -> f64 {
        let (cols, vals) = self.row(i);
        let mut s = 0.0;
        for (&c, &v) in cols.iter().zip(vals) {
            s += v * x[c];
        }
        s
    }
}

/// [`CgPressureSolver::project`] as a differentiable op (cold start, pressure discarded): the
/// backward is one CG solve of the adjoint system, to the same `rel_tol`. Non-convergence is a
/// candle error carrying the solver's message.
pub fn make_incompressible_masked_cg(u: &MacField, solver: &Arc<CgPressureSolver>) -> Result<MacField> {
    if u.grid() != solver.grid() || u.bc() != solver.bc() {
        return Err(Error::Invalid {
            field: "solver",
            reason: "the CG pressure solver was built for another grid or other boundaries".into(),
        });
    }
    let y = apply1(u.values(), CgProjection(solver.clone()))?;
    Ok(MacField::from_parts(y, *u.grid(), *u.bc()))
}

#[derive(Clone)]
struct CgProjection(Arc<CgPressureSolver>);

/// Runs `f` on f64 copies of each `[2, ny, nx]` slice of `x`, writing `out`.
fn per_slice<T: Real>(
    s: &CgPressureSolver,
    x: &[T],
    out: &mut [T],
    f: impl Fn(&[f64], &mut [f64]) -> Result<CgStats>,
) -> candle_core::Result<()> {
    let n2 = 2 * s.grid.cells();
    let mut o = vec![0.0; n2];
    for (xb, ob) in x.chunks(n2).zip(out.chunks_mut(n2)) {
        let xf: Vec<f64> = xb.iter().map(|&v| <T as candle_core::WithDType>::to_f64(v)).collect();
        f(&xf, &mut o).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        for (a, &b) in ob.iter_mut().zip(&o) {
            *a = T::c(b);
        }
    }
    Ok(())
}

impl Kernel1 for CgProjection {
    fn name(&self) -> &'static str {
        "make_incompressible_masked_cg"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_mac_shape(self.name(), s, &self.0.grid)
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let s = &*self.0;
        per_slice(s, x, out, |xf, o| {
            o.copy_from_slice(xf);
            s.project_slice(o, &mut vec![0.0; s.grid.cells()])
        })
    }
}

impl Op1 for CgProjection {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, CgProjectionAdjoint(self.0.clone()))
    }
}

struct CgProjectionAdjoint(Arc<CgPressureSolver>);

impl Kernel1 for CgProjectionAdjoint {
    fn name(&self) -> &'static str {
        "make_incompressible_masked_cg_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let s = &*self.0;
        per_slice(s, g, out, |gf, o| s.project_adjoint_slice(gf, o))
    }
}

/// Preconditioned conjugate gradients for `A x = b` from the start `x` (2D and 3D share it):
/// stops when `|b - A x| <= rel_tol * bnorm`. On failure gives (iterations, relative residual,
/// hint) for the caller's typed error.
pub(crate) fn pcg(
    b: &[f64],
    x: &mut [f64],
    bnorm: f64,
    settings: &CgSettings,
    matvec: impl Fn(&[f64], &mut [f64]),
    precondition: impl Fn(&[f64], &mut [f64]),
) -> std::result::Result<CgStats, (usize, f64, &'static str)> {
    let n = b.len();
    let target = settings.rel_tol * bnorm;
    let (mut z, mut q) = (vec![0.0; n], vec![0.0; n]);
    // r = b - A x (the start); a start already within the tolerance costs no iteration.
    matvec(x, &mut q);
    let mut r: Vec<f64> = b.iter().zip(&q).map(|(b, q)| b - q).collect();
    let mut rnorm = dot(&r, &r).sqrt();
    if rnorm <= target {
        return Ok(CgStats { iterations: 0, rel_residual: rnorm / bnorm });
    }
    precondition(&r, &mut z);
    let mut d = z.clone();
    let mut rz = dot(&r, &z);
    for it in 1..=settings.max_iter {
        matvec(&d, &mut q);
        let dq = dot(&d, &q);
        if !(dq > 0.0 && rz.is_finite()) {
            return Err((it, rnorm / bnorm, "the search direction lost positive curvature"));
        }
        let alpha = rz / dq;
        for ((xi, ri), (di, qi)) in x.iter_mut().zip(r.iter_mut()).zip(d.iter().zip(&q)) {
            *xi += alpha * di;
            *ri -= alpha * qi;
        }
        rnorm = dot(&r, &r).sqrt();
        if rnorm <= target {
            return Ok(CgStats { iterations: it, rel_residual: rnorm / bnorm });
        }
        precondition(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for (di, zi) in d.iter_mut().zip(&z) {
            *di = zi + beta * *di;
        }
    }
    Err((settings.max_iter, rnorm / bnorm, "raise max_iter or loosen rel_tol"))
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

pub(crate) fn remove_mean(x: &mut [f64]) {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter_mut().for_each(|v| *v -= m);
}
