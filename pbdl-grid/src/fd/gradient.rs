//! Gradient of a centred scalar, on the faces of a MAC grid.

use super::{dims4, grad_padded, grad_padded_adjoint};
use crate::boundary::{Boundaries, Ghosts};
use crate::field::{CenteredField, MacField};
use crate::pad::{pad, pad_adjoint};
use crate::{Error, Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;

/// `grad p` on the faces (`[batch, 2, ny, nx]`) of a one-channel centred field, using `p`'s
/// boundary conditions for the ghosts; stored boundary faces that `velocity_bc` fixes (walls,
/// inflow) get 0, so the result can be subtracted from a velocity with those boundaries.
pub fn gradient(p: &CenteredField, velocity_bc: &Boundaries) -> Result<MacField> {
    velocity_bc.validate()?;
    let g = *p.grid();
    if p.values().dims()[1] != 1 {
        return Err(Error::Shape {
            op: "gradient",
            arg: "p",
            expected: "one channel".into(),
            got: p.values().dims().to_vec(),
        });
    }
    let mg = velocity_bc.mac_ghosts(g.nx, g.ny);
    let op =
        Gradient { grid: g, ghosts: p.bc().ghosts(g.nx, g.ny), fixed: (mg.u_fixed.is_some(), mg.v_fixed.is_some()) };
    Ok(MacField::from_parts(apply1(p.values(), op)?, g, *velocity_bc))
}

#[derive(Clone, Copy)]
pub(crate) struct Gradient {
    pub grid: Grid,
    pub ghosts: Ghosts,
    pub fixed: (bool, bool),
}

impl Kernel1 for Gradient {
    fn name(&self) -> &'static str {
        "gradient"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, _, _, _) = dims4(s)?;
        Ok(Shape::from((b, 2, self.grid.ny, self.grid.nx)))
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let mut pp = vec![T::zero(); (nx + 2) * (ny + 2)];
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(2 * n)) {
            pad(xb, nx, ny, &self.ghosts, true, &mut pp);
            let (ou, ov) = ob.split_at_mut(n);
            grad_padded(&pp, nx, ny, T::c(1.0 / self.grid.dx()), T::c(1.0 / self.grid.dy()), self.fixed, ou, ov);
        }
        Ok(())
    }
}

impl Op1 for Gradient {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, GradientAdjoint(*self))
    }
}

pub(crate) struct GradientAdjoint(pub Gradient);

impl Kernel1 for GradientAdjoint {
    fn name(&self) -> &'static str {
        "gradient_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, _, ny, nx) = dims4(s)?;
        Ok(Shape::from((b, 1, ny, nx)))
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let (nx, ny) = (op.grid.nx, op.grid.ny);
        let n = nx * ny;
        let mut gp = vec![T::zero(); (nx + 2) * (ny + 2)];
        for (gb, ob) in g.chunks(2 * n).zip(out.chunks_mut(n)) {
            gp.iter_mut().for_each(|x| *x = T::zero());
            let (gu, gv) = gb.split_at(n);
            grad_padded_adjoint(gu, gv, nx, ny, T::c(1.0 / op.grid.dx()), T::c(1.0 / op.grid.dy()), op.fixed, &mut gp);
            pad_adjoint(&mut gp, nx, ny, &op.ghosts, ob);
        }
        Ok(())
    }
}
