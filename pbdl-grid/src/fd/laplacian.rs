//! Five-point Laplacian of a centred field.

use super::dims4;
use crate::boundary::Ghosts;
use crate::field::CenteredField;
use crate::pad::{pad, pad_adjoint};
use crate::{Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;

/// `lap f` at cell centres, every channel, with `f`'s boundary conditions as ghosts (Dirichlet
/// values enter as constants).
pub fn laplacian(f: &CenteredField) -> Result<CenteredField> {
    let g = *f.grid();
    let op = Laplacian { grid: g, ghosts: f.bc().ghosts(g.nx, g.ny) };
    Ok(CenteredField::from_parts(apply1(f.values(), op)?, g, *f.bc()))
}

#[derive(Clone, Copy)]
pub(crate) struct Laplacian {
    pub grid: Grid,
    pub ghosts: Ghosts,
}

impl Kernel1 for Laplacian {
    fn name(&self) -> &'static str {
        "laplacian"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let w = nx + 2;
        let (ax, ay) = (T::c(1.0 / (self.grid.dx() * self.grid.dx())), T::c(1.0 / (self.grid.dy() * self.grid.dy())));
        let two = T::c(2.0);
        let mut pp = vec![T::zero(); w * (ny + 2)];
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(n)) {
            pad(xb, nx, ny, &self.ghosts, true, &mut pp);
            for j in 0..ny {
                let r = (j + 1) * w;
                let (ps, p0, pn) = (&pp[r - w..r], &pp[r..r + w], &pp[r + w..r + 2 * w]);
                let o = &mut ob[j * nx..(j + 1) * nx];
                for i in 0..nx {
                    let c = p0[i + 1];
                    o[i] = (p0[i] + p0[i + 2] - two * c) * ax + (ps[i + 1] + pn[i + 1] - two * c) * ay;
                }
            }
        }
        Ok(())
    }
}

impl Op1 for Laplacian {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, LaplacianAdjoint(*self))
    }
}

struct LaplacianAdjoint(Laplacian);

impl Kernel1 for LaplacianAdjoint {
    fn name(&self) -> &'static str {
        "laplacian_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let _ = dims4(s)?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let (nx, ny) = (op.grid.nx, op.grid.ny);
        let n = nx * ny;
        let w = nx + 2;
        let (ax, ay) = (T::c(1.0 / (op.grid.dx() * op.grid.dx())), T::c(1.0 / (op.grid.dy() * op.grid.dy())));
        let centre = T::c(-2.0) * (ax + ay);
        let mut gp = vec![T::zero(); w * (ny + 2)];
        for (gb, ob) in g.chunks(n).zip(out.chunks_mut(n)) {
            gp.iter_mut().for_each(|x| *x = T::zero());
            for j in 0..ny {
                let r = (j + 1) * w;
                for i in 0..nx {
                    let a = gb[j * nx + i];
                    gp[r + i + 1] += centre * a;
                    gp[r + i] += ax * a;
                    gp[r + i + 2] += ax * a;
                    gp[r - w + i + 1] += ay * a;
                    gp[r + w + i + 1] += ay * a;
                }
            }
            pad_adjoint(&mut gp, nx, ny, &op.ghosts, ob);
        }
        Ok(())
    }
}
