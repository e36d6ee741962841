//! Forces on obstacles from a control-volume momentum balance, and drag / lift coefficients.
//!
//! For the fluid between a body `B` and a fixed rectangle `S` around it (density `rho = 1`, so
//! every force here is per unit density: multiply by `rho`), the momentum balance gives the force
//! of the fluid on the body
//!
//! `F = - d/dt ∫_CV u dV - ∮_S u (u·n) dS - ∮_S p n dS + ∮_S nu (∇u + ∇u^T) n dS`,
//!
//! `n` the outward normal of `S`, `CV` the region inside `S` (the body's own volume adds nothing
//! to the first term while it is at rest). Only velocities enter: the pressure on `S` is
//! recovered up to a constant (which `∮ p n dS` does not see) by integrating the momentum
//! equation along `S`, `∂p/∂s = t·(-∂u/∂t - (u·∇)u + nu ∇²u)`, `t` the tangent. The loop's
//! closure error (the discrete curl of that right-hand side) is spread linearly over the
//! perimeter and reported ([`Force::pressure_closure`]).
//!
//! Discretisation on the MAC grid: `S` runs along cell faces (the rectangle of cells
//! `i0 <= i < i1`, `j0 <= j < j1`, [`ControlVolume`]); fluxes and stresses are evaluated at the
//! face centres on `S` (normal velocity stored there, tangential velocity and derivatives from
//! second-order central averages and differences), the momentum right-hand side at the faces
//! next to `S` (midpoint rule for the pressure path), the volume integral by the trapezoidal rule.
//! Every part is second order for smooth flow, so `S` should lie in smooth flow, a few cells away
//! from the body and at least two cells inside the domain. The method does not care how the
//! body was represented (staircase mask, immersed boundary).
//!
//! Coefficients: `c_D = 2 F_x / (rho U^2 L)`, `c_L = 2 F_y / (rho U^2 L)` ([`coefficients`]).

use crate::{Error, Grid, MacField, Result};
use candle_core::{DType, Tensor};

/// A rectangle of whole cells `i0 <= i < i1`, `j0 <= j < j1` whose boundary is the control
/// surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlVolume {
    /// First cell `[i0, j0]`.
    pub lo: [usize; 2],
    /// One past the last cell `[i1, j1]`.
    pub hi: [usize; 2],
}

/// The force on what lies inside a [`ControlVolume`], per unit density, split into its parts
/// (`total` is their sum), each `[x, y]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Force {
    /// The force of the fluid on the body `[F_x, F_y]` (drag, lift for a flow along +x).
    pub total: [f64; 2],
    /// `-∮ u (u·n) dS`.
    pub momentum_flux: [f64; 2],
    /// `-∮ p n dS`.
    pub pressure: [f64; 2],
    /// `∮ nu (∇u + ∇u^T) n dS`.
    pub viscous: [f64; 2],
    /// `-d/dt ∫ u dV` (0 without a time derivative).
    pub unsteady: [f64; 2],
    /// The pressure path's failure to close, `|∮ ∂p/∂s ds|`, before it was spread.
    pub pressure_closure: f64,
}

/// `[c_D, c_L] = 2 F / (rho U^2 L)` for a force `F` (per unit density when `rho = 1`), reference
/// speed `u_ref` and length `l_ref`.
pub fn coefficients(force: [f64; 2], rho: f64, u_ref: f64, l_ref: f64) -> [f64; 2] {
    let q = 0.5 * rho * u_ref * u_ref * l_ref;
    [force[0] / q, force[1] / q]
}

impl ControlVolume {
    /// The cells of `grid` whose faces lie closest to the rectangle `[lo, hi]` (domain
    /// coordinates, the grid's origin at 0). The rectangle must keep two cells from every edge
    /// of the domain and span at least one cell.
    pub fn from_rect(grid: &Grid, lo: [f64; 2], hi: [f64; 2]) -> Result<Self> {
        let snap = |x: f64, h: f64| (x / h).round().max(0.0) as usize;
        let cv = Self {
            lo: [snap(lo[0], grid.dx()), snap(lo[1], grid.dy())],
            hi: [snap(hi[0], grid.dx()), snap(hi[1], grid.dy())],
        };
        cv.validate(grid)?;
        Ok(cv)
    }

    /// Checks that the rectangle is non-empty and two cells inside the domain.
    pub fn validate(&self, grid: &Grid) -> Result<()> {
        let [i0, j0] = self.lo;
        let [i1, j1] = self.hi;
        if !(i0 < i1 && j0 < j1 && i0 >= 2 && j0 >= 2 && i1 + 2 <= grid.nx && j1 + 2 <= grid.ny) {
            return Err(Error::Invalid {
                field: "control_volume",
                reason: format!(
                    "cells {:?}..{:?} must be non-empty and keep 2 cells from the edges of the {}x{} grid",
                    self.lo, self.hi, grid.nx, grid.ny
                ),
            });
        }
        Ok(())
    }

    /// The force of the fluid on whatever lies inside the control volume (per unit density),
    /// from the velocity `u` (batch 1), the kinematic viscosity `nu` and, for unsteady flow,
    /// the time derivative `du_dt` of the velocity (`[1, 2, ny, nx]`, e.g. a central difference
    /// of consecutive states; `None` for a steady state).
    pub fn force(&self, u: &MacField, nu: f64, du_dt: Option<&Tensor>) -> Result<Force> {
        let grid = *u.grid();
        self.validate(&grid)?;
        if u.batch() != 1 {
            return Err(Error::Invalid {
                field: "velocity",
                reason: format!("the force takes one sample, got batch {}", u.batch()),
            });
        }
        let flat = |t: &Tensor| -> Result<Vec<f64>> { Ok(t.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?) };
        let w = flat(u.values())?;
        let n = grid.cells();
        let dw = match du_dt {
            Some(t) => {
                if t.dims() != u.values().dims() {
                    return Err(Error::Invalid {
                        field: "du_dt",
                        reason: format!("shape {:?}, the velocity's {:?}", t.dims(), u.values().dims()),
                    });
                }
                flat(t)?
            }
            None => vec![0.0; 2 * n],
        };
        Ok(Balance { nx: grid.nx, dx: grid.dx(), dy: grid.dy(), nu, w: &w, dw: &dw, n }.force(self))
    }
}

/// Velocity access by face position: `uf(I, j)` is `u` at `x = I dx, y = (j + 1/2) dy`,
/// `vf(i, J)` is `v` at `x = (i + 1/2) dx, y = J dy` (stored at `I - 1`, `J - 1`).
struct Balance<'a> {
    nx: usize,
    n: usize,
    dx: f64,
    dy: f64,
    nu: f64,
    w: &'a [f64],
    dw: &'a [f64],
}

impl Balance<'_> {
    fn uf(&self, i: usize, j: usize) -> f64 {
        self.w[j * self.nx + i - 1]
    }
    fn vf(&self, i: usize, j: usize) -> f64 {
        self.w[self.n + (j - 1) * self.nx + i]
    }
    fn dudt(&self, i: usize, j: usize) -> f64 {
        self.dw[j * self.nx + i - 1]
    }
    fn dvdt(&self, i: usize, j: usize) -> f64 {
        self.dw[self.n + (j - 1) * self.nx + i]
    }
    /// `v` averaged to the `u` face `(I, j)`.
    fn v_at_u(&self, i: usize, j: usize) -> f64 {
        0.25 * (self.vf(i - 1, j) + self.vf(i, j) + self.vf(i - 1, j + 1) + self.vf(i, j + 1))
    }
    /// `u` averaged to the `v` face `(i, J)`.
    fn u_at_v(&self, i: usize, j: usize) -> f64 {
        0.25 * (self.uf(i, j - 1) + self.uf(i + 1, j - 1) + self.uf(i, j) + self.uf(i + 1, j))
    }
    /// Derivatives at the `u` face `(I, j)`: `[u_x, u_y, v_x]`.
    fn grad_at_u(&self, i: usize, j: usize) -> [f64; 3] {
        let ux = (self.uf(i + 1, j) - self.uf(i - 1, j)) / (2.0 * self.dx);
        let uy = (self.uf(i, j + 1) - self.uf(i, j - 1)) / (2.0 * self.dy);
        // v at the cell centres on either side, differenced across the face.
        let vc = |ii: usize| 0.5 * (self.vf(ii, j) + self.vf(ii, j + 1));
        let vx = (vc(i) - vc(i - 1)) / self.dx;
        [ux, uy, vx]
    }
    /// Derivatives at the `v` face `(i, J)`: `[v_x, v_y, u_y]`.
    fn grad_at_v(&self, i: usize, j: usize) -> [f64; 3] {
        let vx = (self.vf(i + 1, j) - self.vf(i - 1, j)) / (2.0 * self.dx);
        let vy = (self.vf(i, j + 1) - self.vf(i, j - 1)) / (2.0 * self.dy);
        let uc = |jj: usize| 0.5 * (self.uf(i, jj) + self.uf(i + 1, jj));
        let uy = (uc(j) - uc(j - 1)) / self.dy;
        [vx, vy, uy]
    }
    /// `-(u·∇)u + nu ∇²u - ∂u/∂t` (= `∂p/∂x`) at the `u` face `(I, j)`.
    fn rhs_u(&self, i: usize, j: usize) -> f64 {
        let u = self.uf(i, j);
        let [ux, uy, _] = self.grad_at_u(i, j);
        let lap = (self.uf(i + 1, j) - 2.0 * u + self.uf(i - 1, j)) / (self.dx * self.dx)
            + (self.uf(i, j + 1) - 2.0 * u + self.uf(i, j - 1)) / (self.dy * self.dy);
        -(u * ux + self.v_at_u(i, j) * uy) + self.nu * lap - self.dudt(i, j)
    }
    /// `-(u·∇)v + nu ∇²v - ∂v/∂t` (= `∂p/∂y`) at the `v` face `(i, J)`.
    fn rhs_v(&self, i: usize, j: usize) -> f64 {
        let v = self.vf(i, j);
        let [vx, vy, _] = self.grad_at_v(i, j);
        let lap = (self.vf(i + 1, j) - 2.0 * v + self.vf(i - 1, j)) / (self.dx * self.dx)
            + (self.vf(i, j + 1) - 2.0 * v + self.vf(i, j - 1)) / (self.dy * self.dy);
        -(self.u_at_v(i, j) * vx + v * vy) + self.nu * lap - self.dvdt(i, j)
    }
    /// `∂p/∂x` at the vertex `(I dx, J dy)`.
    fn px(&self, i: usize, j: usize) -> f64 {
        0.5 * (self.rhs_u(i, j - 1) + self.rhs_u(i, j))
    }
    /// `∂p/∂y` at the vertex `(I dx, J dy)`.
    fn py(&self, i: usize, j: usize) -> f64 {
        0.5 * (self.rhs_v(i - 1, j) + self.rhs_v(i, j))
    }

    fn force(&self, cv: &ControlVolume) -> Force {
        let [i0, j0] = cv.lo;
        let [i1, j1] = cv.hi;
        let (dx, dy, nu) = (self.dx, self.dy, self.nu);
        let mut flux = [0.0; 2];
        let mut visc = [0.0; 2];
        // Vertical sides (u faces): sign -1 on the left (n = -x), +1 on the right.
        for (i, s) in [(i0, -1.0), (i1, 1.0)] {
            for j in j0..j1 {
                let (u, v) = (self.uf(i, j), self.v_at_u(i, j));
                let [ux, uy, vx] = self.grad_at_u(i, j);
                flux[0] -= s * u * u * dy;
                flux[1] -= s * u * v * dy;
                visc[0] += s * 2.0 * nu * ux * dy;
                visc[1] += s * nu * (uy + vx) * dy;
            }
        }
        // Horizontal sides (v faces): -1 at the bottom (n = -y), +1 at the top.
        for (j, s) in [(j0, -1.0), (j1, 1.0)] {
            for i in i0..i1 {
                let (u, v) = (self.u_at_v(i, j), self.vf(i, j));
                let [vx, vy, uy] = self.grad_at_v(i, j);
                flux[0] -= s * u * v * dx;
                flux[1] -= s * v * v * dx;
                visc[0] += s * nu * (uy + vx) * dx;
                visc[1] += s * 2.0 * nu * vy * dx;
            }
        }
        // Pressure along the loop, counter-clockwise from the first bottom face: (value, arc
        // length, side) per face centre on S.
        #[derive(Clone, Copy)]
        enum Side {
            Bottom,
            Right,
            Top,
            Left,
        }
        let mut pts: Vec<(f64, f64, Side)> = Vec::new();
        let (mut p, mut s) = (0.0, 0.0);
        pts.push((p, s, Side::Bottom));
        for i in i0 + 1..i1 {
            p += dx * self.px(i, j0);
            s += dx;
            pts.push((p, s, Side::Bottom));
        }
        p += 0.5 * dx * self.px(i1, j0) + 0.5 * dy * self.py(i1, j0);
        s += 0.5 * (dx + dy);
        pts.push((p, s, Side::Right));
        for j in j0 + 1..j1 {
            p += dy * self.py(i1, j);
            s += dy;
            pts.push((p, s, Side::Right));
        }
        p += 0.5 * dy * self.py(i1, j1) - 0.5 * dx * self.px(i1, j1);
        s += 0.5 * (dx + dy);
        pts.push((p, s, Side::Top));
        for i in (i0 + 1..i1).rev() {
            p -= dx * self.px(i, j1);
            s += dx;
            pts.push((p, s, Side::Top));
        }
        p += -0.5 * dx * self.px(i0, j1) - 0.5 * dy * self.py(i0, j1);
        s += 0.5 * (dx + dy);
        pts.push((p, s, Side::Left));
        for j in (j0 + 1..j1).rev() {
            p -= dy * self.py(i0, j);
            s += dy;
            pts.push((p, s, Side::Left));
        }
        p += -0.5 * dy * self.py(i0, j0) + 0.5 * dx * self.px(i0, j0);
        s += 0.5 * (dx + dy);
        // Back at the start: `p` is the closure error, spread over the perimeter `s`.
        let (closure, perimeter) = (p, s);
        let mut pres = [0.0; 2];
        for &(pv, sv, side) in &pts {
            let pc = pv - closure * sv / perimeter;
            match side {
                Side::Bottom => pres[1] += pc * dx,
                Side::Top => pres[1] -= pc * dx,
                Side::Left => pres[0] += pc * dy,
                Side::Right => pres[0] -= pc * dy,
            }
        }
        // -d/dt of the momentum inside, trapezoidal rule over the faces in the rectangle.
        let mut unsteady = [0.0; 2];
        for j in j0..j1 {
            for i in i0..=i1 {
                let wgt = if i == i0 || i == i1 { 0.5 } else { 1.0 };
                unsteady[0] -= wgt * self.dudt(i, j) * dx * dy;
            }
        }
        for j in j0..=j1 {
            for i in i0..i1 {
                let wgt = if j == j0 || j == j1 { 0.5 } else { 1.0 };
                unsteady[1] -= wgt * self.dvdt(i, j) * dx * dy;
            }
        }
        let total = [0, 1].map(|k| flux[k] + pres[k] + visc[k] + unsteady[k]);
        Force { total, momentum_flux: flux, pressure: pres, viscous: visc, unsteady, pressure_closure: closure.abs() }
    }
}
