//! Conservative transport of cell-centred scalars in 3D: finite-volume flux form with Zalesak's
//! flux-corrected transport (FCT), the 3D form of the 2D [`crate::advect::conservative()`].
//!
//! **Layout.** `q` is `[batch, C, nz, ny, nx]` (every channel moved), the velocity a
//! [`MacField3d`]: `u` index `i` on the x-face at `(i + 1) dx` (the same for `v`, `w`). Each
//! axis is either [`AxisFaces3d::Wall`] (the closed box of [`super::Smoke3d`] and
//! [`super::Cavity3d`]: the faces at `0` and at `l` pass no flux, whatever the last stored face
//! holds) or [`AxisFaces3d::Periodic`] (stored index `n - 1` is the face at `l`, which is the face
//! at `0`). The 3D grid has no inflow or outflow faces, so there is no open face here.
//!
//! **Conservation.** One step is `q_c <- q_c - sum over the six faces of +-F_face`, with face
//! fluxes (already times `dt / h`) computed once per face and given with opposite signs to the
//! two cells the face separates: `sum q dx dy dz` changes by nothing (walls pass no flux,
//! periodic faces the same number on both sides), to round-off, for any velocity.
//!
//! **Fluxes.** `F = F_L + C (F_H - F_L)` per face:
//! * `F_L`: first-order upwind `u q_upwind`;
//! * `F_H`: Lax-Wendroff with *both* transverse terms. For constant `u = (u1, u2, u3)` the
//!   Taylor series of the exact step is `q - dt u.grad q + dt^2 / 2 sum_a sum_b u_a u_b q_ab +
//!   O(dt^3)`. A flux `F_a = dt u_a (q - dt / 2 u.grad q)` at the `a`-faces gives, through the
//!   divergence, `- dt u.grad q + dt^2 / 2 sum_a u_a d_a (sum_b u_b q_b)`: exactly that series
//!   to second order. So the face flux along `a` must carry the full `u.grad q`: its own-axis
//!   difference `u_a (q_r - q_l) / h_a` and, for each of the two other axes `b`, `u_b dq/db`
//!   with `u_b` the mean of the four `b`-faces of the two cells and `dq/db` the mean of the two
//!   cells' central differences. Each mixed term `u_a u_b q_ab` (a != b) then enters twice (once
//!   from the `a`-faces, once from the `b`-faces), as in the series. The 1D Lax-Wendroff flux per
//!   axis (no transverse terms) would miss them and be first order in time on diagonal flows.
//!   The triple-product term `u1 u2 u3 q_xyz` of Colella's/Saltzman's 3D corner transport
//!   upwind is `O(dt^3)`: not needed for second order, so it is left out;
//! * `C in [0, 1]`: Zalesak's limiter. Per cell the incoming (`P+`) and outgoing (`P-`)
//!   corrections are summed and scaled so that the cell stays within `[q_min, q_max]`, the
//!   extrema of the old values and of the upwind solution over its 3x3x3 neighbourhood (wrapped
//!   across periodic faces, the nearest cell repeated beyond walls); a face takes the smaller of
//!   the ratios of the cell it fills and the cell it drains. With
//!   [`Conservative3d::limiter`] off, `C = 1` (the plain Lax-Wendroff scheme, for accuracy tests
//!   only: not bounded, and not a stable scheme on its own in 3D. Its von Neumann amplification
//!   for a constant velocity is `1 - i sum c_a sin t_a - 2 sum c_a^2 sin^2(t_a / 2) - 1/2
//!   sum_(a != b) c_a c_b sin t_a sin t_b` (`c_a = u_a dt / h_a`), whose modulus exceeds 1 on
//!   diagonal flows from a Courant number of about 0.2 per axis (1.004 at 0.25, 1.03 at 0.3; in
//!   2D from about 0.35 per axis): high-frequency modes grow slowly. The limited scheme is
//!   bounded whatever the high-order flux does, so this costs it only limiter activity).
//!
//! **Bound.** The limited update lies within `[q_min, q_max]` of each cell. With a discretely
//! divergence-free velocity and outflow CFL `<= 1` the upwind value of a cell is a convex
//! combination of its old value and its face neighbours': no new extrema, to round-off.
//!
//! **CFL.** Outflow CFL per cell `dt sum_a (max(u_a+, 0) - min(u_a-, 0)) / h_a` (the cell's
//! upper and lower face along `a`). The op sub-cycles: `k = ceil(max outflow CFL)` steps of
//! `dt / k` (one `k` per batch item, at most [`MAX_SUBSTEPS`]).
//!
//! **Accuracy.** Second order where the limiter is inactive (tests/conservative3d.rs measures
//! the order of both); the limiter clips smooth extrema.
//!
//! **Gradient.** None yet: a backward pass through this op is an error (the 2D op has the full
//! adjoint; the 3D one is a forward scheme for now). [`super::Smoke3d`] reports itself
//! partially differentiable when its density uses it.
//!
//! **Parallelism.** Every pass runs over z-slabs (faces, cells), with rayon for large grids
//! (the crate's row policy).

use super::field::{check_values, MacField3d};
use super::Grid3d;
use crate::advect::conservative::{min_first, neg, pos, MAX_SUBSTEPS};
use crate::pad::{for_rows, parallel_cells};
use crate::scratch::zeros;
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply2, Kernel2, Op2};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// The two faces of the box along one axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AxisFaces3d {
    /// Impermeable walls at `0` and `l` (zero flux; the scalar's ghost repeats the nearest cell).
    #[default]
    Wall,
    /// Periodic: the face at `l` is the face at `0`.
    Periodic,
    /// A wall at `0` and an open face at `l` (outflow): the stored last face's velocity carries
    /// the first-order upwind flux with the nearest cell as the outside value (zero gradient), no
    /// high-order correction there. What leaves is counted by [`Conservative3d::step_counting`].
    OpenHi,
}

/// A conservative, bounded transport of cell-centred scalars (see the [module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Conservative3d {
    /// Faces along `[x, y, z]`.
    pub faces: [AxisFaces3d; 3],
    /// Zalesak's limiter (on: bounded, mass-conserving; off: plain Lax-Wendroff with transverse
    /// terms, second order but not bounded).
    pub limiter: bool,
}

impl Default for Conservative3d {
    fn default() -> Self {
        Self::closed_box()
    }
}

impl Conservative3d {
    /// Walls on all six faces (the smoke box), limited.
    pub fn closed_box() -> Self {
        Self { faces: [AxisFaces3d::Wall; 3], limiter: true }
    }

    /// Periodic along every axis, limited.
    pub fn periodic() -> Self {
        Self { faces: [AxisFaces3d::Periodic; 3], limiter: true }
    }

    /// The same faces without the limiter.
    pub fn unlimited(self) -> Self {
        Self { limiter: false, ..self }
    }

    /// One step of `q` (`[batch, C, nz, ny, nx]`, f32 or f64) moved by `velocity` over `dt >= 0`,
    /// sub-cycled to outflow CFL <= 1. Typed errors for a shape, batch or dtype mismatch, a bad
    /// `dt`, or a CFL number beyond [`MAX_SUBSTEPS`]. Not differentiable (see the module docs).
    pub fn step(&self, q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<Tensor> {
        let op = Fct3d::new(*self, q, velocity, dt)?;
        Ok(apply2(q, velocity.values(), op)?)
    }

    /// [`Self::step`] that also returns, per batch item and channel (`[b][c]`), the amount
    /// `sum q dx dy dz` that left through the open faces ([`AxisFaces3d::OpenHi`]; negative when
    /// it came in), summed over the sub-steps exactly as the fluxes moved it: `sum(q_new) dV =
    /// sum(q) dV - outflow` to round-off. Forward only.
    pub fn step_counting(&self, q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<(Tensor, Vec<Vec<f64>>)> {
        let op = Fct3d::new(*self, q, velocity, dt)?;
        let (shape, dtype) = (q.shape().clone(), q.dtype());
        let v = velocity.values();
        Ok(match dtype {
            candle_core::DType::F32 => {
                let (qv, vv) = (q.flatten_all()?.to_vec1::<f32>()?, v.flatten_all()?.to_vec1::<f32>()?);
                let mut out = vec![0f32; qv.len()];
                let flux = op.run(&qv, &shape, &vv, &mut out)?;
                (Tensor::from_vec(out, shape, q.device())?, flux)
            }
            _ => {
                let (qv, vv) = (
                    q.to_dtype(candle_core::DType::F64)?.flatten_all()?.to_vec1::<f64>()?,
                    v.to_dtype(candle_core::DType::F64)?.flatten_all()?.to_vec1::<f64>()?,
                );
                let mut out = vec![0f64; qv.len()];
                let flux = op.run(&qv, &shape, &vv, &mut out)?;
                (Tensor::from_vec(out, shape, q.device())?.to_dtype(dtype)?, flux)
            }
        })
    }

    /// The largest outflow CFL number of `velocity` over `dt` (the sub-step count is its ceiling,
    /// at least 1); a typed error when it is not finite.
    pub fn outflow_cfl(&self, velocity: &MacField3d, dt: f64) -> Result<f64> {
        let g = *velocity.grid();
        let v = velocity.values().to_dtype(candle_core::DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
        let op = Fct3d { cfg: *self, grid: g, dt };
        let mut worst = 0.0f64;
        for vb in v.chunks(3 * g.cells()) {
            let (mut uf, mut vf, mut wf) = op.face_buffers::<f64>();
            op.face_velocity(vb, &mut uf, &mut vf, &mut wf);
            worst = worst.max(op.max_cfl(&uf, &vf, &wf));
        }
        if !worst.is_finite() {
            return Err(Error::NonFinite { what: "velocity", value: worst });
        }
        Ok(worst)
    }
}

/// One conservative step of the closed-box scalar `q` (walls on all faces, limited): the
/// density transport of [`super::Smoke3d`] with `density_advection = conservative`.
pub fn conservative_scalar(q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<Tensor> {
    Conservative3d::closed_box().step(q, velocity, dt)
}

/// The op: inputs `(q, velocity)`.
#[derive(Clone, Copy, Debug)]
struct Fct3d {
    cfg: Conservative3d,
    grid: Grid3d,
    dt: f64,
}

/// Sizes and strides of one grid.
#[derive(Clone, Copy)]
struct Dims {
    nx: usize,
    ny: usize,
    nz: usize,
    /// Cells per z-slab.
    nxy: usize,
    /// Padded strides along y and z (x: 1).
    py: usize,
    pz: usize,
}

impl Dims {
    fn of(g: &Grid3d) -> Self {
        Self { nx: g.nx, ny: g.ny, nz: g.nz, nxy: g.nx * g.ny, py: g.nx + 2, pz: (g.nx + 2) * (g.ny + 2) }
    }
    /// Padded index of cell `(i, j, k)` (each may be -1 or n: the ghost layer).
    #[inline(always)]
    fn p(&self, i: usize, j: usize, k: usize) -> usize {
        k * self.pz + j * self.py + i
    }
    fn padded(&self) -> usize {
        self.pz * (self.nz + 2)
    }
    /// Faces per slab along x (`ny (nx + 1)`) and y (`(ny + 1) nx`); along z a face layer has `nxy`.
    fn sx(&self) -> usize {
        self.ny * (self.nx + 1)
    }
    fn sy(&self) -> usize {
        (self.ny + 1) * self.nx
    }
}

impl Fct3d {
    fn new(cfg: Conservative3d, q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<Self> {
        let grid = *velocity.grid();
        check_values("grid3d::conservative", "q", q, &grid, None)?;
        if !(dt >= 0.0 && dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("conservative transport needs a finite dt >= 0, got {dt}"),
            });
        }
        if q.dims()[0] != velocity.batch() {
            return Err(Error::Shape {
                op: "grid3d::conservative",
                arg: "velocity",
                expected: format!("batch {} (the advected field's)", q.dims()[0]),
                got: velocity.values().dims().to_vec(),
            });
        }
        if q.dtype() != velocity.values().dtype() {
            return Err(Error::Invalid {
                field: "velocity",
                reason: format!(
                    "dtype {:?} differs from the advected field's {:?}",
                    velocity.values().dtype(),
                    q.dtype()
                ),
            });
        }
        Ok(Self { cfg, grid, dt })
    }

    fn periodic(&self, axis: usize) -> bool {
        self.cfg.faces[axis] == AxisFaces3d::Periodic
    }

    fn open(&self, axis: usize) -> bool {
        self.cfg.faces[axis] == AxisFaces3d::OpenHi
    }

    fn face_buffers<T: Real>(&self) -> (Vec<T>, Vec<T>, Vec<T>) {
        let d = Dims::of(&self.grid);
        (vec![T::zero(); d.sx() * d.nz], vec![T::zero(); d.sy() * d.nz], vec![T::zero(); d.nxy * (d.nz + 1)])
    }

    /// Face-indexed velocities of one batch item (`vel`: `[u | v | w]`): `uf[(k ny + j)(nx + 1) +
    /// f]` is `u` on the x-face at `f dx` (`f = 0..=nx`), `vf[(k (ny + 1) + f) nx + i]`,
    /// `wf[(f ny + j) nx + i]`; boundary faces 0 on walls, the wrapped stored face when periodic.
    fn face_velocity<T: Real>(&self, vel: &[T], uf: &mut [T], vf: &mut [T], wf: &mut [T]) {
        let d = Dims::of(&self.grid);
        let (nx, ny, nz, n) = (d.nx, d.ny, d.nz, d.nxy * d.nz);
        let (u, v, w) = (&vel[..n], &vel[n..2 * n], &vel[2 * n..3 * n]);
        let zero = T::zero();
        let per = [self.periodic(0), self.periodic(1), self.periodic(2)];
        let open = [self.open(0), self.open(1), self.open(2)];
        for r in 0..ny * nz {
            for f in 0..=nx {
                uf[r * (nx + 1) + f] = if f == 0 || f == nx {
                    if per[0] || (f == nx && open[0]) {
                        u[r * nx + nx - 1]
                    } else {
                        zero
                    }
                } else {
                    u[r * nx + f - 1]
                };
            }
        }
        for k in 0..nz {
            for f in 0..=ny {
                let src =
                    if f == 0 || f == ny { (per[1] || (f == ny && open[1])).then_some(ny - 1) } else { Some(f - 1) };
                let dst = &mut vf[(k * (ny + 1) + f) * nx..(k * (ny + 1) + f + 1) * nx];
                match src {
                    Some(s) => dst.copy_from_slice(&v[(k * ny + s) * nx..(k * ny + s + 1) * nx]),
                    None => dst.fill(zero),
                }
            }
        }
        for f in 0..=nz {
            let src = if f == 0 || f == nz { (per[2] || (f == nz && open[2])).then_some(nz - 1) } else { Some(f - 1) };
            let dst = &mut wf[f * d.nxy..(f + 1) * d.nxy];
            match src {
                Some(s) => dst.copy_from_slice(&w[s * d.nxy..(s + 1) * d.nxy]),
                None => dst.fill(zero),
            }
        }
    }

    /// The largest outflow CFL number over the cells (NaN when a velocity is NaN).
    fn max_cfl<T: Real>(&self, uf: &[T], vf: &[T], wf: &[T]) -> f64 {
        let d = Dims::of(&self.grid);
        let [dx, dy, dz] = self.grid.spacing();
        let (cx, cy, cz) = (self.dt / dx, self.dt / dy, self.dt / dz);
        let mut cfl = 0.0f64;
        for k in 0..d.nz {
            for j in 0..d.ny {
                for i in 0..d.nx {
                    let xf = (k * d.ny + j) * (d.nx + 1) + i;
                    let yf = (k * (d.ny + 1) + j) * d.nx + i;
                    let zf = (k * d.ny + j) * d.nx + i;
                    let out = cx * (uf[xf + 1].wide().max(0.0) - uf[xf].wide().min(0.0))
                        + cy * (vf[yf + d.nx].wide().max(0.0) - vf[yf].wide().min(0.0))
                        + cz * (wf[zf + d.nxy].wide().max(0.0) - wf[zf].wide().min(0.0));
                    if out.is_nan() {
                        return f64::NAN;
                    }
                    cfl = cfl.max(out);
                }
            }
        }
        cfl
    }

    /// Pads `q` (`nx ny nz` cells) by one ghost layer: wrapped along periodic axes, the nearest
    /// cell repeated beyond walls.
    fn pad<T: Real>(&self, q: &[T], out: &mut [T], par: bool) {
        let d = Dims::of(&self.grid);
        let map = |m: usize, n: usize, periodic: bool| -> usize {
            if m == 0 {
                if periodic {
                    n - 1
                } else {
                    0
                }
            } else if m == n + 1 {
                if periodic {
                    0
                } else {
                    n - 1
                }
            } else {
                m - 1
            }
        };
        let per = [self.periodic(0), self.periodic(1), self.periodic(2)];
        for_rows(out, d.pz, par, |kk, slab| {
            let k = map(kk, d.nz, per[2]);
            for jj in 0..d.ny + 2 {
                let j = map(jj, d.ny, per[1]);
                let src = &q[(k * d.ny + j) * d.nx..(k * d.ny + j + 1) * d.nx];
                let row = &mut slab[jj * d.py..(jj + 1) * d.py];
                row[1..=d.nx].copy_from_slice(src);
                row[0] = src[map(0, d.nx, per[0])];
                row[d.nx + 1] = src[map(d.nx + 1, d.nx, per[0])];
            }
        });
    }

    /// One sub-step `q -> out` with `c = (dt/dx, dt/dy, dt/dz)` of the sub-step.
    #[allow(clippy::too_many_arguments)]
    fn substep<T: Real>(
        &self,
        wk: &mut Work<T>,
        (uf, vf, wf): (&[T], &[T], &[T]),
        (cx, cy, cz): (T, T, T),
        q: &[T],
        out: &mut [T],
        par: bool,
    ) -> f64 {
        let d = Dims::of(&self.grid);
        let (nx, ny, nz, nxy, py, pz) = (d.nx, d.ny, d.nz, d.nxy, d.py, d.pz);
        let (sx, sy) = (d.sx(), d.sy());
        let (h, qu, zero, one) = (T::c(0.5), T::c(0.25), T::zero(), T::one());
        let per = [self.periodic(0), self.periodic(1), self.periodic(2)];
        let open = [self.open(0), self.open(1), self.open(2)];
        self.pad(q, &mut wk.qp, par);
        let qp = &*wk.qp;
        // x faces: slab k holds [F_L | A] of its ny (nx + 1) faces; face f at x = f dx between
        // cells f - 1 and f (padded columns f, f + 1).
        for_rows(&mut wk.fx, 2 * sx, par, |k, slab| {
            let (fl, a) = slab.split_at_mut(sx);
            for j in 0..ny {
                for f in 0..=nx {
                    let e = j * (nx + 1) + f;
                    let u = uf[(k * ny + j) * (nx + 1) + f];
                    let pl = d.p(f, j + 1, k + 1);
                    if f == nx && open[0] {
                        // Open face: upwind only, the ghost repeats the last cell.
                        fl[e] = cx * (pos(u) * qp[pl] + neg(u) * qp[pl + 1]);
                        a[e] = zero;
                        continue;
                    }
                    if (f == 0 || f == nx) && !per[0] {
                        fl[e] = zero;
                        a[e] = zero;
                        continue;
                    }
                    let (ql, qr) = (qp[pl], qp[pl + 1]);
                    let low = cx * (pos(u) * ql + neg(u) * qr);
                    fl[e] = low;
                    let (l, r) = ((f + nx - 1) % nx, f % nx);
                    let vr = |jj: usize| (k * (ny + 1) + jj) * nx;
                    let vb = qu * (vf[vr(j) + l] + vf[vr(j + 1) + l] + vf[vr(j) + r] + vf[vr(j + 1) + r]);
                    let wr = |kk: usize| (kk * ny + j) * nx;
                    let wb = qu * (wf[wr(k) + l] + wf[wr(k + 1) + l] + wf[wr(k) + r] + wf[wr(k + 1) + r]);
                    let dy = qu * ((qp[pl + py] - qp[pl - py]) + (qp[pl + 1 + py] - qp[pl + 1 - py]));
                    let dz = qu * ((qp[pl + pz] - qp[pl - pz]) + (qp[pl + 1 + pz] - qp[pl + 1 - pz]));
                    let high = cx * u * (h * (ql + qr) - h * cx * u * (qr - ql) - h * cy * vb * dy - h * cz * wb * dz);
                    a[e] = high - low;
                }
            }
        });
        // y faces: slab k holds [F_L | A] of its (ny + 1) nx faces; face f at y = f dy.
        for_rows(&mut wk.fy, 2 * sy, par, |k, slab| {
            let (fl, a) = slab.split_at_mut(sy);
            for f in 0..=ny {
                let opened = f == ny && open[1];
                let wall = (f == 0 || f == ny) && !per[1] && !opened;
                let (b, t) = ((f + ny - 1) % ny, f % ny);
                for i in 0..nx {
                    let e = f * nx + i;
                    if wall {
                        fl[e] = zero;
                        a[e] = zero;
                        continue;
                    }
                    let v = vf[(k * (ny + 1) + f) * nx + i];
                    let pb = d.p(i + 1, f, k + 1);
                    let (qb, qt) = (qp[pb], qp[pb + py]);
                    let low = cy * (pos(v) * qb + neg(v) * qt);
                    fl[e] = low;
                    if opened {
                        a[e] = zero;
                        continue;
                    }
                    let ur = |jj: usize| (k * ny + jj) * (nx + 1) + i;
                    let ub = qu * (uf[ur(b)] + uf[ur(b) + 1] + uf[ur(t)] + uf[ur(t) + 1]);
                    let wr = |kk: usize, jj: usize| (kk * ny + jj) * nx + i;
                    let wb = qu * (wf[wr(k, b)] + wf[wr(k + 1, b)] + wf[wr(k, t)] + wf[wr(k + 1, t)]);
                    let dx = qu * ((qp[pb + 1] - qp[pb - 1]) + (qp[pb + py + 1] - qp[pb + py - 1]));
                    let dz = qu * ((qp[pb + pz] - qp[pb - pz]) + (qp[pb + py + pz] - qp[pb + py - pz]));
                    let high = cy * v * (h * (qb + qt) - h * cy * v * (qt - qb) - h * cx * ub * dx - h * cz * wb * dz);
                    a[e] = high - low;
                }
            }
        });
        // z faces: layer f (z = f dz) holds [F_L | A] of its nx ny faces.
        for_rows(&mut wk.fz, 2 * nxy, par, |f, layer| {
            let (fl, a) = layer.split_at_mut(nxy);
            if f == nz && open[2] {
                for (e, (fl, a)) in fl.iter_mut().zip(a.iter_mut()).enumerate() {
                    let w = wf[f * nxy + e];
                    let pd = d.p(e % nx + 1, e / nx + 1, f);
                    *fl = cz * (pos(w) * qp[pd] + neg(w) * qp[pd + pz]);
                    *a = zero;
                }
                return;
            }
            if (f == 0 || f == nz) && !per[2] {
                fl.fill(zero);
                a.fill(zero);
                return;
            }
            let (dn, up) = ((f + nz - 1) % nz, f % nz);
            for j in 0..ny {
                for i in 0..nx {
                    let e = j * nx + i;
                    let w = wf[f * nxy + e];
                    let pd = d.p(i + 1, j + 1, f);
                    let (qd, qv) = (qp[pd], qp[pd + pz]);
                    let low = cz * (pos(w) * qd + neg(w) * qv);
                    fl[e] = low;
                    let ur = |kk: usize| (kk * ny + j) * (nx + 1) + i;
                    let ub = qu * (uf[ur(dn)] + uf[ur(dn) + 1] + uf[ur(up)] + uf[ur(up) + 1]);
                    let vr = |kk: usize, jj: usize| (kk * (ny + 1) + jj) * nx + i;
                    let vb = qu * (vf[vr(dn, j)] + vf[vr(dn, j + 1)] + vf[vr(up, j)] + vf[vr(up, j + 1)]);
                    let dx = qu * ((qp[pd + 1] - qp[pd - 1]) + (qp[pd + pz + 1] - qp[pd + pz - 1]));
                    let dy = qu * ((qp[pd + py] - qp[pd - py]) + (qp[pd + pz + py] - qp[pd + pz - py]));
                    let high = cz * w * (h * (qd + qv) - h * cz * w * (qv - qd) - h * cx * ub * dx - h * cy * vb * dy);
                    a[e] = high - low;
                }
            }
        });
        // The six faces of cell (i, j, k) in the face buffers: (index of the lower face, of the
        // upper face) per axis, F_L at the index, A at index + the block size.
        let faces = |i: usize, j: usize, k: usize| -> [(usize, usize, usize); 3] {
            let x = 2 * sx * k + j * (nx + 1) + i;
            let y = 2 * sy * k + j * nx + i;
            let z = 2 * nxy * k + j * nx + i;
            [(x, x + 1, sx), (y, y + nx, sy), (z, z + 2 * nxy, nxy)]
        };
        // Upwind solution.
        let (fx, fy, fz) = (&*wk.fx, &*wk.fy, &*wk.fz);
        for_rows(&mut wk.td, nxy, par, |k, slab| {
            for j in 0..ny {
                for i in 0..nx {
                    let [x, y, z] = faces(i, j, k);
                    let c = j * nx + i;
                    slab[c] = q[k * nxy + c] - (fx[x.1] - fx[x.0]) - (fy[y.1] - fy[y.0]) - (fz[z.1] - fz[z.0]);
                }
            }
        });
        if self.cfg.limiter {
            self.pad(&wk.td, &mut wk.tp, par);
            // Bounds over the 3x3x3 neighbourhood of old and upwind values; Zalesak's ratios,
            // slab k holding [R+ | R-].
            let (tp, td) = (&*wk.tp, &*wk.td);
            for_rows(&mut wk.r, 2 * nxy, par, |k, slab| {
                let (rp, rm) = slab.split_at_mut(nxy);
                for j in 0..ny {
                    for i in 0..nx {
                        let c = j * nx + i;
                        let pc = d.p(i + 1, j + 1, k + 1);
                        let (mut hi, mut lo) = (tp[pc], tp[pc]);
                        for oz in [pc - pz, pc, pc + pz] {
                            for oy in [oz - py, oz, oz + py] {
                                for m in oy - 1..=oy + 1 {
                                    hi = hi.fmax(qp[m]).fmax(tp[m]);
                                    lo = lo.fmin(qp[m]).fmin(tp[m]);
                                }
                            }
                        }
                        let [x, y, z] = faces(i, j, k);
                        let parts = [
                            fx[x.0 + x.2],
                            -fx[x.1 + x.2],
                            fy[y.0 + y.2],
                            -fy[y.1 + y.2],
                            fz[z.0 + z.2],
                            -fz[z.1 + z.2],
                        ];
                        let pp = parts.iter().fold(zero, |s, &x| s + pos(x));
                        let pm = parts.iter().fold(zero, |s, &x| s + neg(x));
                        let t = td[k * nxy + c];
                        rp[c] = if pp > zero { min_first((hi - t) / pp, one) } else { zero };
                        rm[c] = if pm < zero { min_first((lo - t) / pm, one) } else { zero };
                    }
                }
            });
            // Face coefficients: A <- C A, the correction filling the downstream cell and
            // draining the upstream one only as far as both allow.
            let r = &*wk.r;
            let rp = |k: usize, c: usize| r[2 * nxy * k + c];
            let rm = |k: usize, c: usize| r[2 * nxy * k + nxy + c];
            let limit = |a: T, (kd, cd): (usize, usize), (ku, cu): (usize, usize)| -> T {
                // `d` lies on the lower side, `u` on the upper side of the face.
                let c = if a >= zero { min_first(rp(ku, cu), rm(kd, cd)) } else { min_first(rp(kd, cd), rm(ku, cu)) };
                c * a
            };
            for_rows(&mut wk.fx, 2 * sx, par, |k, slab| {
                let a = &mut slab[sx..];
                for j in 0..ny {
                    for f in 0..=nx {
                        let e = j * (nx + 1) + f;
                        if (f == 0 || f == nx) && !per[0] {
                            continue; // walls and the open face carry no correction
                        }
                        a[e] = limit(a[e], (k, j * nx + (f + nx - 1) % nx), (k, j * nx + f % nx));
                    }
                }
            });
            for_rows(&mut wk.fy, 2 * sy, par, |k, slab| {
                let a = &mut slab[sy..];
                for f in 0..=ny {
                    if (f == 0 || f == ny) && !per[1] {
                        continue;
                    }
                    let (b, t) = ((f + ny - 1) % ny, f % ny);
                    for i in 0..nx {
                        let e = f * nx + i;
                        a[e] = limit(a[e], (k, b * nx + i), (k, t * nx + i));
                    }
                }
            });
            for_rows(&mut wk.fz, 2 * nxy, par, |f, layer| {
                if (f == 0 || f == nz) && !per[2] {
                    return;
                }
                let (dn, up) = ((f + nz - 1) % nz, f % nz);
                let a = &mut layer[nxy..];
                for (c, a) in a.iter_mut().enumerate() {
                    *a = limit(*a, (dn, c), (up, c));
                }
            });
        }
        // out = upwind - div(C A).
        let (fx, fy, fz, td) = (&*wk.fx, &*wk.fy, &*wk.fz, &*wk.td);
        for_rows(out, nxy, par, |k, slab| {
            for j in 0..ny {
                for i in 0..nx {
                    let [x, y, z] = faces(i, j, k);
                    let c = j * nx + i;
                    slab[c] = td[k * nxy + c]
                        - (fx[x.1 + x.2] - fx[x.0 + x.2])
                        - (fy[y.1 + y.2] - fy[y.0 + y.2])
                        - (fz[z.1 + z.2] - fz[z.0 + z.2]);
                }
            }
        });
        // What left through the open faces (their F_L; A is 0 there), in units of q.
        let mut outflow = 0.0;
        if open[0] {
            for k in 0..nz {
                for j in 0..ny {
                    outflow += fx[2 * sx * k + j * (nx + 1) + nx].wide();
                }
            }
        }
        if open[1] {
            for k in 0..nz {
                for i in 0..nx {
                    outflow += fy[2 * sy * k + ny * nx + i].wide();
                }
            }
        }
        if open[2] {
            outflow += fz[2 * nxy * nz..2 * nxy * nz + nxy].iter().map(|v| v.wide()).sum::<f64>();
        }
        outflow
    }

    fn check_shapes(&self, q: &Shape, v: &Shape) -> candle_core::Result<()> {
        let (qd, vd) = (q.dims(), v.dims());
        let g = &self.grid;
        let fits = |d: &[usize]| d.len() == 5 && d[2] == g.nz && d[3] == g.ny && d[4] == g.nx;
        if !(fits(qd) && fits(vd) && vd[0] == qd[0] && vd[1] == 3 && qd[1] >= 1) {
            candle_core::bail!(
                "grid3d conservative: q {qd:?} and velocity {vd:?} do not fit a cell-centred field and a MAC velocity \
                 on {}x{}x{}",
                g.nz,
                g.ny,
                g.nx
            );
        }
        Ok(())
    }
}

/// Scratch of one sub-step.
struct Work<T: Real> {
    qp: crate::scratch::Buf<T>,
    tp: crate::scratch::Buf<T>,
    fx: crate::scratch::Buf<T>,
    fy: crate::scratch::Buf<T>,
    fz: crate::scratch::Buf<T>,
    td: crate::scratch::Buf<T>,
    r: crate::scratch::Buf<T>,
}

impl<T: Real> Work<T> {
    fn new(g: &Grid3d) -> Self {
        let d = Dims::of(g);
        Self {
            qp: zeros(d.padded()),
            tp: zeros(d.padded()),
            fx: zeros(2 * d.sx() * d.nz),
            fy: zeros(2 * d.sy() * d.nz),
            fz: zeros(2 * d.nxy * (d.nz + 1)),
            td: zeros(d.nxy * d.nz),
            r: zeros(2 * d.nxy * d.nz),
        }
    }
}

impl Kernel2 for Fct3d {
    fn name(&self) -> &'static str {
        "grid3d_advect_conservative"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.check_shapes(a, b)?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.run(q, qs, v, out).map(|_| ())
    }
}

impl Fct3d {
    /// The forward pass; returns the outflow per batch item and channel (`sum q dV`).
    fn run<T: Real>(&self, q: &[T], qs: &Shape, v: &[T], out: &mut [T]) -> candle_core::Result<Vec<Vec<f64>>> {
        let chans = qs.dims()[1];
        let vol = self.grid.spacing().iter().product::<f64>();
        let mut flux = Vec::new();
        let n = self.grid.cells();
        let par = parallel_cells(n);
        let [dx, dy, dz] = self.grid.spacing();
        let (mut uf, mut vf, mut wf) = self.face_buffers::<T>();
        let mut wk = Work::<T>::new(&self.grid);
        let mut scratch = zeros::<T>(n);
        for (b, vb) in v.chunks(3 * n).enumerate() {
            self.face_velocity(vb, &mut uf, &mut vf, &mut wf);
            let cfl = self.max_cfl(&uf, &vf, &wf);
            // NaN velocities give NaN values (one step), not a hang.
            let k = if cfl.is_nan() || cfl <= 1.0 { 1.0 } else { cfl.ceil() };
            if k > MAX_SUBSTEPS as f64 {
                candle_core::bail!(
                    "grid3d conservative: outflow CFL number {cfl:.3e} needs more than {MAX_SUBSTEPS} sub-steps; \
                     shorten dt"
                );
            }
            let s = self.dt / k;
            let c = (T::c(s / dx), T::c(s / dy), T::c(s / dz));
            let mut per_channel = Vec::with_capacity(chans);
            for ch in 0..chans {
                let off = (b * chans + ch) * n;
                let o = &mut out[off..off + n];
                o.copy_from_slice(&q[off..off + n]);
                let mut left = 0.0;
                for _ in 0..k as usize {
                    scratch.copy_from_slice(o);
                    left += self.substep(&mut wk, (&uf, &vf, &wf), c, &scratch, o, par);
                }
                per_channel.push(left * vol);
            }
            flux.push(per_channel);
        }
        Ok(flux)
    }
}

impl Op2 for Fct3d {
    fn backward(&self, _q: &Tensor, _v: &Tensor, _y: &Tensor, _g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        candle_core::bail!(
            "grid3d conservative transport has no adjoint yet: differentiate through semi_lagrangian or mac_cormack \
             density advection instead"
        )
    }
}
