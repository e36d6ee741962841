//! The momentum right-hand side on a MAC grid: central flux-form advection plus explicit viscous
//! diffusion, fused in one custom op (one pass over memory instead of two).

use crate::boundary::MacGhosts;
use crate::fd::dims4;
use crate::field::MacField;
use crate::pad::{for_rows, pad, pad_adjoint, parallel_cells};
use crate::scratch::uninit;
use crate::{Grid, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel2, Kernel1, Kernel2, Op1};
use pbdl_core::Real;

/// The advective tendency `-div(u u)` of a MAC velocity, on its faces (fixed boundary faces get 0).
pub fn flux_form(u: &MacField) -> Result<MacField> {
    let rhs = MomentumRhs::new(u, true, 0.0);
    u.with_values(rhs.apply(u.values())?)
}

/// `advect * (-div(u u)) + nu * lap(u)` on the faces of a MAC velocity.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MomentumRhs {
    pub grid: Grid,
    pub ghosts: MacGhosts,
    pub advect: bool,
    pub nu: f64,
}

/// Per-grid constants of the stencil, in the kernel's float type.
struct Coef<T> {
    a: T,
    h: T,
    idx: T,
    idy: T,
    ax: T,
    ay: T,
    nu: T,
}

impl MomentumRhs {
    pub(crate) fn new(u: &MacField, advect: bool, nu: f64) -> Self {
        let g = *u.grid();
        Self { grid: g, ghosts: u.bc().mac_ghosts(g.nx, g.ny), advect, nu }
    }

    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, *self)
    }

    fn coef<T: Real>(&self) -> Coef<T> {
        let (dx, dy) = (self.grid.dx(), self.grid.dy());
        Coef {
            a: T::c(if self.advect { 1.0 } else { 0.0 }),
            h: T::c(0.5),
            idx: T::c(1.0 / dx),
            idy: T::c(1.0 / dy),
            ax: T::c(1.0 / (dx * dx)),
            ay: T::c(1.0 / (dy * dy)),
            nu: T::c(self.nu),
        }
    }
}

impl Kernel1 for MomentumRhs {
    fn name(&self) -> &'static str {
        "momentum_rhs"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (n, w) = (nx * ny, nx + 2);
        let k = self.coef::<T>();
        let two = T::c(2.0);
        // `pad` writes every element of the padded buffers.
        let mut up = uninit::<T>(w * (ny + 2));
        let mut vp = uninit::<T>(w * (ny + 2));
        let (u_fixed, v_fixed) = (self.ghosts.u_fixed.is_some(), self.ghosts.v_fixed.is_some());
        for (xb, ob) in x.chunks(2 * n).zip(out.chunks_mut(2 * n)) {
            pad(&xb[..n], nx, ny, &self.ghosts.u, true, &mut up);
            pad(&xb[n..], nx, ny, &self.ghosts.v, true, &mut vp);
            let (up, vp) = (&*up, &*vp);
            for_rows(ob, nx, parallel_cells(n), |row, o| {
                let o = &mut o[..nx];
                if row < ny {
                    let r = (row + 1) * w;
                    let (um, u0, un) = (&up[r - w..r], &up[r..r + w], &up[r + w..r + 2 * w]);
                    let (vm, v0) = (&vp[r - w..r], &vp[r..r + w]);
                    for i in 0..nx {
                        let (uc, ue_, uw_) = (u0[i + 1], u0[i + 2], u0[i]);
                        let (ue, uw) = (k.h * (uc + ue_), k.h * (uw_ + uc));
                        let (vn, unn) = (k.h * (v0[i + 1] + v0[i + 2]), k.h * (uc + un[i + 1]));
                        let (vs, uss) = (k.h * (vm[i + 1] + vm[i + 2]), k.h * (um[i + 1] + uc));
                        let adv = (ue * ue - uw * uw) * k.idx + (vn * unn - vs * uss) * k.idy;
                        let lap = (ue_ + uw_ - two * uc) * k.ax + (un[i + 1] + um[i + 1] - two * uc) * k.ay;
                        o[i] = k.nu * lap - k.a * adv;
                    }
                    if u_fixed {
                        o[nx - 1] = T::zero();
                    }
                } else {
                    let j = row - ny;
                    if v_fixed && j == ny - 1 {
                        o.iter_mut().for_each(|x| *x = T::zero());
                        return;
                    }
                    let r = (j + 1) * w;
                    let (vm, v0, vn) = (&vp[r - w..r], &vp[r..r + w], &vp[r + w..r + 2 * w]);
                    let (u0, un) = (&up[r..r + w], &up[r + w..r + 2 * w]);
                    for i in 0..nx {
                        let (vc, vn_, vs_, ve_, vw_) = (v0[i + 1], vn[i + 1], vm[i + 1], v0[i + 2], v0[i]);
                        let (vnf, vsf) = (k.h * (vc + vn_), k.h * (vs_ + vc));
                        let (ue, ve) = (k.h * (u0[i + 1] + un[i + 1]), k.h * (vc + ve_));
                        let (uw, vw) = (k.h * (u0[i] + un[i]), k.h * (vw_ + vc));
                        let adv = (vnf * vnf - vsf * vsf) * k.idy + (ue * ve - uw * vw) * k.idx;
                        let lap = (ve_ + vw_ - two * vc) * k.ax + (vn_ + vs_ - two * vc) * k.ay;
                        o[i] = k.nu * lap - k.a * adv;
                    }
                }
            });
        }
        Ok(())
    }
}

impl Op1 for MomentumRhs {
    fn backward(&self, x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, gy, MomentumRhsAdjoint(*self))
    }
}

/// Vector-Jacobian product of [`MomentumRhs`] at `x` with cotangent `g`.
struct MomentumRhsAdjoint(MomentumRhs);

impl Kernel2 for MomentumRhsAdjoint {
    fn name(&self) -> &'static str {
        "momentum_rhs_adjoint"
    }
    fn output_shape(&self, a: &Shape, _b: &Shape) -> candle_core::Result<Shape> {
        let _ = dims4(a)?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _xs: &Shape, g: &[T], _gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let (nx, ny) = (op.grid.nx, op.grid.ny);
        let (n, w) = (nx * ny, nx + 2);
        let k = op.coef::<T>();
        let diag = T::c(-2.0) * k.nu * (k.ax + k.ay);
        let mut up = vec![T::zero(); w * (ny + 2)];
        let mut vp = up.clone();
        let mut gu = up.clone();
        let mut gv = up.clone();
        let (u_fixed, v_fixed) = (op.ghosts.u_fixed.is_some(), op.ghosts.v_fixed.is_some());
        for ((xb, gb), ob) in x.chunks(2 * n).zip(g.chunks(2 * n)).zip(out.chunks_mut(2 * n)) {
            pad(&xb[..n], nx, ny, &op.ghosts.u, true, &mut up);
            pad(&xb[n..], nx, ny, &op.ghosts.v, true, &mut vp);
            gu.iter_mut().chain(gv.iter_mut()).for_each(|x| *x = T::zero());
            for j in 0..ny {
                let r = (j + 1) * w;
                for i in 0..nx {
                    let c = r + i + 1; // padded (J, I)
                                       // u equation at (J, I).
                    let g1 = if u_fixed && i == nx - 1 { T::zero() } else { gb[j * nx + i] };
                    let uc = up[c];
                    let (ue, uw) = (k.h * (uc + up[c + 1]), k.h * (up[c - 1] + uc));
                    let (vn, unn) = (k.h * (vp[c] + vp[c + 1]), k.h * (uc + up[c + w]));
                    let (vs, uss) = (k.h * (vp[c - w] + vp[c - w + 1]), k.h * (up[c - w] + uc));
                    gu[c] += g1 * (diag - k.a * ((ue - uw) * k.idx + k.h * (vn - vs) * k.idy));
                    gu[c + 1] += g1 * (k.nu * k.ax - k.a * ue * k.idx);
                    gu[c - 1] += g1 * (k.nu * k.ax + k.a * uw * k.idx);
                    gu[c + w] += g1 * (k.nu * k.ay - k.a * k.h * vn * k.idy);
                    gu[c - w] += g1 * (k.nu * k.ay + k.a * k.h * vs * k.idy);
                    let tn = g1 * k.a * k.h * unn * k.idy;
                    gv[c] -= tn;
                    gv[c + 1] -= tn;
                    let ts = g1 * k.a * k.h * uss * k.idy;
                    gv[c - w] += ts;
                    gv[c - w + 1] += ts;
                    // v equation at (J, I).
                    let g2 = if v_fixed && j == ny - 1 { T::zero() } else { gb[n + j * nx + i] };
                    let vc = vp[c];
                    let (vnf, vsf) = (k.h * (vc + vp[c + w]), k.h * (vp[c - w] + vc));
                    let (ue, ve) = (k.h * (up[c] + up[c + w]), k.h * (vc + vp[c + 1]));
                    let (uw, vw) = (k.h * (up[c - 1] + up[c + w - 1]), k.h * (vp[c - 1] + vc));
                    gv[c] += g2 * (diag - k.a * ((vnf - vsf) * k.idy + k.h * (ue - uw) * k.idx));
                    gv[c + w] += g2 * (k.nu * k.ay - k.a * vnf * k.idy);
                    gv[c - w] += g2 * (k.nu * k.ay + k.a * vsf * k.idy);
                    gv[c + 1] += g2 * (k.nu * k.ax - k.a * k.h * ue * k.idx);
                    gv[c - 1] += g2 * (k.nu * k.ax + k.a * k.h * uw * k.idx);
                    let te = g2 * k.a * k.h * ve * k.idx;
                    gu[c] -= te;
                    gu[c + w] -= te;
                    let tw = g2 * k.a * k.h * vw * k.idx;
                    gu[c - 1] += tw;
                    gu[c + w - 1] += tw;
                }
            }
            let (ou, ov) = ob.split_at_mut(n);
            pad_adjoint(&mut gu, nx, ny, &op.ghosts.u, ou);
            pad_adjoint(&mut gv, nx, ny, &op.ghosts.v, ov);
        }
        Ok(())
    }
}
