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
use crate::scratch::zeros;
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, Kernel1, Kernel3, Op1, Op3};
use pbdl_core::Real;
use std::any::TypeId;
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
        if TypeId::of::<T>() == TypeId::of::<f32>() {
            // SAFETY: T is f32 (checked by TypeId): same size and layout.
            let (r, o) = unsafe { (cast::<T, f32>(rhs), cast_mut::<T, f32>(out)) };
            self.f32.solve(r, o);
        } else if TypeId::of::<T>() == TypeId::of::<f64>() {
            // SAFETY: T is f64 (checked by TypeId).
            let (r, o) = unsafe { (cast::<T, f64>(rhs), cast_mut::<T, f64>(out)) };
            self.f64.solve(r, o);
        } else {
            unreachable!("Real is implemented for f32 and f64 only");
        }
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

/// Reinterprets a slice of `T` as `U`. Caller guarantees `T == U`.
unsafe fn cast<T: 'static, U: 'static>(x: &[T]) -> &[U] {
    debug_assert_eq!(TypeId::of::<T>(), TypeId::of::<U>());
    // SAFETY: the caller guarantees T and U are the same type.
    unsafe { std::slice::from_raw_parts(x.as_ptr() as *const U, x.len()) }
}

/// Mutable variant of [`cast`].
unsafe fn cast_mut<T: 'static, U: 'static>(x: &mut [T]) -> &mut [U] {
    debug_assert_eq!(TypeId::of::<T>(), TypeId::of::<U>());
    // SAFETY: the caller guarantees T and U are the same type.
    unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr() as *mut U, x.len()) }
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

/// `P(a + w1 b + w2 c)` (or without `P`) in one op: a Runge-Kutta stage update and its
/// projection without intermediate tensors. Backward: `h = P g`, gradients `(h, w1 h, w2 h)`.
#[derive(Clone)]
pub(crate) struct CombineProject3d {
    pub w: [f64; 2],
    pub projection: Option<Projection3d>,
}

impl Kernel3 for CombineProject3d {
    fn name(&self) -> &'static str {
        "grid3d_combine_project"
    }
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape> {
        if a != b || a != c {
            candle_core::bail!("{}: shapes differ: {a:?} {b:?} {c:?}", self.name());
        }
        Ok(a.clone())
    }
    fn forward<T: Real>(
        &self,
        a: &[T],
        s: &Shape,
        b: &[T],
        _bs: &Shape,
        c: &[T],
        _cs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let (w1, w2) = (T::c(self.w[0]), T::c(self.w[1]));
        let comb = |o: &mut [T]| {
            for ((o, &x), (&y, &z)) in o.iter_mut().zip(a).zip(b.iter().zip(c)) {
                *o = x + w1 * y + w2 * z;
            }
        };
        match &self.projection {
            None => comb(out),
            Some(p) => {
                let mut tmp = zeros::<T>(a.len());
                comb(&mut tmp);
                p.forward(&tmp, s, out)?;
            }
        }
        Ok(())
    }
}

impl Op3 for CombineProject3d {
    fn backward(
        &self,
        _a: &Tensor,
        _b: &Tensor,
        _c: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let h = match &self.projection {
            Some(p) => p.apply(gy)?,
            None => gy.clone(),
        };
        Ok((h.clone(), h.affine(self.w[0], 0.0)?, h.affine(self.w[1], 0.0)?))
    }
}
