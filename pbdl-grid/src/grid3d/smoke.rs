//! A buoyant smoke plume in the closed 3D box: the 3D counterpart of the 2D [`crate::Fluid`] with a
//! density, buoyancy and an inflow, on the walls of [`super::walls`] (no-slip, at rest) by
//! default. [`Smoke3d::with_boundaries`] takes other boundaries ([`Smoke3dBoundaries`]): per-face
//! walls ([`Walls3d`]: free-slip, periodic pairs, outflow on upper faces), static obstacles
//! ([`Obstacle3d`]: solid cells, every face touching one 0 after each step, left out of the
//! pressure solve, density 0 inside) and an inflow patch ([`InflowPatch3d`]); those topologies
//! (all but free-slip) are assembled by the sparse Cholesky factor only.
//!
//! One [`Smoke3d::step`] (PhiFlow's smoke-plume order):
//! 1. density: advect by the old velocity ([`super::advect`], MacCormack by default; or
//!    [`Advection3d::Conservative`], the flux form of [`super::conservative`]: the density's mass
//!    is then exactly what the source injected, to round-off), add the inflow `dt * rate` in the
//!    cells whose centres lie in a sphere ([`SphereSource`]);
//! 2. velocity: advect by itself (MacCormack by default, no-slip walls), add the Boussinesq force
//!    `dt * beta * rho` along `+y` ([`buoyancy`]: the new density averaged to the y-faces);
//! 3. viscosity when `nu > 0`: explicit (`u + dt nu L u`, forward Euler, its limit checked at
//!    build time) or implicit (`(I - dt nu L)^-1 u`, backward Euler, CG to round-off), with the
//!    no-slip ghosts of [`super::walls`]; nothing at `nu = 0`;
//! 4. projection in the closed box ([`super::box_pressure`]: [`BoxPressure::Auto`] factors a
//!    sparse Cholesky up to 32^3 cells and runs MIC(0)-CG above, as [`super::Cavity3d`]).
//!
//! The pressure split: [`Smoke3d::step_unprojected`] runs steps 1-3,
//! [`Smoke3d::project_keep_pressure`] step 4 returning the pressure it solved for, and
//! [`Smoke3d::correct_with_pressure`] step 4 with a given pressure instead of a solve (what
//! latent-space physics does with a predicted pressure). All three and [`Smoke3d::step`] run one
//! projection kernel, so the split step equals the step to the bit.
//!
//! A [`Smoke3d`] is built once and holds only what its configuration needs;
//! [`Smoke3d::operators`] lists them. Every part has a hand-written adjoint (advection,
//! buoyancy, both viscosities, the projection), so a step is differentiable in the initial
//! velocity and density and in the inflow rate (pass it as a tensor to [`Smoke3d::step`]);
//! except the conservative density transport, which has no adjoint yet (a backward pass through
//! it is an error; the stepper then reports itself partially differentiable).
//! Semi-Lagrangian and MacCormack advection are unconditionally stable, so the only time-step
//! limit is the explicit viscosity's; [`Smoke3d::cfl`] reports the CFL number for accuracy.

use super::advect::{Advection3d, Sl3d};
use super::box_pressure::{BoxPressure, BoxSolver, BoxTopology, WallProjection};
use super::conservative::{AxisFaces3d, Conservative3d};
use super::field::{check_values, MacField3d};
use super::stability::check_time_step;
use super::walls::{CavityWalls, Face3d, WallMomentumRhs, Walls3d};
use super::Grid3d;
use crate::time_stepping::ButcherTableau;
use crate::{Error, Result};
use candle_core::{DType, Device, Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// How the viscous term is stepped (only when `nu > 0`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Viscosity3d {
    /// Forward Euler `u + dt nu L u`; needs `4 dt nu (1/dx^2 + 1/dy^2 + 1/dz^2) <= 2`.
    Explicit,
    /// Backward Euler `(I - dt nu L)^-1 u` by conjugate gradients (default; no time-step limit).
    #[default]
    Implicit,
}

/// A spherical density inflow: `dt * rate` is added each step to every cell whose centre lies
/// in the sphere.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereSource {
    /// Centre `[x, y, z]` (inside the box).
    pub centre: [f64; 3],
    /// Radius (> 0; the sphere must cover at least one cell centre).
    pub radius: f64,
    /// Density added per unit time (finite; [`Smoke3d::step`] can override it with a tensor).
    pub rate: f64,
}

impl SphereSource {
    /// Checks the source against `grid`: finite values, centre inside the box, positive radius,
    /// at least one cell centre covered.
    pub fn validate(&self, grid: &Grid3d) -> Result<()> {
        let inv = |reason: String| Error::Invalid { field: "source", reason };
        if !self.centre.iter().all(|c| c.is_finite()) || !self.rate.is_finite() {
            return Err(inv(format!("centre {:?} and rate {} must be finite", self.centre, self.rate)));
        }
        if !(self.radius > 0.0 && self.radius.is_finite()) {
            return Err(inv(format!("radius must be positive and finite, got {}", self.radius)));
        }
        let l = [grid.lx, grid.ly, grid.lz];
        if (0..3).any(|a| self.centre[a] < 0.0 || self.centre[a] > l[a]) {
            return Err(inv(format!(
                "centre {:?} lies outside the box [0, {}] x [0, {}] x [0, {}]",
                self.centre, l[0], l[1], l[2]
            )));
        }
        if self.cells(grid) == 0 {
            return Err(inv(format!(
                "the sphere of radius {} at {:?} covers no cell centre (spacing {:?}); enlarge it",
                self.radius,
                self.centre,
                grid.spacing()
            )));
        }
        Ok(())
    }

    fn inside(&self, grid: &Grid3d, i: usize, j: usize, k: usize) -> bool {
        let h = grid.spacing();
        let p = [(i as f64 + 0.5) * h[0], (j as f64 + 0.5) * h[1], (k as f64 + 0.5) * h[2]];
        (0..3).map(|a| (p[a] - self.centre[a]).powi(2)).sum::<f64>() <= self.radius * self.radius
    }

    /// Number of cells whose centre lies in the sphere.
    pub fn cells(&self, grid: &Grid3d) -> usize {
        let mut c = 0;
        for k in 0..grid.nz {
            for j in 0..grid.ny {
                for i in 0..grid.nx {
                    c += usize::from(self.inside(grid, i, j, k));
                }
            }
        }
        c
    }

    /// The 0/1 cell mask `[1, 1, nz, ny, nx]` (f64), after [`Self::validate`].
    pub fn mask(&self, grid: &Grid3d) -> Result<Tensor> {
        self.validate(grid)?;
        let mut m = vec![0.0; grid.cells()];
        for k in 0..grid.nz {
            for j in 0..grid.ny {
                for i in 0..grid.nx {
                    if self.inside(grid, i, j, k) {
                        m[(k * grid.ny + j) * grid.nx + i] = 1.0;
                    }
                }
            }
        }
        Ok(Tensor::from_vec(m, grid.shape(1, 1).to_vec(), &Device::Cpu)?)
    }
}

/// A static solid obstacle of a [`Smoke3d`]: the cells whose centres lie in it are solid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle3d {
    /// A ball.
    Sphere {
        /// Centre `[x, y, z]` (the scene key `center`, as the 2D circle's).
        center: [f64; 3],
        /// Radius (> 0).
        radius: f64,
    },
    /// A circular cylinder along z through the whole box (a 2D circle extruded).
    Cylinder {
        /// Axis position `[x, y]`.
        center: [f64; 2],
        /// Radius (> 0).
        radius: f64,
    },
    /// An axis-aligned box `[lower, upper]`.
    Box {
        /// Lower corner `[x, y, z]`.
        lower: [f64; 3],
        /// Upper corner `[x, y, z]` (each coordinate above the lower one).
        upper: [f64; 3],
    },
}

impl Obstacle3d {
    /// Whether the point `p` lies in the obstacle.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        match self {
            Self::Sphere { center, radius } => {
                (0..3).map(|a| (p[a] - center[a]).powi(2)).sum::<f64>() <= radius * radius
            }
            Self::Cylinder { center, radius } => {
                (p[0] - center[0]).powi(2) + (p[1] - center[1]).powi(2) <= radius * radius
            }
            Self::Box { lower, upper } => (0..3).all(|a| p[a] >= lower[a] && p[a] <= upper[a]),
        }
    }

    /// Finite values, positive extent (the error names `obstacles[k]`).
    fn validate(&self, k: usize) -> Result<()> {
        let bad = |reason: String| Error::Invalid { field: "obstacles", reason: format!("obstacles[{k}]: {reason}") };
        match self {
            Self::Sphere { center, radius } => {
                if !(center.iter().all(|c| c.is_finite()) && *radius > 0.0 && radius.is_finite()) {
                    return Err(bad(format!("need a finite centre and radius > 0, got {center:?}, {radius}")));
                }
            }
            Self::Cylinder { center, radius } => {
                if !(center.iter().all(|c| c.is_finite()) && *radius > 0.0 && radius.is_finite()) {
                    return Err(bad(format!("need a finite axis and radius > 0, got {center:?}, {radius}")));
                }
            }
            Self::Box { lower, upper } => {
                if !(0..3).all(|a| lower[a].is_finite() && upper[a].is_finite() && lower[a] < upper[a]) {
                    return Err(bad(format!("need finite corners with lower < upper, got {lower:?}, {upper:?}")));
                }
            }
        }
        Ok(())
    }
}

/// The lower face an [`InflowPatch3d`] sits on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InflowFace3d {
    /// `x = 0`; the patch's coordinates are `(y, z)`.
    XLo,
    /// `y = 0` (the floor); the patch's coordinates are `(x, z)`.
    YLo,
    /// `z = 0`; the patch's coordinates are `(x, y)`.
    ZLo,
}

impl InflowFace3d {
    /// The axis normal to the face (0 = x).
    pub fn axis(self) -> usize {
        self as usize
    }
}

/// The shape of an [`InflowPatch3d`] in the face's two other coordinates, in axis order.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum PatchShape3d {
    /// A disc.
    Disc {
        /// Centre.
        center: [f64; 2],
        /// Radius (> 0).
        radius: f64,
    },
    /// A rectangle `[lower, upper]`.
    Rect {
        /// Lower corner.
        lower: [f64; 2],
        /// Upper corner.
        upper: [f64; 2],
    },
}

/// An inflow through a patch of a lower face: the first layer of cells whose face centres lie in
/// the patch become inflow cells (left out of the pressure solve like solid cells, their density
/// held at `density`), and the face between each and the fluid cell next to it is held at the
/// normal velocity `velocity` (positive: into the box). The density enters by advection through
/// those faces. An inflow needs an outflow face (else no divergence-free field exists).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InflowPatch3d {
    /// The face (`x_lo`, `y_lo` or `z_lo`).
    pub face: InflowFace3d,
    /// The patch.
    pub shape: PatchShape3d,
    /// Normal velocity into the box (finite).
    pub velocity: f64,
    /// Density of the inflowing smoke (finite, >= 0).
    pub density: f64,
}

impl InflowPatch3d {
    /// The inflow cells (flat indices), after checking the values; typed errors name `inflow`.
    pub fn cells(&self, grid: &Grid3d) -> Result<Vec<usize>> {
        let bad = |reason: String| Error::Invalid { field: "inflow", reason };
        if !(self.velocity.is_finite() && self.density.is_finite() && self.density >= 0.0) {
            return Err(bad(format!(
                "velocity {} must be finite and density {} finite and >= 0",
                self.velocity, self.density
            )));
        }
        match self.shape {
            PatchShape3d::Disc { center, radius }
                if !(center.iter().all(|c| c.is_finite()) && radius > 0.0 && radius.is_finite()) =>
            {
                return Err(bad(format!("disc needs a finite centre and radius > 0, got {center:?}, {radius}")))
            }
            PatchShape3d::Rect { lower, upper }
                if !(0..2).all(|a| lower[a].is_finite() && upper[a].is_finite() && lower[a] < upper[a]) =>
            {
                return Err(bad(format!("rect needs finite corners with lower < upper, got {lower:?}, {upper:?}")))
            }
            _ => {}
        }
        let a = self.face.axis();
        let (b, c) = match a {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let n = [grid.nx, grid.ny, grid.nz];
        let h = grid.spacing();
        let st = [1, n[0], n[0] * n[1]];
        let mut out = Vec::new();
        for ic in 0..n[c] {
            for ib in 0..n[b] {
                let (pb, pc) = ((ib as f64 + 0.5) * h[b], (ic as f64 + 0.5) * h[c]);
                let inside = match self.shape {
                    PatchShape3d::Disc { center, radius } => {
                        (pb - center[0]).powi(2) + (pc - center[1]).powi(2) <= radius * radius
                    }
                    PatchShape3d::Rect { lower, upper } => {
                        pb >= lower[0] && pb <= upper[0] && pc >= lower[1] && pc <= upper[1]
                    }
                };
                if inside {
                    out.push(ib * st[b] + ic * st[c]);
                }
            }
        }
        if out.is_empty() {
            return Err(bad(format!(
                "the patch {:?} covers no cell of the face (spacing {h:?}); enlarge it",
                self.shape
            )));
        }
        Ok(out)
    }
}

/// The density bookkeeping of one step per batch item ([`Smoke3d::step_balance`]), in
/// `sum rho dx dy dz` units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MassBalance3d {
    /// Added by the source sphere.
    pub source: f64,
    /// Added to the inflow cells to hold them at the inflow density (what the advection moved
    /// out of them into the box through the inflow faces).
    pub inflow: f64,
    /// What left through the outflow faces, as the conservative fluxes moved it (`None` for
    /// semi-Lagrangian / MacCormack, which move no fluxes).
    pub outflow: Option<f64>,
}

/// The boundaries of a [`Smoke3d`] beyond the closed no-slip box ([`Smoke3d::with_boundaries`];
/// the default is that box). Kept out of [`Smoke3dConfig`] so that configurations written as
/// struct literals elsewhere keep compiling.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Smoke3dBoundaries {
    /// Per-face conditions (no-slip, free-slip, periodic pairs, outflow on upper faces).
    #[serde(default)]
    pub walls: Walls3d,
    /// Static solid obstacles.
    #[serde(default)]
    pub obstacles: Vec<Obstacle3d>,
    /// An inflow patch on a lower face.
    #[serde(default)]
    pub inflow: Option<InflowPatch3d>,
}

impl Smoke3dBoundaries {
    /// The solid cell mask (`None` without obstacles); typed errors for bad obstacles, an
    /// obstacle covering no cell centre, or one covering the whole box.
    pub fn solid_mask(&self, grid: &Grid3d) -> Result<Option<Arc<Vec<bool>>>> {
        if self.obstacles.is_empty() {
            return Ok(None);
        }
        let h = grid.spacing();
        let mut mask = vec![false; grid.cells()];
        for (k, o) in self.obstacles.iter().enumerate() {
            o.validate(k)?;
            let mut any = false;
            for (m, s) in mask.iter_mut().enumerate() {
                let (i, r) = (m % grid.nx, m / grid.nx);
                let (j, kk) = (r % grid.ny, r / grid.ny);
                let p = [(i as f64 + 0.5) * h[0], (j as f64 + 0.5) * h[1], (kk as f64 + 0.5) * h[2]];
                if o.contains(p) {
                    *s = true;
                    any = true;
                }
            }
            if !any {
                return Err(Error::Invalid {
                    field: "obstacles",
                    reason: format!(
                        "obstacles[{k}] covers no cell centre (spacing {h:?}); enlarge it or move it inside"
                    ),
                });
            }
        }
        if mask.iter().all(|&s| s) {
            return Err(Error::Invalid { field: "obstacles", reason: "the obstacles fill the whole box".into() });
        }
        Ok(Some(Arc::new(mask)))
    }
}

/// Parameters of a [`Smoke3d`] stepper.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Smoke3dConfig {
    /// Time step (> 0; no stability limit except the explicit viscosity's, but keep the CFL
    /// number moderate for accuracy).
    pub dt: f64,
    /// Kinematic viscosity (>= 0; 0 runs no viscous operator). Default 0.
    #[serde(default)]
    pub nu: f64,
    /// How the viscous term is stepped when `nu > 0`. Default implicit.
    #[serde(default)]
    pub viscosity: Viscosity3d,
    /// Velocity self-advection. Default MacCormack.
    #[serde(default)]
    pub advection: Advection3d,
    /// Density advection. Default MacCormack. [`Advection3d::Conservative`] conserves the mass
    /// (forward only); the velocity refuses it.
    #[serde(default)]
    pub density_advection: Advection3d,
    /// Boussinesq coefficient `beta`: the force `beta rho` along `+y` (0: no buoyancy operator).
    #[serde(default)]
    pub buoyancy: f64,
    /// The density inflow, if any.
    #[serde(default)]
    pub source: Option<SphereSource>,
}

impl Smoke3dConfig {
    /// A rising plume on `grid`: a sphere of radius `0.08 min(lx, ly, lz)` (at least 1.5 cells)
    /// centred at `(lx / 2, 0.15 ly, lz / 2)` injecting at rate 1, `beta = 1`, inviscid,
    /// MacCormack for both fields, `dt` as given.
    pub fn plume(grid: &Grid3d, dt: f64) -> Self {
        let l = grid.lx.min(grid.ly).min(grid.lz);
        let radius = (0.08 * l).max(1.5 * grid.spacing().into_iter().fold(0.0, f64::max));
        Self {
            dt,
            nu: 0.0,
            viscosity: Viscosity3d::default(),
            advection: Advection3d::MacCormack,
            density_advection: Advection3d::MacCormack,
            buoyancy: 1.0,
            source: Some(SphereSource { centre: [0.5 * grid.lx, 0.15 * grid.ly, 0.5 * grid.lz], radius, rate: 1.0 }),
        }
    }
}

/// The state a [`Smoke3d`] advances.
#[derive(Clone, Debug)]
pub struct Smoke3dState {
    /// MAC velocity (wall faces 0 after a step).
    pub velocity: MacField3d,
    /// Smoke density `[batch, 1, nz, ny, nx]`, same dtype and batch as the velocity.
    pub density: Tensor,
}

/// The viscous operator a stepper runs.
#[derive(Clone, Copy, Debug)]
enum Visc {
    Explicit(WallMomentumRhs),
    Implicit(ImplicitViscosity3d),
}

/// A built 3D smoke-plume stepper (closed box of no-slip walls, or the boundaries given to
/// [`Smoke3d::with_boundaries`]).
pub struct Smoke3d {
    grid: Grid3d,
    config: Smoke3dConfig,
    source_mask: Option<Tensor>,
    viscosity: Option<Visc>,
    projection: WallProjection,
    operators: Vec<&'static str>,
    boundaries: Smoke3dBoundaries,
    /// The fluid-cell mask `[1, 1, nz, ny, nx]` (f64; 0 in solid cells) when there are obstacles.
    fluid_mask: Option<Tensor>,
    /// The inflow-cell mask `[1, 1, nz, ny, nx]` (f64, 1 in inflow cells) with an inflow patch.
    inflow_mask: Option<Tensor>,
}

impl std::fmt::Debug for Smoke3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Smoke3d")
            .field("grid", &self.grid)
            .field("config", &self.config)
            .field("operators", &self.operators)
            .finish()
    }
}

impl Smoke3d {
    /// Builds the stepper: validates the configuration (typed errors naming the bad field),
    /// refuses an explicit viscosity beyond its limit, builds the source mask and the pressure
    /// solver (`pressure`: [`BoxPressure::default()`] = `Auto`, i.e. sparse Cholesky factored
    /// here up to 32^3 cells, MIC(0)-CG above; or [`BoxPressure::Cholesky`] /
    /// [`BoxPressure::Cg`], a bare [`crate::pressure::CgSettings`] converts into the latter).
    pub fn new(grid: Grid3d, config: Smoke3dConfig, pressure: impl Into<BoxPressure>) -> Result<Self> {
        Self::with_boundaries(grid, config, Smoke3dBoundaries::default(), pressure)
    }

    /// [`Smoke3d::new`] with other boundaries: per-face walls (free-slip: the tangential ghost
    /// mirrors; periodic pairs; outflow on upper faces) and static obstacles (solid cells: every
    /// velocity face touching one is 0 after each step, the cells are left out of the pressure
    /// solve, their density is 0). Typed errors: unpaired periodic faces or outflow on a lower
    /// face (`Error::Boundary` naming the face), bad obstacles or an obstacle overlapping the
    /// source (`obstacles`), CG asked for with a topology only the Cholesky factor assembles
    /// (`pressure`), conservative density transport with an outflow face (`density_advection`).
    pub fn with_boundaries(
        grid: Grid3d,
        config: Smoke3dConfig,
        boundaries: Smoke3dBoundaries,
        pressure: impl Into<BoxPressure>,
    ) -> Result<Self> {
        grid.validate()?;
        boundaries.walls.validate(&grid)?;
        if !(config.dt > 0.0 && config.dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("time step must be positive and finite, got {}", config.dt),
            });
        }
        if !(config.nu >= 0.0 && config.nu.is_finite()) {
            return Err(Error::Invalid {
                field: "nu",
                reason: format!("viscosity must be finite and >= 0, got {}", config.nu),
            });
        }
        if !config.buoyancy.is_finite() {
            return Err(Error::Invalid {
                field: "buoyancy",
                reason: format!("must be finite, got {}", config.buoyancy),
            });
        }
        if config.advection == Advection3d::Conservative {
            return Err(Error::Invalid {
                field: "advection",
                reason: "conservative transport is for the density (`density_advection`); the velocity takes \
                         semi_lagrangian or mac_cormack"
                    .into(),
            });
        }
        let walls = boundaries.walls;
        let solid = boundaries.solid_mask(&grid)?;
        let inflow_cells = match &boundaries.inflow {
            Some(patch) => {
                let a = patch.face.axis();
                if walls.periodic(a) {
                    return Err(Error::Boundary {
                        face: super::walls::FACE_NAMES[a][0],
                        reason: "an inflow patch sits on a wall face, not on a periodic one".into(),
                    });
                }
                if !walls.any_open() {
                    return Err(Error::Invalid {
                        field: "inflow",
                        reason: "an inflow needs an outflow face (no divergence-free field exists in a closed box \
                                 with an inflow); make an upper face outflow"
                            .into(),
                    });
                }
                let cells = patch.cells(&grid)?;
                if let Some(s) = &solid {
                    if let Some(&m) = cells.iter().find(|&&m| s[m]) {
                        return Err(Error::Invalid {
                            field: "obstacles",
                            reason: format!("an obstacle covers inflow cell {m}; move it off the inflow patch"),
                        });
                    }
                }
                if let Some(src) = &config.source {
                    if let Some(&m) = cells.iter().find(|&&m| {
                        let (i, r) = (m % grid.nx, m / grid.nx);
                        src.inside(&grid, i, r % grid.ny, r / grid.ny)
                    }) {
                        return Err(Error::Invalid {
                            field: "inflow",
                            reason: format!("the source sphere covers inflow cell {m}; move one of them"),
                        });
                    }
                }
                Some(cells)
            }
            None => None,
        };
        let mut operators = vec![config.density_advection.operator_name(false)];
        let source_mask = match &config.source {
            Some(s) => {
                operators.push("grid3d.source.sphere");
                Some(s.mask(&grid)?)
            }
            None => None,
        };
        if let Some(src) = &config.source {
            let h = grid.spacing();
            for (k, o) in boundaries.obstacles.iter().enumerate() {
                let hit = (0..grid.cells()).find(|&m| {
                    let (i, r) = (m % grid.nx, m / grid.nx);
                    let (j, kk) = (r % grid.ny, r / grid.ny);
                    let p = [(i as f64 + 0.5) * h[0], (j as f64 + 0.5) * h[1], (kk as f64 + 0.5) * h[2]];
                    src.inside(&grid, i, j, kk) && o.contains(p)
                });
                if let Some(m) = hit {
                    return Err(Error::Invalid {
                        field: "obstacles",
                        reason: format!(
                            "obstacles[{k}] covers cell {m} of the source sphere (a source cell must stay fluid); \
                             move it off the source"
                        ),
                    });
                }
            }
        }
        let fluid_mask = match &solid {
            Some(s) => {
                operators.push("grid3d.obstacles");
                let m: Vec<f64> = s.iter().map(|&x| if x { 0.0 } else { 1.0 }).collect();
                Some(Tensor::from_vec(m, grid.shape(1, 1).to_vec(), &Device::Cpu)?)
            }
            None => None,
        };
        operators.push(config.advection.operator_name(true));
        if config.buoyancy != 0.0 {
            operators.push("grid3d.buoyancy");
        }
        let viscosity = if config.nu > 0.0 {
            Some(match config.viscosity {
                Viscosity3d::Explicit => {
                    check_time_step(&grid, [0.0; 3], config.nu, &ButcherTableau::forward_euler(), config.dt)?;
                    operators.push("grid3d.diffuse.explicit");
                    let lid = CavityWalls { lid_velocity: 0.0 };
                    Visc::Explicit(WallMomentumRhs { grid, walls: lid, advect: false, nu: config.nu, faces: walls })
                }
                Viscosity3d::Implicit => {
                    operators.push("grid3d.diffuse.implicit");
                    Visc::Implicit(ImplicitViscosity3d { grid, nu_dt: config.nu * config.dt, faces: walls })
                }
            })
        } else {
            None
        };
        let (inflow_mask, fixed, solid_all) = match (&inflow_cells, &boundaries.inflow) {
            (Some(cells), Some(patch)) => {
                operators.push("grid3d.inflow.patch");
                let a = patch.face.axis();
                let n = grid.cells();
                let mut mask = vec![0.0; n];
                let mut all = solid.as_ref().map_or_else(|| vec![false; n], |s| s.to_vec());
                let mut fixed = Vec::with_capacity(cells.len());
                for &m in cells {
                    mask[m] = 1.0;
                    all[m] = true;
                    // The stored face of component `a` at index 0 along `a` is the one between
                    // the inflow cell and the fluid cell next to it.
                    fixed.push((a * n + m, patch.velocity));
                }
                (
                    Some(Tensor::from_vec(mask, grid.shape(1, 1).to_vec(), &Device::Cpu)?),
                    Some(Arc::new(fixed)),
                    Some(Arc::new(all)),
                )
            }
            _ => (None, None, solid.clone()),
        };
        let topology = BoxTopology { faces: walls, solid: solid_all, fixed };
        let projection = WallProjection { solver: pressure.into().build_for(grid, &topology)?, homogeneous: false };
        operators.push(projection.solver.operator_name());
        Ok(Self { grid, config, source_mask, viscosity, projection, operators, boundaries, fluid_mask, inflow_mask })
    }

    /// The operators this stepper runs, in order, e.g. `["grid3d.advect.mac_cormack(density)",
    /// "grid3d.source.sphere", "grid3d.advect.mac_cormack(velocity)", "grid3d.buoyancy",
    /// "grid3d.pressure.sparse_cholesky"]`.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The configuration.
    pub fn config(&self) -> &Smoke3dConfig {
        &self.config
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The boundaries (walls per face, obstacles).
    pub fn boundaries(&self) -> &Smoke3dBoundaries {
        &self.boundaries
    }

    /// The fluid-cell mask `[1, 1, nz, ny, nx]` (f64, 0 in solid cells), when there are obstacles.
    pub fn fluid_mask(&self) -> Option<&Tensor> {
        self.fluid_mask.as_ref()
    }

    /// The inflow-cell mask `[1, 1, nz, ny, nx]` (f64, 1 in inflow cells), with an inflow patch.
    pub fn inflow_mask(&self) -> Option<&Tensor> {
        self.inflow_mask.as_ref()
    }

    /// The pressure solver (shared).
    pub fn solver(&self) -> &BoxSolver {
        &self.projection.solver
    }

    /// The source's 0/1 cell mask `[1, 1, nz, ny, nx]` (f64), when there is a source.
    pub fn source_mask(&self) -> Option<&Tensor> {
        self.source_mask.as_ref()
    }

    /// The density mass `sum(rho) dx dy dz` one step injects at the configured rate.
    pub fn injected_per_step(&self) -> f64 {
        match (&self.config.source, &self.source_mask) {
            (Some(s), Some(_)) => {
                let [dx, dy, dz] = self.grid.spacing();
                s.rate * self.config.dt * s.cells(&self.grid) as f64 * dx * dy * dz
            }
            _ => 0.0,
        }
    }

    /// A state at rest with zero density, batch `batch`.
    pub fn rest(&self, batch: usize, dtype: DType) -> Result<Smoke3dState> {
        let velocity = MacField3d::zeros(self.grid, batch, dtype)?;
        let density = Tensor::zeros(self.grid.shape(batch, 1).to_vec(), dtype, &Device::Cpu)?;
        Ok(Smoke3dState { velocity, density })
    }

    /// Projects a velocity (use once on an initial condition).
    pub fn project(&self, u: &MacField3d) -> Result<MacField3d> {
        u.check_stepper_grid(&self.grid)?;
        Ok(MacField3d::from_parts(self.projection.apply(u.values())?, self.grid))
    }

    /// `dt (max|u|/dx + max|v|/dy + max|w|/dz)` of a state (typed error when it is not finite).
    pub fn cfl(&self, state: &Smoke3dState) -> Result<f64> {
        let m = state.velocity.max_abs_components()?;
        let h = self.grid.spacing();
        Ok(self.config.dt * (0..3).map(|a| m[a] / h[a]).sum::<f64>())
    }

    fn check_state(&self, state: &Smoke3dState) -> Result<()> {
        state.velocity.check_stepper_grid(&self.grid)?;
        let rho = &state.density;
        check_values("Smoke3d::step", "density", rho, &self.grid, Some(1))?;
        if rho.dims()[0] != state.velocity.batch() || rho.dtype() != state.velocity.values().dtype() {
            return Err(Error::Invalid {
                field: "density",
                reason: format!(
                    "batch {} / dtype {:?} differ from the velocity's {} / {:?}",
                    rho.dims()[0],
                    rho.dtype(),
                    state.velocity.batch(),
                    state.velocity.values().dtype()
                ),
            });
        }
        state.velocity.max_abs_components()?;
        let total = rho.abs()?.sum_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        if !total.is_finite() {
            return Err(Error::NonFinite { what: "density", value: total });
        }
        Ok(())
    }

    /// One step. `rate` overrides the configured inflow rate with a tensor (a scalar, or one
    /// rate per batch item `[B, 1, 1, 1, 1]`) that receives a gradient; `None` uses the
    /// configured rate (ignored without a source). Refuses a state on another grid, of
    /// mismatched batch or dtype, or with non-finite values (typed errors).
    pub fn step(&self, state: &Smoke3dState, rate: Option<&Tensor>) -> Result<Smoke3dState> {
        let (v, rho) = self.before_projection(state, rate)?;
        // 4. Projection.
        let v = self.projection.apply(&v)?;
        Ok(Smoke3dState { velocity: MacField3d::from_parts(v, self.grid), density: rho })
    }

    /// Steps 1-3 of [`Smoke3d::step`] (density transport and inflow, velocity advection,
    /// buoyancy, viscosity) without the projection: the first half of the pressure split that
    /// latent-space physics replaces on some steps. [`Smoke3d::project_keep_pressure`] of the
    /// returned velocity is [`Smoke3d::step`]'s velocity to the bit, and the returned density is
    /// the step's. Every [`Smoke3d`] configuration projects exactly once per step (the velocity
    /// takes semi-Lagrangian or MacCormack advection, the conservative scheme is refused at build
    /// time), so the split is defined for all of them. Differentiable as [`Smoke3d::step`].
    ///
    /// # Errors
    /// As [`Smoke3d::step`].
    pub fn step_unprojected(&self, state: &Smoke3dState, rate: Option<&Tensor>) -> Result<Smoke3dState> {
        let (v, rho) = self.before_projection(state, rate)?;
        Ok(Smoke3dState { velocity: MacField3d::from_parts(v, self.grid), density: rho })
    }

    /// The projection of [`Smoke3d::step`] that also returns its pressure (cell-centred,
    /// `[B, 1, nz, ny, nx]` in the velocity's dtype, in the units of the solve: `u <- u - G p`,
    /// so `p` is the physical pressure times `dt / density`; zero mean per sample). Computed by
    /// the same kernel as the step (in f64, rounded to the velocity's dtype), so
    /// `project_keep_pressure(step_unprojected(s).velocity).0 == step(s).velocity` bit for bit.
    /// Not differentiable.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a velocity on another grid, not f32/f64 or not on the CPU;
    /// [`Error::Shape`] for other than `[B, 3, nz, ny, nx]`; a solver error (CG not converged).
    pub fn project_keep_pressure(&self, u: &MacField3d) -> Result<(MacField3d, Tensor)> {
        let (v, p) = match u.values().dtype() {
            DType::F32 => self.pressure_split::<f32>(u, None)?,
            _ => self.pressure_split::<f64>(u, None)?,
        };
        let p = p.ok_or_else(|| Error::Invalid { field: "pressure", reason: "the solve kept no pressure".into() })?;
        Ok((v, p))
    }

    /// The velocity correction of [`Smoke3d::step`] with a given pressure (e.g. a decoded,
    /// predicted one) instead of a solve: wall faces set to 0 as the projection sets them, then
    /// `u - G p` (computed in f64, returned in the velocity's dtype). With the pressure of
    /// [`Smoke3d::project_keep_pressure`] it equals that projection (to the bit for f64
    /// velocities; for f32 the kept pressure was rounded to f32, so to f32 round-off). The
    /// result is divergence-free only as far as `p` solves the step's Poisson problem. Not
    /// differentiable.
    ///
    /// # Errors
    /// As [`Smoke3d::project_keep_pressure`]; [`Error::Shape`] when `pressure` is not
    /// `[B, 1, nz, ny, nx]` for `u`'s batch `B`, [`Error::Invalid`] when it is not f32/f64 or not
    /// on the CPU.
    pub fn correct_with_pressure(&self, u: &MacField3d, pressure: &Tensor) -> Result<MacField3d> {
        const OP: &str = "Smoke3d::correct_with_pressure";
        check_values(OP, "pressure", pressure, &self.grid, Some(1))?;
        let b = u.values().dims().first().copied().unwrap_or(0);
        if pressure.dims()[0] != b {
            return Err(Error::Shape {
                op: OP,
                arg: "pressure",
                expected: format!(
                    "[{b}, 1, {}, {}, {}] (the velocity's batch)",
                    self.grid.nz, self.grid.ny, self.grid.nx
                ),
                got: pressure.dims().to_vec(),
            });
        }
        Ok(match u.values().dtype() {
            DType::F32 => self.pressure_split::<f32>(u, Some(pressure))?.0,
            _ => self.pressure_split::<f64>(u, Some(pressure))?.0,
        })
    }

    /// The projection kernel on `T` slices (the velocity's dtype): with `given` the correction
    /// by that pressure, else the solve, returning its pressure.
    fn pressure_split<T: Real>(&self, u: &MacField3d, given: Option<&Tensor>) -> Result<(MacField3d, Option<Tensor>)> {
        u.check_stepper_grid(&self.grid)?;
        check_values("Smoke3d::project_keep_pressure", "u", u.values(), &self.grid, Some(3))?;
        let values = u.values();
        let shape = values.shape().clone();
        let b = shape.dims()[0];
        let x: Vec<T> = values.to_dtype(T::DTYPE)?.flatten_all()?.to_vec1::<T>()?;
        let mut out = vec![T::zero(); x.len()];
        let pressure = match given {
            Some(p) => {
                let p: Vec<T> = p.to_dtype(T::DTYPE)?.flatten_all()?.to_vec1::<T>()?;
                self.projection.correct(&x, &p, &mut out)?;
                None
            }
            None => {
                let mut p = vec![T::zero(); b * self.grid.cells()];
                self.projection.forward_keep_pressure(&x, &mut out, &mut p)?;
                Some(Tensor::from_vec(p, self.grid.shape(b, 1).to_vec(), values.device())?.to_dtype(values.dtype())?)
            }
        };
        let v = Tensor::from_vec(out, shape, values.device())?.to_dtype(values.dtype())?;
        Ok((MacField3d::from_parts(v, self.grid), pressure))
    }

    /// Steps 1-3 (everything before the projection): the velocity values and the new density.
    /// One step with its density bookkeeping per batch item ([`MassBalance3d`]): with
    /// conservative density transport the density's content `sum rho dV` after the step equals
    /// the content before plus `source + inflow - outflow`, to round-off. Not differentiable
    /// (use [`Smoke3d::step`]).
    pub fn step_balance(&self, state: &Smoke3dState) -> Result<(Smoke3dState, Vec<MassBalance3d>)> {
        let mut balance = Vec::new();
        let (v, rho) = self.before_projection_counting(state, None, Some(&mut balance))?;
        let v = self.projection.apply(&v)?;
        Ok((Smoke3dState { velocity: MacField3d::from_parts(v, self.grid), density: rho }, balance))
    }

    fn before_projection(&self, state: &Smoke3dState, rate: Option<&Tensor>) -> Result<(Tensor, Tensor)> {
        self.before_projection_counting(state, rate, None)
    }

    fn before_projection_counting(
        &self,
        state: &Smoke3dState,
        rate: Option<&Tensor>,
        mut balance: Option<&mut Vec<MassBalance3d>>,
    ) -> Result<(Tensor, Tensor)> {
        self.check_state(state)?;
        let (dt, g) = (self.config.dt, self.grid);
        let u = &state.velocity;
        let vol = g.spacing().iter().product::<f64>();
        let batch = state.density.dims()[0];
        if let Some(b) = balance.as_deref_mut() {
            b.clear();
            b.resize(batch, MassBalance3d::default());
        }
        // Per batch item `sum(t) dV`.
        let content = |t: &Tensor| -> Result<Vec<f64>> {
            Ok(t.to_dtype(DType::F64)?
                .flatten_from(1)?
                .sum(1)?
                .to_vec1::<f64>()?
                .into_iter()
                .map(|x| x * vol)
                .collect())
        };
        // 1. Density.
        let walls = self.boundaries.walls;
        let mut rho = match self.config.density_advection {
            Advection3d::SemiLagrangian => {
                Sl3d::scalar(&state.density, u, dt)?.with_walls(walls).apply(&state.density, u.values())?
            }
            Advection3d::MacCormack => {
                Sl3d::scalar(&state.density, u, dt)?.with_walls(walls).mac_cormack(&state.density, u.values())?
            }
            Advection3d::Conservative => {
                let faces = [0, 1, 2].map(|a| {
                    if walls.periodic(a) {
                        AxisFaces3d::Periodic
                    } else if walls.open_hi(a) {
                        AxisFaces3d::OpenHi
                    } else {
                        AxisFaces3d::Wall
                    }
                });
                let op = Conservative3d { faces, limiter: true };
                match balance.as_deref_mut() {
                    Some(b) => {
                        let (r, out) = op.step_counting(&state.density, u, dt)?;
                        for (bi, o) in b.iter_mut().zip(out) {
                            bi.outflow = Some(o.iter().sum());
                        }
                        r
                    }
                    None => op.step(&state.density, u, dt)?,
                }
            }
        };
        if let Some(fluid) = &self.fluid_mask {
            // Nothing lives in a solid cell. The conservative scheme moves nothing into one (its
            // faces carry zero velocity after the projection), interpolation can: cut it.
            rho = rho.broadcast_mul(&fluid.to_dtype(rho.dtype())?)?;
        }
        if let (Some(mask), Some(patch)) = (&self.inflow_mask, &self.boundaries.inflow) {
            // Hold the inflow cells at the inflow density: what advection took out of them
            // through the inflow faces is put back (and counted as the inflow).
            let m = mask.to_dtype(rho.dtype())?;
            let held = m.affine(patch.density, 0.0)?;
            let before = rho.broadcast_mul(&m)?;
            if let Some(b) = balance.as_deref_mut() {
                let (had, full) = (content(&before)?, patch.density * content(&m)?[0]);
                for (bi, h) in b.iter_mut().zip(had) {
                    bi.inflow = full - h;
                }
            }
            rho = (rho - before)?.broadcast_add(&held)?;
        }
        if let (Some(mask), Some(src)) = (&self.source_mask, &self.config.source) {
            let m = mask.to_dtype(rho.dtype())?;
            let add = match rate {
                Some(r) => m.broadcast_mul(&r.to_dtype(rho.dtype())?.affine(dt, 0.0)?)?,
                None => m.affine(dt * src.rate, 0.0)?,
            };
            if let Some(b) = balance {
                let added = content(&add.broadcast_as(state.density.shape())?.contiguous()?)?;
                for (bi, a) in b.iter_mut().zip(added) {
                    bi.source = a;
                }
            }
            rho = rho.broadcast_add(&add)?;
        }
        // 2. Velocity.
        let sl = Sl3d::velocity(u, u, dt)?.with_walls(walls);
        let mut v = match self.config.advection {
            Advection3d::SemiLagrangian => sl.apply(u.values(), u.values())?,
            Advection3d::MacCormack => sl.mac_cormack(u.values(), u.values())?,
            Advection3d::Conservative => {
                // Refused in `Smoke3d::new`; kept as a typed error rather than a panic.
                return Err(Error::Invalid {
                    field: "advection",
                    reason: "conservative transport is for the density only".into(),
                });
            }
        };
        if self.config.buoyancy != 0.0 {
            let f = apply1(&rho, Buoyancy3d { grid: g, beta: self.config.buoyancy * dt, y_hi: walls.y_hi })?;
            v = (v + f)?;
        }
        // 3. Viscosity.
        match &self.viscosity {
            Some(Visc::Explicit(op)) => v = (&v + op.apply(&v)?.affine(dt, 0.0)?)?,
            Some(Visc::Implicit(op)) => v = apply1(&v, *op)?,
            None => {}
        }
        Ok((v, rho))
    }
}

/// [`Smoke3d`] as a [`pbdl_core::stepper::Stepper`] (state: [`Smoke3dState`]); its step is
/// [`Smoke3d::step`] at the configured inflow rate.
impl pbdl_core::stepper::Stepper for Smoke3d {
    type State = Smoke3dState;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config.dt
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    /// Full: every operator has a hand-written adjoint (see the module docs); partial with the
    /// conservative density transport, whose backward is an error.
    fn differentiability(&self) -> pbdl_core::stepper::Differentiability {
        if self.config.density_advection == Advection3d::Conservative {
            pbdl_core::stepper::Differentiability::Partial(&["grid3d.advect.conservative(density)"])
        } else {
            pbdl_core::stepper::Differentiability::Full
        }
    }

    fn step(&self, state: &Smoke3dState) -> Result<Smoke3dState> {
        Smoke3d::step(self, state, None)
    }
}

/// The Boussinesq force `(0, beta rho, 0)` on the faces of a closed-box MAC velocity: `rho`
/// (`[batch, 1, nz, ny, nx]`) averaged over the two cells each y-face separates; the wall
/// faces (`y = ly`) and the x- and z-faces get 0. Differentiable (the transpose of the average).
pub fn buoyancy(density: &Tensor, grid: &Grid3d, beta: f64) -> Result<MacField3d> {
    grid.validate()?;
    check_values("grid3d::buoyancy", "density", density, grid, Some(1))?;
    if !beta.is_finite() {
        return Err(Error::Invalid { field: "buoyancy", reason: format!("beta must be finite, got {beta}") });
    }
    let op = Buoyancy3d { grid: *grid, beta, y_hi: Face3d::NoSlip };
    Ok(MacField3d::from_parts(apply1(density, op)?, *grid))
}

/// The buoyancy op: `[b, 1, ...]` to `[b, 3, ...]`.
#[derive(Clone, Copy, Debug)]
struct Buoyancy3d {
    grid: Grid3d,
    beta: f64,
    /// The face `y = ly`: a wall gets no force on it, a periodic pair averages the top and the
    /// bottom cell, an outflow face takes the top cell's density (zero gradient).
    y_hi: Face3d,
}

impl Buoyancy3d {
    /// The two cells (row indices within a z-slab-major layout, `r = k ny + j`) whose mean
    /// drives the y-face above row `r`, or `None` for a wall face.
    #[inline(always)]
    fn cells(&self, r: usize) -> Option<(usize, usize)> {
        let ny = self.grid.ny;
        if r % ny != ny - 1 {
            return Some((r, r + 1));
        }
        match self.y_hi {
            Face3d::Periodic => Some((r, r + 1 - ny)),
            Face3d::Outflow => Some((r, r)),
            Face3d::NoSlip | Face3d::FreeSlip => None,
        }
    }
}

impl Kernel1 for Buoyancy3d {
    fn name(&self) -> &'static str {
        "grid3d_buoyancy"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let d = s.dims();
        let g = &self.grid;
        if d.len() != 5 || d[1..] != [1, g.nz, g.ny, g.nx] {
            candle_core::bail!("grid3d_buoyancy: density {d:?} is not one channel on {}x{}x{}", g.nz, g.ny, g.nx);
        }
        Ok(Shape::from(vec![d[0], 3, g.nz, g.ny, g.nx]))
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, n) = (self.grid.nx, self.grid.cells());
        let hb = T::c(0.5 * self.beta);
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(3 * n)) {
            let ov = &mut ob[n..2 * n];
            for (r, row) in ov.chunks_mut(nx).enumerate() {
                let Some((r0, r1)) = self.cells(r) else {
                    continue; // the wall y = ly
                };
                for (i, o) in row.iter_mut().enumerate() {
                    *o = hb * (xb[r0 * nx + i] + xb[r1 * nx + i]);
                }
            }
        }
        Ok(())
    }
}

impl Op1 for Buoyancy3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, Buoyancy3dAdjoint(*self))
    }
}

/// Transpose of [`Buoyancy3d`]: `[b, 3, ...]` to `[b, 1, ...]`.
struct Buoyancy3dAdjoint(Buoyancy3d);

impl Kernel1 for Buoyancy3dAdjoint {
    fn name(&self) -> &'static str {
        "grid3d_buoyancy_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let d = s.dims();
        if d.len() != 5 || d[1] != 3 {
            candle_core::bail!("grid3d_buoyancy_adjoint: cotangent {d:?} is not a 3D MAC velocity");
        }
        Ok(Shape::from(vec![d[0], 1, d[2], d[3], d[4]]))
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let (nx, n) = (op.grid.nx, op.grid.cells());
        let hb = T::c(0.5 * op.beta);
        for (gb, ob) in g.chunks(3 * n).zip(out.chunks_mut(n)) {
            let gv = &gb[n..2 * n];
            for r in 0..n / nx {
                let Some((r0, r1)) = op.cells(r) else {
                    continue;
                };
                for i in 0..nx {
                    let a = hb * gv[r * nx + i];
                    ob[r0 * nx + i] += a;
                    ob[r1 * nx + i] += a;
                }
            }
        }
        Ok(())
    }
}

/// Relative residual at which the implicit viscous solve stops: near round-off, so that its
/// gradient (one more solve) agrees with finite differences.
const VISCOSITY_REL_TOL: f64 = 1e-13;
/// Iteration cap of the implicit viscous solve.
const VISCOSITY_MAX_ITER: usize = 5000;

/// Backward-Euler viscosity `(I - nu dt L)^-1 u` per component with the ghost rules of
/// [`super::walls`] (no-slip by default; per face with `faces`) (a face across a wall along the component's own axis is 0; a tangential
/// ghost is `-q_inner`), wall faces 0 in and out; unpreconditioned CG in f64. `I - nu dt L` is
/// symmetric positive definite (eigenvalues >= 1), so the backward is the same solve of the
/// cotangent.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ImplicitViscosity3d {
    pub grid: Grid3d,
    pub nu_dt: f64,
    /// Per-face conditions: a free-slip or outflow face mirrors the tangential ghost (`+x`), an
    /// outflow face repeats the normal component beyond it, periodic pairs wrap.
    pub faces: Walls3d,
}

impl ImplicitViscosity3d {
    /// Whether face `p` of component `c` is a stored wall face (held at 0).
    #[inline(always)]
    fn wall_face(&self, c: usize, p: [usize; 3], n: [usize; 3]) -> bool {
        p[c] == n[c] - 1 && !self.faces.periodic(c) && !self.faces.open_hi(c)
    }
}

impl ImplicitViscosity3d {
    /// `y = (I - nu dt L) x` for component `c` (wall faces of `x` are ignored, of `y` set to 0).
    fn matvec(&self, c: usize, x: &[f64], y: &mut [f64]) {
        let n = [self.grid.nx, self.grid.ny, self.grid.nz];
        let st = [1, n[0], n[0] * n[1]];
        let w = self.grid.spacing().map(|h| self.nu_dt / (h * h));
        let f = &self.faces;
        for (m, ym) in y.iter_mut().enumerate() {
            let p = [m % n[0], (m / n[0]) % n[1], m / st[2]];
            if self.wall_face(c, p, n) {
                *ym = 0.0;
                continue;
            }
            let xm = x[m];
            let mut s = xm;
            for a in 0..3 {
                // Neighbour above / below along a: wrapped when periodic; else a wall along c
                // is 0, a tangential ghost -x (no-slip) or +x (free-slip, outflow), and beyond
                // an open face the normal component repeats.
                let (up, down) = if f.periodic(a) {
                    let up = if p[a] + 1 < n[a] { m + st[a] } else { m + st[a] - n[a] * st[a] };
                    let down = if p[a] > 0 { m - st[a] } else { m + (n[a] - 1) * st[a] };
                    (x[up], x[down])
                } else {
                    let mirror = |free: bool| if free { xm } else { -xm };
                    let open = f.open_hi(a);
                    let hi_in = if a == c && !open { p[a] + 2 < n[a] } else { p[a] + 1 < n[a] };
                    let up = if hi_in {
                        x[m + st[a]]
                    } else if open {
                        xm
                    } else if a == c {
                        0.0
                    } else {
                        mirror(f.free_slip(a, true))
                    };
                    let down = if p[a] > 0 {
                        x[m - st[a]]
                    } else if a == c {
                        0.0
                    } else {
                        mirror(f.free_slip(a, false))
                    };
                    (up, down)
                };
                s -= w[a] * (up + down - 2.0 * xm);
            }
            *ym = s;
        }
    }

    /// Solves `(I - nu dt L) x = b` for component `c` by CG (`b`'s wall faces are ignored).
    fn solve(&self, c: usize, b: &mut [f64], x: &mut [f64]) -> candle_core::Result<()> {
        let n = [self.grid.nx, self.grid.ny, self.grid.nz];
        let nxy = n[0] * n[1];
        for (m, bm) in b.iter_mut().enumerate() {
            let p = [m % n[0], (m / n[0]) % n[1], m / nxy];
            if self.wall_face(c, p, n) {
                *bm = 0.0;
            }
        }
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let bnorm = dot(b, b).sqrt();
        x.copy_from_slice(b);
        if bnorm == 0.0 {
            return Ok(());
        }
        let mut r = vec![0.0; b.len()];
        self.matvec(c, x, &mut r);
        for (ri, bi) in r.iter_mut().zip(b.iter()) {
            *ri = bi - *ri;
        }
        let mut p = r.clone();
        let mut ap = vec![0.0; b.len()];
        let mut rr = dot(&r, &r);
        for _ in 0..VISCOSITY_MAX_ITER {
            if rr.sqrt() <= VISCOSITY_REL_TOL * bnorm {
                return Ok(());
            }
            self.matvec(c, &p, &mut ap);
            let alpha = rr / dot(&p, &ap);
            for ((xi, ri), (pi, api)) in x.iter_mut().zip(r.iter_mut()).zip(p.iter().zip(&ap)) {
                *xi += alpha * pi;
                *ri -= alpha * api;
            }
            let rr_new = dot(&r, &r);
            let beta = rr_new / rr;
            rr = rr_new;
            for (pi, ri) in p.iter_mut().zip(&r) {
                *pi = ri + beta * *pi;
            }
        }
        candle_core::bail!(
            "grid3d implicit viscosity: CG not converged after {VISCOSITY_MAX_ITER} iterations (relative residual {:.3e})",
            rr.sqrt() / bnorm
        )
    }
}

impl Kernel1 for ImplicitViscosity3d {
    fn name(&self) -> &'static str {
        "grid3d_implicit_viscosity"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        super::momentum::check_shape(self.name(), s, &self.grid)?;
        Ok(s.clone())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let n = self.grid.cells();
        let (mut b, mut y) = (vec![0.0f64; n], vec![0.0f64; n]);
        for (xb, ob) in x.chunks(3 * n).zip(out.chunks_mut(3 * n)) {
            for c in 0..3 {
                for (bi, xi) in b.iter_mut().zip(&xb[c * n..(c + 1) * n]) {
                    *bi = xi.wide();
                }
                self.solve(c, &mut b, &mut y)?;
                for (o, yi) in ob[c * n..(c + 1) * n].iter_mut().zip(&y) {
                    *o = T::c(*yi);
                }
            }
        }
        Ok(())
    }
}

impl Op1 for ImplicitViscosity3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        // Symmetric on the interior faces, zero on the wall faces in and out.
        apply1(gy, *self)
    }
}

/// One backward-Euler viscous step `(I - nu dt L)^-1 u` in the no-slip box (wall faces 0).
/// Differentiable (the backward is the same solve). `nu dt >= 0`.
pub fn implicit_viscosity(u: &MacField3d, nu: f64, dt: f64) -> Result<MacField3d> {
    if !(nu >= 0.0 && nu.is_finite() && dt >= 0.0 && dt.is_finite()) {
        return Err(Error::Invalid { field: "nu", reason: format!("need finite nu >= 0 and dt >= 0, got {nu}, {dt}") });
    }
    let op = ImplicitViscosity3d { grid: *u.grid(), nu_dt: nu * dt, faces: Walls3d::closed() };
    Ok(MacField3d::from_parts(apply1(u.values(), op)?, *u.grid()))
}
