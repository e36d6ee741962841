//! The momentum right-hand side on the periodic 3D MAC grid: second-order central flux-form
//! advection `-div(u u)` plus the explicit viscous term `nu lap u`, fused in one custom op with a
//! hand-written adjoint.
//!
//! For component `c` at its face and each direction `d`, the flux difference is
//! `(A+ B+ - A- B-) / h_d` with `A+ = (q_d + q_d[+e_c]) / 2` (the `d`-velocity interpolated
//! along `c`), `B+ = (q_c + q_c[+e_d]) / 2` (the transported `c`-velocity interpolated along
//! `d`), and `A-`, `B-` the same one cell back along `d`. For `d = c` this is `(u_E^2 - u_W^2) /
//! dx` at cell centres, for `d != c` the product at cell edges: the 3D form of the 2D
//! [`crate::advect::flux_form`]. Central fluxes conserve momentum and (with a divergence-free
//! velocity) kinetic energy, and add no numerical diffusion: step them with RK4 or SSP-RK3.

use super::field::MacField3d;
use super::periodic::{Periodic, E};
use super::Grid3d;
use crate::pad::{accumulate_rows, for_rows, parallel_cells};
use crate::stability::check_nu;
use crate::Result;
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel2, Kernel1, Kernel2, Op1};
use pbdl_core::Real;

/// The advective tendency `-div(u u)` on the faces. Differentiable (hand-written adjoint).
pub fn flux_form(u: &MacField3d) -> Result<MacField3d> {
    let op = MomentumRhs3d { grid: *u.grid(), advect: true, nu: 0.0 };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// The viscous tendency `nu lap u` (seven-point Laplacian per component); `nu >= 0`. Differentiable.
pub fn viscous(u: &MacField3d, nu: f64) -> Result<MacField3d> {
    check_nu(nu)?;
    let op = MomentumRhs3d { grid: *u.grid(), advect: false, nu };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// The full tendency `-div(u u) + nu lap u` in one pass. Differentiable.
pub fn momentum_rhs(u: &MacField3d, nu: f64) -> Result<MacField3d> {
    check_nu(nu)?;
    let op = MomentumRhs3d { grid: *u.grid(), advect: true, nu };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// `advect * (-div(u u)) + nu lap u` as a custom op on `[batch, 3, nz, ny, nx]`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MomentumRhs3d {
    pub grid: Grid3d,
    pub advect: bool,
    pub nu: f64,
}

/// Per-grid constants in the kernel's float type.
struct Coef<T> {
    a: T,
    nu: T,
    ih: [T; 3],
    ih2: [T; 3],
}

impl MomentumRhs3d {
    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, *self)
    }

    fn coef<T: Real>(&self) -> Coef<T> {
        let h = self.grid.spacing();
        Coef {
            a: T::c(if self.advect { 1.0 } else { 0.0 }),
            nu: T::c(self.nu),
            ih: h.map(|h| T::c(1.0 / h)),
            ih2: h.map(|h| T::c(1.0 / (h * h))),
        }
    }
}

/// The 27 neighbour rows `(comp, k + dk, j + dj)` of one row, so that the inner loop only wraps `i`.
struct Rows<'a, T> {
    r: [[[&'a [T]; 3]; 3]; 3],
}

impl<'a, T> Rows<'a, T> {
    fn new(p: &Periodic, q: &'a [T], r: usize) -> Self {
        let (n, nx) = (p.cells(), p.nx);
        let at = |c: usize, dk: isize, dj: isize| {
            let s = c * n + p.row(r, dk, dj) * nx;
            &q[s..s + nx]
        };
        let mk = |c| [-1isize, 0, 1].map(|dk| [-1isize, 0, 1].map(|dj| at(c, dk, dj)));
        Self { r: [mk(0), mk(1), mk(2)] }
    }
}

impl<T: Copy> Rows<'_, T> {
    /// `q_c` at `(k + o[0], j + o[1], i + o[2])`.
    #[inline(always)]
    fn at(&self, p: &Periodic, c: usize, i: usize, o: [isize; 3]) -> T {
        self.r[c][(o[0] + 1) as usize][(o[1] + 1) as usize][p.col(i, o[2])]
    }
}

#[inline(always)]
fn add(a: [isize; 3], b: [isize; 3]) -> [isize; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline(always)]
fn neg(a: [isize; 3]) -> [isize; 3] {
    [-a[0], -a[1], -a[2]]
}

/// The tendency of component `C` along one row.
#[inline(always)]
fn row_rhs<const C: usize, T: Real>(p: &Periodic, rows: &Rows<T>, k: &Coef<T>, out: &mut [T]) {
    let (h, two, z) = (T::c(0.5), T::c(2.0), [0isize; 3]);
    for (i, o) in out.iter_mut().enumerate() {
        let qc = rows.at(p, C, i, z);
        let (mut adv, mut lap) = (T::zero(), T::zero());
        for d in 0..3 {
            let (ec, ed) = (E[C], E[d]);
            let ap = h * (rows.at(p, d, i, z) + rows.at(p, d, i, ec));
            let bp = h * (qc + rows.at(p, C, i, ed));
            let am = h * (rows.at(p, d, i, neg(ed)) + rows.at(p, d, i, add(ec, neg(ed))));
            let qm = rows.at(p, C, i, neg(ed));
            let bm = h * (qm + qc);
            adv += (ap * bp - am * bm) * k.ih[d];
            lap += (rows.at(p, C, i, ed) + qm - two * qc) * k.ih2[d];
        }
        *o = k.nu * lap - k.a * adv;
    }
}

impl Kernel1 for MomentumRhs3d {
    fn name(&self) -> &'static str {
        "grid3d_momentum_rhs"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_shape(self.name(), s, &self.grid)?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let p = Periodic::new(&self.grid);
        let (n, rows) = (p.cells(), p.rows());
        let k = self.coef::<T>();
        for (xb, ob) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)) {
            // One task per (component, row).
            for_rows(ob, p.nx, parallel_cells(n), |cr, o| {
                let (c, r) = (cr / rows, cr % rows);
                let rw = Rows::new(&p, xb, r);
                match c {
                    0 => row_rhs::<0, T>(&p, &rw, &k, o),
                    1 => row_rhs::<1, T>(&p, &rw, &k, o),
                    _ => row_rhs::<2, T>(&p, &rw, &k, o),
                }
            });
        }
        Ok(())
    }
}

pub(crate) fn check_shape(op: &str, s: &Shape, g: &Grid3d) -> candle_core::Result<()> {
    let d = s.dims();
    if d != [d.first().copied().unwrap_or(0), 3, g.nz, g.ny, g.nx] {
        candle_core::bail!("{op}: expected [batch, 3, {}, {}, {}], got {d:?}", g.nz, g.ny, g.nx);
    }
    Ok(())
}

/// Shapes of an adjoint kernel: the input `a` a 3D MAC velocity on `g`, the cotangent `b` the same.
pub(crate) fn check_adjoint_shapes(op: &str, a: &Shape, b: &Shape, g: &Grid3d) -> candle_core::Result<Shape> {
    check_shape(op, a, g)?;
    if a != b {
        candle_core::bail!("{op}: cotangent {b:?} differs from input {a:?}");
    }
    Ok(a.clone())
}

impl Op1 for MomentumRhs3d {
    fn backward(&self, x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, gy, MomentumRhs3dAdjoint(*self))
    }
}

/// Vector-Jacobian product of [`MomentumRhs3d`] at `x` with cotangent `g`: the forward stencil
/// differentiated term by term and scattered to the inputs it read.
struct MomentumRhs3dAdjoint(MomentumRhs3d);

impl Kernel2 for MomentumRhs3dAdjoint {
    fn name(&self) -> &'static str {
        "grid3d_momentum_rhs_adjoint"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        check_adjoint_shapes(self.name(), a, b, &self.0.grid)
    }
    fn forward<T: Real>(&self, x: &[T], _xs: &Shape, g: &[T], _gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let p = Periodic::new(&op.grid);
        let (n, rows, nx) = (p.cells(), p.rows(), p.nx);
        let k = op.coef::<T>();
        let (h, two) = (T::c(0.5), T::c(2.0));
        for ((xb, gb), ob) in x.chunks(3 * n).zip(g.chunks(3 * n)).zip(out.chunks_mut(3 * n)) {
            accumulate_rows(ob, 3 * rows, parallel_cells(n), |cr, acc| {
                let (c, r) = (cr / rows, cr % rows);
                let rw = Rows::new(&p, xb, r);
                // Flat index of `q_comp` at offset `o` from (r, i).
                let idx = |comp: usize, i: usize, o: [isize; 3]| comp * n + p.row(r, o[0], o[1]) * nx + p.col(i, o[2]);
                let z = [0isize; 3];
                for i in 0..nx {
                    let gc = gb[c * n + r * nx + i];
                    let qc = rw.at(&p, c, i, z);
                    for d in 0..3 {
                        let (ec, ed) = (E[c], E[d]);
                        // Viscous part (symmetric stencil).
                        let l = gc * k.nu * k.ih2[d];
                        acc[idx(c, i, ed)] += l;
                        acc[idx(c, i, neg(ed))] += l;
                        acc[idx(c, i, z)] -= two * l;
                        // Advective part: y -= a (A+ B+ - A- B-) / h_d.
                        let s = -gc * k.a * k.ih[d] * h;
                        let ap = h * (rw.at(&p, d, i, z) + rw.at(&p, d, i, ec));
                        let bp = h * (qc + rw.at(&p, c, i, ed));
                        let am = h * (rw.at(&p, d, i, neg(ed)) + rw.at(&p, d, i, add(ec, neg(ed))));
                        let bm = h * (rw.at(&p, c, i, neg(ed)) + qc);
                        acc[idx(d, i, z)] += s * bp;
                        acc[idx(d, i, ec)] += s * bp;
                        acc[idx(c, i, z)] += s * (ap - am);
                        acc[idx(c, i, ed)] += s * ap;
                        acc[idx(d, i, neg(ed))] -= s * bm;
                        acc[idx(d, i, add(ec, neg(ed)))] -= s * bm;
                        acc[idx(c, i, neg(ed))] -= s * am;
                    }
                }
            });
        }
        Ok(())
    }
}
