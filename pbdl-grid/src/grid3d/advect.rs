//! Semi-Lagrangian and MacCormack advection in the closed 3D box: cell-centred scalars
//! (density, smoke; `[batch, C, nz, ny, nx]`) and the MAC velocity ([`MacField3d`]), moved by a
//! MAC velocity with no-slip walls on all six faces (the walls of [`super::CavityWalls`] at rest).
//!
//! One semi-Lagrangian step is `q1(x) = q0(x - dt u(x))` at every sample point `x` of `q` (cell
//! centres, or the faces of one velocity component): `u(x)` is the MAC velocity interpolated
//! trilinearly to `x` (first-order backtrace) and `q0` is interpolated trilinearly on `q`'s own
//! lattice, the 3D form of the 2D [`crate::advect::semi_lagrangian()`]. What lies outside the
//! stored values:
//! * a cell-centred scalar: departure points are clamped to the box of cell centres (zero-gradient
//!   extension; the walls are impermeable, so nothing is read from outside);
//! * a velocity component along its own axis: the wall faces (the implicit one at 0 and the
//!   stored last one) are 0; departure points are clamped to the walls;
//! * a velocity component along another axis: the no-slip ghost `-q_inner` (the component is 0 on
//!   the wall, as in [`super::walls`]); departure points are clamped to the walls.
//!
//! Other faces ([`super::Walls3d`], through [`super::Smoke3d::with_boundaries`]): a free-slip
//! face mirrors the tangential ghost (`+q_inner`), a periodic pair wraps every lattice, an
//! outflow face clamps departure points to its stored face (zero gradient beyond it).
//!
//! The stored wall faces of an advected velocity are 0 on output, whatever they held on input.
//! Semi-Lagrangian is unconditionally stable (a convex combination of old values, up to the sign
//! of the no-slip ghosts), first order and diffusive.
//!
//! [`mac_cormack_scalar`] / [`mac_cormack_velocity`]: predictor `a = SL(q, dt)`, corrector
//! `b = SL(a, -dt)`, `a + (q - b) / 2`, clamped to the min/max of the eight values the predictor
//! interpolated from (Selle, Fedkiw, Kim, Liu & Rossignac, "An unconditionally stable MacCormack
//! method", J. Sci. Comput. 35 (2008)), as in 2D ([`crate::advect::mac_cormack()`]). Second order
//! where smooth, no new extrema. Neither scheme conserves mass (interpolation moves no fluxes).
//!
//! Everything is differentiable in the advected field and in the velocity, with hand-written
//! adjoints: the transpose of the interpolation (for `q`), the derivative of the trilinear
//! interpolant times `-dt / h` pushed back through the velocity interpolation (for the
//! velocity); the limiter's bounds pass their gradient to the extremal corner (none to the
//! velocity, which only picks the cell), the clamp to whichever input is active. The velocity
//! at the sample points is interpolated once per step (its own linear op, adjoint a scatter) and
//! shared by the predictor, the corrector and the bounds.

use super::field::{check_values, MacField3d};
use super::momentum::check_shape;
use super::walls::Walls3d;
use super::Grid3d;
use crate::pad::{accumulate_rows, for_rows, parallel_cells};
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{
    apply1, apply2, apply3, apply_kernel1, apply_kernel2, apply_kernel3, Kernel1, Kernel2, Kernel3, Op1, Op2, Op3,
};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// An advection scheme of the 3D smoke stepper ([`super::Smoke3d`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Advection3d {
    /// First-order semi-Lagrangian (trilinear, first-order backtrace).
    SemiLagrangian,
    /// MacCormack with the Selle et al. (2008) limiter (default).
    #[default]
    MacCormack,
    /// Finite-volume flux form with flux-corrected transport ([`super::conservative`]): mass
    /// conserved to round-off, no new extrema. Cell-centred scalars (the density) only; forward
    /// only (no adjoint yet).
    Conservative,
}

impl Advection3d {
    /// The operator name for the density (`velocity` false) or the velocity, e.g.
    /// `"grid3d.advect.mac_cormack(density)"`.
    pub fn operator_name(self, velocity: bool) -> &'static str {
        match (self, velocity) {
            (Self::SemiLagrangian, false) => "grid3d.advect.semi_lagrangian(density)",
            (Self::MacCormack, false) => "grid3d.advect.mac_cormack(density)",
            (Self::SemiLagrangian, true) => "grid3d.advect.semi_lagrangian(velocity)",
            (Self::MacCormack, true) => "grid3d.advect.mac_cormack(velocity)",
            (Self::Conservative, false) => "grid3d.advect.conservative(density)",
            (Self::Conservative, true) => "grid3d.advect.conservative(velocity)",
        }
    }
}

/// One semi-Lagrangian step of a cell-centred scalar `q` (`[batch, C, nz, ny, nx]`, every channel)
/// by `velocity` over `dt`. Differentiable in `q` and `velocity`.
pub fn semi_lagrangian_scalar(q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<Tensor> {
    let op = Sl3d::scalar(q, velocity, dt)?;
    Ok(op.apply(q, velocity.values())?)
}

/// One MacCormack step (Selle et al. limiter) of a cell-centred scalar. Differentiable.
pub fn mac_cormack_scalar(q: &Tensor, velocity: &MacField3d, dt: f64) -> Result<Tensor> {
    let op = Sl3d::scalar(q, velocity, dt)?;
    Ok(op.mac_cormack(q, velocity.values())?)
}

/// One step of a cell-centred scalar with `scheme` (in the closed box). Differentiable, except
/// [`Advection3d::Conservative`] (forward only).
pub fn advect_scalar(q: &Tensor, velocity: &MacField3d, dt: f64, scheme: Advection3d) -> Result<Tensor> {
    match scheme {
        Advection3d::SemiLagrangian => semi_lagrangian_scalar(q, velocity, dt),
        Advection3d::MacCormack => mac_cormack_scalar(q, velocity, dt),
        Advection3d::Conservative => super::conservative::conservative_scalar(q, velocity, dt),
    }
}

/// One semi-Lagrangian step of the velocity `u` moved by `velocity` (pass `u` twice for
/// self-advection) in the no-slip box; the wall faces of the result are 0. Differentiable in both.
pub fn semi_lagrangian_velocity(u: &MacField3d, velocity: &MacField3d, dt: f64) -> Result<MacField3d> {
    let op = Sl3d::velocity(u, velocity, dt)?;
    Ok(MacField3d::from_parts(op.apply(u.values(), velocity.values())?, *u.grid()))
}

/// One MacCormack step (Selle et al. limiter) of the velocity `u` moved by `velocity` in the
/// no-slip box; the wall faces of the result are 0. Differentiable in both.
pub fn mac_cormack_velocity(u: &MacField3d, velocity: &MacField3d, dt: f64) -> Result<MacField3d> {
    let op = Sl3d::velocity(u, velocity, dt)?;
    Ok(MacField3d::from_parts(op.mac_cormack(u.values(), velocity.values())?, *u.grid()))
}

/// One step of the velocity `u` moved by `velocity` with `scheme` (not
/// [`Advection3d::Conservative`]: a typed error). Differentiable.
pub fn advect_velocity(u: &MacField3d, velocity: &MacField3d, dt: f64, scheme: Advection3d) -> Result<MacField3d> {
    match scheme {
        Advection3d::SemiLagrangian => semi_lagrangian_velocity(u, velocity, dt),
        Advection3d::MacCormack => mac_cormack_velocity(u, velocity, dt),
        Advection3d::Conservative => Err(Error::Invalid {
            field: "advection",
            reason: "conservative transport is for cell-centred scalars; move the velocity with semi_lagrangian \
                     or mac_cormack"
                .into(),
        }),
    }
}

/// How the samples of one channel sit along one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Axis {
    /// Cell centres `(m + 1/2) h`, zero-gradient beyond the first and last.
    Centre,
    /// Faces normal to the axis `(m + 1) h`, `m = -1..n-1`; the two walls (`m = -1`, `n - 1`) are 0.
    Normal,
    /// Velocity along another axis at `(m + 1/2) h`; ghosts at `m = -1` and `m = n`: `-q` for a
    /// no-slip face, `+q` where the flag (`[lo, hi]`) is set (free-slip or open face).
    Tangential([bool; 2]),
    /// Faces normal to the axis, open at the upper face: as `Normal`, but the stored face at
    /// `n - 1` is free and the ghost beyond it repeats it (zero gradient).
    NormalOpen,
    /// A periodic axis with samples at `(m + offset) h` (0.5: centres and tangential
    /// components, 1: faces normal to it), wrapped.
    Periodic(bool),
}

impl Axis {
    /// Index-space offset: the sample `m` sits at `(m + offset) h`.
    #[inline(always)]
    fn offset(self) -> f64 {
        match self {
            Self::Normal | Self::NormalOpen | Self::Periodic(true) => 1.0,
            _ => 0.5,
        }
    }
}

/// The lattice of velocity component `c` (axis-indexed `[x, y, z]`) in a box with `walls`.
#[inline(always)]
fn velocity_lattice(c: usize, walls: &Walls3d) -> [Axis; 3] {
    [0, 1, 2].map(|a| {
        if walls.periodic(a) {
            Axis::Periodic(a == c)
        } else if a == c {
            if walls.open_hi(a) {
                Axis::NormalOpen
            } else {
                Axis::Normal
            }
        } else {
            Axis::Tangential([walls.free_slip(a, false), walls.free_slip(a, true) || walls.open_hi(a)])
        }
    })
}

/// The two interpolation nodes along one axis: stored indices, coefficients (1, 0 for a wall,
/// -1 for a no-slip ghost), the weight `t` of the upper node and `d position / d x` (0 when
/// clamped).
#[derive(Clone, Copy)]
struct AxisFoot {
    idx: [usize; 2],
    coef: [f64; 2],
    t: f64,
    slope: f64,
}

#[inline(always)]
fn clamp_pos(s: f64, lo: f64, hi: f64) -> (f64, f64) {
    if s < lo {
        (lo, 0.0)
    } else if s > hi {
        (hi, 0.0)
    } else {
        (s, 1.0)
    }
}

/// The footprint along one axis of the point `x` (in cells: position / h) on lattice `ax` of `n`
/// cells.
#[inline(always)]
fn axis_foot(ax: Axis, x: f64, n: usize) -> AxisFoot {
    let (nf, ni) = (n as f64, n as isize);
    match ax {
        Axis::Centre => {
            let (s, slope) = clamp_pos(x - 0.5, 0.0, nf - 1.0);
            let i0 = (s.floor() as usize).min(n - 2);
            AxisFoot { idx: [i0, i0 + 1], coef: [1.0, 1.0], t: s - i0 as f64, slope }
        }
        Axis::Normal => {
            let (s, slope) = clamp_pos(x - 1.0, -1.0, nf - 1.0);
            let i0 = (s.floor() as isize).clamp(-1, ni - 2);
            let node = |m: isize| if m < 0 || m >= ni - 1 { (0, 0.0) } else { (m as usize, 1.0) };
            let (a, b) = (node(i0), node(i0 + 1));
            AxisFoot { idx: [a.0, b.0], coef: [a.1, b.1], t: s - i0 as f64, slope }
        }
        Axis::NormalOpen => {
            // Departure points are clamped to the last stored face: zero gradient beyond it.
            let (s, slope) = clamp_pos(x - 1.0, -1.0, nf - 1.0);
            let i0 = (s.floor() as isize).clamp(-1, ni - 2);
            let node = |m: isize| if m < 0 { (0, 0.0) } else { (m as usize, 1.0) };
            let (a, b) = (node(i0), node(i0 + 1));
            AxisFoot { idx: [a.0, b.0], coef: [a.1, b.1], t: s - i0 as f64, slope }
        }
        Axis::Periodic(face) => {
            let s = x - if face { 1.0 } else { 0.5 };
            let f = s.floor();
            let i0 = f as isize;
            let wrap = |m: isize| m.rem_euclid(ni) as usize;
            AxisFoot { idx: [wrap(i0), wrap(i0 + 1)], coef: [1.0, 1.0], t: s - f, slope: 1.0 }
        }
        Axis::Tangential(free) => {
            let (s, slope) = clamp_pos(x - 0.5, -0.5, nf - 0.5);
            let i0 = (s.floor() as isize).clamp(-1, ni - 1);
            let sign = |f: bool| if f { 1.0 } else { -1.0 };
            let node = |m: isize| {
                if m < 0 {
                    (0, sign(free[0]))
                } else if m >= ni {
                    (n - 1, sign(free[1]))
                } else {
                    (m as usize, 1.0)
                }
            };
            let (a, b) = (node(i0), node(i0 + 1));
            AxisFoot { idx: [a.0, b.0], coef: [a.1, b.1], t: s - i0 as f64, slope }
        }
    }
}

/// A trilinear footprint: the eight corners (stored index within one component, coefficient) and
/// the per-axis feet.
struct Foot {
    k: [usize; 8],
    c: [f64; 8],
    ax: [AxisFoot; 3],
}

impl Foot {
    #[inline(always)]
    fn new(lat: [Axis; 3], x: [f64; 3], n: [usize; 3]) -> Self {
        let ax = [axis_foot(lat[0], x[0], n[0]), axis_foot(lat[1], x[1], n[1]), axis_foot(lat[2], x[2], n[2])];
        let mut k = [0; 8];
        let mut c = [0.0; 8];
        for b in 0..8 {
            let (bx, by, bz) = (b & 1, (b >> 1) & 1, b >> 2);
            k[b] = (ax[2].idx[bz] * n[1] + ax[1].idx[by]) * n[0] + ax[0].idx[bx];
            c[b] = ax[0].coef[bx] * ax[1].coef[by] * ax[2].coef[bz];
        }
        Self { k, c, ax }
    }

    /// The interpolation weights times the coefficients.
    #[inline(always)]
    fn weights(&self) -> [f64; 8] {
        let w = |a: usize, bit: usize| if bit == 0 { 1.0 - self.ax[a].t } else { self.ax[a].t };
        std::array::from_fn(|b| self.c[b] * w(0, b & 1) * w(1, (b >> 1) & 1) * w(2, b >> 2))
    }

    /// `d weights / d x_a` (in cells), clamping included.
    #[inline(always)]
    fn dweights(&self, a: usize) -> [f64; 8] {
        let w = |e: usize, bit: usize| {
            if e == a {
                self.ax[a].slope * if bit == 0 { -1.0 } else { 1.0 }
            } else if bit == 0 {
                1.0 - self.ax[e].t
            } else {
                self.ax[e].t
            }
        };
        std::array::from_fn(|b| self.c[b] * w(0, b & 1) * w(1, (b >> 1) & 1) * w(2, b >> 2))
    }

    #[inline(always)]
    fn dot<T: Real>(&self, w: &[f64; 8], q: &[T]) -> f64 {
        (0..8).map(|b| if self.c[b] == 0.0 { 0.0 } else { w[b] * q[self.k[b]].wide() }).sum()
    }

    #[inline(always)]
    fn scatter<T: Real>(&self, w: &[f64; 8], v: f64, acc: &mut [T]) {
        for b in 0..8 {
            if self.c[b] != 0.0 {
                acc[self.k[b]] += T::c(w[b] * v);
            }
        }
    }
}

/// What the sample kernel computes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Value,
    Min,
    Max,
}

/// One semi-Lagrangian step of `q` (`[batch, C, nz, ny, nx]`) by a MAC velocity
/// (`[batch, 3, nz, ny, nx]`) in the closed box.
///
/// Composed of two differentiable ops: [`SampleVel3d`] interpolates the velocity to the sample
/// points of `q` once (shared by the MacCormack predictor, corrector and limiter bounds), and
/// [`SlCore3d`] backtraces and interpolates `q` with those sample velocities.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sl3d {
    pub grid: Grid3d,
    /// `q` is a MAC velocity (3 channels on the face lattices) rather than cell-centred.
    pub velocity: bool,
    pub dt: f64,
    /// The faces of the box (ghost rules of every lattice).
    pub walls: Walls3d,
}

impl Sl3d {
    fn checked(grid: Grid3d, velocity: bool, dt: f64, q: &Tensor, u: &MacField3d) -> Result<Self> {
        if !dt.is_finite() {
            return Err(Error::Invalid { field: "dt", reason: format!("must be finite, got {dt}") });
        }
        if q.dims()[0] != u.batch() {
            return Err(Error::Shape {
                op: "grid3d::advect",
                arg: "velocity",
                expected: format!("batch {} (the advected field's)", q.dims()[0]),
                got: u.values().dims().to_vec(),
            });
        }
        if q.dtype() != u.values().dtype() {
            return Err(Error::Invalid {
                field: "velocity",
                reason: format!("dtype {:?} differs from the advected field's {:?}", u.values().dtype(), q.dtype()),
            });
        }
        Ok(Self { grid, velocity, dt, walls: Walls3d::closed() })
    }

    /// The same step in a box with per-face conditions `walls`.
    pub(crate) fn with_walls(self, walls: Walls3d) -> Self {
        Self { walls, ..self }
    }

    pub(crate) fn scalar(q: &Tensor, u: &MacField3d, dt: f64) -> Result<Self> {
        check_values("grid3d::advect", "q", q, u.grid(), None)?;
        Self::checked(*u.grid(), false, dt, q, u)
    }

    pub(crate) fn velocity(q: &MacField3d, u: &MacField3d, dt: f64) -> Result<Self> {
        if q.grid() != u.grid() {
            return Err(Error::Invalid {
                field: "velocity",
                reason: format!("lives on {:?}, the advected field on {:?}", u.grid(), q.grid()),
            });
        }
        Self::checked(*u.grid(), true, dt, q.values(), u)
    }

    /// The velocity at the sample points of `q`'s channels: `[batch, 3, ...]` (cell centres) for
    /// a scalar, `[batch, 9, ...]` (channel `3 c + e`: component `e` on the faces of `c`) for a
    /// velocity.
    fn sample_velocity(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, SampleVel3d(*self))
    }

    pub(crate) fn apply(&self, q: &Tensor, u: &Tensor) -> candle_core::Result<Tensor> {
        apply2(q, &self.sample_velocity(u)?, SlCore3d(*self))
    }

    /// The limited MacCormack step, composed of differentiable ops.
    pub(crate) fn mac_cormack(&self, q: &Tensor, u: &Tensor) -> candle_core::Result<Tensor> {
        let sv = self.sample_velocity(u)?;
        let a = apply2(q, &sv, SlCore3d(*self))?;
        let b = apply2(&a, &sv, SlCore3d(Self { dt: -self.dt, ..*self }))?;
        let mc = (&a + ((q - b)? * 0.5)?)?;
        let lo = apply2(q, &sv, Bounds3d { sl: *self, max: false })?;
        let hi = apply2(q, &sv, Bounds3d { sl: *self, max: true })?;
        apply3(&mc, &lo, &hi, Clamp3d)
    }

    fn n(&self) -> [usize; 3] {
        [self.grid.nx, self.grid.ny, self.grid.nz]
    }

    /// The lattice of channel `ch`.
    fn lattice(&self, ch: usize) -> [Axis; 3] {
        if self.velocity {
            velocity_lattice(ch, &self.walls)
        } else {
            [0, 1, 2].map(|a| if self.walls.periodic(a) { Axis::Periodic(false) } else { Axis::Centre })
        }
    }

    /// Channels of the sample velocity.
    fn sample_channels(&self) -> usize {
        if self.velocity {
            9
        } else {
            3
        }
    }

    /// First sample-velocity channel of `q`'s channel `ch`.
    fn sample_base(&self, ch: usize) -> usize {
        if self.velocity {
            3 * ch
        } else {
            0
        }
    }

    /// `dt / h` per axis.
    fn cfl(&self) -> [f64; 3] {
        self.grid.spacing().map(|h| self.dt / h)
    }

    /// Whether sample `(i, j, k)` of channel `ch` is a stored wall face (kept at 0).
    #[inline(always)]
    fn is_wall(&self, ch: usize, p: [usize; 3]) -> bool {
        self.velocity && p[ch] == self.n()[ch] - 1 && !self.walls.periodic(ch) && !self.walls.open_hi(ch)
    }

    /// The sample position (in cells) of `(i, j, k)` on lattice `lat`.
    #[inline(always)]
    fn sample_pos(lat: [Axis; 3], p: [usize; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| p[a] as f64 + lat[a].offset())
    }

    /// The footprint of the departure point of sample `p` (flat index `m`) on lattice `lat`, from
    /// the sample velocities `sv` of its channel (`3 n` values: components along x, y, z).
    #[inline(always)]
    fn departure<T: Real>(&self, sv: &[T], lat: [Axis; 3], p: [usize; 3], m: usize) -> Foot {
        let x = Self::sample_pos(lat, p);
        let (cfl, nc) = (self.cfl(), self.grid.cells());
        let d = [0, 1, 2].map(|a| x[a] - cfl[a] * sv[a * nc + m].wide());
        Foot::new(lat, d, self.n())
    }

    fn check_shapes(&self, q: &Shape, v: &Shape, v_channels: usize) -> candle_core::Result<()> {
        let (qd, vd) = (q.dims(), v.dims());
        let g = &self.grid;
        let fits = |d: &[usize]| d.len() == 5 && d[2] == g.nz && d[3] == g.ny && d[4] == g.nx;
        let ok = fits(qd)
            && fits(vd)
            && vd[0] == qd[0]
            && vd[1] == v_channels
            && (!self.velocity || qd[1] == 3)
            && qd[1] >= 1;
        if !ok {
            candle_core::bail!(
                "grid3d semi_lagrangian: q {qd:?} and velocity {vd:?} do not fit a {} and a {v_channels}-channel \
                 velocity on {}x{}x{}",
                if self.velocity { "MAC velocity" } else { "cell-centred field" },
                g.nz,
                g.ny,
                g.nx
            );
        }
        Ok(())
    }

    /// Forward in one of three modes (the value, or the limiter's bounds); `sv` are the sample
    /// velocities.
    fn run<T: Real>(&self, q: &[T], qs: &Shape, sv: &[T], out: &mut [T], mode: Mode) {
        let n = self.n();
        let nc = self.grid.cells();
        let chans = qs.dims()[1];
        let sc = self.sample_channels();
        for (b, svb) in sv.chunks(sc * nc).enumerate() {
            for ch in 0..chans {
                let off = (b * chans + ch) * nc;
                let lat = self.lattice(ch);
                let qc = &q[off..off + nc];
                let svc = &svb[self.sample_base(ch) * nc..(self.sample_base(ch) + 3) * nc];
                for_rows(&mut out[off..off + nc], n[0], parallel_cells(nc), |r, o| {
                    let (j, k) = (r % n[1], r / n[1]);
                    for (i, o) in o.iter_mut().enumerate() {
                        let p = [i, j, k];
                        if self.is_wall(ch, p) {
                            continue; // output starts at 0
                        }
                        let f = self.departure(svc, lat, p, r * n[0] + i);
                        let corner = |b: usize| if f.c[b] == 0.0 { T::zero() } else { T::c(f.c[b]) * qc[f.k[b]] };
                        *o = match mode {
                            Mode::Value => T::c(f.dot(&f.weights(), qc)),
                            Mode::Min => (1..8).fold(corner(0), |m, b| m.fmin(corner(b))),
                            Mode::Max => (1..8).fold(corner(0), |m, b| m.fmax(corner(b))),
                        };
                    }
                });
            }
        }
    }

    /// Gradient with respect to `q`: the transpose of the interpolation, or (with `max` set) of
    /// the extremum selection (the first corner attaining it).
    fn grad_q<T: Real>(&self, q: Option<&[T]>, chans: usize, sv: &[T], g: &[T], out: &mut [T], max: Option<bool>) {
        let n = self.n();
        let nc = self.grid.cells();
        let sc = self.sample_channels();
        for (b, svb) in sv.chunks(sc * nc).enumerate() {
            for ch in 0..chans {
                let off = (b * chans + ch) * nc;
                let lat = self.lattice(ch);
                let gc = &g[off..off + nc];
                let qc = q.map(|q| &q[off..off + nc]);
                let svc = &svb[self.sample_base(ch) * nc..(self.sample_base(ch) + 3) * nc];
                accumulate_rows(&mut out[off..off + nc], n[1] * n[2], parallel_cells(nc), |r, acc| {
                    let (j, k) = (r % n[1], r / n[1]);
                    for i in 0..n[0] {
                        let p = [i, j, k];
                        let a = gc[r * n[0] + i];
                        if a == T::zero() || self.is_wall(ch, p) {
                            continue;
                        }
                        let f = self.departure(svc, lat, p, r * n[0] + i);
                        match (max, qc) {
                            (Some(max), Some(qc)) => {
                                let corner = |b: usize| if f.c[b] == 0.0 { 0.0 } else { f.c[b] * qc[f.k[b]].wide() };
                                let mut best = 0;
                                for b in 1..8 {
                                    let (v, w) = (corner(b), corner(best));
                                    if (max && v > w) || (!max && v < w) {
                                        best = b;
                                    }
                                }
                                if f.c[best] != 0.0 {
                                    acc[f.k[best]] += T::c(f.c[best]) * a;
                                }
                            }
                            _ => f.scatter(&f.weights(), a.wide(), acc),
                        }
                    }
                });
            }
        }
    }

    /// Gradient with respect to the sample velocities: per sample and axis, `g * dq/dx_e * (-dt
    /// / h_e)` (no scatter: each sample owns its velocity).
    fn grad_sample_velocity<T: Real>(&self, q: &[T], chans: usize, sv: &[T], g: &[T], out: &mut [T]) {
        let n = self.n();
        let nc = self.grid.cells();
        let sc = self.sample_channels();
        let cfl = self.cfl();
        for (b, (svb, ob)) in sv.chunks(sc * nc).zip(out.chunks_mut(sc * nc)).enumerate() {
            for ch in 0..chans {
                let off = (b * chans + ch) * nc;
                let lat = self.lattice(ch);
                let (gc, qc) = (&g[off..off + nc], &q[off..off + nc]);
                let base = self.sample_base(ch);
                let svc = &svb[base * nc..(base + 3) * nc];
                let ob = &mut ob[base * nc..(base + 3) * nc];
                // Rows of `[3][nx]` per grid row, filled in parallel, then added to `ob`.
                let mut tmp = vec![T::zero(); 3 * nc];
                for_rows(&mut tmp, 3 * n[0], parallel_cells(nc), |r, o| {
                    let (j, k) = (r % n[1], r / n[1]);
                    for i in 0..n[0] {
                        let p = [i, j, k];
                        let m = r * n[0] + i;
                        let a = gc[m].wide();
                        if a == 0.0 || self.is_wall(ch, p) {
                            continue;
                        }
                        let f = self.departure(svc, lat, p, m);
                        for e in 0..3 {
                            // d q / d x_e at the departure point, times d x_e / d v_e = -dt / h_e.
                            o[e * n[0] + i] = T::c(-a * f.dot(&f.dweights(e), qc) * cfl[e]);
                        }
                    }
                });
                for (r, row) in tmp.chunks(3 * n[0]).enumerate() {
                    for e in 0..3 {
                        let dst = &mut ob[e * nc + r * n[0]..e * nc + (r + 1) * n[0]];
                        for (d, s) in dst.iter_mut().zip(&row[e * n[0]..(e + 1) * n[0]]) {
                            *d += *s;
                        }
                    }
                }
            }
        }
    }
}

/// The velocity interpolated to the sample points of the advected channels (see
/// [`Sl3d::sample_velocity`]); linear, its backward the transpose (a scatter).
#[derive(Clone, Copy)]
struct SampleVel3d(Sl3d);

impl SampleVel3d {
    /// The channels of `q` whose sample points this op covers: one cell-centred lattice for a
    /// scalar, the three face lattices for a velocity.
    fn lattices(&self) -> usize {
        if self.0.velocity {
            3
        } else {
            1
        }
    }
}

impl Kernel1 for SampleVel3d {
    fn name(&self) -> &'static str {
        "grid3d_sample_velocity"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_shape(self.name(), s, &self.0.grid)?;
        let d = s.dims();
        Ok(Shape::from(vec![d[0], self.0.sample_channels(), d[2], d[3], d[4]]))
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let sl = &self.0;
        let (n, nc, sc) = (sl.n(), sl.grid.cells(), sl.sample_channels());
        for (vb, ob) in x.chunks(3 * nc).zip(out.chunks_mut(sc * nc)) {
            for ch in 0..self.lattices() {
                let lat = sl.lattice(ch);
                for e in 0..3 {
                    let o = &mut ob[(3 * ch + e) * nc..(3 * ch + e + 1) * nc];
                    let ve = &vb[e * nc..(e + 1) * nc];
                    for_rows(o, n[0], parallel_cells(nc), |r, o| {
                        let (j, k) = (r % n[1], r / n[1]);
                        for (i, o) in o.iter_mut().enumerate() {
                            let p = [i, j, k];
                            if sl.is_wall(ch, p) {
                                continue;
                            }
                            let f = Foot::new(velocity_lattice(e, &sl.walls), Sl3d::sample_pos(lat, p), n);
                            *o = T::c(f.dot(&f.weights(), ve));
                        }
                    });
                }
            }
        }
        Ok(())
    }
}

impl Op1 for SampleVel3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, SampleVel3dAdjoint(*self))
    }
}

/// Transpose of [`SampleVel3d`]: `[batch, 3 or 9, ...]` to `[batch, 3, ...]`.
struct SampleVel3dAdjoint(SampleVel3d);

impl Kernel1 for SampleVel3dAdjoint {
    fn name(&self) -> &'static str {
        "grid3d_sample_velocity_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let d = s.dims();
        Ok(Shape::from(vec![d[0], 3, d[2], d[3], d[4]]))
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let sl = &self.0 .0;
        let (n, nc, sc) = (sl.n(), sl.grid.cells(), sl.sample_channels());
        for (gb, ob) in g.chunks(sc * nc).zip(out.chunks_mut(3 * nc)) {
            for ch in 0..self.0.lattices() {
                let lat = sl.lattice(ch);
                for e in 0..3 {
                    let ge = &gb[(3 * ch + e) * nc..(3 * ch + e + 1) * nc];
                    accumulate_rows(&mut ob[e * nc..(e + 1) * nc], n[1] * n[2], parallel_cells(nc), |r, acc| {
                        let (j, k) = (r % n[1], r / n[1]);
                        for i in 0..n[0] {
                            let p = [i, j, k];
                            let a = ge[r * n[0] + i];
                            if a == T::zero() || sl.is_wall(ch, p) {
                                continue;
                            }
                            let f = Foot::new(velocity_lattice(e, &sl.walls), Sl3d::sample_pos(lat, p), n);
                            f.scatter(&f.weights(), a.wide(), acc);
                        }
                    });
                }
            }
        }
        Ok(())
    }
}

/// Backtrace and interpolation of `q` with given sample velocities; inputs `(q, sample velocity)`.
#[derive(Clone, Copy)]
struct SlCore3d(Sl3d);

impl Kernel2 for SlCore3d {
    fn name(&self) -> &'static str {
        "grid3d_semi_lagrangian"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.0.check_shapes(a, b, self.0.sample_channels())?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.0.run(q, qs, v, out, Mode::Value);
        Ok(())
    }
}

impl Op2 for SlCore3d {
    fn backward(&self, q: &Tensor, v: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gq = apply_kernel2(v, g, SlGradQ3d(self.0))?;
        let gv = apply_kernel3(q, v, g, SlGradVel3d(self.0))?;
        Ok((gq, gv))
    }
}

/// Vector-Jacobian product of [`SlCore3d`] with respect to `q`; inputs `(sample velocity, g)`.
struct SlGradQ3d(Sl3d);

impl Kernel2 for SlGradQ3d {
    fn name(&self) -> &'static str {
        "grid3d_semi_lagrangian_grad_q"
    }
    fn output_shape(&self, _v: &Shape, g: &Shape) -> candle_core::Result<Shape> {
        Ok(g.clone())
    }
    fn forward<T: Real>(&self, v: &[T], _vs: &Shape, g: &[T], gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.0.grad_q(None, gs.dims()[1], v, g, out, None);
        Ok(())
    }
}

/// Vector-Jacobian product of [`SlCore3d`] with respect to the sample velocities; inputs
/// `(q, sample velocity, g)`.
struct SlGradVel3d(Sl3d);

impl Kernel3 for SlGradVel3d {
    fn name(&self) -> &'static str {
        "grid3d_semi_lagrangian_grad_velocity"
    }
    fn output_shape(&self, _q: &Shape, v: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(v.clone())
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
        self.0.grad_sample_velocity(q, qs.dims()[1], v, g, out);
        Ok(())
    }
}

/// The limiter bounds: the min (`max = false`) or max of the eight values each sample
/// interpolates from; the gradient goes to the extremal corner, none to the velocity.
/// Inputs `(q, sample velocity)`.
#[derive(Clone, Copy)]
struct Bounds3d {
    sl: Sl3d,
    max: bool,
}

impl Kernel2 for Bounds3d {
    fn name(&self) -> &'static str {
        "grid3d_semi_lagrangian_bounds"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        self.sl.check_shapes(a, b, self.sl.sample_channels())?;
        Ok(a.clone())
    }
    fn forward<T: Real>(&self, q: &[T], qs: &Shape, v: &[T], _vs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.sl.run(q, qs, v, out, if self.max { Mode::Max } else { Mode::Min });
        Ok(())
    }
}

impl Op2 for Bounds3d {
    fn backward(&self, q: &Tensor, v: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gq = apply_kernel3(q, v, g, BoundsGradQ3d(*self))?;
        Ok((gq, v.zeros_like()?))
    }
}

/// Vector-Jacobian product of [`Bounds3d`] with respect to `q`; inputs `(q, sample velocity, g)`.
struct BoundsGradQ3d(Bounds3d);

impl Kernel3 for BoundsGradQ3d {
    fn name(&self) -> &'static str {
        "grid3d_semi_lagrangian_bounds_grad_q"
    }
    fn output_shape(&self, q: &Shape, _v: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(q.clone())
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
        self.0.sl.grad_q(Some(q), qs.dims()[1], v, g, out, Some(self.0.max));
        Ok(())
    }
}

/// `clamp(x, lo, hi)` elementwise, the gradient routed to whichever input is active (ties to
/// the bound, so a degenerate interval such as a wall face passes nothing to `x`).
#[derive(Clone, Copy)]
struct Clamp3d;

impl Kernel3 for Clamp3d {
    fn name(&self) -> &'static str {
        "grid3d_clamp"
    }
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape> {
        if a != b || a != c {
            candle_core::bail!("grid3d_clamp: shapes differ: {a:?} {b:?} {c:?}");
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

impl Op3 for Clamp3d {
    fn backward(
        &self,
        x: &Tensor,
        lo: &Tensor,
        hi: &Tensor,
        _y: &Tensor,
        g: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let below = x.le(lo)?;
        let above = x.ge(hi)?.mul(&below.ne(1u8)?)?;
        let zero = g.zeros_like()?;
        let g_lo = below.where_cond(g, &zero)?;
        let g_hi = above.where_cond(g, &zero)?;
        let g_x = below.add(&above)?.where_cond(&zero, g)?;
        Ok((g_x, g_lo, g_hi))
    }
}
