//! The pressure projection of the closed box ([`super::walls`]) with a choice of solver: the
//! factor-once sparse Cholesky ([`CholeskyBox3d`]) or MIC(0)/IC(0)/Jacobi conjugate gradients
//! ([`CgBox3d`]), both on `A = -D G`, the seven-point Neumann Laplacian.
//!
//! The projection is `P u = u - G A^+ (-D u)` after the wall faces are set to 0. On the interior
//! faces `D = -G^T`, so `P` is symmetric: its backward is one more projection of the cotangent,
//! i.e. one adjoint solve with the same (symmetric) matrix, never unrolled iterations.
//!
//! Which solver is the default ([`BoxPressure::default`]) was decided by measurement
//! (`benches/pressure3d.rs`, one projection of a walled box at 32^3 and 64^3, CG at relative
//! tolerance 1e-6): see [`BoxPressure`] for the numbers.

use super::cg::CgBox3d;
use super::cholesky::CholeskyBox3d;
use super::field::MacField3d;
use super::momentum::check_shape;
use super::walls::{unit, WallGeom};
use super::{CavityWalls, Grid3d};
use crate::pressure::CgSettings;
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// Which solver the closed-box projection uses (a choice of the [`super::Cavity3d`] stepper).
///
/// Default: [`BoxPressure::Auto`]: the Cholesky factor up to [`AUTO_CHOLESKY_CELLS`] (32^3)
/// cells, CG (default settings) above. Cholesky is the faster per projection in
/// `benches/pressure3d.rs` (criterion medians of one projection of a closed unit cube, f64 input unless noted; CG is
/// MIC(0), tau 0.97, rel_tol 1e-6; measured on a 2-core machine under load ~5 from other
/// builds, so take +-30%):
///
/// | box | Cholesky | CG cold (iterations) | CG warm (iterations) | factor time, size |
/// |---|---|---|---|---|
/// | 32^3 | 31.7 ms | 44.2 ms (33) | 42.1 ms (25) | 1.4 s, 10.1 M entries (77 MiB), AMD |
/// | 64^3 | 639 ms; 256 ms with f32 input | 772 ms (61); 788 ms f32 | 532 ms (43) | 40 s, 197 M entries (1.5 GiB), nested dissection |
///
/// The f32 and f64 Cholesky rows run the same f64 solve, so their 2.5x spread at 64^3 is the
/// machine load; the stepper uses CG cold, which the factor beats at both sizes. The price is the
/// set-up: at 64^3 the 40 s factorisation pays for itself only after roughly 75-300 projections
/// (20-75 RK4 steps), and the factor's 1.5 GiB grows with fill-in (entries per cell about
/// linear in the box edge: 309 at 32^3, 750 at 64^3), so a 128^3 factor (~23 GiB) is refused
/// ([`super::cholesky::MAX_FACTOR_BYTES`]). Hence `Auto`: at 64^3 one projection costs about
/// the same either way (639 ms vs 532-772 ms), so the 40 s and 1.5 GiB set-up is not worth it by
/// default; at 32^3 the factor costs 1.4 s and saves ~30% per projection.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum BoxPressure {
    /// Cholesky up to [`AUTO_CHOLESKY_CELLS`] cells, CG with default settings above.
    #[default]
    Auto,
    /// Sparse Cholesky factor (faer, nested-dissection order), factored once at build time; each
    /// projection is one forward and one backward substitution, exact to round-off.
    Cholesky,
    /// Preconditioned conjugate gradients with these settings (zero start each projection).
    Cg(CgSettings),
}

impl From<CgSettings> for BoxPressure {
    fn from(s: CgSettings) -> Self {
        Self::Cg(s)
    }
}

/// Largest box (cells) for which [`BoxPressure::Auto`] factors the matrix (32^3).
pub const AUTO_CHOLESKY_CELLS: usize = 32 * 32 * 32;

impl BoxPressure {
    /// Builds the solver for `grid` (the factorisation, or CG's preconditioner).
    pub fn build(&self, grid: Grid3d) -> Result<BoxSolver> {
        Ok(match self {
            Self::Auto if grid.cells() <= AUTO_CHOLESKY_CELLS => BoxSolver::Cholesky(CholeskyBox3d::new(grid)?),
            Self::Auto => BoxSolver::Cg(CgBox3d::new(grid, CgSettings::default())?),
            Self::Cholesky => BoxSolver::Cholesky(CholeskyBox3d::new(grid)?),
            Self::Cg(s) => BoxSolver::Cg(CgBox3d::new(grid, *s)?),
        })
    }
}

/// A built closed-box pressure solver; cheap to clone (shared).
#[derive(Clone, Debug)]
pub enum BoxSolver {
    /// The factored matrix.
    Cholesky(Arc<CholeskyBox3d>),
    /// Conjugate gradients.
    Cg(Arc<CgBox3d>),
}

impl BoxSolver {
    /// The grid it was built for.
    pub fn grid(&self) -> &Grid3d {
        match self {
            Self::Cholesky(c) => c.grid(),
            Self::Cg(c) => c.grid(),
        }
    }

    /// The operator name listed by [`super::Cavity3d::operators`].
    pub fn operator_name(&self) -> &'static str {
        match self {
            Self::Cholesky(_) => "grid3d.pressure.sparse_cholesky",
            Self::Cg(c) => match c.settings().preconditioner {
                crate::pressure::CgPreconditioner::Jacobi => "grid3d.pressure.jacobi_cg",
                crate::pressure::CgPreconditioner::Mic0 { .. } => "grid3d.pressure.mic0_cg",
            },
        }
    }

    /// `x = A^+ b` (mean of `b` removed, `x` zero mean); CG starts from zero.
    pub fn solve(&self, b: &mut [f64], x: &mut [f64]) -> Result<()> {
        match self {
            Self::Cholesky(c) => c.solve(b, x),
            Self::Cg(c) => c.solve(b, x).map(|_| ()),
        }
    }

    fn check(&self, grid: &Grid3d) -> Result<()> {
        if grid != self.grid() {
            return Err(Error::Invalid {
                field: "solver",
                reason: format!(
                    "built for {:?}, the field lives on {grid:?}; build it for the field's grid",
                    self.grid()
                ),
            });
        }
        Ok(())
    }
}

/// Projects one `[3, nz, ny, nx]` f64 slice in place: wall faces to 0, `b = -D u`, `p = A^+ b`
/// by `solve(b, p)` (`p` holds the start for a warm-started solver and receives the pressure),
/// then `u -= G p`.
pub(crate) fn project_box_slice<S>(grid: &Grid3d, u: &mut [f64], p: &mut [f64], solve: S) -> Result<()>
where
    S: FnOnce(&mut [f64], &mut [f64]) -> Result<()>,
{
    let geo = WallGeom::new(grid, &CavityWalls { lid_velocity: 0.0 });
    let n = geo.cells();
    let st = [1, grid.nx, grid.nx * grid.ny];
    let ih = grid.spacing().map(|h| 1.0 / h);
    for c in 0..3 {
        for m in 0..n {
            if geo.is_wall_face(c, geo.pos(m)) {
                u[c * n + m] = 0.0;
            }
        }
    }
    let mut b = vec![0.0; n];
    for (m, bm) in b.iter_mut().enumerate() {
        let pos = geo.pos(m);
        let mut div = 0.0;
        for a in 0..3 {
            let back = if pos[a] > 0 { u[a * n + m - st[a]] } else { 0.0 };
            div += (u[a * n + m] - back) * ih[a];
        }
        *bm = -div;
    }
    solve(&mut b, p)?;
    for a in 0..3 {
        let e = unit(a);
        for m in 0..n {
            let pos = geo.pos(m);
            if !geo.is_wall_face(a, pos) {
                let up = m + st[a];
                debug_assert_eq!(geo.pos(up)[a], pos[a] + e[a]);
                u[a * n + m] -= (p[up] - p[m]) * ih[a];
            }
        }
    }
    Ok(())
}

/// Projects `u` in the closed box onto discretely divergence-free fields with zero normal
/// velocity on the walls (wall faces set to 0), with either solver. Differentiable: the backward
/// is the same projection of the cotangent (one adjoint solve). CG non-convergence is an error.
pub fn make_incompressible_box(u: &MacField3d, solver: &BoxSolver) -> Result<MacField3d> {
    solver.check(u.grid())?;
    let op = WallProjection { solver: solver.clone() };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// The walled projection as a custom op (computed in f64, returned in the input's dtype).
#[derive(Clone)]
pub(crate) struct WallProjection {
    pub solver: BoxSolver,
}

impl WallProjection {
    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, self.clone())
    }

    /// The one code path of the projection: per `[3, nz, ny, nx]` sample `b` of `x`, in f64,
    /// wall faces to 0, `rhs = -D u`, the pressure `p` from `pressure(b, rhs, p)` (a solve, or a
    /// given pressure copied in), `u -= G p`; written to `out` in `T`. The differentiable
    /// projection, [`Self::forward_keep_pressure`] and [`Self::correct`] all run this, so they
    /// agree to the bit.
    pub(crate) fn forward_with<T: Real>(
        &self,
        x: &[T],
        out: &mut [T],
        mut pressure: impl FnMut(usize, &mut [f64], &mut [f64]) -> Result<()>,
    ) -> Result<()> {
        let grid = *self.solver.grid();
        let n = grid.cells();
        let (mut w, mut p) = (vec![0.0f64; 3 * n], vec![0.0f64; n]);
        for (b, (xb, ob)) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)).enumerate() {
            for (a, &v) in w.iter_mut().zip(xb) {
                *a = <T as candle_core::WithDType>::to_f64(v);
            }
            project_box_slice(&grid, &mut w, &mut p, |rhs, p| pressure(b, rhs, p))?;
            for (o, &a) in ob.iter_mut().zip(&w) {
                *o = T::c(a);
            }
        }
        Ok(())
    }

    /// The projection of `[B, 3, nz, ny, nx]` values that also writes each sample's pressure
    /// (`[nz, ny, nx]` per sample, rounded to `T`) into `pressure` (not differentiable; the
    /// pressure split of a step).
    pub(crate) fn forward_keep_pressure<T: Real>(&self, x: &[T], out: &mut [T], pressure: &mut [T]) -> Result<()> {
        let n = self.solver.grid().cells();
        self.forward_with(x, out, |b, rhs, p| {
            self.solver.solve(rhs, p)?;
            for (o, &v) in pressure[b * n..(b + 1) * n].iter_mut().zip(p.iter()) {
                *o = T::c(v);
            }
            Ok(())
        })
    }

    /// The velocity correction with a given pressure (`[nz, ny, nx]` per sample) instead of a
    /// solve: wall faces to 0, `u -= G p` (not differentiable).
    pub(crate) fn correct<T: Real>(&self, x: &[T], pressure: &[T], out: &mut [T]) -> Result<()> {
        let n = self.solver.grid().cells();
        self.forward_with(x, out, |b, _, p| {
            for (d, &v) in p.iter_mut().zip(&pressure[b * n..(b + 1) * n]) {
                *d = <T as candle_core::WithDType>::to_f64(v);
            }
            Ok(())
        })
    }
}

impl Kernel1 for WallProjection {
    fn name(&self) -> &'static str {
        "grid3d_make_incompressible_walls"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_shape(self.name(), s, self.solver.grid())?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        Ok(self.forward_with(x, out, |_, rhs, p| self.solver.solve(rhs, p))?)
    }
}

impl Op1 for WallProjection {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        // Symmetric on the interior faces, zero on the wall faces in and out: P^T = P.
        self.apply(gy)
    }
}
