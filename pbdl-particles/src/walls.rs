//! Wall particles of the SPH solvers ([`crate::Wcsph`], [`crate::Iisph`] and
//! [`crate::dfsph::Dfsph`] in 2D; [`crate::wcsph3d::Wcsph3d`] and the 3D [`crate::dfsph::Dfsph`]
//! in 3D; every item is generic over the dimension `D`): one implementation of Adami, Hu & Adams (2012), "A generalized wall
//! boundary condition for smoothed particle hydrodynamics", J. Comput. Phys. 231, 7057-7075, and
//! the container diagnostics the solvers share.
//!
//! Fixed wall particles (several layers, as thick as the kernel support) take their state from
//! the fluid around them:
//!
//! * **pressure** (Adami et al. 2012, eq. 27):
//!   `p_w = (Σ_f p_f W_wf + (g - a_w)·Σ_f ρ_f (x_w - x_f) W_wf) / Σ_f W_wf`, clamped at 0 (a wall
//!   does not pull on the fluid); the tank is at rest, so `a_w = 0`. WCSPH then gives the wall
//!   particle the density of its equation of state, `ρ_w = ρ0 (p_w / B + 1)^(1/7)`; the
//!   incompressible solvers use `ρ0`. For IISPH and DFSPH the same extrapolation is evaluated
//!   inside every iteration of the pressure solve, as Band et al. (2018), "Pressure boundaries for
//!   implicit incompressible SPH", ACM TOG 37(2), do for IISPH: a wall pressure that follows the
//!   fluid's is consistent with the pressure equation (its only unknowns stay the fluid
//!   pressures; the wall value is a linear function of them plus the hydrostatic term, which is
//!   the part of the wall force that the column's weight needs). Mirroring (`p_w = p_i`) or
//!   Akinci et al.'s boundary volumes, the usual choice with DFSPH (Bender & Koschier 2017), lost
//!   the hydrostatic term and let a column at rest churn (see the iisph module docs), so the
//!   three solvers share this one method;
//! * **velocity** for the viscous terms (no-slip, Adami et al. 2012, eqs. 22-23): the wall
//!   particle carries `2 v_w - ṽ_w`, `ṽ_w = Σ_f v_f W_wf / Σ_f W_wf` the fluid velocity seen
//!   from the wall and `v_w = 0` the wall's own, so the velocity interpolated at the wall surface
//!   is the wall's.
//!
//! [`WallStencil`] holds, per wall particle, its fluid neighbours with `W_wf` and `x_w - x_f`;
//! it is built once per step from the fluid rows of a neighbour list (the search radius is
//! symmetric, so a wall particle sees exactly the fluid particles whose lists hold it), which is
//! cheaper than listing the wall particles' own neighbours, and a pressure solve can evaluate
//! the extrapolation in every iteration as a gather.
//!
//! The container helpers ([`enforce_container`], [`leaked`], [`front`]) are the impermeable-wall
//! fallback and the diagnostics of the incompressible solvers (see [`enforce_container`]).

use crate::kernels::Kernel;
use crate::neighbors::{Domain, NeighborList};
use pbdl_core::Real;
use rayon::prelude::*;

/// Per wall particle, its fluid neighbours with the kernel weight `W_wf` and the offset
/// `x_w - x_f` (a transposed, wall-rows-only neighbour list); see the module docs.
#[derive(Clone, Debug)]
pub struct WallStencil<T: Real, const D: usize = 2> {
    n_fluid: usize,
    offsets: Vec<usize>,
    fluid: Vec<u32>,
    w: Vec<T>,
    d: Vec<[T; D]>,
    inv_sum: Vec<T>,
    fill: Vec<usize>,
}

// Not derived: `[T; D]: Default` does not hold for every `D`.
impl<T: Real, const D: usize> Default for WallStencil<T, D> {
    fn default() -> Self {
        WallStencil {
            n_fluid: 0,
            offsets: Vec::new(),
            fluid: Vec::new(),
            w: Vec::new(),
            d: Vec::new(),
            inv_sum: Vec::new(),
            fill: Vec::new(),
        }
    }
}

/// `a·b`, summed from the first component on (in 2D `a0 b0 + a1 b1`, the same operations in the
/// same order as the 2D solvers' hand-written sums, so their results are unchanged bit for bit).
#[inline]
fn dot<T: Real, const D: usize>(a: &[T; D], b: &[T; D]) -> T {
    let mut s = a[0] * b[0];
    for k in 1..D {
        s += a[k] * b[k];
    }
    s
}

impl<T: Real, const D: usize> WallStencil<T, D> {
    /// Rebuilds the stencil for the positions `x` (fluid first, then `x.len() - n_fluid` wall
    /// particles) from `nl`, whose first `n_fluid` rows are the fluid particles' neighbour lists
    /// (further rows, if any, are not read).
    pub fn build(
        &mut self,
        x: &[[T; D]],
        n_fluid: usize,
        nl: &NeighborList,
        kernel: &Kernel<T>,
        domain: &Domain<T, D>,
    ) {
        let n_wall = x.len() - n_fluid;
        self.n_fluid = n_fluid;
        self.offsets.clear();
        self.offsets.resize(n_wall + 1, 0);
        for f in 0..n_fluid {
            for &j in nl.neighbors(f) {
                let j = j as usize;
                if j >= n_fluid {
                    self.offsets[j - n_fluid + 1] += 1;
                }
            }
        }
        for k in 0..n_wall {
            self.offsets[k + 1] += self.offsets[k];
        }
        let total = self.offsets[n_wall];
        self.fluid.resize(total, 0);
        self.w.resize(total, T::zero());
        self.d.resize(total, [T::zero(); D]);
        self.fill.clear();
        self.fill.extend_from_slice(&self.offsets[..n_wall]);
        for f in 0..n_fluid {
            for &j in nl.neighbors(f) {
                let j = j as usize;
                if j < n_fluid {
                    continue;
                }
                let k = j - n_fluid;
                let slot = self.fill[k];
                self.fill[k] += 1;
                // displacement(a, b) = b - a: the offset x_w - x_f.
                let d = domain.displacement(&x[f], &x[j]);
                self.fluid[slot] = f as u32;
                self.w[slot] = kernel.w(dot(&d, &d).sqrt());
                self.d[slot] = d;
            }
        }
        self.inv_sum.clear();
        self.inv_sum.extend((0..n_wall).map(|k| {
            let s = self.w[self.offsets[k]..self.offsets[k + 1]].iter().fold(T::zero(), |a, &b| a + b);
            if s > T::zero() {
                T::one() / s
            } else {
                T::zero()
            }
        }));
    }

    /// Number of wall particles.
    pub fn n_wall(&self) -> usize {
        self.inv_sum.len()
    }

    fn row(&self, k: usize) -> std::ops::Range<usize> {
        self.offsets[k]..self.offsets[k + 1]
    }

    /// Wall pressures `p_w = max(0, (Σ_f p_f W_wf + accel·Σ_f ρ_f (x_w - x_f) W_wf) / Σ_f W_wf)`
    /// into `out` (one per wall particle), with `accel = g - a_w` (gravity for a tank at rest; a
    /// zero `accel` extrapolates without the hydrostatic term, as for an impulse pressure). A wall
    /// particle without fluid neighbours gets 0. `p` and `rho` are indexed by fluid particle.
    pub fn pressure(&self, p: &[T], rho: &[T], accel: [T; D], out: &mut Vec<T>) {
        let hydro = accel != [T::zero(); D];
        out.clear();
        out.resize(self.n_wall(), T::zero());
        out.par_iter_mut().enumerate().for_each(|(k, pw)| {
            let mut s = T::zero();
            for e in self.row(k) {
                let f = self.fluid[e] as usize;
                let mut pf = p[f];
                if hydro {
                    pf += rho[f] * dot(&accel, &self.d[e]);
                }
                s += pf * self.w[e];
            }
            *pw = (s * self.inv_sum[k]).fmax(T::zero());
        });
    }

    /// No-slip wall velocities `2 v_w - ṽ_w = -ṽ_w` (walls at rest), `ṽ_w = Σ_f v_f W_wf / Σ_f W_wf`,
    /// into `out` (one per wall particle; 0 without fluid neighbours). `v` is indexed by fluid
    /// particle.
    pub fn no_slip_velocity(&self, v: &[[T; D]], out: &mut Vec<[T; D]>) {
        out.clear();
        out.resize(self.n_wall(), [T::zero(); D]);
        out.par_iter_mut().enumerate().for_each(|(k, vw)| {
            let mut s = [T::zero(); D];
            for e in self.row(k) {
                let f = self.fluid[e] as usize;
                for c in 0..D {
                    s[c] += v[f][c] * self.w[e];
                }
            }
            *vw = s.map(|c| -c * self.inv_sum[k]);
        });
    }
}

/// Outcome of [`enforce_container`] for one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContainerFix {
    /// Fluid centres put back onto the container surface (per particle and axis).
    pub corrections: u64,
    /// Deepest crossing of the surface before the correction (0 when none).
    pub depth: f64,
}

/// The impermeable-wall fallback of the incompressible solvers (`v·n >= 0` on the container
/// surface): a fluid centre (of the first `n_fluid` in `x`) that crossed the box `container`
/// goes back onto it and loses its inward velocity. Why a fallback is needed next to the wall
/// particles: a density-deficient particle (spray, a broken-up film) has an extrapolated wall
/// pressure of 0 and reaches `ρ0` only about `0.25 dx` behind the surface, so the wall
/// particles alone may not stop it (see the iisph module docs for how rarely it acts).
pub fn enforce_container<T: Real, const D: usize>(
    x: &mut [[T; D]],
    v: &mut [[T; D]],
    n_fluid: usize,
    container: [[f64; D]; 2],
) -> ContainerFix {
    let [lo, hi] = container.map(|b| b.map(T::c));
    let mut fix = ContainerFix::default();
    for i in 0..n_fluid {
        for d in 0..D {
            let (below, above) = (lo[d] - x[i][d], x[i][d] - hi[d]);
            if below > T::zero() || above > T::zero() {
                fix.depth = fix.depth.max(below.fmax(above).wide());
                fix.corrections += 1;
                x[i][d] = x[i][d].fmax(lo[d]).fmin(hi[d]);
                v[i][d] = if below > T::zero() { v[i][d].fmax(T::zero()) } else { v[i][d].fmin(T::zero()) };
            }
        }
    }
    fix
}

/// Fluid particles (the first `n_fluid` of `x`) outside the box `container` or non-finite,
/// compared in `T`.
pub fn leaked<T: Real, const D: usize>(x: &[[T; D]], n_fluid: usize, container: [[f64; D]; 2]) -> usize {
    let [lo, hi] = container.map(|b| b.map(T::c));
    x[..n_fluid].iter().filter(|p| !(0..D).all(|d| p[d] >= lo[d] && p[d] <= hi[d])).count()
}

/// The largest x of the first `n_fluid` particles (the surge front of a dam break).
pub fn front<T: Real, const D: usize>(x: &[[T; D]], n_fluid: usize) -> f64 {
    x[..n_fluid].iter().fold(f64::NEG_INFINITY, |a, p| a.max(p[0].wide()))
}
