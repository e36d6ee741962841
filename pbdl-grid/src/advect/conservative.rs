//! Conservative transport of cell-centred scalars: finite-volume flux form with Zalesak's
//! flux-corrected transport (FCT; Boris & Book 1973, Zalesak, J. Comput. Phys. 31, 1979).
//!
//! **Conservation.** One step is
//! `q_ij <- q_ij - (F_{i+1/2,j} - F_{i-1/2,j}) - (G_{i,j+1/2} - G_{i,j-1/2})` with face fluxes
//! (already multiplied by `dt/dx`, `dt/dy`) that are computed once per face and given with
//! opposite signs to the two cells the face separates, so `sum q dx dy` changes only by what
//! crosses the domain boundary: nothing through periodic faces (the fluxes on the two sides are
//! the same numbers) and through walls (no-slip, free-slip, moving wall: zero flux, whatever is
//! stored on the face); the upwind flux through open faces (inflow, outflow). Mass is therefore
//! conserved to round-off, for any velocity (divergence-free or not).
//!
//! **Fluxes.** A face flux is the upwind flux plus a limited correction, `F = F_L + C (F_H - F_L)`:
//! * `F_L`: first-order upwind, `u q_upwind` (monotone for outflow CFL <= 1);
//! * `F_H`: Lax-Wendroff with the transverse term, `u (q_face - dt/2 (u dq/dx + v dq/dy))` with
//!   `q_face` the mean of the two cells, `dq/dx` their difference, `v dq/dy` averaged from the
//!   four `v` faces and the central `y` differences of the two cells. The transverse term keeps
//!   the cross derivative `u v q_xy` of the Taylor series, so the unlimited scheme is second
//!   order in space and time in 2D (the 1D Lax-Wendroff flux per axis would drop it and be first
//!   order in time on diagonal flows);
//! * `C in [0, 1]`: Zalesak's limiter. Per cell it sums the incoming (`P+`) and outgoing (`P-`)
//!   corrections and scales them so that the cell stays within `[q_min, q_max]`, the extrema of
//!   the old values and of the upwind solution over its 3x3 neighbourhood inside the domain
//!   (wrapped across periodic faces); a face takes the smaller of the ratios of the cell it
//!   fills and the cell it drains.
//!
//! **Bound.** The limited update lies within `[q_min, q_max]` of each cell, whatever the
//! velocity (the cell's own upwind value is in the set, and each face's correction is scaled so
//! that neither side's sum of corrections can pass its bound). With a discretely
//! divergence-free velocity (the projected one) and outflow CFL <= 1 the upwind value of a cell
//! is a convex combination of its old value, its face neighbours' and, through inflow faces, the
//! scalar's ghost values; so the new values lie within the old extrema of the 3x3 neighbourhood
//! and of what flows in: no new extrema, to round-off (the global range never grows in closed or
//! periodic boxes). With divergence the upwind part carries it (compression concentrates `q`,
//! as `q_t + div(u q) = 0` says), still without negative values from non-negative ones (upwind
//! at outflow CFL <= 1 has non-negative weights).
//!
//! **CFL.** The upwind part is bounded for outflow CFL
//! `dt (max(u_e, 0) - min(u_w, 0)) / dx + dt (max(v_n, 0) - min(v_s, 0)) / dy <= 1` in every cell.
//! The op sub-cycles: it takes `k = ceil(max outflow CFL)` steps of `dt / k` (one `k` per batch
//! item), so any `dt >= 0` works, at `k` times the cost (at most [`MAX_SUBSTEPS`]).
//!
//! **Accuracy.** Second order where the limiter is inactive; the limiter clips smooth extrema
//! (there it falls towards first order), as every bounded scheme does.
//!
//! **Gradient.** Hand-written vector-Jacobian products with respect to `q` and to the velocity,
//! through the whole limiter (the bounds' arg-extrema, the ratios `Q/P` and their cap at 1, the
//! face `min` and the sign switch of each correction): the exact derivative of the piecewise
//! smooth step wherever it is differentiable, one one-sided derivative on its measure-zero ties.
//! Nothing is frozen. The sub-step count is piecewise constant in the velocity: no gradient.
//! The backward recomputes the forward sub-steps (memory `k` fields per channel).

use super::Advected;
use crate::boundary::{Ghosts, MacGhosts};
use crate::fd::dims4;
use crate::field::{CenteredField, MacField};
use crate::pad::{pad, pad_adjoint};
use crate::scratch::{zeros, Buf};
use crate::{Bc, Error, Grid, Result, ScalarBc, ScalarBoundaries};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply2, apply_kernel3, Kernel2, Kernel3, Op2};
use pbdl_core::Real;

/// The most sub-steps one call takes (outflow CFL up to this number); beyond, the op refuses.
pub const MAX_SUBSTEPS: usize = 4096;

/// One conservative, bounded step: `q` moved by `velocity` over `dt` (`>= 0`) with
/// flux-corrected transport (see the [module docs](self)): mass conserved to round-off, no new
/// extrema for a discretely divergence-free velocity, second order where smooth, sub-cycled to
/// outflow CFL <= 1.
///
/// Every channel of `q` is moved. Walls of `velocity` (no-slip, free-slip, moving wall) pass no
/// flux; inflow and outflow faces pass the upwind flux (the scalar's ghost value coming in);
/// periodic axes must be periodic for both fields. Differentiable in `q` and `velocity`.
pub fn conservative(q: &CenteredField, velocity: &MacField, dt: f64) -> Result<CenteredField> {
    let op = FluxCorrected::new(q, velocity, dt)?;
    Ok(q.with_advected(apply2(q.values(), velocity.values(), op)?))
}

/// What a face does with the flux.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Face {
    /// Inside the domain: full limited flux.
    Interior,
    /// On a periodic boundary: as an interior face, with the neighbour wrapped.
    Periodic,
    /// Solid: no flux.
    Wall,
    /// Inflow or outflow: upwind flux only (no correction: the limiter has no cell outside).
    Open,
}

fn face_kind(b: Bc) -> Face {
    match b {
        Bc::Periodic => Face::Periodic,
        Bc::NoSlip | Bc::FreeSlip | Bc::MovingWall { .. } => Face::Wall,
        Bc::Inflow { .. } | Bc::Outflow => Face::Open,
    }
}

/// One conservative step of a `[batch, C, ny, nx]` scalar by a `[batch, 2, ny, nx]` MAC velocity.
#[derive(Clone, Debug)]
pub(crate) struct FluxCorrected {
    grid: Grid,
    vel: MacGhosts,
    scalar: Ghosts,
    /// Ghosts of the limiter's bounds: periodic axes wrap, other sides copy the nearest cell (a
    /// Dirichlet ghost `2 g - q` is an extrapolation, not a value the scalar takes).
    bound: Ghosts,
    /// Boundary faces `x_lo, x_hi, y_lo, y_hi`.
    faces: [Face; 4],
    dt: f64,
}

/// Forward intermediates of one sub-step (kept for its adjoint).
struct Work<T: Real> {
    /// Padded old values (the scalar's ghosts, for the fluxes; the bounds' ghosts, for the
    /// bounds) and padded upwind solution (the bounds' ghosts).
    qp: Buf<T>,
    qb: Buf<T>,
    tp: Buf<T>,
    /// x faces (`ny x (nx + 1)`): upwind flux, correction `F_H - F_L`, limiter coefficient.
    flx: Buf<T>,
    ax: Buf<T>,
    cx: Buf<T>,
    /// y faces (`(ny + 1) x nx`): the same.
    fly: Buf<T>,
    ay: Buf<T>,
    cy: Buf<T>,
    /// Per cell: upwind solution, bounds, their arg (index into `[qb | tp]`), P+-, R+-.
    td: Buf<T>,
    qmax: Buf<T>,
    qmin: Buf<T>,
    amax: Vec<usize>,
    amin: Vec<usize>,
    pp: Buf<T>,
    pm: Buf<T>,
    rp: Buf<T>,
    rm: Buf<T>,
}

impl<T: Real> Work<T> {
    fn new(nx: usize, ny: usize) -> Self {
        let (n, pn, fx, fy) = (nx * ny, (nx + 2) * (ny + 2), ny * (nx + 1), (ny + 1) * nx);
        Self {
            qp: zeros(pn),
            qb: zeros(pn),
            tp: zeros(pn),
            flx: zeros(fx),
            ax: zeros(fx),
            cx: zeros(fx),
            fly: zeros(fy),
            ay: zeros(fy),
            cy: zeros(fy),
            td: zeros(n),
            qmax: zeros(n),
            qmin: zeros(n),
            amax: vec![0; n],
            amin: vec![0; n],
            pp: zeros(n),
            pm: zeros(n),
            rp: zeros(n),
            rm: zeros(n),
        }
    }
}

/// Adjoint scratch of one sub-step.
struct Back<T: Real> {
    gtd: Buf<T>,
    gax: Buf<T>,
    gay: Buf<T>,
    grp: Buf<T>,
    grm: Buf<T>,
    gqp: Buf<T>,
    gqb: Buf<T>,
    gtp: Buf<T>,
    tmp: Buf<T>,
}

impl<T: Real> Back<T> {
    fn new(nx: usize, ny: usize) -> Self {
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        Self {
            gtd: zeros(n),
            gax: zeros(ny * (nx + 1)),
            gay: zeros((ny + 1) * nx),
            grp: zeros(n),
            grm: zeros(n),
            gqp: zeros(pn),
            gqb: zeros(pn),
            gtp: zeros(pn),
            tmp: zeros(n),
        }
    }
}

#[inline(always)]
pub(crate) fn pos<T: Real>(x: T) -> T {
    x.fmax(T::zero())
}

#[inline(always)]
pub(crate) fn neg<T: Real>(x: T) -> T {
    x.fmin(T::zero())
}

/// `min(a, b)`, ties to `a` (the adjoint follows the same rule).
#[inline(always)]
pub(crate) fn min_first<T: Real>(a: T, b: T) -> T {
    if a <= b {
        a
    } else {
        b
    }
}

impl FluxCorrected {
    pub(crate) fn new(q: &CenteredField, velocity: &MacField, dt: f64) -> Result<Self> {
        let g = *velocity.grid();
        if q.grid() != &g {
            return Err(Error::Invalid {
                field: "velocity",
                reason: format!("lives on {g:?}, the advected field on {:?}", q.grid()),
            });
        }
        if !(dt >= 0.0 && dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("conservative transport needs a finite dt >= 0, got {dt}"),
            });
        }
        if q.values().dims()[0] != velocity.batch() {
            return Err(Error::Shape {
                op: "advect.conservative",
                arg: "velocity",
                expected: format!("batch {} (the advected field's)", q.values().dims()[0]),
                got: velocity.values().dims().to_vec(),
            });
        }
        let (sb, vb) = (q.bc(), velocity.bc());
        for (axis, s, v) in [("x", sb.x_lo, vb.x_lo), ("y", sb.y_lo, vb.y_lo)] {
            if (s == ScalarBc::Periodic) != (v == Bc::Periodic) {
                return Err(Error::Invalid {
                    field: "velocity",
                    reason: format!(
                        "periodic along {axis} for one of the scalar and the velocity but not the other; \
                         conservative transport needs both periodic or both not"
                    ),
                });
            }
        }
        Ok(Self {
            grid: g,
            vel: vb.mac_ghosts(g.nx, g.ny),
            scalar: sb.ghosts(g.nx, g.ny),
            bound: {
                let f = |b: ScalarBc| if b == ScalarBc::Periodic { b } else { ScalarBc::Neumann };
                ScalarBoundaries { x_lo: f(sb.x_lo), x_hi: f(sb.x_hi), y_lo: f(sb.y_lo), y_hi: f(sb.y_hi) }
                    .ghosts(g.nx, g.ny)
            },
            faces: [face_kind(vb.x_lo), face_kind(vb.x_hi), face_kind(vb.y_lo), face_kind(vb.y_hi)],
            dt,
        })
    }

    fn face_x(&self, i: usize) -> Face {
        if i == 0 {
            self.faces[0]
        } else if i == self.grid.nx {
            self.faces[1]
        } else {
            Face::Interior
        }
    }

    fn face_y(&self, k: usize) -> Face {
        if k == 0 {
            self.faces[2]
        } else if k == self.grid.ny {
            self.faces[3]
        } else {
            Face::Interior
        }
    }

    /// Padded velocity entries that the op reads as zero: the normal velocity on wall faces
    /// (padded `u` columns `0` / `nx`, `v` rows `0` / `ny`). Applied after padding (forward) and
    /// to the padded gradient before its adjoint (backward).
    fn zero_walls<T: Real>(&self, up: &mut [T], vp: &mut [T]) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let w = nx + 2;
        for (face, col) in [(self.faces[0], 0), (self.faces[1], nx)] {
            if face == Face::Wall {
                (0..ny + 2).for_each(|jj| up[jj * w + col] = T::zero());
            }
        }
        for (face, row) in [(self.faces[2], 0), (self.faces[3], ny)] {
            if face == Face::Wall {
                vp[row * w..(row + 1) * w].iter_mut().for_each(|x| *x = T::zero());
            }
        }
    }

    /// Pads one batch item's velocity (`[u | v]`, `2 n` values) into `up`, `vp`.
    fn pad_velocity<T: Real>(&self, vb: &[T], up: &mut [T], vp: &mut [T]) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let n = nx * ny;
        pad(&vb[..n], nx, ny, &self.vel.u, true, up);
        pad(&vb[n..], nx, ny, &self.vel.v, true, vp);
        self.zero_walls(up, vp);
    }

    /// Sub-steps for outflow CFL <= 1, and `(dt/dx, dt/dy)` of one sub-step.
    fn substeps<T: Real>(&self, up: &[T], vp: &[T]) -> candle_core::Result<(usize, (T, T))> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let w = nx + 2;
        let (cx, cy) = (self.dt / self.grid.dx(), self.dt / self.grid.dy());
        let mut cfl = 0.0f64;
        for j in 0..ny {
            let r = (j + 1) * w;
            for i in 0..nx {
                let out = cx * (up[r + i + 1].wide().max(0.0) - up[r + i].wide().min(0.0))
                    + cy * (vp[r + i + 1].wide().max(0.0) - vp[r - w + i + 1].wide().min(0.0));
                if out.is_nan() {
                    cfl = f64::NAN;
                } else if out > cfl {
                    cfl = out;
                }
            }
        }
        // NaN velocities give NaN values (one step), not a hang.
        let k = if cfl.is_nan() || cfl <= 1.0 { 1.0 } else { cfl.ceil() };
        if k > MAX_SUBSTEPS as f64 {
            candle_core::bail!(
                "advect.conservative: outflow CFL number {cfl:.3e} needs more than {MAX_SUBSTEPS} sub-steps; \
                 shorten dt"
            );
        }
        let k = k as usize;
        let s = k as f64;
        Ok((k, (T::c(cx / s), T::c(cy / s))))
    }

    /// One sub-step `q -> out`, leaving its intermediates in `wk`.
    #[allow(clippy::too_many_arguments)]
    fn step<T: Real>(&self, wk: &mut Work<T>, up: &[T], vp: &[T], (cx, cy): (T, T), q: &[T], out: &mut [T]) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (w, pn, fw) = (nx + 2, (nx + 2) * (ny + 2), nx + 1);
        let (h, qu, zero, one) = (T::c(0.5), T::c(0.25), T::zero(), T::one());
        pad(q, nx, ny, &self.scalar, true, &mut wk.qp);
        let qp = &*wk.qp;
        // x faces: face (j, i) at x = i dx between cells i - 1 and i (padded columns i, i + 1).
        for j in 0..ny {
            let r = (j + 1) * w;
            for i in 0..=nx {
                let f = j * fw + i;
                let kind = self.face_x(i);
                if kind == Face::Wall {
                    wk.flx[f] = zero;
                    wk.ax[f] = zero;
                    continue;
                }
                let u = up[r + i];
                let (ql, qr) = (qp[r + i], qp[r + i + 1]);
                let fl = cx * (pos(u) * ql + neg(u) * qr);
                wk.flx[f] = fl;
                wk.ax[f] = if kind == Face::Open {
                    zero
                } else {
                    let vb = qu * (vp[r - w + i] + vp[r - w + i + 1] + vp[r + i] + vp[r + i + 1]);
                    let dy = qu * ((qp[r + w + i] - qp[r - w + i]) + (qp[r + w + i + 1] - qp[r - w + i + 1]));
                    let fh = cx * u * (h * (ql + qr) - h * cx * u * (qr - ql) - h * cy * vb * dy);
                    fh - fl
                };
            }
        }
        // y faces: face (k, i) at y = k dy between cell rows k - 1 and k (padded rows k, k + 1).
        for k in 0..=ny {
            let r = k * w;
            let kind = self.face_y(k);
            for i in 0..nx {
                let f = k * nx + i;
                if kind == Face::Wall {
                    wk.fly[f] = zero;
                    wk.ay[f] = zero;
                    continue;
                }
                let v = vp[r + i + 1];
                let (qb, qt) = (qp[r + i + 1], qp[r + w + i + 1]);
                let fl = cy * (pos(v) * qb + neg(v) * qt);
                wk.fly[f] = fl;
                wk.ay[f] = if kind == Face::Open {
                    zero
                } else {
                    let ub = qu * (up[r + i] + up[r + i + 1] + up[r + w + i] + up[r + w + i + 1]);
                    let dx = qu * ((qp[r + i + 2] - qp[r + i]) + (qp[r + w + i + 2] - qp[r + w + i]));
                    let fh = cy * v * (h * (qb + qt) - h * cy * v * (qt - qb) - h * cx * ub * dx);
                    fh - fl
                };
            }
        }
        // Upwind solution.
        for j in 0..ny {
            for i in 0..nx {
                let (c, fx, fy) = (j * nx + i, j * fw + i, j * nx + i);
                wk.td[c] = q[c] - (wk.flx[fx + 1] - wk.flx[fx]) - (wk.fly[fy + nx] - wk.fly[fy]);
            }
        }
        pad(q, nx, ny, &self.bound, true, &mut wk.qb);
        pad(&wk.td, nx, ny, &self.bound, true, &mut wk.tp);
        // Bounds over the 3x3 neighbourhood of old and upwind values; Zalesak's ratios.
        let (qb, tp) = (&*wk.qb, &*wk.tp);
        for j in 0..ny {
            for i in 0..nx {
                let c = j * nx + i;
                let pc = (j + 1) * w + i + 1;
                let (mut hi, mut ahi, mut lo, mut alo) = (tp[pc], pn + pc, tp[pc], pn + pc);
                for row in [pc - w, pc, pc + w] {
                    for k in row - 1..=row + 1 {
                        for (v, code) in [(qb[k], k), (tp[k], pn + k)] {
                            if v > hi {
                                hi = v;
                                ahi = code;
                            }
                            if v < lo {
                                lo = v;
                                alo = code;
                            }
                        }
                    }
                }
                wk.qmax[c] = hi;
                wk.qmin[c] = lo;
                wk.amax[c] = ahi;
                wk.amin[c] = alo;
                let (fx, fy) = (j * fw + i, j * nx + i);
                let parts = [wk.ax[fx], -wk.ax[fx + 1], wk.ay[fy], -wk.ay[fy + nx]];
                let pp = parts.iter().fold(zero, |s, &x| s + pos(x));
                let pm = parts.iter().fold(zero, |s, &x| s + neg(x));
                wk.pp[c] = pp;
                wk.pm[c] = pm;
                let td = wk.td[c];
                wk.rp[c] = if pp > zero { min_first((hi - td) / pp, one) } else { zero };
                wk.rm[c] = if pm < zero { min_first((lo - td) / pm, one) } else { zero };
            }
        }
        // Face coefficients: the correction may fill the downstream cell and drain the upstream
        // one only as far as both allow.
        for j in 0..ny {
            for i in 0..=nx {
                let f = j * fw + i;
                wk.cx[f] = match self.face_x(i) {
                    Face::Wall | Face::Open => zero,
                    _ => {
                        let (l, r) =
                            (j * nx + if i == 0 { nx - 1 } else { i - 1 }, j * nx + if i == nx { 0 } else { i });
                        let (a, b) = if wk.ax[f] >= zero { (wk.rp[r], wk.rm[l]) } else { (wk.rp[l], wk.rm[r]) };
                        min_first(a, b)
                    }
                };
            }
        }
        for k in 0..=ny {
            let kind = self.face_y(k);
            for i in 0..nx {
                let f = k * nx + i;
                wk.cy[f] = match kind {
                    Face::Wall | Face::Open => zero,
                    _ => {
                        let (b, t) =
                            ((if k == 0 { ny - 1 } else { k - 1 }) * nx + i, (if k == ny { 0 } else { k }) * nx + i);
                        let (x, y) = if wk.ay[f] >= zero { (wk.rp[t], wk.rm[b]) } else { (wk.rp[b], wk.rm[t]) };
                        min_first(x, y)
                    }
                };
            }
        }
        for j in 0..ny {
            for i in 0..nx {
                let (c, fx, fy) = (j * nx + i, j * fw + i, j * nx + i);
                let east = wk.cx[fx + 1] * wk.ax[fx + 1];
                let west = wk.cx[fx] * wk.ax[fx];
                let north = wk.cy[fy + nx] * wk.ay[fy + nx];
                let south = wk.cy[fy] * wk.ay[fy];
                out[c] = wk.td[c] - (east - west) - (north - south);
            }
        }
    }

    /// Adjoint of one sub-step whose forward left `wk`: `gq = (d out / d q)^T g`, and the
    /// velocity part added into the padded `gu`, `gv`.
    #[allow(clippy::too_many_arguments)]
    fn step_adjoint<T: Real>(
        &self,
        wk: &Work<T>,
        bk: &mut Back<T>,
        up: &[T],
        vp: &[T],
        (cx, cy): (T, T),
        g: &[T],
        gq: &mut [T],
        gu: &mut [T],
        gv: &mut [T],
    ) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (w, pn, fw) = (nx + 2, (nx + 2) * (ny + 2), nx + 1);
        let (h, qu, zero, one) = (T::c(0.5), T::c(0.25), T::zero(), T::one());
        bk.gtd.copy_from_slice(g);
        for b in [&mut bk.gax, &mut bk.gay, &mut bk.grp, &mut bk.grm, &mut bk.gqp, &mut bk.gqb, &mut bk.gtp] {
            b.fill(zero);
        }
        // out = td - div(C A): to C and A, then C = min(R+, R-) to the ratio it took.
        for j in 0..ny {
            for i in 0..=nx {
                let f = j * fw + i;
                if matches!(self.face_x(i), Face::Wall | Face::Open) {
                    continue;
                }
                let gd = (if i < nx { g[j * nx + i] } else { zero }) - (if i > 0 { g[j * nx + i - 1] } else { zero });
                bk.gax[f] += gd * wk.cx[f];
                let gc = gd * wk.ax[f];
                let (l, r) = (j * nx + if i == 0 { nx - 1 } else { i - 1 }, j * nx + if i == nx { 0 } else { i });
                let (p, m) = if wk.ax[f] >= zero { (r, l) } else { (l, r) };
                if wk.rp[p] <= wk.rm[m] {
                    bk.grp[p] += gc;
                } else {
                    bk.grm[m] += gc;
                }
            }
        }
        for k in 0..=ny {
            if matches!(self.face_y(k), Face::Wall | Face::Open) {
                continue;
            }
            for i in 0..nx {
                let f = k * nx + i;
                let gd = (if k < ny { g[k * nx + i] } else { zero }) - (if k > 0 { g[(k - 1) * nx + i] } else { zero });
                bk.gay[f] += gd * wk.cy[f];
                let gc = gd * wk.ay[f];
                let (b, t) = ((if k == 0 { ny - 1 } else { k - 1 }) * nx + i, (if k == ny { 0 } else { k }) * nx + i);
                let (p, m) = if wk.ay[f] >= zero { (t, b) } else { (b, t) };
                if wk.rp[p] <= wk.rm[m] {
                    bk.grp[p] += gc;
                } else {
                    bk.grm[m] += gc;
                }
            }
        }
        // R+- = min(Q+- / P+-, 1): to the bounds, the upwind solution and the corrections.
        for j in 0..ny {
            for i in 0..nx {
                let c = j * nx + i;
                let (fx, fy) = (j * fw + i, j * nx + i);
                let td = wk.td[c];
                let mut gpp = zero;
                let mut gpm = zero;
                if wk.pp[c] > zero {
                    let ratio = (wk.qmax[c] - td) / wk.pp[c];
                    if ratio <= one {
                        let gq_ = bk.grp[c] / wk.pp[c];
                        gpp = -bk.grp[c] * ratio / wk.pp[c];
                        bk.gtd[c] -= gq_;
                        let a = wk.amax[c];
                        if a < pn {
                            bk.gqb[a] += gq_;
                        } else {
                            bk.gtp[a - pn] += gq_;
                        }
                    }
                }
                if wk.pm[c] < zero {
                    let ratio = (wk.qmin[c] - td) / wk.pm[c];
                    if ratio <= one {
                        let gq_ = bk.grm[c] / wk.pm[c];
                        gpm = -bk.grm[c] * ratio / wk.pm[c];
                        bk.gtd[c] -= gq_;
                        let a = wk.amin[c];
                        if a < pn {
                            bk.gqb[a] += gq_;
                        } else {
                            bk.gtp[a - pn] += gq_;
                        }
                    }
                }
                // P+ = sum pos(s_k a_k), P- = sum neg(s_k a_k).
                let idx = [(fx, true, one), (fx + 1, true, -one), (fy, false, one), (fy + nx, false, -one)];
                for (f, is_x, s) in idx {
                    let a = if is_x { wk.ax[f] } else { wk.ay[f] };
                    let part = s * a;
                    let ga = if part > zero {
                        s * gpp
                    } else if part < zero {
                        s * gpm
                    } else {
                        zero
                    };
                    if is_x {
                        bk.gax[f] += ga;
                    } else {
                        bk.gay[f] += ga;
                    }
                }
            }
        }
        pad_adjoint(&mut bk.gtp, nx, ny, &self.bound, &mut bk.tmp);
        for (a, b) in bk.gtd.iter_mut().zip(bk.tmp.iter()) {
            *a += *b;
        }
        // td = q - div(F_L); A = F_H - F_L.
        gq.copy_from_slice(&bk.gtd);
        let (gtd, qp, gqp) = (&*bk.gtd, &*wk.qp, &mut *bk.gqp);
        for j in 0..ny {
            let r = (j + 1) * w;
            for i in 0..=nx {
                let f = j * fw + i;
                let kind = self.face_x(i);
                if kind == Face::Wall {
                    continue;
                }
                let ga = bk.gax[f];
                let gfl = (if i < nx { gtd[j * nx + i] } else { zero })
                    - (if i > 0 { gtd[j * nx + i - 1] } else { zero })
                    - ga;
                let u = up[r + i];
                let (ql, qr) = (qp[r + i], qp[r + i + 1]);
                gqp[r + i] += gfl * cx * pos(u);
                gqp[r + i + 1] += gfl * cx * neg(u);
                gu[r + i] += gfl * cx * if u >= zero { ql } else { qr };
                if kind == Face::Open || ga == zero {
                    continue;
                }
                let vb = qu * (vp[r - w + i] + vp[r - w + i + 1] + vp[r + i] + vp[r + i + 1]);
                let dy = qu * ((qp[r + w + i] - qp[r - w + i]) + (qp[r + w + i + 1] - qp[r - w + i + 1]));
                let a1 = ga * cx * u;
                gqp[r + i] += a1 * (h + h * cx * u);
                gqp[r + i + 1] += a1 * (h - h * cx * u);
                let gdy = -a1 * h * cy * vb * qu;
                gqp[r + w + i] += gdy;
                gqp[r - w + i] -= gdy;
                gqp[r + w + i + 1] += gdy;
                gqp[r - w + i + 1] -= gdy;
                gu[r + i] += ga * cx * (h * (ql + qr) - cx * u * (qr - ql) - h * cy * vb * dy);
                let gvb = -a1 * h * cy * dy * qu;
                for k in [r - w + i, r - w + i + 1, r + i, r + i + 1] {
                    gv[k] += gvb;
                }
            }
        }
        for k in 0..=ny {
            let r = k * w;
            let kind = self.face_y(k);
            if kind == Face::Wall {
                continue;
            }
            for i in 0..nx {
                let f = k * nx + i;
                let ga = bk.gay[f];
                let gfl = (if k < ny { gtd[k * nx + i] } else { zero })
                    - (if k > 0 { gtd[(k - 1) * nx + i] } else { zero })
                    - ga;
                let v = vp[r + i + 1];
                let (qb, qt) = (qp[r + i + 1], qp[r + w + i + 1]);
                gqp[r + i + 1] += gfl * cy * pos(v);
                gqp[r + w + i + 1] += gfl * cy * neg(v);
                gv[r + i + 1] += gfl * cy * if v >= zero { qb } else { qt };
                if kind == Face::Open || ga == zero {
                    continue;
                }
                let ub = qu * (up[r + i] + up[r + i + 1] + up[r + w + i] + up[r + w + i + 1]);
                let dx = qu * ((qp[r + i + 2] - qp[r + i]) + (qp[r + w + i + 2] - qp[r + w + i]));
                let a1 = ga * cy * v;
                gqp[r + i + 1] += a1 * (h + h * cy * v);
                gqp[r + w + i + 1] += a1 * (h - h * cy * v);
                let gdx = -a1 * h * cx * ub * qu;
                gqp[r + i + 2] += gdx;
                gqp[r + i] -= gdx;
                gqp[r + w + i + 2] += gdx;
                gqp[r + w + i] -= gdx;
                gv[r + i + 1] += ga * cy * (h * (qb + qt) - cy * v * (qt - qb) - h * cx * ub * dx);
                let gub = -a1 * h * cx * dx * qu;
                for m in [r + i, r + i + 1, r + w + i, r + w + i + 1] {
                    gu[m] += gub;
                }
            }
        }
        pad_adjoint(gqp, nx, ny, &self.scalar, &mut bk.tmp);
        for (a, b) in gq.iter_mut().zip(bk.tmp.iter()) {
            *a += *b;
        }
        pad_adjoint(&mut bk.gqb, nx, ny, &self.bound, &mut bk.tmp);
        for (a, b) in gq.iter_mut().zip(bk.tmp.iter()) {
            *a += *b;
        }
    }

    fn check_shapes(&self, q: &Shape, v: &Shape) -> candle_core::Result<()> {
        let (b, _c, ny, nx) = dims4(q)?;
        let vd = dims4(v)?;
        let g = self.grid;
        if ny != g.ny || nx != g.nx || vd != (b, 2, g.ny, g.nx) {
            candle_core::bail!(
                "advect.conservative: q {q:?} and velocity {v:?} do not fit a scalar and a MAC velocity on {}x{}",
                g.ny,
                g.nx
            );
        }
        Ok(())
    }

    /// Forward over all batch items and channels; with `grad = Some((g, wrt_velocity))` the
    /// adjoint instead (the gradient with respect to `q`, or to the velocity).
    fn run<T: Real>(
        &self,
        q: &[T],
        q_shape: &Shape,
        vel: &[T],
        grad: Option<(&[T], bool)>,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let (batch, chans, ny, nx) = dims4(q_shape)?;
        let (n, pn) = (nx * ny, (nx + 2) * (ny + 2));
        let mut up = zeros::<T>(pn);
        let mut vp = zeros::<T>(pn);
        let mut wk = Work::<T>::new(nx, ny);
        let mut scratch = zeros::<T>(n);
        for b in 0..batch {
            self.pad_velocity(&vel[2 * b * n..2 * (b + 1) * n], &mut up, &mut vp);
            let (k, c) = self.substeps(&up, &vp)?;
            let Some((g, wrt_velocity)) = grad else {
                for ch in 0..chans {
                    let off = (b * chans + ch) * n;
                    let o = &mut out[off..off + n];
                    o.copy_from_slice(&q[off..off + n]);
                    for _ in 0..k {
                        scratch.copy_from_slice(o);
                        self.step(&mut wk, &up, &vp, c, &scratch, o);
                    }
                }
                continue;
            };
            let mut bk = Back::<T>::new(nx, ny);
            let mut gu = zeros::<T>(pn);
            let mut gv = zeros::<T>(pn);
            let mut states = vec![T::zero(); k * n];
            let mut gcur = zeros::<T>(n);
            let mut gnext = zeros::<T>(n);
            for ch in 0..chans {
                let off = (b * chans + ch) * n;
                states[..n].copy_from_slice(&q[off..off + n]);
                for s in 1..k {
                    let (prev, next) = states.split_at_mut(s * n);
                    self.step(&mut wk, &up, &vp, c, &prev[(s - 1) * n..], &mut next[..n]);
                }
                gcur.copy_from_slice(&g[off..off + n]);
                for s in (0..k).rev() {
                    self.step(&mut wk, &up, &vp, c, &states[s * n..(s + 1) * n], &mut scratch);
                    self.step_adjoint(&wk, &mut bk, &up, &vp, c, &gcur, &mut gnext, &mut gu, &mut gv);
                    std::mem::swap(&mut gcur, &mut gnext);
                }
                if !wrt_velocity {
                    out[off..off + n].copy_from_slice(&gcur);
                }
            }
            if wrt_velocity {
                // The op read the wall faces as zero: no gradient reaches the stored values there.
                self.zero_walls(&mut gu, &mut gv);
                let (ou, ov) = out[2 * b * n..2 * (b + 1) * n].split_at_mut(n);
                pad_adjoint(&mut gu, nx, ny, &self.vel.u, ou);
                pad_adjoint(&mut gv, nx, ny, &self.vel.v, ov);
            }
        }
        Ok(())
    }
}

impl Kernel2 for FluxCorrected {
    fn name(&self) -> &'static str {
        "advect_conservative"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.check_shapes(a, b)?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.run(q, qs, v, None, out)
    }
}

impl Op2 for FluxCorrected {
    fn backward(&self, q: &Tensor, v: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gq = apply_kernel3(q, v, g, FluxCorrectedGrad { op: self.clone(), wrt_velocity: false })?;
        let gv = apply_kernel3(q, v, g, FluxCorrectedGrad { op: self.clone(), wrt_velocity: true })?;
        Ok((gq, gv))
    }
}

/// The vector-Jacobian product of [`FluxCorrected`], inputs `(q, velocity, g)`, with respect to
/// `q` or to the velocity.
struct FluxCorrectedGrad {
    op: FluxCorrected,
    wrt_velocity: bool,
}

impl Kernel3 for FluxCorrectedGrad {
    fn name(&self) -> &'static str {
        if self.wrt_velocity {
            "advect_conservative_grad_velocity"
        } else {
            "advect_conservative_grad_q"
        }
    }
    fn output_shape(&self, q: &Shape, v: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(if self.wrt_velocity { v.clone() } else { q.clone() })
    }
    fn forward<T: Real>(
        &self,
        q: &[T],
        qs: &Shape,
        v: &[T],
        _vs: &Shape,
        g: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        self.op.run(q, qs, v, Some((g, self.wrt_velocity)), out)
    }
}
