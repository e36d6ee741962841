//! A closed 3D box: no-slip walls on all six faces, the wall `y = ly` (the lid) sliding along
//! `+x`. Ghost rules and the momentum right-hand side (flux-form advection + viscosity) with walls.
//!
//! Storage is the periodic one (`[batch, 3, nz, ny, nx]`); the last stored face of each component
//! along its own axis (`u` at `x = lx`, `v` at `y = ly`, `w` at `z = lz`) is a wall face, kept at
//! 0, and the wall faces at 0 are implicit. Reads outside the box follow the ghost rules:
//! * a component along its own axis (normal to the wall): 0;
//! * a tangential component: `2 U_wall - q_inner` (linear reflection: the wall velocity on the
//!   wall), with `U_wall` the lid speed for `u` at `y = ly` and 0 everywhere else.
//!
//! [`Walls3d`] generalises the box per face (used by [`super::Smoke3d::with_boundaries`]): a
//! [`Face3d::FreeSlip`] face mirrors the tangential ghost (`+q_inner`: zero shear), a
//! [`Face3d::Periodic`] pair wraps (the last stored face along that axis is then an ordinary
//! face, the one at 0). The normal component is 0 on every wall face, no-slip or free-slip.
//!
//! The stencil is the periodic one ([`super::momentum`]); no stencil point leaves the box along
//! two axes at once, so corners never need a rule. Tendencies on the wall faces are 0.

use super::field::MacField3d;
use super::momentum::{check_adjoint_shapes, check_shape};
use super::Grid3d;
use crate::pad::{accumulate_rows, for_rows, parallel_cells};
use crate::stability::check_nu;
use crate::{Error, Result};
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel2, Kernel1, Kernel2, Op1};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};

/// No-slip walls on every face of the box; the wall `y = ly` slides along `+x` at `lid_velocity`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CavityWalls {
    /// Tangential speed of the lid `y = ly` along `+x` (0: a closed box at rest).
    pub lid_velocity: f64,
}

impl CavityWalls {
    /// Checks the lid speed.
    pub fn validate(&self) -> Result<()> {
        if !self.lid_velocity.is_finite() {
            return Err(Error::Boundary {
                face: "y_hi",
                reason: format!("lid velocity {} is not finite", self.lid_velocity),
            });
        }
        Ok(())
    }
}

/// The condition on one face of the 3D box (scene values `no_slip`, `free_slip`, `periodic`,
/// the names of the 2D [`crate::Bc`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Face3d {
    /// Solid wall at rest: normal velocity 0, tangential ghost `-q_inner` (the tangential
    /// velocity is 0 on the wall). The default.
    #[default]
    NoSlip,
    /// Solid wall without friction: normal velocity 0, tangential ghost `+q_inner` (zero shear:
    /// the tangential velocity's normal derivative is 0 on the wall).
    FreeSlip,
    /// Wraps to the opposite face (both faces of the axis must be periodic).
    Periodic,
    /// Open (outflow, the 2D [`crate::Bc::Outflow`]): pressure 0 beyond the face (Dirichlet in
    /// the projection), zero-gradient velocity; the normal velocity on the face is free. Upper
    /// faces (`x_hi`, `y_hi`, `z_hi`) only, where the face is stored.
    Outflow,
}

/// Per-face conditions of the 3D box. The default is the closed box of no-slip walls (what
/// [`super::Smoke3d::new`] and [`super::Cavity3d`] use).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Walls3d {
    /// The face `x = 0`.
    #[serde(default)]
    pub x_lo: Face3d,
    /// The face `x = lx`.
    #[serde(default)]
    pub x_hi: Face3d,
    /// The face `y = 0`.
    #[serde(default)]
    pub y_lo: Face3d,
    /// The face `y = ly`.
    #[serde(default)]
    pub y_hi: Face3d,
    /// The face `z = 0`.
    #[serde(default)]
    pub z_lo: Face3d,
    /// The face `z = lz`.
    #[serde(default)]
    pub z_hi: Face3d,
}

/// The face names, axis-major, low before high.
pub(crate) const FACE_NAMES: [[&str; 2]; 3] = [["x_lo", "x_hi"], ["y_lo", "y_hi"], ["z_lo", "z_hi"]];

impl Walls3d {
    /// The closed box of no-slip walls.
    pub fn closed() -> Self {
        Self::default()
    }

    /// Every face `kind` (`Periodic` makes the fully periodic box).
    pub fn all(kind: Face3d) -> Self {
        Self { x_lo: kind, x_hi: kind, y_lo: kind, y_hi: kind, z_lo: kind, z_hi: kind }
    }

    /// The faces as `[[lo, hi]; 3]` along x, y, z.
    pub fn faces(&self) -> [[Face3d; 2]; 3] {
        [[self.x_lo, self.x_hi], [self.y_lo, self.y_hi], [self.z_lo, self.z_hi]]
    }

    /// Whether axis `a` (0 = x) is periodic.
    #[inline(always)]
    pub fn periodic(&self, a: usize) -> bool {
        self.faces()[a][0] == Face3d::Periodic
    }

    /// Whether the face of axis `a` (`hi`: the upper one) is free-slip.
    #[inline(always)]
    pub fn free_slip(&self, a: usize, hi: bool) -> bool {
        self.faces()[a][usize::from(hi)] == Face3d::FreeSlip
    }

    /// Whether the upper face of axis `a` is open ([`Face3d::Outflow`]).
    #[inline(always)]
    pub fn open_hi(&self, a: usize) -> bool {
        self.faces()[a][1] == Face3d::Outflow
    }

    /// Whether any face is open (then the pressure problem is definite).
    pub fn any_open(&self) -> bool {
        (0..3).any(|a| self.open_hi(a))
    }

    /// Whether this is the closed no-slip box.
    pub fn is_closed_no_slip(&self) -> bool {
        *self == Self::closed()
    }

    /// Checks that periodic faces come in pairs and that a periodic axis has at least 3 cells
    /// (with 2 the two neighbours of a cell would be the same cell).
    pub fn validate(&self, grid: &Grid3d) -> Result<()> {
        let n = [grid.nx, grid.ny, grid.nz];
        for (a, [lo, hi]) in self.faces().into_iter().enumerate() {
            if (lo == Face3d::Periodic) != (hi == Face3d::Periodic) {
                let face = FACE_NAMES[a][usize::from(lo == Face3d::Periodic)];
                return Err(Error::Boundary {
                    face,
                    reason: format!(
                        "{lo:?} / {hi:?}: periodic faces come in pairs; make both {} and {} periodic or neither",
                        FACE_NAMES[a][0], FACE_NAMES[a][1]
                    ),
                });
            }
            if lo == Face3d::Outflow {
                return Err(Error::Boundary {
                    face: FACE_NAMES[a][0],
                    reason: "outflow is for the upper faces (x_hi, y_hi, z_hi), where the face velocity is stored; \
                             put the open face on the upper side"
                        .into(),
                });
            }
            if lo == Face3d::Periodic && n[a] < 3 {
                return Err(Error::Boundary {
                    face: FACE_NAMES[a][0],
                    reason: format!("a periodic axis needs at least 3 cells, got {}", n[a]),
                });
            }
        }
        Ok(())
    }
}

/// Axis-indexed position `[i, j, k]` with signed entries (ghosts at -1 and n).
pub(crate) type Pos = [isize; 3];

/// Unit offset along axis `a` (axis-indexed).
#[inline(always)]
pub(crate) fn unit(a: usize) -> Pos {
    let mut e = [0; 3];
    e[a] = 1;
    e
}

#[inline(always)]
fn add(a: Pos, b: Pos) -> Pos {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline(always)]
fn sub(a: Pos, b: Pos) -> Pos {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Where a read of `q_c` at `pos` comes from: `coef * q[index] + constant` (`index` `None`: constant only).
#[derive(Clone, Copy)]
struct Source {
    index: Option<usize>,
    coef: f64,
    constant: f64,
}

/// Index arithmetic and ghost rules of one walled box.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WallGeom {
    pub n: [usize; 3],
    pub lid: f64,
    pub faces: Walls3d,
}

impl WallGeom {
    pub(crate) fn new(g: &Grid3d, walls: &CavityWalls) -> Self {
        Self { n: [g.nx, g.ny, g.nz], lid: walls.lid_velocity, faces: Walls3d::closed() }
    }

    /// The geometry with per-face conditions (no lid).
    pub(crate) fn with_faces(g: &Grid3d, faces: Walls3d) -> Self {
        Self { n: [g.nx, g.ny, g.nz], lid: 0.0, faces }
    }

    /// The flat index (within one component) of the neighbour of `m` one cell along `a`
    /// (`up`: towards `+a`), wrapped across periodic faces; `None` across a wall.
    #[inline(always)]
    pub(crate) fn neighbour(&self, m: usize, a: usize, up: bool) -> Option<usize> {
        let st = [1, self.n[0], self.n[0] * self.n[1]][a];
        let pa = self.pos(m)[a] as usize;
        let per = self.faces.periodic(a);
        match (up, pa + 1 < self.n[a], pa > 0) {
            (true, true, _) => Some(m + st),
            (true, false, _) if per => Some(m + st - self.n[a] * st),
            (false, _, true) => Some(m - st),
            (false, _, false) if per => Some(m + (self.n[a] - 1) * st),
            _ => None,
        }
    }

    pub(crate) fn cells(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Flat index of component `c` at an in-range position.
    #[inline(always)]
    pub(crate) fn lin(&self, c: usize, p: Pos) -> usize {
        c * self.cells() + (p[2] as usize * self.n[1] + p[1] as usize) * self.n[0] + p[0] as usize
    }

    /// Position of cell-row-major index `m` (within one component).
    #[inline(always)]
    pub(crate) fn pos(&self, m: usize) -> Pos {
        let (i, r) = (m % self.n[0], m / self.n[0]);
        [i as isize, (r % self.n[1]) as isize, (r / self.n[1]) as isize]
    }

    /// Whether `q_c` at `p` is a stored wall face (last along `c`'s own axis).
    #[inline(always)]
    pub(crate) fn is_wall_face(&self, c: usize, p: Pos) -> bool {
        p[c] == self.n[c] as isize - 1 && !self.faces.periodic(c) && !self.faces.open_hi(c)
    }

    /// Where a read of `q_c` at `p` comes from. A point outside the box along several axes (only
    /// the open face's stencil reaches one: the closed box never does) composes the rules axis by
    /// axis.
    #[inline(always)]
    fn source(&self, c: usize, p: Pos) -> Source {
        let mut p = p;
        let (mut coef, mut constant) = (1.0, 0.0);
        for a in 0..3 {
            if self.faces.periodic(a) {
                p[a] = p[a].rem_euclid(self.n[a] as isize);
                continue;
            }
            let (lo, hi) = (p[a] < 0, p[a] >= self.n[a] as isize);
            if !(lo || hi) {
                continue;
            }
            p[a] = if lo { 0 } else { self.n[a] as isize - 1 };
            if hi && self.faces.open_hi(a) {
                // Open face: zero gradient for both the normal and the tangential components.
                continue;
            }
            if a == c {
                return Source { index: None, coef: 0.0, constant: 0.0 };
            }
            if self.faces.free_slip(a, hi) {
                // Zero shear: the ghost mirrors the inner value.
                continue;
            }
            let wall = if c == 0 && a == 1 && hi { self.lid } else { 0.0 };
            constant = 2.0 * wall - constant;
            coef = -coef;
        }
        Source { index: Some(self.lin(c, p)), coef, constant }
    }

    /// `q_c` at `p`, ghosts by the wall rules.
    #[inline(always)]
    fn get<T: Real>(&self, q: &[T], c: usize, p: Pos) -> T {
        let s = self.source(c, p);
        match s.index {
            Some(m) if s.coef == 1.0 && s.constant == 0.0 => q[m],
            Some(m) => T::c(s.constant) + T::c(s.coef) * q[m],
            None => T::zero(),
        }
    }

    /// Adjoint of [`Self::get`]: adds `v` to the gradient of whatever `q_c` at `p` was read from.
    #[inline(always)]
    fn scatter<T: Real>(&self, acc: &mut [T], c: usize, p: Pos, v: T) {
        let s = self.source(c, p);
        if let Some(m) = s.index {
            acc[m] += if s.coef == 1.0 { v } else { T::c(s.coef) * v };
        }
    }
}

/// The tendency `-a div(u u) + nu lap u` with walls (wall faces 0). Differentiable.
pub fn momentum_rhs_walls(u: &MacField3d, walls: &CavityWalls, nu: f64) -> Result<MacField3d> {
    check_nu(nu)?;
    walls.validate()?;
    let op = WallMomentumRhs { grid: *u.grid(), walls: *walls, advect: true, nu, faces: Walls3d::closed() };
    Ok(MacField3d::from_parts(op.apply(u.values())?, *u.grid()))
}

/// The walled momentum right-hand side as a custom op.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WallMomentumRhs {
    pub grid: Grid3d,
    pub walls: CavityWalls,
    pub advect: bool,
    pub nu: f64,
    /// Per-face conditions (the lid applies only to a no-slip `y_hi`).
    pub faces: Walls3d,
}

impl WallMomentumRhs {
    pub(crate) fn apply(&self, u: &Tensor) -> candle_core::Result<Tensor> {
        apply1(u, *self)
    }

    fn consts<T: Real>(&self) -> (T, T, [T; 3], [T; 3]) {
        let h = self.grid.spacing();
        (
            T::c(if self.advect { 1.0 } else { 0.0 }),
            T::c(self.nu),
            h.map(|h| T::c(1.0 / h)),
            h.map(|h| T::c(1.0 / (h * h))),
        )
    }
}

impl Kernel1 for WallMomentumRhs {
    fn name(&self) -> &'static str {
        "grid3d_momentum_rhs_walls"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        check_shape(self.name(), s, &self.grid)?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let geo = WallGeom { faces: self.faces, ..WallGeom::new(&self.grid, &self.walls) };
        let (n, nx) = (geo.cells(), geo.n[0]);
        let rows = n / nx;
        let (a, nu, ih, ih2) = self.consts::<T>();
        let (h, two) = (T::c(0.5), T::c(2.0));
        for (xb, ob) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)) {
            for_rows(ob, nx, parallel_cells(n), |cr, o| {
                let (c, r) = (cr / rows, cr % rows);
                for (i, o) in o.iter_mut().enumerate() {
                    let p = geo.pos(r * nx + i);
                    if geo.is_wall_face(c, p) {
                        continue; // output starts at 0
                    }
                    let q = |comp: usize, at: Pos| geo.get(xb, comp, at);
                    let qc = q(c, p);
                    let (mut adv, mut lap) = (T::zero(), T::zero());
                    for d in 0..3 {
                        let (ec, ed) = (unit(c), unit(d));
                        let ap = h * (q(d, p) + q(d, add(p, ec)));
                        let bp = h * (qc + q(c, add(p, ed)));
                        let am = h * (q(d, sub(p, ed)) + q(d, sub(add(p, ec), ed)));
                        let qm = q(c, sub(p, ed));
                        let bm = h * (qm + qc);
                        adv += (ap * bp - am * bm) * ih[d];
                        lap += (q(c, add(p, ed)) + qm - two * qc) * ih2[d];
                    }
                    *o = nu * lap - a * adv;
                }
            });
        }
        Ok(())
    }
}

impl Op1 for WallMomentumRhs {
    fn backward(&self, x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, gy, WallMomentumRhsAdjoint(*self))
    }
}

/// Vector-Jacobian product of [`WallMomentumRhs`]: each read of the forward differentiated and
/// scattered back through the ghost rules (a reflected ghost sends `-g` to its inner face).
struct WallMomentumRhsAdjoint(WallMomentumRhs);

impl Kernel2 for WallMomentumRhsAdjoint {
    fn name(&self) -> &'static str {
        "grid3d_momentum_rhs_walls_adjoint"
    }
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        check_adjoint_shapes(self.name(), a, b, &self.0.grid)
    }
    fn forward<T: Real>(&self, x: &[T], _xs: &Shape, g: &[T], _gs: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let geo = WallGeom { faces: op.faces, ..WallGeom::new(&op.grid, &op.walls) };
        let (n, nx) = (geo.cells(), geo.n[0]);
        let rows = n / nx;
        let (a, nu, ih, ih2) = op.consts::<T>();
        let (h, two) = (T::c(0.5), T::c(2.0));
        for ((xb, gb), ob) in x.chunks(3 * n).zip(g.chunks(3 * n)).zip(out.chunks_mut(3 * n)) {
            accumulate_rows(ob, 3 * rows, parallel_cells(n), |cr, acc| {
                let (c, r) = (cr / rows, cr % rows);
                for i in 0..nx {
                    let p = geo.pos(r * nx + i);
                    if geo.is_wall_face(c, p) {
                        continue;
                    }
                    let gc = gb[c * n + r * nx + i];
                    let q = |comp: usize, at: Pos| geo.get(xb, comp, at);
                    let qc = q(c, p);
                    for d in 0..3 {
                        let (ec, ed) = (unit(c), unit(d));
                        let l = gc * nu * ih2[d];
                        geo.scatter(acc, c, add(p, ed), l);
                        geo.scatter(acc, c, sub(p, ed), l);
                        geo.scatter(acc, c, p, -two * l);
                        let s = -gc * a * ih[d] * h;
                        let ap = h * (q(d, p) + q(d, add(p, ec)));
                        let bp = h * (qc + q(c, add(p, ed)));
                        let am = h * (q(d, sub(p, ed)) + q(d, sub(add(p, ec), ed)));
                        let bm = h * (q(c, sub(p, ed)) + qc);
                        geo.scatter(acc, d, p, s * bp);
                        geo.scatter(acc, d, add(p, ec), s * bp);
                        geo.scatter(acc, c, p, s * (ap - am));
                        geo.scatter(acc, c, add(p, ed), s * ap);
                        geo.scatter(acc, d, sub(p, ed), -s * bm);
                        geo.scatter(acc, d, sub(add(p, ec), ed), -s * bm);
                        geo.scatter(acc, c, sub(p, ed), -s * am);
                    }
                }
            });
        }
        Ok(())
    }
}
