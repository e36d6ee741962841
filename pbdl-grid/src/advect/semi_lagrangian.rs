//! Semi-Lagrangian advection: trace each sample point back along the velocity and interpolate.
//!
//! For a quantity `q` sampled at points `x` (cell centres, `u` faces or `v` faces), one step is
//! `q1(x) = q0(x - dt u(x))` with `u(x)` the MAC velocity averaged to `x` (first-order backtrace)
//! and `q0` interpolated bilinearly on `q`'s own padded grid (one ghost layer from its boundary
//! conditions, so walls, inflows and Dirichlet values are seen). The scheme is unconditionally
//! stable (the result is a convex combination of old values): it has no time-step limit, only an
//! accuracy limit (first order, diffusive at large CFL). Departure points beyond the ghost layer
//! are clamped to it on closed axes and wrapped on periodic ones.
//!
//! The op is differentiable in `q` (the transpose of the interpolation) and in the velocity
//! (the derivative of the bilinear interpolant, through the averaging); both backward kernels are
//! hand-written and FD-checked.

use crate::boundary::{Ghosts, MacGhosts};
use crate::fd::dims4;
use crate::pad::{accumulate_rows, for_rows, pad, pad_adjoint, parallel_cells};
use crate::scratch::zeros;
use crate::Grid;
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply2, apply_kernel2, apply_kernel3, Kernel2, Kernel3, Op2};
use pbdl_core::Real;

/// Where the samples of one channel sit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Loc {
    /// Cell centres.
    Centre,
    /// x-faces (`u` of a MAC velocity).
    UFace,
    /// y-faces (`v` of a MAC velocity).
    VFace,
}

/// How an advected field is laid out: per channel its sample location, ghost rules and a fixed
/// stored boundary face (MAC walls and inflows). Opaque; built by [`super::Advected`].
#[derive(Clone, Debug)]
pub struct Layout {
    pub(crate) chans: Vec<(Loc, Ghosts)>,
    pub(crate) periodic: [bool; 2],
    pub(crate) u_fixed: Option<f64>,
    pub(crate) v_fixed: Option<f64>,
}

/// One semi-Lagrangian step of `q` (`[batch, C, ny, nx]`) with a MAC velocity (`[batch, 2, ny, nx]`).
#[derive(Clone, Debug)]
pub(crate) struct SemiLagrangian {
    pub grid: Grid,
    pub vel: MacGhosts,
    pub layout: Layout,
    pub dt: f64,
}

/// What the stencil kernel computes per sample.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Value,
    Min,
    Max,
}

/// The backtraced position on one axis in padded index space: lower index, weight, slope.
#[inline(always)]
fn locate(x: f64, n: usize, periodic: bool) -> (usize, f64, f64) {
    let nf = n as f64;
    let (p, slope) = if periodic {
        (x - nf * (x / nf).floor() + 1.0, 1.0)
    } else {
        let p = x + 1.0;
        if p < 0.0 {
            (0.0, 0.0)
        } else if p > nf + 1.0 {
            (nf + 1.0, 0.0)
        } else {
            (p, 1.0)
        }
    };
    let i0 = (p.floor() as usize).min(n);
    (i0, p - i0 as f64, slope)
}

/// Velocity (physical units) at the sample `loc` of padded cell `c`.
#[inline(always)]
fn vel_at<T: Real>(up: &[T], vp: &[T], w: usize, c: usize, loc: Loc) -> (T, T) {
    let (h, q) = (T::c(0.5), T::c(0.25));
    match loc {
        Loc::Centre => (h * (up[c - 1] + up[c]), h * (vp[c - w] + vp[c])),
        Loc::UFace => (up[c], q * (vp[c - w] + vp[c - w + 1] + vp[c] + vp[c + 1])),
        Loc::VFace => (q * (up[c - 1] + up[c] + up[c + w - 1] + up[c + w]), vp[c]),
    }
}

/// Adjoint of [`vel_at`]: adds `(au, av)` back onto the padded velocity gradients.
#[inline(always)]
fn vel_at_adjoint<T: Real>(gu: &mut [T], gv: &mut [T], w: usize, c: usize, loc: Loc, au: T, av: T) {
    let (h, q) = (T::c(0.5), T::c(0.25));
    match loc {
        Loc::Centre => {
            gu[c - 1] += h * au;
            gu[c] += h * au;
            gv[c - w] += h * av;
            gv[c] += h * av;
        }
        Loc::UFace => {
            gu[c] += au;
            for k in [c - w, c - w + 1, c, c + 1] {
                gv[k] += q * av;
            }
        }
        Loc::VFace => {
            for k in [c - 1, c, c + w - 1, c + w] {
                gu[k] += q * au;
            }
            gv[c] += av;
        }
    }
}

/// A sample's bilinear footprint on the padded quantity.
struct Foot {
    /// Padded indices of the corners (00, 10, 01, 11).
    k: [usize; 4],
    tx: f64,
    ty: f64,
    sx: f64,
    sy: f64,
}

impl SemiLagrangian {
    #[inline(always)]
    fn foot<T: Real>(&self, up: &[T], vp: &[T], j: usize, i: usize, loc: Loc, cfl: (f64, f64)) -> Foot {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let w = nx + 2;
        let c = (j + 1) * w + i + 1;
        let (u, v) = vel_at(up, vp, w, c, loc);
        let x = i as f64 - cfl.0 * u.to_f64();
        let y = j as f64 - cfl.1 * v.to_f64();
        let (i0, tx, sx) = locate(x, nx, self.layout.periodic[0]);
        let (j0, ty, sy) = locate(y, ny, self.layout.periodic[1]);
        let k0 = j0 * w + i0;
        Foot { k: [k0, k0 + 1, k0 + w, k0 + w + 1], tx, ty, sx, sy }
    }

    /// `(dt / dx, dt / dy)`, hoisted out of the per-sample loop.
    fn cfl(&self) -> (f64, f64) {
        (self.dt / self.grid.dx(), self.dt / self.grid.dy())
    }

    /// Forward in one of three modes, shared by the value op and the limiter bounds.
    fn run<T: Real>(&self, q: &[T], vel: &[T], out: &mut [T], mode: Mode) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        let nc = self.layout.chans.len();
        let cfl = self.cfl();
        let mut up = zeros::<T>(pn);
        let mut vp = zeros::<T>(pn);
        let mut qp = zeros::<T>(pn);
        for (b, vb) in vel.chunks(2 * n).enumerate() {
            pad(&vb[..n], nx, ny, &self.vel.u, true, &mut up);
            pad(&vb[n..], nx, ny, &self.vel.v, true, &mut vp);
            for (ch, &(loc, gh)) in self.layout.chans.iter().enumerate() {
                let off = (b * nc + ch) * n;
                pad(&q[off..off + n], nx, ny, &gh, true, &mut qp);
                let (up, vp, qp) = (&*up, &*vp, &*qp);
                for_rows(&mut out[off..off + n], nx, parallel_cells(n), |j, o| {
                    for (i, o) in o.iter_mut().enumerate() {
                        let f = self.foot(up, vp, j, i, loc, cfl);
                        let c = f.k.map(|k| qp[k]);
                        *o = match mode {
                            Mode::Value => {
                                let (tx, ty) = (T::c(f.tx), T::c(f.ty));
                                let one = T::one();
                                (one - ty) * ((one - tx) * c[0] + tx * c[1]) + ty * ((one - tx) * c[2] + tx * c[3])
                            }
                            Mode::Min => c.into_iter().fold(c[0], |m, x| if x < m { x } else { m }),
                            Mode::Max => c.into_iter().fold(c[0], |m, x| if x > m { x } else { m }),
                        };
                    }
                });
                self.set_fixed(&mut out[off..off + n], ch);
            }
        }
    }

    /// Stored boundary faces fixed by a wall or an inflow keep their value.
    fn set_fixed<T: Real>(&self, o: &mut [T], ch: usize) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        match self.layout.chans[ch].0 {
            Loc::UFace => {
                if let Some(v) = self.layout.u_fixed {
                    (0..ny).for_each(|j| o[j * nx + nx - 1] = T::c(v));
                }
            }
            Loc::VFace => {
                if let Some(v) = self.layout.v_fixed {
                    o[(ny - 1) * nx..].iter_mut().for_each(|x| *x = T::c(v));
                }
            }
            Loc::Centre => {}
        }
    }

    fn is_fixed(&self, ch: usize, j: usize, i: usize) -> bool {
        match self.layout.chans[ch].0 {
            Loc::UFace => self.layout.u_fixed.is_some() && i == self.grid.nx - 1,
            Loc::VFace => self.layout.v_fixed.is_some() && j == self.grid.ny - 1,
            Loc::Centre => false,
        }
    }

    pub(crate) fn apply(&self, q: &Tensor, vel: &Tensor) -> candle_core::Result<Tensor> {
        apply2(q, vel, self.clone())
    }

    /// The min (`max = false`) or max of the four values each sample interpolates from (the
    /// MacCormack limiter's bounds), differentiable.
    pub(crate) fn bounds(&self, q: &Tensor, vel: &Tensor, max: bool) -> candle_core::Result<Tensor> {
        apply2(q, vel, Bounds { sl: self.clone(), max })
    }

    fn check_shapes(&self, q: &Shape, v: &Shape) -> candle_core::Result<()> {
        let (b, c, ny, nx) = dims4(q)?;
        let (vb, vc, vny, vnx) = dims4(v)?;
        let g = self.grid;
        if c != self.layout.chans.len() || ny != g.ny || nx != g.nx || (vb, vc, vny, vnx) != (b, 2, g.ny, g.nx) {
            candle_core::bail!(
                "semi_lagrangian: q {q:?} and velocity {v:?} do not fit a {}-channel field and a MAC velocity on {}x{}",
                self.layout.chans.len(),
                g.ny,
                g.nx
            );
        }
        Ok(())
    }
}

impl Kernel2 for SemiLagrangian {
    fn name(&self) -> &'static str {
        "semi_lagrangian"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.check_shapes(a, b)?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], _qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.run(q, v, out, Mode::Value);
        Ok(())
    }
}

impl Op2 for SemiLagrangian {
    fn backward(&self, q: &Tensor, v: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gq = apply_kernel2(v, g, SlGradQ { sl: self.clone(), max: None })?;
        let gv = apply_kernel3(q, v, g, SlGradVel(self.clone()))?;
        Ok((gq, gv))
    }
}

/// Gradient with respect to `q`: the transpose of the interpolation (or of the min/max
/// selection when `max` is set), through the ghost padding. Inputs `(velocity, g)`; the limiter
/// variant needs `q` too, so it takes `(q, velocity, g)` via [`BoundsGradQ`].
struct SlGradQ {
    sl: SemiLagrangian,
    max: Option<bool>,
}

impl SlGradQ {
    fn run<T: Real>(&self, q: Option<&[T]>, vel: &[T], g: &[T], out: &mut [T]) {
        let sl = &self.sl;
        let (nx, ny) = (sl.grid.nx, sl.grid.ny);
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        let nc = sl.layout.chans.len();
        let cfl = sl.cfl();
        let mut up = zeros::<T>(pn);
        let mut vp = zeros::<T>(pn);
        let mut qp = zeros::<T>(pn);
        let mut gp = zeros::<T>(pn);
        for (b, vb) in vel.chunks(2 * n).enumerate() {
            pad(&vb[..n], nx, ny, &sl.vel.u, true, &mut up);
            pad(&vb[n..], nx, ny, &sl.vel.v, true, &mut vp);
            for (ch, &(loc, gh)) in sl.layout.chans.iter().enumerate() {
                let off = (b * nc + ch) * n;
                if let Some(q) = q {
                    pad(&q[off..off + n], nx, ny, &gh, true, &mut qp);
                }
                gp.fill(T::zero());
                let (up, vp, qp) = (&*up, &*vp, &*qp);
                accumulate_rows(&mut gp, ny, parallel_cells(n), |j, gp| {
                    for i in 0..nx {
                        let a = g[off + j * nx + i];
                        if sl.is_fixed(ch, j, i) || a == T::zero() {
                            continue;
                        }
                        let f = sl.foot(up, vp, j, i, loc, cfl);
                        match self.max {
                            None => {
                                let (tx, ty) = (T::c(f.tx), T::c(f.ty));
                                let one = T::one();
                                gp[f.k[0]] += a * (one - tx) * (one - ty);
                                gp[f.k[1]] += a * tx * (one - ty);
                                gp[f.k[2]] += a * (one - tx) * ty;
                                gp[f.k[3]] += a * tx * ty;
                            }
                            Some(max) => {
                                // The first corner attaining the extremum takes the gradient.
                                let mut best = f.k[0];
                                for &k in &f.k[1..] {
                                    if (max && qp[k] > qp[best]) || (!max && qp[k] < qp[best]) {
                                        best = k;
                                    }
                                }
                                gp[best] += a;
                            }
                        }
                    }
                });
                pad_adjoint(&mut gp, nx, ny, &gh, &mut out[off..off + n]);
            }
        }
    }
}

impl Kernel2 for SlGradQ {
    fn name(&self) -> &'static str {
        "semi_lagrangian_grad_q"
    }
    fn output_shape(&self, _v: &Shape, g: &Shape) -> candle_core::Result<Shape> {
        Ok(g.clone())
    }
    fn forward<T: Real>(&self, v: &[T], _vs: &Shape, g: &[T], _gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.run(None, v, g, out);
        Ok(())
    }
}

/// Gradient with respect to the velocity: `g * d(interp)/d(position) * d(position)/d(velocity)`.
struct SlGradVel(SemiLagrangian);

impl Kernel3 for SlGradVel {
    fn name(&self) -> &'static str {
        "semi_lagrangian_grad_velocity"
    }
    fn output_shape(&self, _q: &Shape, v: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(v.clone())
    }
    fn forward<T: Real>(
        &self,
        q: &[T],
        _qs: &Shape,
        vel: &[T],
        _vs: &Shape,
        g: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let sl = &self.0;
        let (nx, ny) = (sl.grid.nx, sl.grid.ny);
        let (n, pn, w) = (nx * ny, (nx + 2) * (ny + 2), nx + 2);
        let nc = sl.layout.chans.len();
        let cfl = sl.cfl();
        let (cx, cy) = (-cfl.0, -cfl.1);
        let mut up = zeros::<T>(pn);
        let mut vp = zeros::<T>(pn);
        let mut qp = zeros::<T>(pn);
        // The u and v ghost-padded gradients side by side: `[gu | gv]`.
        let mut guv = zeros::<T>(2 * pn);
        for (b, (vb, ob)) in vel.chunks(2 * n).zip(out.chunks_mut(2 * n)).enumerate() {
            pad(&vb[..n], nx, ny, &sl.vel.u, true, &mut up);
            pad(&vb[n..], nx, ny, &sl.vel.v, true, &mut vp);
            guv.fill(T::zero());
            for (ch, &(loc, gh)) in sl.layout.chans.iter().enumerate() {
                let off = (b * nc + ch) * n;
                pad(&q[off..off + n], nx, ny, &gh, true, &mut qp);
                let (up, vp, qp) = (&*up, &*vp, &*qp);
                accumulate_rows(&mut guv, ny, parallel_cells(n), |j, guv| {
                    let (gu, gv) = guv.split_at_mut(pn);
                    for i in 0..nx {
                        let a = g[off + j * nx + i];
                        if sl.is_fixed(ch, j, i) || a == T::zero() {
                            continue;
                        }
                        let f = sl.foot(up, vp, j, i, loc, cfl);
                        let c = f.k.map(|k| qp[k].to_f64());
                        let dqx = (1.0 - f.ty) * (c[1] - c[0]) + f.ty * (c[3] - c[2]);
                        let dqy = (1.0 - f.tx) * (c[2] - c[0]) + f.tx * (c[3] - c[1]);
                        let au = a * T::c(dqx * f.sx * cx);
                        let av = a * T::c(dqy * f.sy * cy);
                        vel_at_adjoint(gu, gv, w, (j + 1) * w + i + 1, loc, au, av);
                    }
                });
            }
            let (ou, ov) = ob.split_at_mut(n);
            let (gu, gv) = guv.split_at_mut(pn);
            pad_adjoint(gu, nx, ny, &sl.vel.u, ou);
            pad_adjoint(gv, nx, ny, &sl.vel.v, ov);
        }
        Ok(())
    }
}

/// The limiter bounds as a differentiable op (gradient to the extremal corner of `q`; the
/// velocity only picks the cell, so its gradient is zero almost everywhere).
#[derive(Clone)]
struct Bounds {
    sl: SemiLagrangian,
    max: bool,
}

impl Kernel2 for Bounds {
    fn name(&self) -> &'static str {
        "semi_lagrangian_bounds"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.sl.check_shapes(a, b)?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], _qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.sl.run(q, v, out, if self.max { Mode::Max } else { Mode::Min });
        Ok(())
    }
}

impl Op2 for Bounds {
    fn backward(&self, q: &Tensor, v: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gq = apply_kernel3(q, v, g, BoundsGradQ(SlGradQ { sl: self.sl.clone(), max: Some(self.max) }))?;
        Ok((gq, v.zeros_like()?))
    }
}

struct BoundsGradQ(SlGradQ);

impl Kernel3 for BoundsGradQ {
    fn name(&self) -> &'static str {
        "semi_lagrangian_bounds_grad_q"
    }
    fn output_shape(&self, q: &Shape, _v: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(q.clone())
    }
    fn forward<T: Real>(
        &self,
        q: &[T],
        _qs: &Shape,
        v: &[T],
        _vs: &Shape,
        g: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        self.0.run(Some(q), v, g, out);
        Ok(())
    }
}

/// `clamp(x, lo, hi)` elementwise with the gradient routed to whichever input is active.
#[derive(Clone, Copy)]
pub(crate) struct Clamp;

impl Kernel3 for Clamp {
    fn name(&self) -> &'static str {
        "clamp"
    }
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape> {
        if a != b || a != c {
            candle_core::bail!("clamp: shapes differ: {a:?} {b:?} {c:?}");
        }
        Ok(a.clone())
    }
    fn forward<T: Real>(
        &self,
        x: &[T],
        _s: &Shape,
        lo: &[T],
        _ls: &Shape,
        hi: &[T],
        _hs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        for (((o, &x), &l), &h) in out.iter_mut().zip(x).zip(lo).zip(hi) {
            *o = if x < l {
                l
            } else if x > h {
                h
            } else {
                x
            };
        }
        Ok(())
    }
}

impl pbdl_core::op::Op3 for Clamp {
    fn backward(
        &self,
        x: &Tensor,
        lo: &Tensor,
        hi: &Tensor,
        _y: &Tensor,
        g: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        // Ties go to the bound, so a degenerate interval (lo == hi, e.g. a fixed face) passes
        // nothing to `x`, matching the flat function.
        let below = x.le(lo)?;
        let above = x.ge(hi)?.mul(&below.ne(1u8)?)?;
        let zero = g.zeros_like()?;
        let g_lo = below.where_cond(g, &zero)?;
        let g_hi = above.where_cond(g, &zero)?;
        let g_x = below.add(&above)?.where_cond(&zero, g)?;
        Ok((g_x, g_lo, g_hi))
    }
}
