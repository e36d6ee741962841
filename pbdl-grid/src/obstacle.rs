//! Obstacles: solid cells inside the domain.
//!
//! An [`Obstacle`] (cylinder or box) marks the cells whose centres it covers as solid; an
//! [`ObstacleMask`] is the union over a list. Solid cells leave the pressure solve (the masked
//! Laplacian is factored once, [`crate::pressure::MaskedPressureSolver`]) and every face that
//! touches a solid cell carries zero normal velocity after projection (static obstacles).

use crate::boundary::Boundaries;
use crate::{Bc, Error, Grid, Result};
use candle_core::{DType, Device, Tensor};
use serde::{Deserialize, Serialize};

/// A static solid shape, in domain coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle {
    /// A disc of radius `radius` around `center`.
    Cylinder {
        /// Centre `[x, y]`.
        center: [f64; 2],
        /// Radius (> 0).
        radius: f64,
    },
    /// An axis-aligned box `[lo, hi]`.
    Box {
        /// Lower corner `[x, y]`.
        lo: [f64; 2],
        /// Upper corner `[x, y]`.
        hi: [f64; 2],
    },
}

impl Obstacle {
    /// `true` when the point `(x, y)` is inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match *self {
            Obstacle::Cylinder { center, radius } => {
                (x - center[0]).powi(2) + (y - center[1]).powi(2) <= radius * radius
            }
            Obstacle::Box { lo, hi } => x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1],
        }
    }

    /// Checks that the shape is finite, non-empty and inside the domain of `grid`.
    pub fn validate(&self, grid: &Grid) -> Result<()> {
        let bad = |reason: String| Err(Error::Invalid { field: "obstacles", reason });
        let (lo, hi) = match *self {
            Obstacle::Cylinder { center, radius } => {
                if !(radius > 0.0 && radius.is_finite()) {
                    return bad(format!("cylinder radius must be positive and finite, got {radius}"));
                }
                ([center[0] - radius, center[1] - radius], [center[0] + radius, center[1] + radius])
            }
            Obstacle::Box { lo, hi } => {
                if !(lo[0] < hi[0] && lo[1] < hi[1]) {
                    return bad(format!("box needs lo < hi on both axes, got lo {lo:?} hi {hi:?}"));
                }
                (lo, hi)
            }
        };
        if !lo.iter().chain(&hi).all(|v| v.is_finite())
            || lo[0] < 0.0
            || lo[1] < 0.0
            || hi[0] > grid.lx
            || hi[1] > grid.ly
        {
            return bad(format!(
                "{self:?} reaches outside the domain [0, {}] x [0, {}]; move or shrink it",
                grid.lx, grid.ly
            ));
        }
        Ok(())
    }
}

/// Which cells of a grid are solid.
#[derive(Clone, Debug, PartialEq)]
pub struct ObstacleMask {
    grid: Grid,
    solid: Vec<bool>,
}

impl ObstacleMask {
    /// The cells whose centres lie inside any of `obstacles` (each validated against the grid).
    /// At least one cell must be solid and one fluid.
    pub fn new(grid: Grid, obstacles: &[Obstacle]) -> Result<Self> {
        grid.validate()?;
        for o in obstacles {
            o.validate(&grid)?;
        }
        let (dx, dy) = (grid.dx(), grid.dy());
        let mut solid = vec![false; grid.cells()];
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = ((i as f64 + 0.5) * dx, (j as f64 + 0.5) * dy);
                solid[j * grid.nx + i] = obstacles.iter().any(|o| o.contains(x, y));
            }
        }
        Self::from_cells(grid, solid)
    }

    /// A mask from per-cell flags (`true` = solid), row-major `ny x nx`.
    pub fn from_cells(grid: Grid, solid: Vec<bool>) -> Result<Self> {
        if solid.len() != grid.cells() {
            return Err(Error::Invalid {
                field: "obstacles",
                reason: format!("mask has {} cells, the grid {}", solid.len(), grid.cells()),
            });
        }
        let count = solid.iter().filter(|s| **s).count();
        if count == 0 || count == solid.len() {
            return Err(Error::Invalid {
                field: "obstacles",
                reason: format!(
                    "the obstacles cover {count} of {} cells; they must cover at least one cell and leave fluid",
                    solid.len()
                ),
            });
        }
        Ok(Self { grid, solid })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// `true` when cell `(j, i)` is solid.
    pub fn is_solid(&self, j: usize, i: usize) -> bool {
        self.solid[j * self.grid.nx + i]
    }

    /// The per-cell flags (`true` = solid), row-major `ny x nx`.
    pub fn solid_flags(&self) -> Vec<bool> {
        self.solid.clone()
    }

    /// Number of solid cells.
    pub fn solid_cells(&self) -> usize {
        self.solid.iter().filter(|s| **s).count()
    }

    /// `1` in fluid cells and `0` in solid ones, `[1, 1, ny, nx]`.
    pub fn fluid_tensor(&self, dtype: DType) -> Result<Tensor> {
        let v: Vec<f64> = self.solid.iter().map(|&s| if s { 0.0 } else { 1.0 }).collect();
        Ok(Tensor::from_vec(v, (1, 1, self.grid.ny, self.grid.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }

    /// Open-face masks `(u faces, v faces)` of a MAC velocity with boundaries `bc`: 0 on every
    /// face that touches a solid cell (across a periodic edge too), 1 elsewhere.
    pub(crate) fn face_masks(&self, bc: &Boundaries) -> (Vec<f64>, Vec<f64>) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
        let mut mu = vec![1.0; nx * ny];
        let mut mv = vec![1.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let me = self.is_solid(j, i);
                let east = if i + 1 < nx { self.is_solid(j, i + 1) } else { px && self.is_solid(j, 0) };
                let north = if j + 1 < ny { self.is_solid(j + 1, i) } else { py && self.is_solid(0, i) };
                if me || east {
                    mu[j * nx + i] = 0.0;
                }
                if me || north {
                    mv[j * nx + i] = 0.0;
                }
            }
        }
        (mu, mv)
    }

    /// The open-face masks as a `[1, 2, ny, nx]` tensor (for multiplying a velocity).
    pub fn face_tensor(&self, bc: &Boundaries, dtype: DType) -> Result<Tensor> {
        let (mut mu, mv) = self.face_masks(bc);
        mu.extend(mv);
        Ok(Tensor::from_vec(mu, (1, 2, self.grid.ny, self.grid.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }
}

/// Direct-forcing immersed boundary for static obstacles: a no-slip condition on the *true*
/// (curved) surface of the obstacles, not on the staircase of cells.
///
/// Method (Fadlun, Verzicco, Orlandi & Mohd-Yusof, J. Comput. Phys. 161 (2000) 35-60, the
/// "direct forcing with linear interpolation" variant): every velocity face whose position lies
/// inside an obstacle is set to 0 (the body is at rest). A face *outside* the obstacles that
/// has at least one of its four same-component neighbours inside is a *forcing point*; along the
/// grid line towards the nearest such neighbour the surface crossing lies at distance
/// `d in [0, h)` (found by bisection on [`Obstacle::contains`], so any shape works). The forcing
/// point gets the value that the linear profile between the wall (`u = 0` at distance `d`) and
/// the next face outward (distance `d + h`) takes there:
///
/// `u_f = u_o * d / (d + h)`.
///
/// Linear interpolation of a smooth velocity that vanishes on the wall is exact to `O(h^2)`, so
/// the boundary condition is imposed to second order in space on the curved surface (a
/// staircase mask imposes it with an `O(h)` error in the wall position). The map `u -> M u` is
/// linear: its vector-Jacobian product is `M^T g` (exact adjoint). The pressure solve then runs
/// on the whole domain (the fictitious flow inside the body included); [`crate::Fluid`]
/// alternates this forcing with the projection ([`ObstacleTreatment::ImmersedBoundary`]).
#[derive(Clone, Debug)]
pub struct ImmersedBoundary {
    grid: Grid,
    /// Flat face indices (`[2, ny, nx]` layout) set to 0.
    inside: Vec<usize>,
    /// `(forcing face, outer face, coefficient)`: `out[f] = c * in[o]`.
    forcing: Vec<(usize, usize, f64)>,
}

/// How [`crate::Fluid`] treats the surface of its obstacles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ObstacleTreatment {
    /// Cells whose centres lie inside are solid and leave the pressure solve; every face
    /// touching them has zero normal velocity (first order in the wall position). Default.
    #[default]
    Staircase,
    /// Direct-forcing immersed boundary ([`ImmersedBoundary`], second order in the wall
    /// position): the pressure solve covers the whole domain; the projection is
    /// `P (F P)^(iterations - 1) F`, alternating the forcing `F` and the projection `P`
    /// ("multi-direct forcing"), so that no-slip and zero divergence both hold closely.
    ImmersedBoundary {
        /// Forcing / projection pairs per projection (>= 1; 2-3 reduce the slip that the last
        /// projection leaves on the surface).
        iterations: usize,
    },
}

impl ImmersedBoundary {
    /// The forcing of `obstacles` (validated against the grid) on a MAC velocity with boundaries
    /// `bc`. Stored boundary faces fixed by `bc` are left alone. At least one face must be inside.
    pub fn new(grid: Grid, bc: &Boundaries, obstacles: &[Obstacle]) -> Result<Self> {
        grid.validate()?;
        for o in obstacles {
            o.validate(&grid)?;
        }
        let (nx, ny, n) = (grid.nx, grid.ny, grid.cells());
        let (dx, dy) = (grid.dx(), grid.dy());
        let mg = bc.mac_ghosts(nx, ny);
        let solid = |x: f64, y: f64| obstacles.iter().any(|o| o.contains(x, y));
        // Face position of component c at stored (j, i), possibly outside the stored range.
        let pos = |c: usize, j: isize, i: isize| -> (f64, f64) {
            if c == 0 {
                ((i as f64 + 1.0) * dx, (j as f64 + 0.5) * dy)
            } else {
                ((i as f64 + 0.5) * dx, (j as f64 + 1.0) * dy)
            }
        };
        let stored = |j: isize, i: isize| j >= 0 && i >= 0 && (j as usize) < ny && (i as usize) < nx;
        let fixed = |c: usize, j: usize, i: usize| {
            (c == 0 && i == nx - 1 && mg.u_fixed.is_some()) || (c == 1 && j == ny - 1 && mg.v_fixed.is_some())
        };
        let mut inside = Vec::new();
        let mut forcing = Vec::new();
        for c in 0..2 {
            for j in 0..ny {
                for i in 0..nx {
                    if fixed(c, j, i) {
                        continue;
                    }
                    let k = c * n + j * nx + i;
                    let (x, y) = pos(c, j as isize, i as isize);
                    if solid(x, y) {
                        inside.push(k);
                        continue;
                    }
                    // The nearest wall crossing along the four grid directions.
                    let mut best: Option<(f64, isize, isize, f64)> = None;
                    for (di, dj, h) in [(1isize, 0isize, dx), (-1, 0, dx), (0, 1, dy), (0, -1, dy)] {
                        let (xn, yn) = pos(c, j as isize + dj, i as isize + di);
                        if !solid(xn, yn) {
                            continue;
                        }
                        // Bisection for the crossing between (x, y) (outside) and (xn, yn) (inside).
                        let (mut a, mut b) = (0.0f64, 1.0f64);
                        for _ in 0..60 {
                            let m = 0.5 * (a + b);
                            if solid(x + m * (xn - x), y + m * (yn - y)) {
                                b = m;
                            } else {
                                a = m;
                            }
                        }
                        let d = 0.5 * (a + b) * h;
                        if best.is_none_or(|(bd, ..)| d < bd) {
                            best = Some((d, di, dj, h));
                        }
                    }
                    if let Some((d, di, dj, h)) = best {
                        let (jo, io) = (j as isize - dj, i as isize - di);
                        let (xo, yo) = pos(c, jo, io);
                        if stored(jo, io) && !solid(xo, yo) {
                            let o = c * n + jo as usize * nx + io as usize;
                            forcing.push((k, o, d / (d + h)));
                        } else {
                            // No outer fluid face to interpolate from (a thin body or the domain
                            // edge): hold the face at rest.
                            inside.push(k);
                        }
                    }
                }
            }
        }
        if inside.is_empty() {
            return Err(Error::Invalid {
                field: "obstacles",
                reason: "the obstacles cover no velocity face; enlarge them or refine the grid".into(),
            });
        }
        Ok(Self { grid, inside, forcing })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Number of faces held at rest inside the obstacles.
    pub fn inside_faces(&self) -> usize {
        self.inside.len()
    }

    /// Number of forcing points (fluid faces next to the surface, interpolated).
    pub fn forcing_points(&self) -> usize {
        self.forcing.len()
    }

    /// `u -> M u` on a `[batch, 2, ny, nx]` MAC velocity tensor (differentiable).
    pub fn apply(&self, u: &Tensor) -> Result<Tensor> {
        Ok(pbdl_core::op::apply1(u, ImmersedForcing(std::sync::Arc::new(self.clone())))?)
    }

    fn forward<T: pbdl_core::Real>(&self, x: &[T], out: &mut [T]) {
        let n2 = 2 * self.grid.cells();
        for (xb, ob) in x.chunks(n2).zip(out.chunks_mut(n2)) {
            ob.copy_from_slice(xb);
            for &(f, o, c) in &self.forcing {
                ob[f] = T::c(c) * xb[o];
            }
            for &k in &self.inside {
                ob[k] = T::zero();
            }
        }
    }

    fn adjoint<T: pbdl_core::Real>(&self, g: &[T], out: &mut [T]) {
        let n2 = 2 * self.grid.cells();
        for (gb, ob) in g.chunks(n2).zip(out.chunks_mut(n2)) {
            ob.copy_from_slice(gb);
            for &(f, _, _) in &self.forcing {
                ob[f] = T::zero();
            }
            for &k in &self.inside {
                ob[k] = T::zero();
            }
            for &(f, o, c) in &self.forcing {
                ob[o] += T::c(c) * gb[f];
            }
        }
    }
}

#[derive(Clone)]
struct ImmersedForcing(std::sync::Arc<ImmersedBoundary>);

impl pbdl_core::op::Kernel1 for ImmersedForcing {
    fn name(&self) -> &'static str {
        "immersed_boundary"
    }
    fn output_shape(&self, s: &candle_core::Shape) -> candle_core::Result<candle_core::Shape> {
        crate::pressure::check_mac_shape(self.name(), s, &self.0.grid)
    }
    fn forward<T: pbdl_core::Real>(&self, x: &[T], _s: &candle_core::Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.0.forward(x, out);
        Ok(())
    }
}

impl pbdl_core::op::Op1 for ImmersedForcing {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        pbdl_core::op::apply_kernel1(gy, ImmersedForcingAdjoint(self.0.clone()))
    }
}

struct ImmersedForcingAdjoint(std::sync::Arc<ImmersedBoundary>);

impl pbdl_core::op::Kernel1 for ImmersedForcingAdjoint {
    fn name(&self) -> &'static str {
        "immersed_boundary_adjoint"
    }
    fn output_shape(&self, s: &candle_core::Shape) -> candle_core::Result<candle_core::Shape> {
        Ok(s.clone())
    }
    fn forward<T: pbdl_core::Real>(&self, g: &[T], _s: &candle_core::Shape, out: &mut [T]) -> candle_core::Result<()> {
        self.0.adjoint(g, out);
        Ok(())
    }
}
