//! Projection of a MAC velocity onto divergence-free fields (`fluid.make_incompressible`).

use super::PressureSolver;
use crate::boundary::{Ghosts, MacGhosts};
use crate::fd::{div_padded, div_padded_adjoint, grad_padded, grad_padded_adjoint};
use crate::field::MacField;
use crate::pad::{pad, pad_adjoint};
use crate::scratch::{zeros, Buf};
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

    fn faces(&self) -> Faces<'_> {
        Faces { grid: &self.grid, mac: &self.mac, p: &self.p, open: None }
    }

    /// The projection of `[B, 2, ny, nx]` values that also writes the pressure `[B, ny, nx]`
    /// (not differentiable; the pressure split of a step).
    pub(crate) fn project_keep_pressure<T: Real>(&self, x: &[T], out: &mut [T], pressure: &mut [T]) {
        self.faces().forward_keep_pressure(x, out, pressure, |r, o| self.solver.solve_slice(r, o));
    }

    /// The correction `m F x - m G p` with a given pressure `[B, ny, nx]` (not differentiable).
    pub(crate) fn correct<T: Real>(&self, x: &[T], pressure: &[T], out: &mut [T]) {
        self.faces().correct(x, pressure, out);
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
        self.faces().forward(x, out, |r, o| self.solver.solve_slice(r, o));
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

/// What the 2D projection kernels (plain and with obstacles) share: the grid, the ghost rules,
/// and with obstacles the open-face masks `m` of `u` and `v`.
pub(crate) struct Faces<'a> {
    pub grid: &'a Grid,
    pub mac: &'a MacGhosts,
    pub p: &'a Ghosts,
    pub open: Option<(&'a [f64], &'a [f64])>,
}

impl Faces<'_> {
    fn fixed(&self) -> (bool, bool) {
        (self.mac.u_fixed.is_some(), self.mac.v_fixed.is_some())
    }

    /// Zeroes the closed faces of a `[2, ny, nx]` slice (nothing without obstacles).
    fn mask<T: Real>(&self, x: &mut [T]) {
        if let Some((mu, mv)) = self.open {
            let (xu, xv) = x.split_at_mut(self.grid.cells());
            for (e, &m) in xu.iter_mut().zip(mu).chain(xv.iter_mut().zip(mv)) {
                if m == 0.0 {
                    *e = T::zero();
                }
            }
        }
    }

    /// `out = w - m G p`, `w = m F x`, `p = solve(D w)`, per `[2, ny, nx]` sample.
    pub(crate) fn forward<T: Real>(&self, x: &[T], out: &mut [T], solve: impl Fn(&[T], &mut [T])) {
        self.forward_with(x, out, |_, div, p| solve(div, p));
    }

    /// [`Self::forward`] that also writes each sample's pressure `p` (`[ny, nx]` per sample)
    /// into `pressure`.
    pub(crate) fn forward_keep_pressure<T: Real>(
        &self,
        x: &[T],
        out: &mut [T],
        pressure: &mut [T],
        solve: impl Fn(&[T], &mut [T]),
    ) {
        let n = self.grid.cells();
        let cell = std::cell::RefCell::new(pressure);
        self.forward_with(x, out, |b, div, p| {
            solve(div, p);
            cell.borrow_mut()[b * n..(b + 1) * n].copy_from_slice(p);
        });
    }

    /// `out = m F x - m G p` with a given pressure (`[ny, nx]` per sample): the velocity
    /// correction without a solve (e.g. from a predicted pressure).
    pub(crate) fn correct<T: Real>(&self, x: &[T], pressure: &[T], out: &mut [T]) {
        let n = self.grid.cells();
        self.forward_with(x, out, |b, _, p| p.copy_from_slice(&pressure[b * n..(b + 1) * n]));
    }

    /// The projection with the pressure of sample `b` supplied by `pressure(b, D w, p)`.
    fn forward_with<T: Real>(&self, x: &[T], out: &mut [T], mut pressure: impl FnMut(usize, &[T], &mut [T])) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let (idx, idy) = (T::c(1.0 / self.grid.dx()), T::c(1.0 / self.grid.dy()));
        let mut s = Scratch::<T>::new(nx, ny);
        for (b, (xb, ob)) in x.chunks(2 * n).zip(out.chunks_mut(2 * n)).enumerate() {
            ob.copy_from_slice(xb);
            set_fixed(ob, nx, ny, self.mac.u_fixed.map(T::c), self.mac.v_fixed.map(T::c));
            self.mask(ob);
            pad(&ob[..n], nx, ny, &self.mac.u, true, &mut s.a);
            pad(&ob[n..], nx, ny, &self.mac.v, true, &mut s.b);
            div_padded(&s.a, &s.b, nx, ny, idx, idy, &mut s.div);
            pressure(b, &s.div, &mut s.p);
            pad(&s.p, nx, ny, self.p, true, &mut s.c);
            let (gu, gv) = s.g.split_at_mut(n);
            grad_padded(&s.c, nx, ny, idx, idy, self.fixed(), gu, gv);
            self.mask(&mut s.g);
            for (o, &g) in ob.iter_mut().zip(s.g.iter()) {
                *o -= g;
            }
        }
    }

    /// The vector-Jacobian product of [`Self::forward`]: `F m (g - D^T solve(G^T (m g)))`.
    pub(crate) fn adjoint<T: Real>(&self, g: &[T], out: &mut [T], solve: impl Fn(&[T], &mut [T])) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        let (idx, idy) = (T::c(1.0 / self.grid.dx()), T::c(1.0 / self.grid.dy()));
        let mut s = Scratch::<T>::new(nx, ny);
        for (gb, ob) in g.chunks(2 * n).zip(out.chunks_mut(2 * n)) {
            s.g.copy_from_slice(gb);
            self.mask(&mut s.g);
            s.c.iter_mut().for_each(|x| *x = T::zero());
            grad_padded_adjoint(&s.g[..n], &s.g[n..], nx, ny, idx, idy, self.fixed(), &mut s.c);
            pad_adjoint(&mut s.c, nx, ny, self.p, &mut s.div);
            solve(&s.div, &mut s.p);
            s.a.iter_mut().chain(s.b.iter_mut()).for_each(|x| *x = T::zero());
            div_padded_adjoint(&s.p, nx, ny, idx, idy, &mut s.a, &mut s.b);
            let (ou, ov) = ob.split_at_mut(n);
            pad_adjoint(&mut s.a, nx, ny, &self.mac.u, ou);
            pad_adjoint(&mut s.b, nx, ny, &self.mac.v, ov);
            for (o, &gv) in ob.iter_mut().zip(gb) {
                *o = gv - *o;
            }
            self.mask(ob);
            // Fixed faces were overwritten by constants: no gradient reaches their inputs.
            let z = Some(T::zero());
            set_fixed(ob, nx, ny, self.mac.u_fixed.and(z), self.mac.v_fixed.and(z));
        }
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
        op.faces().adjoint(g, out, |r, o| op.solver.solve_slice(r, o));
        Ok(())
    }
}

impl crate::time_stepping::fused::ProjectionKernel for Projection {
    const COMBINE_NAME: &'static str = "combine_project";

    fn adjoint(&self, g: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(g, ProjectionAdjoint(self.clone()))
    }
}
