//! Pressure projection on the periodic 3D MAC grid: `P u = u - G L^+ D u` with `L = D G`
//! solved by FFT ([`PoissonFft3d`]).
//!
//! Because `D = -G^T` on a periodic grid, `G L^+ D = G (G^T G)^+ G^T` is symmetric and `P` is an
//! orthogonal projector: its adjoint is itself, so the backward of the projection is one more
//! projection (of the cotangent).

use super::fft::FftPoisson3d;
use super::field::{check_values, MacField3d};
use super::momentum::check_shape;
use super::periodic::{self, inv_spacing, Periodic};
use super::Grid3d;
use crate::float::with_concrete;
use crate::scratch::zeros;
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// A planned periodic Poisson solver (f32 and f64 plans) for one [`Grid3d`]; build once, share.
pub struct PoissonFft3d {
    grid: Grid3d,
    f32: FftPoisson3d<f32>,
    f64: FftPoisson3d<f64>,
}

impl std::fmt::Debug for PoissonFft3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoissonFft3d").field("grid", &self.grid).finish()
    }
}

impl PoissonFft3d {
    /// Plans the transforms for `grid`.
    pub fn new(grid: Grid3d) -> Result<Arc<Self>> {
        grid.validate()?;
        Ok(Arc::new(Self { grid, f32: FftPoisson3d::new(&grid), f64: FftPoisson3d::new(&grid) }))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// `out = L^+ rhs` for one `nz x ny x nx` slice, in the slice's float type.
    pub(crate) fn solve_slice<T: Real>(&self, rhs: &[T], out: &mut [T]) {
        with_concrete(rhs, out, |r, o| self.f32.solve(r, o), |r, o| self.f64.solve(r, o));
    }

    fn check(&self, grid: &Grid3d) -> Result<()> {
        if grid != &self.grid {
            return Err(Error::Invalid {
                field: "solver",
                reason: format!(
                    "planned for {:?}, the field lives on {grid:?}; build it with PoissonFft3d::new(grid)",
                    self.grid
                ),
            });
        }
        Ok(())
    }
}

/// Projects `u` onto discretely divergence-free fields (`D P u = 0` to round-off). Differentiable:
/// the backward is the same projection.
pub fn make_incompressible(u: &MacField3d, solver: &Arc<PoissonFft3d>) -> Result<MacField3d> {
    solver.check(u.grid())?;
    let op = Projection3d { solver: solver.clone() };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// `L^+ b` for a cell-centred `b` (`[batch, 1, nz, ny, nx]`; the mean is dropped, the result has
/// zero mean). Differentiable: `L^+` is symmetric, so the backward is the same solve.
pub fn solve_poisson(b: &Tensor, solver: &Arc<PoissonFft3d>) -> Result<Tensor> {
    check_values("grid3d::solve_poisson", "b", b, &solver.grid, Some(1))?;
    Ok(apply1(b, PoissonSolve3d(solver.clone()))?)
}

#[derive(Clone)]
struct PoissonSolve3d(Arc<PoissonFft3d>);

impl Kernel1 for PoissonSolve3d {
    fn name(&self) -> &'static str {
        "grid3d_poisson_solve"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let n = self.0.grid.cells();
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(n)) {
            self.0.solve_slice(xb, ob);
        }
        Ok(())
    }
}

impl Op1 for PoissonSolve3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply1(gy, self.clone())
    }
}

/// The projection as a custom op (self-adjoint).
#[derive(Clone)]
pub(crate) struct Projection3d {
    pub solver: Arc<PoissonFft3d>,
}

impl Projection3d {
    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, self.clone())
    }

    /// `out = P x` for one sample of 3 components, in place on `out` after copying.
    fn project_slice<T: Real>(&self, p: &Periodic, x: &[T], out: &mut [T]) {
        let g = &self.solver.grid;
        let n = p.cells();
        let ih = inv_spacing::<T>(g);
        let mut div = zeros::<T>(n);
        let mut phi = zeros::<T>(n);
        let mut grad = zeros::<T>(3 * n);
        periodic::divergence(p, x, ih, &mut div);
        self.solver.solve_slice(&div, &mut phi);
        periodic::gradient(p, &phi, ih, &mut grad);
        for ((o, &a), &b) in out.iter_mut().zip(x).zip(grad.iter()) {
            *o = a - b;
        }
    }
}

impl Kernel1 for Projection3d {
    fn name(&self) -> &'static str {
        "grid3d_make_incompressible"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_shape(self.name(), s, &self.solver.grid)?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let p = Periodic::new(&self.solver.grid);
        let n = p.cells();
        for (xb, ob) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)) {
            self.project_slice(&p, xb, ob);
        }
        Ok(())
    }
}

impl Op1 for Projection3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        // P is symmetric: the vector-Jacobian product is P gy (itself differentiable).
        self.apply(gy)
    }
}

impl crate::time_stepping::fused::ProjectionKernel for Projection3d {
    const COMBINE_NAME: &'static str = "grid3d_combine_project";

    /// `P` is symmetric: its adjoint is itself.
    fn adjoint(&self, g: &Tensor) -> candle_core::Result<Tensor> {
        self.apply(g)
    }
}
