//! The pressure solver: FFT for periodic domains, sparse Cholesky otherwise; built once.

use super::cholesky::CholeskyPoisson;
use super::fft::FftPoisson;
use crate::boundary::{Boundaries, ScalarBoundaries};
use crate::fd::dims4;
use crate::field::CenteredField;
use crate::float::with_concrete;
use crate::{Error, Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

enum Method {
    Fft { f32: FftPoisson<f32>, f64: FftPoisson<f64> },
    Cholesky(CholeskyPoisson),
}

/// Solves `L p = b` (pseudo-inverse where `L` is singular) for one grid and set of pressure
/// conditions. Build it once (the factorisation or FFT plan is the expensive part) and share it
/// (`Arc`) between steps and between the forward and the adjoint.
pub struct PressureSolver {
    grid: Grid,
    bc: ScalarBoundaries,
    method: Method,
}

impl std::fmt::Debug for PressureSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PressureSolver").field("grid", &self.grid).field("method", &self.method_name()).finish()
    }
}

impl PressureSolver {
    /// The solver for the pressure of a velocity with boundaries `bc`: FFT when fully periodic,
    /// sparse Cholesky otherwise.
    pub fn new(grid: Grid, bc: &Boundaries) -> Result<Arc<Self>> {
        bc.validate()?;
        Self::for_scalar(grid, &bc.pressure(), false)
    }

    /// The solver for `L` with the given scalar conditions; `force_cholesky` skips the FFT path
    /// (to cross-check the two).
    pub fn for_scalar(grid: Grid, bc: &ScalarBoundaries, force_cholesky: bool) -> Result<Arc<Self>> {
        grid.validate()?;
        bc.validate()?;
        if let Some((face, b)) =
            bc.faces().into_iter().find(|(_, b)| matches!(b, crate::ScalarBc::Dirichlet { value } if *value != 0.0))
        {
            return Err(Error::Boundary {
                face,
                reason: format!("pressure solves take homogeneous conditions; got {b:?}"),
            });
        }
        let method = if bc.is_periodic() && !force_cholesky {
            Method::Fft { f32: FftPoisson::new(&grid), f64: FftPoisson::new(&grid) }
        } else {
            Method::Cholesky(CholeskyPoisson::new(&grid, &bc.ghosts(grid.nx, grid.ny), !bc.has_dirichlet())?)
        };
        Ok(Arc::new(Self { grid, bc: *bc, method }))
    }

    /// `"fft"` or `"sparse_cholesky"`.
    pub fn method_name(&self) -> &'static str {
        match self.method {
            Method::Fft { .. } => "fft",
            Method::Cholesky(_) => "sparse_cholesky",
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The pressure conditions.
    pub fn bc(&self) -> &ScalarBoundaries {
        &self.bc
    }

    /// `out = L^+ rhs` for one `ny x nx` slice.
    pub(crate) fn solve_slice<T: Real>(&self, rhs: &[T], out: &mut [T]) {
        match &self.method {
            Method::Fft { f32, f64 } => with_concrete(rhs, out, |r, o| f32.solve(r, o), |r, o| f64.solve(r, o)),
            Method::Cholesky(c) => {
                let mut b: Vec<f64> = rhs.iter().map(|&x| <T as candle_core::WithDType>::to_f64(x)).collect();
                c.solve(&mut b);
                for (o, x) in out.iter_mut().zip(b) {
                    *o = T::c(x);
                }
            }
        }
    }
}

/// `L^+ b` for every channel of `b`, differentiable: the adjoint of the solve is the same solve
/// (`L` is symmetric). `b` must live on the solver's grid.
pub fn solve_poisson(b: &CenteredField, solver: &Arc<PressureSolver>) -> Result<CenteredField> {
    if b.grid() != solver.grid() {
        return Err(Error::Invalid { field: "solver", reason: "the solver was built for another grid".into() });
    }
    let p = apply1(b.values(), PoissonSolve(solver.clone()))?;
    Ok(CenteredField::from_parts(p, *b.grid(), *solver.bc()))
}

#[derive(Clone)]
struct PoissonSolve(Arc<PressureSolver>);

impl Kernel1 for PoissonSolve {
    fn name(&self) -> &'static str {
        "poisson_solve"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let _ = dims4(s)?;
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

impl Op1 for PoissonSolve {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, self.clone())
    }
}
