//! Implicit (backward Euler) diffusion: `(I - nu dt L) q1 = q0`, factored once (faer sparse
//! Cholesky) and reused; unconditionally stable, first order in time.
//!
//! `L` is the five-point Laplacian with the field's ghost rules (walls, inflow, Dirichlet values
//! enter as constants on the right-hand side); stored MAC boundary faces that a wall or an
//! inflow fixes are not unknowns and keep their value. The matrix is symmetric positive
//! definite, so the vector-Jacobian product is the same solve: `g -> (I - nu dt L)^-1 g`.

use crate::advect::{Advected, Layout, Loc};
use crate::boundary::Ghosts;
use crate::laplacian_matrix::{unknown_index, Excluded, Factored, Laplacian, NOT_UNKNOWN};
use crate::pad::pad;
use crate::{Error, Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// One factored system: a ghost rule set and the cells it keeps fixed.
struct System {
    /// Fixed value per cell (`None`: unknown).
    fixed: Vec<Option<f64>>,
    /// Unknown index per cell ([`NOT_UNKNOWN`] when fixed).
    index: Vec<usize>,
    free: usize,
    /// `I - alpha L` on the free cells, factored.
    factor: Factored,
    /// `alpha L(z)` on the free cells, `z` = 0 plus the fixed values: the affine part.
    constant: Vec<f64>,
}

/// Backward-Euler diffusion of a field of one layout (a centred scalar with given boundaries,
/// or a MAC velocity with given boundaries), factored once for `nu dt`.
#[derive(Clone)]
pub struct ImplicitDiffusion {
    grid: Grid,
    alpha: f64,
    /// System of each channel.
    chans: Arc<Vec<Arc<System>>>,
}

impl std::fmt::Debug for ImplicitDiffusion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImplicitDiffusion").field("grid", &self.grid).field("nu_dt", &self.alpha).finish()
    }
}

impl ImplicitDiffusion {
    /// Factors `I - nu dt L` for fields shaped like `like` (its grid, boundaries and channels).
    pub fn new<F: Advected>(like: &F, nu: f64, dt: f64) -> Result<Self> {
        if !(nu >= 0.0 && nu.is_finite()) {
            return Err(Error::Invalid { field: "nu", reason: format!("viscosity must be finite and >= 0, got {nu}") });
        }
        if !(dt > 0.0 && dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("time step must be positive and finite, got {dt}"),
            });
        }
        let grid = *like.advected_grid();
        let layout = like.advection_layout();
        let alpha = nu * dt;
        let mut built: Vec<(Ghosts, Option<bool>, Arc<System>)> = Vec::new();
        let mut chans = Vec::new();
        for &(loc, gh) in &layout.chans {
            let key = fixed_kind(&layout, loc);
            let sys = match built.iter().find(|(g, k, _)| *g == gh && *k == key) {
                Some((_, _, s)) => s.clone(),
                None => {
                    let s = Arc::new(System::new(&grid, gh, fixed_cells(&grid, &layout, key), alpha)?);
                    built.push((gh, key, s.clone()));
                    s
                }
            };
            chans.push(sys);
        }
        Ok(Self { grid, alpha, chans: Arc::new(chans) })
    }

    /// One backward-Euler step of `q` (same layout as the field this was built for).
    pub fn apply<F: Advected>(&self, q: &F) -> Result<F> {
        let d = q.advected_values().dims();
        if q.advected_grid() != &self.grid || d[1] != self.chans.len() {
            return Err(Error::Shape {
                op: "diffuse::implicit",
                arg: "q",
                expected: format!("{} channels on {:?}", self.chans.len(), self.grid),
                got: d.to_vec(),
            });
        }
        Ok(q.with_advected(apply1(q.advected_values(), Solve1 { op: self.clone(), adjoint: false })?))
    }

    /// `nu dt`.
    pub fn nu_dt(&self) -> f64 {
        self.alpha
    }
}

/// One backward-Euler diffusion step (factors the matrix on every call; build an
/// [`ImplicitDiffusion`] to reuse it). No time-step limit.
pub fn implicit<F: Advected>(q: &F, nu: f64, dt: f64) -> Result<F> {
    ImplicitDiffusion::new(q, nu, dt)?.apply(q)
}

/// `Some(true)`: the u column at `x = lx` is fixed; `Some(false)`: the v row at `y = ly`.
fn fixed_kind(layout: &Layout, loc: Loc) -> Option<bool> {
    match loc {
        Loc::UFace if layout.u_fixed.is_some() => Some(true),
        Loc::VFace if layout.v_fixed.is_some() => Some(false),
        _ => None,
    }
}

fn fixed_cells(grid: &Grid, layout: &Layout, key: Option<bool>) -> Vec<Option<f64>> {
    let (nx, ny) = (grid.nx, grid.ny);
    let mut f = vec![None; nx * ny];
    match key {
        Some(true) => (0..ny).for_each(|j| f[j * nx + nx - 1] = layout.u_fixed),
        Some(false) => (0..nx).for_each(|i| f[(ny - 1) * nx + i] = layout.v_fixed),
        None => {}
    }
    f
}

impl System {
    fn new(grid: &Grid, g: Ghosts, fixed: Vec<Option<f64>>, alpha: f64) -> Result<Self> {
        let (nx, ny) = (grid.nx, grid.ny);
        let (index, free) = unknown_index(nx * ny, |k| fixed[k].is_none());
        let spec = Laplacian {
            grid,
            ghosts: g,
            index: &index,
            excluded: Excluded::KnownValue,
            scale: alpha,
            shift: 1.0,
            pin_first: false,
        };
        let factor = Factored::new(&spec, false, "implicit diffusion", "")?;
        let (ax, ay) = (alpha / (grid.dx() * grid.dx()), alpha / (grid.dy() * grid.dy()));
        // Affine part: alpha L applied to the fixed values and the ghost constants.
        let z: Vec<f64> = fixed.iter().map(|f| f.unwrap_or(0.0)).collect();
        let w = nx + 2;
        let mut zp = vec![0.0; w * (ny + 2)];
        pad(&z, nx, ny, &g, true, &mut zp);
        let mut constant = vec![0.0; free];
        for j in 0..ny {
            for i in 0..nx {
                let me = j * nx + i;
                if index[me] == NOT_UNKNOWN {
                    continue;
                }
                let c = (j + 1) * w + i + 1;
                constant[index[me]] =
                    ax * (zp[c - 1] + zp[c + 1] - 2.0 * zp[c]) + ay * (zp[c - w] + zp[c + w] - 2.0 * zp[c]);
            }
        }
        Ok(Self { fixed, index, free, factor, constant })
    }

    /// Solves for one `ny x nx` slice; `adjoint`: no constants, fixed cells get 0.
    fn solve<T: Real>(&self, rhs: &[T], out: &mut [T], adjoint: bool) {
        let mut b = vec![0.0; self.free];
        for (k, &ix) in self.index.iter().enumerate() {
            if ix != NOT_UNKNOWN {
                b[ix] = rhs[k].to_f64() + if adjoint { 0.0 } else { self.constant[ix] };
            }
        }
        self.factor.solve(&mut b);
        for (k, &ix) in self.index.iter().enumerate() {
            out[k] = if ix != NOT_UNKNOWN {
                T::c(b[ix])
            } else if adjoint {
                T::zero()
            } else {
                T::c(self.fixed[k].unwrap_or(0.0))
            };
        }
    }
}

#[derive(Clone)]
struct Solve1 {
    op: ImplicitDiffusion,
    adjoint: bool,
}

impl Kernel1 for Solve1 {
    fn name(&self) -> &'static str {
        if self.adjoint {
            "diffuse_implicit_adjoint"
        } else {
            "diffuse_implicit"
        }
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let n = self.op.grid.cells();
        let nc = self.op.chans.len();
        for (k, (xb, ob)) in x.chunks(n).zip(out.chunks_mut(n)).enumerate() {
            self.op.chans[k % nc].solve(xb, ob, self.adjoint);
        }
        Ok(())
    }
}

impl Op1 for Solve1 {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, Solve1 { op: self.op.clone(), adjoint: true })
    }
}
