//! Projection with obstacles: the Laplacian restricted to fluid cells, factored once (faer
//! sparse Cholesky), and a projection that zeroes the normal velocity on every face touching a
//! solid cell.
//!
//! With `m` the open-face mask and `F` the overwrite of the stored boundary faces that a wall or
//! an inflow fixes, the projection is `u -> w - m G p`, `w = m F u`, `p = L_m^+ D w` on fluid
//! cells (`L_m = D m G` there, symmetric). Its vector-Jacobian product is
//! `F m (g - D^T L_m^+ G^T (m g))`: one adjoint solve with the same factor.

use super::project::Faces;
use crate::boundary::{Boundaries, Ghosts, MacGhosts};
use crate::field::MacField;
use crate::laplacian_matrix::{unknown_index, Excluded, Factored, Laplacian, NOT_UNKNOWN};
use crate::obstacle::ObstacleMask;
use crate::{Error, Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// The pressure solve of a domain with obstacles: built once per grid, boundaries and mask.
pub struct MaskedPressureSolver {
    grid: Grid,
    bc: Boundaries,
    mac: MacGhosts,
    p: Ghosts,
    /// Unknown index of each cell, [`NOT_UNKNOWN`] for solid cells.
    index: Vec<usize>,
    fluid: usize,
    mu: Vec<f64>,
    mv: Vec<f64>,
    /// `-L_m` on the fluid cells, factored (first fluid cell pinned when singular).
    poisson: Factored,
    /// The constant part `c = b - m G L_m^+ D b` of the projection when closed faces carry
    /// prescribed velocities `b` ([`MaskedPressureSolver::with_prescribed_faces`]), `[2, ny, nx]`.
    prescribed: Option<Vec<f64>>,
}

impl std::fmt::Debug for MaskedPressureSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MaskedPressureSolver").field("grid", &self.grid).field("fluid_cells", &self.fluid).finish()
    }
}

impl MaskedPressureSolver {
    /// Assembles `-L_m` over the fluid cells of `mask` and factors it. A domain without an
    /// outflow face has a singular `L_m` (constants); the first fluid cell is then pinned and
    /// solves return the zero-mean (pseudo-inverse) solution. Fluid regions cut off from each
    /// other make the factorisation fail (typed [`Error::Solver`]).
    pub fn new(grid: Grid, bc: &Boundaries, mask: &ObstacleMask) -> Result<Arc<Self>> {
        grid.validate()?;
        bc.validate()?;
        if mask.grid() != &grid {
            return Err(Error::Invalid { field: "obstacles", reason: "the mask was built for another grid".into() });
        }
        let (nx, ny) = (grid.nx, grid.ny);
        let pbc = bc.pressure();
        let g = pbc.ghosts(nx, ny);
        let pinned = !pbc.has_dirichlet();
        let (index, fluid) = unknown_index(nx * ny, |k| !mask.is_solid(k / nx, k % nx));
        let spec = Laplacian {
            grid: &grid,
            ghosts: g,
            index: &index,
            excluded: Excluded::ClosedFace,
            scale: 1.0,
            shift: 0.0,
            pin_first: pinned,
        };
        let hint = "; is the fluid region connected and, with an outflow, connected to it?";
        let poisson = Factored::new(&spec, true, "masked pressure cholesky", hint)?;
        let (mu, mv) = mask.face_masks(bc);
        Ok(Arc::new(Self {
            grid,
            bc: *bc,
            mac: bc.mac_ghosts(nx, ny),
            p: g,
            index,
            fluid,
            mu,
            mv,
            poisson,
            prescribed: None,
        }))
    }

    /// The same solve, with prescribed velocities on closed faces (e.g. an inflow profile on the
    /// faces between a solid buffer column and the fluid). `values` (`[2, ny, nx]` layout, `u`
    /// then `v`) gives the velocity of every closed face (faces touching a solid cell); values on
    /// open faces must be 0. The projection becomes affine,
    /// `u -> P_m u + c`, `c = b - m G L_m^+ D b`: the prescribed faces keep `b`, and their flux
    /// enters the divergence of the neighbouring fluid cells, so the result is divergence-free
    /// in the fluid with the prescribed flux. The vector-Jacobian product is that of `P_m`.
    pub fn with_prescribed_faces(
        grid: Grid,
        bc: &Boundaries,
        mask: &ObstacleMask,
        values: &[f64],
    ) -> Result<Arc<Self>> {
        let base = Self::new(grid, bc, mask)?;
        let n = grid.cells();
        if values.len() != 2 * n || values.iter().any(|v| !v.is_finite()) {
            return Err(Error::Invalid {
                field: "prescribed",
                reason: format!("needs {} finite face values ([2, ny, nx]), got {}", 2 * n, values.len()),
            });
        }
        let (mu, mv) = (&base.mu, &base.mv);
        if let Some(k) = (0..2 * n).find(|&k| values[k] != 0.0 && if k < n { mu[k] } else { mv[k - n] } != 0.0) {
            return Err(Error::Invalid {
                field: "prescribed",
                reason: format!(
                    "face {k} is open (not next to a solid cell); only closed faces take prescribed values"
                ),
            });
        }
        // Open the prescribed faces for the divergence, project b, and put b back on them.
        let mut mu2 = mu.clone();
        let mut mv2 = mv.clone();
        for k in 0..2 * n {
            if values[k] != 0.0 {
                if k < n {
                    mu2[k] = 1.0;
                } else {
                    mv2[k - n] = 1.0;
                }
            }
        }
        let faces = Faces { grid: &base.grid, mac: &base.mac, p: &base.p, open: Some((&mu2, &mv2)) };
        let mut c = vec![0.0; 2 * n];
        faces.forward(values, &mut c, |r, o| base.solve_slice(r, o));
        for k in 0..2 * n {
            if values[k] != 0.0 {
                c[k] = values[k];
            }
        }
        let mut s =
            Arc::try_unwrap(base).map_err(|_| Error::Invalid { field: "prescribed", reason: "shared".into() })?;
        s.prescribed = Some(c);
        Ok(Arc::new(s))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The velocity boundaries it was built for.
    pub fn bc(&self) -> &Boundaries {
        &self.bc
    }

    /// Number of fluid cells (unknowns).
    pub fn fluid_cells(&self) -> usize {
        self.fluid
    }

    /// `out = L_m^+ rhs` on fluid cells, 0 in solid cells.
    fn solve_slice<T: Real>(&self, rhs: &[T], out: &mut [T]) {
        let mut b = vec![0.0; self.fluid];
        for (k, &ix) in self.index.iter().enumerate() {
            if ix != NOT_UNKNOWN {
                b[ix] = rhs[k].to_f64();
            }
        }
        self.poisson.solve(&mut b);
        for (k, &ix) in self.index.iter().enumerate() {
            out[k] = if ix == NOT_UNKNOWN { T::zero() } else { T::c(b[ix]) };
        }
    }

    fn faces(&self) -> Faces<'_> {
        Faces { grid: &self.grid, mac: &self.mac, p: &self.p, open: Some((&self.mu, &self.mv)) }
    }
}

/// Removes the divergent part of `u` in the fluid and zeroes the normal velocity on every face
/// that touches an obstacle. Differentiable; the backward is one adjoint solve with the same
/// factor.
pub fn make_incompressible_masked(u: &MacField, solver: &Arc<MaskedPressureSolver>) -> Result<MacField> {
    if u.grid() != solver.grid() || u.bc() != solver.bc() {
        return Err(Error::Invalid {
            field: "solver",
            reason: "the masked pressure solver was built for another grid or other boundaries".into(),
        });
    }
    Ok(MacField::from_parts(MaskedProjection(solver.clone()).apply(u.values())?, *u.grid(), *u.bc()))
}

/// `s` if it is a MAC velocity shape `[batch, 2, ny, nx]` on `grid`, else an error naming `op`.
pub(crate) fn check_mac_shape(op: &str, s: &Shape, grid: &Grid) -> candle_core::Result<Shape> {
    let (_, c, ny, nx) = s.dims4()?;
    if (c, ny, nx) != (2, grid.ny, grid.nx) {
        candle_core::bail!("{op}: {s:?} is not a MAC velocity on the solver's grid");
    }
    Ok(s.clone())
}

/// The masked projection as a custom op.
#[derive(Clone)]
pub(crate) struct MaskedProjection(pub Arc<MaskedPressureSolver>);

impl MaskedProjection {
    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, self.clone())
    }

    /// The projection of `[B, 2, ny, nx]` values that also writes the pressure `[B, ny, nx]`
    /// (not differentiable; the pressure split of a step).
    pub(crate) fn project_keep_pressure<T: Real>(&self, x: &[T], out: &mut [T], pressure: &mut [T]) {
        let s = &*self.0;
        s.faces().forward_keep_pressure(x, out, pressure, |r, o| s.solve_slice(r, o));
        self.add_prescribed(out);
    }

    /// The correction `m F x - m G p (+ c)` with a given pressure `[B, ny, nx]` (not
    /// differentiable).
    pub(crate) fn correct<T: Real>(&self, x: &[T], pressure: &[T], out: &mut [T]) {
        self.0.faces().correct(x, pressure, out);
        self.add_prescribed(out);
    }

    fn add_prescribed<T: Real>(&self, out: &mut [T]) {
        if let Some(c) = &self.0.prescribed {
            for ob in out.chunks_mut(c.len()) {
                for (o, &ci) in ob.iter_mut().zip(c) {
                    *o += T::c(ci);
                }
            }
        }
    }
}

impl Kernel1 for MaskedProjection {
    fn name(&self) -> &'static str {
        "make_incompressible_masked"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_mac_shape(self.name(), s, &self.0.grid)
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let s = &*self.0;
        s.faces().forward(x, out, |r, o| s.solve_slice(r, o));
        self.add_prescribed(out);
        Ok(())
    }
}

impl Op1 for MaskedProjection {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, MaskedProjectionAdjoint(self.clone()))
    }
}

struct MaskedProjectionAdjoint(MaskedProjection);

impl Kernel1 for MaskedProjectionAdjoint {
    fn name(&self) -> &'static str {
        "make_incompressible_masked_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let s = &*self.0 .0;
        s.faces().adjoint(g, out, |r, o| s.solve_slice(r, o));
        Ok(())
    }
}
