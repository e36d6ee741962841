//! Divergence of a MAC velocity, at cell centres.

use super::{dims4, div_padded, div_padded_adjoint};
use crate::boundary::MacGhosts;
use crate::field::{CenteredField, MacField};
use crate::pad::{pad, pad_adjoint};
use crate::{Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;

/// `div u` at cell centres, `[batch, 1, ny, nx]`; inflow velocities on unstored faces enter as
/// constants. The result carries the pressure conditions implied by `u`'s boundaries.
pub fn divergence(u: &MacField) -> Result<CenteredField> {
    let g = *u.grid();
    let op = Divergence { grid: g, ghosts: u.bc().mac_ghosts(g.nx, g.ny) };
    let d = apply1(u.values(), op)?;
    Ok(CenteredField::from_parts(d, g, u.bc().pressure()))
}

#[derive(Clone, Copy)]
pub(crate) struct Divergence {
    pub grid: Grid,
    pub ghosts: MacGhosts,
}

impl Kernel1 for Divergence {
    fn name(&self) -> &'static str {
        "divergence"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, _, _, _) = dims4(s)?;
        Ok(Shape::from((b, 1, self.grid.ny, self.grid.nx)))
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let mut up = vec![T::zero(); (nx + 2) * (ny + 2)];
        let mut vp = up.clone();
        for (xb, ob) in x.chunks(2 * n).zip(out.chunks_mut(n)) {
            pad(&xb[..n], nx, ny, &self.ghosts.u, true, &mut up);
            pad(&xb[n..], nx, ny, &self.ghosts.v, true, &mut vp);
            div_padded(&up, &vp, nx, ny, T::c(1.0 / self.grid.dx()), T::c(1.0 / self.grid.dy()), ob);
        }
        Ok(())
    }
}

impl Op1 for Divergence {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, DivergenceAdjoint(*self))
    }
}

/// `D^T g`: from a centred gradient to the MAC velocity's gradient.
pub(crate) struct DivergenceAdjoint(pub Divergence);

impl Kernel1 for DivergenceAdjoint {
    fn name(&self) -> &'static str {
        "divergence_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, _, ny, nx) = dims4(s)?;
        Ok(Shape::from((b, 2, ny, nx)))
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (grid, gh) = (self.0.grid, self.0.ghosts);
        let (nx, ny) = (grid.nx, grid.ny);
        let n = nx * ny;
        let mut gu = vec![T::zero(); (nx + 2) * (ny + 2)];
        let mut gv = gu.clone();
        for (gb, ob) in g.chunks(n).zip(out.chunks_mut(2 * n)) {
            gu.iter_mut().chain(gv.iter_mut()).for_each(|x| *x = T::zero());
            div_padded_adjoint(gb, nx, ny, T::c(1.0 / grid.dx()), T::c(1.0 / grid.dy()), &mut gu, &mut gv);
            let (ou, ov) = ob.split_at_mut(n);
            pad_adjoint(&mut gu, nx, ny, &gh.u, ou);
            pad_adjoint(&mut gv, nx, ny, &gh.v, ov);
        }
        Ok(())
    }
}
