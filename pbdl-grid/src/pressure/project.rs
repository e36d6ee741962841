//! Projection of a MAC velocity onto divergence-free fields (`fluid.make_incompressible`).

use super::PressureSolver;
use crate::boundary::{Ghosts, MacGhosts};
use crate::fd::{div_padded, div_padded_adjoint, grad_padded, grad_padded_adjoint};
use crate::field::MacField;
use crate::pad::{pad, pad_adjoint};
use crate::scratch::{uninit, zeros, Buf};
use crate::{Error, Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use std::sync::Arc;

/// Removes the divergent part of `u`: `u - M G p` with `L p = D u`, after setting the stored
/// boundary faces that a wall or an inflow fixes to their condition's value (so a closed domain
/// has no net flux and the solve is consistent). Differentiable; the backward is one adjoint solve.
pub fn make_incompressible(u: &MacField, solver: &Arc<PressureSolver>) -> Result<MacField> {
    let op = Projection::new(*u.grid(), u.bc(), solver)?;
    Ok(MacField::from_parts(op.apply(u.values())?, *u.grid(), *u.bc()))
}

/// The projection as a reusable custom op (built once by the stepper).
#[derive(Clone)]
pub(crate) struct Projection {
    grid: Grid,
    mac: MacGhosts,
    p: Ghosts,
    solver: Arc<PressureSolver>,
}

impl Projection {
    pub(crate) fn new(grid: Grid, bc: &crate::Boundaries, solver: &Arc<PressureSolver>) -> Result<Self> {
        if solver.grid() != &grid || solver.bc() != &bc.pressure() {
            return Err(Error::Invalid {
                field: "solver",
                reason: "the pressure solver was built for another grid or other boundaries; build it with PressureSolver::new(grid, bc)".into(),
            });
        }
        Ok(Self {
            grid,
            mac: bc.mac_ghosts(grid.nx, grid.ny),
            p: bc.pressure().ghosts(grid.nx, grid.ny),
            solver: solver.clone(),
        })
    }

    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, self.clone())
    }

    fn fixed(&self) -> (bool, bool) {
        (self.mac.u_fixed.is_some(), self.mac.v_fixed.is_some())
    }
}

/// Scratch of one projection: padded components, divergence, pressure.
struct Scratch<T: Copy + 'static> {
    a: Buf<T>,
    b: Buf<T>,
    c: Buf<T>,
    div: Buf<T>,
    p: Buf<T>,
    g: Buf<T>,
}

impl<T: Real> Scratch<T> {
    fn new(nx: usize, ny: usize) -> Self {
        let pn = (nx + 2) * (ny + 2);
        Self { a: zeros(pn), b: zeros(pn), c: zeros(pn), div: zeros(nx * ny), p: zeros(nx * ny), g: zeros(2 * nx * ny) }
    }
}

impl Kernel1 for Projection {
    fn name(&self) -> &'static str {
        "make_incompressible"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let (idx, idy) = (T::c(1.0 / self.grid.dx()), T::c(1.0 / self.grid.dy()));
        let mut s = Scratch::<T>::new(nx, ny);
        for (xb, ob) in x.chunks(2 * n).zip(out.chunks_mut(2 * n)) {
            ob.copy_from_slice(xb);
            set_fixed(ob, nx, ny, self.mac.u_fixed.map(T::c), self.mac.v_fixed.map(T::c));
            pad(&ob[..n], nx, ny, &self.mac.u, true, &mut s.a);
            pad(&ob[n..], nx, ny, &self.mac.v, true, &mut s.b);
            div_padded(&s.a, &s.b, nx, ny, idx, idy, &mut s.div);
            self.solver.solve_slice(&s.div, &mut s.p);
            pad(&s.p, nx, ny, &self.p, true, &mut s.c);
            let (gu, gv) = s.g.split_at_mut(n);
            grad_padded(&s.c, nx, ny, idx, idy, self.fixed(), gu, gv);
            for (o, &g) in ob.iter_mut().zip(s.g.iter()) {
                *o -= g;
            }
        }
        Ok(())
    }
}

impl Op1 for Projection {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, ProjectionAdjoint(self.clone()))
    }
}

/// Sets the stored boundary faces that a condition fixes: the `u` column at `x = lx`, the `v`
/// row at `y = ly`.
pub(crate) fn set_fixed<T: Real>(x: &mut [T], nx: usize, ny: usize, u: Option<T>, v: Option<T>) {
    let n = nx * ny;
    if let Some(u) = u {
        for j in 0..ny {
            x[j * nx + nx - 1] = u;
        }
    }
    if let Some(v) = v {
        x[n + (ny - 1) * nx..].iter_mut().for_each(|e| *e = v);
    }
}

/// `E^T (g - D^T L^+ (M G)^T g)`, `E` the overwrite of the fixed faces.
struct ProjectionAdjoint(Projection);

impl Kernel1 for ProjectionAdjoint {
    fn name(&self) -> &'static str {
        "make_incompressible_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = &self.0;
        let (nx, ny) = (op.grid.nx, op.grid.ny);
        let n = nx * ny;
        let (idx, idy) = (T::c(1.0 / op.grid.dx()), T::c(1.0 / op.grid.dy()));
        let mut s = Scratch::<T>::new(nx, ny);
        for (gb, ob) in g.chunks(2 * n).zip(out.chunks_mut(2 * n)) {
            s.c.iter_mut().for_each(|x| *x = T::zero());
            grad_padded_adjoint(&gb[..n], &gb[n..], nx, ny, idx, idy, op.fixed(), &mut s.c);
            pad_adjoint(&mut s.c, nx, ny, &op.p, &mut s.div);
            op.solver.solve_slice(&s.div, &mut s.p);
            s.a.iter_mut().chain(s.b.iter_mut()).for_each(|x| *x = T::zero());
            div_padded_adjoint(&s.p, nx, ny, idx, idy, &mut s.a, &mut s.b);
            let (ou, ov) = ob.split_at_mut(n);
            pad_adjoint(&mut s.a, nx, ny, &op.mac.u, ou);
            pad_adjoint(&mut s.b, nx, ny, &op.mac.v, ov);
            for (o, &gv) in ob.iter_mut().zip(gb) {
                *o = gv - *o;
            }
            // Fixed faces were overwritten by constants: no gradient reaches their inputs.
            let z = Some(T::zero());
            set_fixed(ob, nx, ny, op.mac.u_fixed.and(z), op.mac.v_fixed.and(z));
        }
        Ok(())
    }
}

/// `P(x0 + w1 x1 + w2 x2)` (or without `P`) in one op: a Runge-Kutta stage update and its
/// projection without intermediate tensors. Backward: `h = P^T g`, gradients `(h, w1 h, w2 h)`.
#[derive(Clone)]
pub(crate) struct CombineProject {
    pub w: [f64; 2],
    pub projection: Option<Projection>,
}

impl pbdl_core::op::Kernel3 for CombineProject {
    fn name(&self) -> &'static str {
        "combine_project"
    }
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape> {
        if a != b || a != c {
            candle_core::bail!("combine_project: shapes differ: {a:?} {b:?} {c:?}");
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
        match &self.projection {
            None => {
                for ((o, &x), (&y, &z)) in out.iter_mut().zip(a).zip(b.iter().zip(c)) {
                    *o = x + w1 * y + w2 * z;
                }
                Ok(())
            }
            Some(p) => {
                let mut comb = uninit::<T>(a.len());
                for ((o, &x), (&y, &z)) in comb.iter_mut().zip(a).zip(b.iter().zip(c)) {
                    *o = x + w1 * y + w2 * z;
                }
                p.forward(&comb, s, out)
            }
        }
    }
}

impl pbdl_core::op::Op3 for CombineProject {
    fn backward(
        &self,
        _a: &Tensor,
        _b: &Tensor,
        _c: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let h = match &self.projection {
            Some(p) => apply_kernel1(gy, ProjectionAdjoint(p.clone()))?,
            None => gy.clone(),
        };
        Ok((h.clone(), h.affine(self.w[0], 0.0)?, h.affine(self.w[1], 0.0)?))
    }
}
