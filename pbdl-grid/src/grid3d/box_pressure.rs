//! The pressure projection of the closed box ([`super::walls`]) with a choice of solver: the
//! factor-once sparse Cholesky ([`CholeskyBox3d`]) or MIC(0)/IC(0)/Jacobi conjugate gradients
//! ([`CgBox3d`]), both on `A = -D G`, the seven-point Neumann Laplacian.
//!
//! The projection is `P u = u - G A^+ (-D u)` after the wall faces are set to 0. On the interior
//! faces `D = -G^T`, so `P` is symmetric: its backward is one more projection of the cotangent,
//! i.e. one adjoint solve with the same (symmetric) matrix, never unrolled iterations.
//!
//! [`BoxTopology`] generalises the box: periodic pairs, outflow faces (Dirichlet `p = 0`), solid
//! cells (left out: Neumann on their faces) and fixed inflow faces; the sparse Cholesky factor
//! assembles those ([`CholeskyBox3d::with_topology`]), CG keeps the closed box.
//!
//! Which solver is the default ([`BoxPressure::default`]) was decided by measurement
//! (`benches/pressure3d.rs`, one projection of a walled box at 32^3 and 64^3, CG at relative
//! tolerance 1e-6): see [`BoxPressure`] for the numbers.

use super::cg::CgBox3d;
use super::cholesky::CholeskyBox3d;
use super::field::MacField3d;
use super::momentum::check_shape;
use super::walls::{unit, WallGeom, Walls3d};
use super::Grid3d;
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

    /// Builds the solver for `grid` and `topology`. The closed box (no-slip or free-slip walls:
    /// the same matrix) is [`Self::build`]; periodic pairs, open faces and solid cells change
    /// the matrix, which only the Cholesky factor assembles so far: CG (asked for, or `Auto`
    /// above 32^3) is then an [`Error::Invalid`] naming `pressure`.
    pub fn build_for(&self, grid: Grid3d, topology: &BoxTopology) -> Result<BoxSolver> {
        topology.validate(&grid)?;
        if topology.is_plain() {
            // Free-slip walls change the velocity's ghosts, not the projection.
            return self.build(grid);
        }
        match self {
            Self::Cg(_) => Err(Error::Invalid {
                field: "pressure",
                reason: "periodic, open (outflow) faces and obstacles are assembled by the sparse Cholesky factor \
                         only; use BoxPressure::Cholesky or Auto"
                    .into(),
            }),
            Self::Auto if grid.cells() > AUTO_CHOLESKY_CELLS => Err(Error::Invalid {
                field: "pressure",
                reason: format!(
                    "periodic, open (outflow) faces and obstacles are assembled by the sparse Cholesky factor only, \
                     which Auto uses up to {AUTO_CHOLESKY_CELLS} cells ({} here); ask for BoxPressure::Cholesky \
                     explicitly or use a smaller grid",
                    grid.cells()
                ),
            }),
            _ => Ok(BoxSolver::Cholesky(CholeskyBox3d::with_topology(grid, topology.clone())?)),
        }
    }
}

/// What the walled projection sees of the box: the per-face conditions (periodic pairs wrap,
/// [`super::walls::Face3d::Outflow`] faces are Dirichlet `p = 0`, every other face a wall) and
/// the solid cells (left out of the solve; every velocity face touching one is 0).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BoxTopology {
    /// Per-face conditions.
    pub faces: Walls3d,
    /// Solid cells, one flag per cell (flat `(k ny + j) nx + i`); `None`: none.
    pub solid: Option<Arc<Vec<bool>>>,
    /// Faces held at a given velocity (flat index `c n + m` of the stored component, value):
    /// an inflow patch's faces, each between a solid (inflow) cell and a fluid one. They are
    /// blocked (no pressure correction) and written after the blocked faces are zeroed, so the
    /// fluid cell next to one sees the inflow in its divergence. `None`: none.
    pub fixed: Option<Arc<Vec<(usize, f64)>>>,
}

impl BoxTopology {
    /// Whether the matrix is the closed box's (no periodic pair, no open face, no solid).
    pub fn is_plain(&self) -> bool {
        self.solid.is_none()
            && self.fixed.is_none()
            && (0..3).all(|a| !self.faces.periodic(a) && !self.faces.open_hi(a))
    }

    /// Whether cell `m` takes part in the solve.
    #[inline(always)]
    pub fn fluid(&self, m: usize) -> bool {
        self.solid.as_ref().is_none_or(|s| !s[m])
    }

    /// Checks the faces against `grid` and the solid mask's length; at least one fluid cell.
    pub fn validate(&self, grid: &Grid3d) -> Result<()> {
        self.faces.validate(grid)?;
        if let Some(s) = &self.solid {
            if s.len() != grid.cells() {
                return Err(Error::Invalid {
                    field: "obstacles",
                    reason: format!("solid mask of {} cells on a grid of {}", s.len(), grid.cells()),
                });
            }
            if s.iter().all(|&x| x) {
                return Err(Error::Invalid { field: "obstacles", reason: "every cell is solid".into() });
            }
        }
        Ok(())
    }

    /// Whether velocity component `c` at stored face `m` is held at 0: a wall face, or a face
    /// of a solid cell (either of the two cells it separates).
    #[inline(always)]
    pub(crate) fn blocked(&self, geo: &WallGeom, c: usize, m: usize) -> bool {
        if geo.is_wall_face(c, geo.pos(m)) {
            return true;
        }
        match &self.solid {
            None => false,
            Some(s) => s[m] || geo.neighbour(m, c, true).is_some_and(|up| s[up]),
        }
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

    /// The topology it was built for (CG: the closed box).
    pub fn topology(&self) -> BoxTopology {
        match self {
            Self::Cholesky(c) => c.topology().clone(),
            Self::Cg(_) => BoxTopology::default(),
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
    project_topology_slice(grid, &BoxTopology::default(), u, p, false, solve)
}

/// [`project_box_slice`] on a [`BoxTopology`]: blocked faces (walls, faces of solid cells) to
/// 0, the fixed faces to their values (to 0 when `homogeneous`: the linear part, for the
/// backward), `b = -D u` over the fluid cells (solid cells get 0), the solve, then `u -= G p`
/// on the free faces, with `p = 0` beyond an open face.
pub(crate) fn project_topology_slice<S>(
    grid: &Grid3d,
    topo: &BoxTopology,
    u: &mut [f64],
    p: &mut [f64],
    homogeneous: bool,
    solve: S,
) -> Result<()>
where
    S: FnOnce(&mut [f64], &mut [f64]) -> Result<()>,
{
    let geo = WallGeom::with_faces(grid, topo.faces);
    let n = geo.cells();
    let ih = grid.spacing().map(|h| 1.0 / h);
    for c in 0..3 {
        for m in 0..n {
            if topo.blocked(&geo, c, m) {
                u[c * n + m] = 0.0;
            }
        }
    }
    if let (Some(fixed), false) = (&topo.fixed, homogeneous) {
        for &(f, v) in fixed.iter() {
            u[f] = v;
        }
    }
    let mut b = vec![0.0; n];
    for (m, bm) in b.iter_mut().enumerate() {
        if !topo.fluid(m) {
            continue;
        }
        let mut div = 0.0;
        for a in 0..3 {
            let back = match geo.neighbour(m, a, false) {
                Some(lo) => u[a * n + lo],
                None => 0.0,
            };
            div += (u[a * n + m] - back) * ih[a];
        }
        *bm = -div;
    }
    solve(&mut b, p)?;
    for a in 0..3 {
        let e = unit(a);
        for m in 0..n {
            if topo.blocked(&geo, a, m) {
                continue;
            }
            let pu = match geo.neighbour(m, a, true) {
                Some(up) => {
                    debug_assert!(topo.faces.periodic(a) || geo.pos(up)[a] == geo.pos(m)[a] + e[a]);
                    p[up]
                }
                None => 0.0, // an open face: the ghost pressure is 0
            };
            u[a * n + m] -= (pu - p[m]) * ih[a];
        }
    }
    Ok(())
}

/// Projects `u` in the closed box onto discretely divergence-free fields with zero normal
/// velocity on the walls (wall faces set to 0), with either solver. Differentiable: the backward
/// is the same projection of the cotangent (one adjoint solve). CG non-convergence is an error.
pub fn make_incompressible_box(u: &MacField3d, solver: &BoxSolver) -> Result<MacField3d> {
    solver.check(u.grid())?;
    let op = WallProjection { solver: solver.clone(), homogeneous: false };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// The walled projection as a custom op (computed in f64, returned in the input's dtype).
#[derive(Clone)]
pub(crate) struct WallProjection {
    pub solver: BoxSolver,
    /// Fixed (inflow) faces written as 0 instead of their values: the linear part of the affine
    /// projection, which is its backward.
    pub homogeneous: bool,
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
        let topo = self.solver.topology();
        let n = grid.cells();
        let (mut w, mut p) = (vec![0.0f64; 3 * n], vec![0.0f64; n]);
        for (b, (xb, ob)) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)).enumerate() {
            for (a, &v) in w.iter_mut().zip(xb) {
                *a = <T as candle_core::WithDType>::to_f64(v);
            }
            project_topology_slice(&grid, &topo, &mut w, &mut p, self.homogeneous, |rhs, p| pressure(b, rhs, p))?;
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
        // Symmetric on the interior faces, zero on the wall faces in and out: P^T = P (with
        // fixed inflow faces P is affine; its linear part writes them as 0).
        WallProjection { solver: self.solver.clone(), homogeneous: true }.apply(gy)
    }
}
