//! Scenes: a simulation described in TOML, built into a stepper that holds only what it needs.
//!
//! A [`Scene`] is a serde struct (unknown keys are rejected). The defaults ship inside the binary
//! (`pbdl-grid/scenes/*.toml`, embedded with `include_str!`): [`Scene::builtin`] and
//! [`builtin_names`]. [`Scene::build`] validates the scene and builds a [`Simulation`] whose
//! stepper contains only the operators the scene needs: no viscous term at `nu = 0`, no FFT
//! pressure solve in a closed box, no forcing without a forcing section, no buoyancy or density
//! without a density field. [`Simulation::operators`] lists them.
//!
//! ```
//! use pbdl_grid::scene::Scene;
//! let sim = Scene::builtin("taylor_green")?.with_resolution(16).build()?;
//! assert!(sim.operators().contains(&"pressure.fft"));
//! assert!(!sim.operators().iter().any(|o| o.starts_with("buoyancy") || o.starts_with("obstacle")));
//! # Ok::<(), pbdl_grid::scene::SceneError>(())
//! ```
//!
//! Seeded runs (one data item per run, `cargo xtask sim grid SCENE --seeds N`): run `k` is
//! [`Scene::with_seed_offset`]`(k)`, every seeded input ([`Scene::seeded_inputs`]; the `seed` of
//! `init = random_modes`) advanced by `k`.
//!
//! A scene file (all sections; `time` needs `steps` or `t_end`):
//!
//! ```toml
//! name = "my_vortex"
//! about = "Taylor-Green at 32^2"
//! precision = "f32"                 # or "f64"
//! [grid]
//! nx = 32
//! ny = 32                           # 1 for 1D scenes (default)
//! # nz = 32                         # > 1: a 3D scene (navier_stokes_spectral, smoke); lz its length
//! lx = 6.283185307179586
//! ly = 6.283185307179586
//! origin = [0.0, 0.0]               # coordinates of the lower-left corner (init formulas)
//! [physics]
//! kind = "navier_stokes"            # burgers_1d, burgers_2d, heat, poisson, advection_diffusion, navier_stokes, navier_stokes_spectral, smoke, cylinder
//! nu = 0.01
//! [init]
//! kind = "taylor_green"             # zero, uniform, taylor_green, random_modes, sine, gaussian
//! [time]
//! t_end = 1.0                       # or steps = 100
//! cfl = 0.5                         # dt = cfl * h / speed, capped by the scheme's stable step
//! frames = 20                       # frames kept in the trajectory
//! ```

mod build;
mod init;
mod kinds;
mod output;
mod seeds;

pub use build::{Simulation, State, Trajectory};
pub use init::Init;
pub use output::write_trajectory;

use crate::boundary::{Bc, Boundaries, ScalarBc, ScalarBoundaries};
pub use crate::fluid::Advection;
use crate::time_stepping::Scheme;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Errors from reading, validating and building a scene. Each names what to change.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// Not valid TOML, a missing or unknown key, a value of the wrong type.
    #[error("scene `{scene}`: {message}")]
    Parse {
        /// The scene name or file.
        scene: String,
        /// The parser's message (it names the key and the line).
        message: String,
    },
    /// A value out of range.
    #[error("scene `{scene}`: invalid `{field}`: {reason}")]
    Invalid {
        /// The scene name.
        scene: String,
        /// The key, e.g. `"physics.nu"` or `"obstacles[0].radius"`.
        field: String,
        /// Why, and what to use instead.
        reason: String,
    },
    /// No built-in scene of that name (and no such file).
    #[error("unknown scene `{name}`; built-in scenes: {known} (or give a path to a .toml file)")]
    Unknown {
        /// What was asked for.
        name: String,
        /// The built-in scene names.
        known: String,
    },
    /// The scene needs a stepper that this crate does not provide yet.
    #[error("scene `{scene}` needs the {stepper} stepper, which pbdl-grid does not provide yet")]
    NeedsStepper {
        /// The scene name.
        scene: String,
        /// The missing stepper, e.g. `"smoke"`.
        stepper: &'static str,
    },
    /// A scene file could not be read.
    #[error("reading scene file `{path}`: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A solver error while building or stepping.
    #[error(transparent)]
    Grid(#[from] crate::Error),
}

/// Result type of the scene module.
pub type SceneResult<T> = std::result::Result<T, SceneError>;

/// A simulation setup.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Short name (used for output files).
    pub name: String,
    /// One sentence on what the scene shows.
    #[serde(default)]
    pub about: String,
    /// Float precision of the state. Default: f32.
    #[serde(default)]
    pub precision: Precision,
    /// The grid.
    pub grid: GridSpec,
    /// The equations and their parameters.
    pub physics: Physics,
    /// The initial state. Default: zero.
    #[serde(default)]
    pub init: Init,
    /// Time stepping.
    pub time: TimeSpec,
    /// Solid obstacles (need a physics kind that supports them).
    #[serde(default)]
    pub obstacles: Vec<Obstacle>,
}

/// Float precision of a scene's state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    /// 32-bit floats (default).
    #[default]
    F32,
    /// 64-bit floats.
    F64,
}

impl Precision {
    /// The candle dtype.
    pub fn dtype(self) -> candle_core::DType {
        match self {
            Precision::F32 => candle_core::DType::F32,
            Precision::F64 => candle_core::DType::F64,
        }
    }
}

/// A uniform grid; `ny = 1` for 1D scenes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Cells along x.
    pub nx: usize,
    /// Cells along y (default 1: a 1D scene).
    #[serde(default = "one")]
    pub ny: usize,
    /// Length along x.
    pub lx: f64,
    /// Length along y (default 1).
    #[serde(default = "one_f")]
    pub ly: f64,
    /// Cells along z (default 1: a 2D scene; more makes a 3D scene, for the kinds that have a 3D
    /// form: `navier_stokes_spectral`, `smoke`).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub nz: usize,
    /// Length along z (default 1; used by 3D scenes).
    #[serde(default = "one_f", skip_serializing_if = "is_one_f")]
    pub lz: f64,
    /// Coordinates of the lower-left corner, used by the initial-condition formulas. Default: 0.
    #[serde(default)]
    pub origin: [f64; 2],
}

fn one() -> usize {
    1
}
fn one_f() -> f64 {
    1.0
}
fn is_one(v: &usize) -> bool {
    *v == 1
}
fn is_one_f(v: &f64) -> bool {
    *v == 1.0
}
fn half() -> f64 {
    0.5
}
fn twenty() -> usize {
    20
}
fn periodic() -> Boundaries {
    Boundaries::periodic()
}
fn scalar_periodic() -> ScalarBoundaries {
    ScalarBoundaries::periodic()
}
fn dirichlet_zero() -> ScalarBoundaries {
    let d = ScalarBc::Dirichlet { value: 0.0 };
    ScalarBoundaries { x_lo: d, x_hi: d, y_lo: d, y_hi: d }
}

/// The equations of a scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Physics {
    /// 1D viscous Burgers `u_t + (u^2/2)_x = nu u_xx`, periodic (field `u`).
    #[serde(rename = "burgers_1d")]
    Burgers1d {
        /// Viscosity (>= 0).
        nu: f64,
    },
    /// 2D viscous Burgers in conservation form `u_t + div(u u) = nu lap u` for a MAC velocity
    /// (the Navier-Stokes momentum equation without pressure; field `velocity`).
    #[serde(rename = "burgers_2d")]
    Burgers2d {
        /// Viscosity (>= 0).
        nu: f64,
        /// Velocity boundary conditions. Default: periodic.
        #[serde(default = "periodic")]
        boundaries: Boundaries,
    },
    /// Heat equation `T_t = kappa lap T` (field `temperature`).
    Heat {
        /// Diffusivity (> 0).
        kappa: f64,
        /// Boundary conditions. Default: periodic.
        #[serde(default = "scalar_periodic")]
        boundaries: ScalarBoundaries,
    },
    /// Poisson equation `lap phi = f`, solved once (field `phi`; `init` gives the source `f`).
    Poisson {
        /// Homogeneous boundary conditions. Default: Dirichlet 0 on all faces.
        #[serde(default = "dirichlet_zero")]
        boundaries: ScalarBoundaries,
    },
    /// Advection-diffusion of a scalar by a constant velocity, periodic (field `concentration`).
    AdvectionDiffusion {
        /// The advecting velocity `[vx, vy]`.
        velocity: [f64; 2],
        /// Diffusivity (>= 0).
        nu: f64,
    },
    /// Incompressible Navier-Stokes (field `velocity`).
    NavierStokes {
        /// Viscosity (>= 0; 0 drops the viscous operator).
        nu: f64,
        /// Velocity boundary conditions. Default: periodic.
        #[serde(default = "periodic")]
        boundaries: Boundaries,
        /// A body force. Default: none.
        #[serde(default)]
        forcing: Option<Forcing>,
    },
    /// Incompressible Navier-Stokes by the pseudo-spectral method (field `velocity` on the cell
    /// centres): vorticity form, 2/3 dealiasing, implicit viscosity, the low-storage IMEX scheme
    /// of `time.scheme` (`rk4` -> CN-RK4 Carpenter-Kennedy, `ssp_rk3` -> CN-RK3 Williamson; see
    /// [`crate::spectral`]). Periodic boxes only; the keys are those of `navier_stokes`.
    NavierStokesSpectral {
        /// Viscosity (>= 0; 0 drops the viscous operator).
        nu: f64,
        /// Velocity boundary conditions: periodic on every face (the default); anything else is
        /// refused with a typed error.
        #[serde(default = "periodic")]
        boundaries: Boundaries,
        /// A body force. Default: none.
        #[serde(default)]
        forcing: Option<Forcing>,
    },
    /// Buoyant smoke plume (density + velocity, Boussinesq buoyancy, inflow source).
    Smoke {
        /// Viscosity (>= 0).
        nu: f64,
        /// Buoyancy factor: upward force per unit density.
        buoyancy: f64,
        /// Velocity boundary conditions. Default: closed box of no-slip walls.
        #[serde(default = "closed_box")]
        boundaries: Boundaries,
        /// The density source.
        source: Source,
        /// Velocity advection (`semi_lagrangian`, `mac_cormack`, `central_rk4`). Default:
        /// MacCormack.
        #[serde(default)]
        advection: Advection,
        /// Density advection (`semi_lagrangian`, `mac_cormack`, `conservative`). Default: MacCormack,
        /// semi-Lagrangian when the velocity uses it. `conservative` is the flux-form scheme with
        /// flux-corrected transport ([`crate::advect::conservative()`]): the density's mass is
        /// exactly what the source injected (to round-off; MacCormack's is 11% above it after the
        /// shipped plume's 400 steps), no new extrema, sub-cycled to its CFL limit; in 3D
        /// (`grid.nz > 1`) the same method on three axes ([`crate::grid3d::conservative`],
        /// forward only).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        density_advection: Option<Advection>,
        /// 3D only (`grid.nz > 1`): the faces `z = 0` and `z = lz`, with the values of
        /// `boundaries` (`no_slip`, `free_slip`, `periodic`, `outflow` on `z_hi`). Default: no-slip.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        boundaries_z: Option<BoundariesZ>,
        /// 3D only: solid spheres and boxes (`kind = "sphere"`, `center = [x, y, z]`, `radius`;
        /// `kind = "box"`, `lower`, `upper` as `[x, y, z]`). The top-level 2D `obstacles` (circles,
        /// boxes) are extruded through the whole depth in 3D.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        obstacles3d: Vec<crate::grid3d::Obstacle3d>,
        /// 3D only: an inflow patch on a lower face (`face = "y_lo"`, `shape = { kind = "disc",
        /// center = [x, z], radius }` or `{ kind = "rect", lower, upper }` in the face's two other
        /// coordinates, `velocity` into the box, `density`); needs an `outflow` face.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        inflow_patch: Option<crate::grid3d::InflowPatch3d>,
    },
    /// Flow past obstacles (the Karman street behind a cylinder); obstacles from `obstacles`.
    /// Uniform inflow at `x = 0`, zero-gradient outflow at `x = lx`, free-slip walls at
    /// `y = 0, ly` by default. `inflow_profile = "parabolic"` makes the inflow the Poiseuille
    /// profile `4 inflow y (ly - y) / ly^2` held on the `u` faces at `x = dx` (the first cell
    /// column becomes a buffer outside the flow, see [`crate::boundary::InflowProfile`]);
    /// `walls = { kind = "no_slip" }` gives no-slip channel walls; `surface = { kind =
    /// "immersed_boundary", iterations = 2 }` treats the obstacle surfaces by the direct-forcing
    /// immersed boundary ([`crate::obstacle::ImmersedBoundary`]) instead of the staircase mask.
    /// With all three (and `nu = 1e-3`, `inflow = 0.3` or `1.5`, a circle of radius 0.05 at
    /// `(0.2 + dx, 0.2)` in `2.2 + dx` x 0.41) this is the Schaefer & Turek (1996) 2D-1 / 2D-2
    /// benchmark (tests/schaefer_turek.rs).
    Cylinder {
        /// Viscosity (> 0).
        nu: f64,
        /// Inflow speed at `x = 0` (the centreline speed with a parabolic profile).
        inflow: f64,
        /// `uniform` (default) or `parabolic`.
        #[serde(default, skip_serializing_if = "is_default")]
        inflow_profile: crate::boundary::InflowShape,
        /// Condition on the walls `y = 0, ly`: `{ kind = "free_slip" }` (default) or
        /// `{ kind = "no_slip" }`.
        #[serde(default = "free_slip", skip_serializing_if = "is_free_slip")]
        walls: Bc,
        /// Obstacle surfaces: `{ kind = "staircase" }` (default) or
        /// `{ kind = "immersed_boundary", iterations = 2 }`.
        #[serde(default, skip_serializing_if = "is_default")]
        surface: crate::obstacle::ObstacleTreatment,
        /// Velocity advection (`semi_lagrangian`, `mac_cormack`, `central_rk4`). Default:
        /// MacCormack.
        #[serde(default)]
        advection: Advection,
        /// Transverse velocity, in units of `inflow`, put at `t = 0` into a square of one
        /// diameter centred 1.5 diameters behind the first circle and half a diameter above its
        /// axis, so that the symmetric wake starts shedding early. Default: 0.3; 0: none.
        #[serde(default = "default_kick")]
        kick: f64,
    },
}

fn default_kick() -> f64 {
    0.3
}

fn free_slip() -> Bc {
    Bc::FreeSlip
}

fn is_free_slip(b: &Bc) -> bool {
    *b == Bc::FreeSlip
}

fn is_default<T: Default + PartialEq>(t: &T) -> bool {
    *t == T::default()
}

fn closed_box() -> Boundaries {
    Boundaries { x_lo: Bc::NoSlip, x_hi: Bc::NoSlip, y_lo: Bc::NoSlip, y_hi: Bc::NoSlip }
}

/// The two z faces of a 3D smoke scene (`physics.boundaries_z`), with the values of the x and y
/// faces in `physics.boundaries`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundariesZ {
    /// Face `z = 0`.
    pub z_lo: Bc,
    /// Face `z = lz`.
    pub z_hi: Bc,
}

/// A body force on the velocity.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Forcing {
    /// Kolmogorov forcing `f_x = amplitude sin(2 pi wavenumber y / ly) - drag u`, `f_y = -drag v`.
    Kolmogorov {
        /// Force amplitude.
        amplitude: f64,
        /// Number of forcing periods along y.
        wavenumber: u32,
        /// Linear drag coefficient (>= 0). Default: 0.
        #[serde(default)]
        drag: f64,
    },
}

/// A density source of the smoke scene: a disc emitting `rate` density per unit time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// Centre of the disc (of the sphere in 3D: `[x, y]`, with `z` below).
    pub center: [f64; 2],
    /// `z` of the sphere's centre in a 3D scene. Default: the middle of the box.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub z: Option<f64>,
    /// Radius of the disc.
    pub radius: f64,
    /// Density added per unit time inside the disc.
    pub rate: f64,
}

/// A solid obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle {
    /// A disc.
    Circle {
        /// Centre.
        center: [f64; 2],
        /// Radius (> 0).
        radius: f64,
    },
    /// An axis-aligned box.
    Box {
        /// Lower-left corner.
        lower: [f64; 2],
        /// Upper-right corner.
        upper: [f64; 2],
    },
}

/// Time stepping of a scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSpec {
    /// Number of steps (give `steps` or `t_end`).
    #[serde(default)]
    pub steps: Option<usize>,
    /// End time; the step is then shortened so that a whole number of steps ends there.
    #[serde(default)]
    pub t_end: Option<f64>,
    /// A fixed time step; default: from `cfl`.
    #[serde(default)]
    pub dt: Option<f64>,
    /// Courant number on the characteristic speed (default 0.5), capped by the stable step.
    #[serde(default = "half")]
    pub cfl: f64,
    /// Characteristic speed for the time step; default: the largest initial or boundary speed.
    #[serde(default)]
    pub speed: Option<f64>,
    /// Runge-Kutta scheme. Default: RK4.
    #[serde(default)]
    pub scheme: Scheme,
    /// Frames kept in the trajectory (evenly spaced, first and last included). Default: 20.
    #[serde(default = "twenty")]
    pub frames: usize,
}

macro_rules! builtin {
    ($($name:literal),* $(,)?) => {
        &[$(($name, include_str!(concat!("../../scenes/", $name, ".toml")))),*]
    };
}

/// The embedded default scenes: `(name, TOML text)`.
pub const BUILTIN: &[(&str, &str)] = builtin!(
    "burgers_1d",
    "burgers_2d",
    "heat",
    "poisson",
    "advection_diffusion",
    "taylor_green",
    "taylor_green_spectral",
    "decaying_turbulence",
    "lid_driven_cavity",
    "kolmogorov",
    "smoke_plume",
    "cylinder",
    "smoke3d_obstacle",
);

/// Names of the built-in scenes.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|(n, _)| *n).collect()
}

impl Scene {
    /// Parses a scene from TOML text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> SceneResult<Self> {
        let scene: Scene =
            toml::from_str(text).map_err(|e| SceneError::Parse { scene: origin.into(), message: e.to_string() })?;
        scene.validate()?;
        Ok(scene)
    }

    /// A built-in scene by name.
    pub fn builtin(name: &str) -> SceneResult<Self> {
        match BUILTIN.iter().find(|(n, _)| *n == name) {
            Some((n, text)) => Self::from_toml_str(text, n),
            None => Err(SceneError::Unknown { name: name.into(), known: builtin_names().join(", ") }),
        }
    }

    /// Reads a scene file.
    pub fn from_file(path: impl AsRef<Path>) -> SceneResult<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io { path: path.into(), source })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// A built-in scene name or a path to a `.toml` file.
    pub fn load(name_or_path: &str) -> SceneResult<Self> {
        if name_or_path.ends_with(".toml") || Path::new(name_or_path).is_file() {
            Self::from_file(name_or_path)
        } else {
            Self::builtin(name_or_path)
        }
    }

    /// The same scene with `n` cells along x (and y, z scaled to keep the aspect; 1D stays 1D,
    /// 2D stays 2D).
    pub fn with_resolution(mut self, n: usize) -> Self {
        let scale = |m: usize| ((n as f64 * m as f64 / self.grid.nx.max(1) as f64).round() as usize).max(1);
        if self.grid.nz > 1 {
            self.grid.nz = scale(self.grid.nz).max(2);
        }
        if self.grid.ny > 1 {
            self.grid.ny = scale(self.grid.ny);
        }
        self.grid.nx = n;
        self
    }

    /// The same scene run for exactly `steps` steps (the time step is kept).
    pub fn with_steps(mut self, steps: usize) -> Self {
        self.time.steps = Some(steps);
        self.time.t_end = None;
        self
    }

    /// Checks every value; the error names the key.
    pub fn validate(&self) -> SceneResult<()> {
        let bad = |field: &str, reason: String| {
            Err(SceneError::Invalid { scene: self.name.clone(), field: field.into(), reason })
        };
        let g = &self.grid;
        let one_d = matches!(self.physics, Physics::Burgers1d { .. });
        if g.nx < 2 {
            return bad("grid.nx", format!("need at least 2 cells, got {}", g.nx));
        }
        if one_d && g.ny != 1 {
            return bad("grid.ny", format!("burgers_1d is one-dimensional: use ny = 1, got {}", g.ny));
        }
        if !one_d && g.ny < 2 {
            return bad("grid.ny", format!("a 2D scene needs at least 2 cells, got {}", g.ny));
        }
        // Checked here so that the stepper's per-cell arithmetic cannot overflow.
        if g.nx.checked_mul(g.ny).and_then(|c| c.checked_mul(64)).is_none() {
            return bad("grid", format!("{} x {} cells do not fit in memory; use fewer cells", g.nx, g.ny));
        }
        for (f, l) in [("grid.lx", g.lx), ("grid.ly", g.ly)] {
            if !(l > 0.0 && l.is_finite()) {
                return bad(f, format!("must be a positive finite length, got {l}"));
            }
        }
        if g.nz != 1 {
            if !matches!(self.physics, Physics::NavierStokesSpectral { .. } | Physics::Smoke { .. }) {
                return bad(
                    "grid.nz",
                    format!(
                        "only navier_stokes_spectral and smoke have a 3D form; use nz = 1 for this kind, got {}",
                        g.nz
                    ),
                );
            }
            if g.nz < 2 {
                return bad("grid.nz", format!("a 3D scene needs at least 2 cells, got {}", g.nz));
            }
            // A 3D state holds several fields of 3 components: beyond 2^28 cells (512^3 is 2^27)
            // one field alone passes 6 GiB in f64, so the allocation would abort the process.
            let cells = g.nx.checked_mul(g.ny).and_then(|c| c.checked_mul(g.nz));
            if cells.is_none_or(|c| c > 1 << 28) {
                return bad(
                    "grid",
                    format!("{} x {} x {} cells do not fit in memory (at most 2^28 cells in 3D)", g.nx, g.ny, g.nz),
                );
            }
            if !(g.lz > 0.0 && g.lz.is_finite()) {
                return bad("grid.lz", format!("must be a positive finite length, got {}", g.lz));
            }
        }
        if !g.origin.iter().all(|v| v.is_finite()) {
            return bad("grid.origin", "must be finite".into());
        }
        let nonneg = |field: &str, v: f64| {
            if v >= 0.0 && v.is_finite() {
                Ok(())
            } else {
                bad(field, format!("must be finite and >= 0, got {v}"))
            }
        };
        let velocity_bc = |b: &Boundaries| {
            b.validate().map_err(|e| SceneError::Invalid {
                scene: self.name.clone(),
                field: "physics.boundaries".into(),
                reason: e.to_string(),
            })
        };
        match &self.physics {
            Physics::Burgers1d { nu } => nonneg("physics.nu", *nu)?,
            Physics::Burgers2d { nu, boundaries } => {
                nonneg("physics.nu", *nu)?;
                velocity_bc(boundaries)?;
            }
            Physics::Heat { kappa, boundaries } => {
                nonneg("physics.kappa", *kappa)?;
                boundaries.validate().map_err(|e| SceneError::Invalid {
                    scene: self.name.clone(),
                    field: "physics.boundaries".into(),
                    reason: e.to_string(),
                })?;
            }
            Physics::Poisson { boundaries } => {
                if let Some((face, b)) = boundaries
                    .faces()
                    .into_iter()
                    .find(|(_, b)| matches!(b, ScalarBc::Dirichlet { value } if *value != 0.0))
                {
                    return bad(
                        &format!("physics.boundaries.{face}"),
                        format!("the Poisson scene takes homogeneous conditions (Dirichlet value 0), got {b:?}"),
                    );
                }
                boundaries.validate()?;
            }
            Physics::AdvectionDiffusion { velocity, nu } => {
                nonneg("physics.nu", *nu)?;
                if !velocity.iter().all(|v| v.is_finite()) {
                    return bad("physics.velocity", "must be finite".into());
                }
            }
            Physics::NavierStokes { nu, boundaries, forcing }
            | Physics::NavierStokesSpectral { nu, boundaries, forcing } => {
                nonneg("physics.nu", *nu)?;
                velocity_bc(boundaries)?;
                if matches!(self.physics, Physics::NavierStokesSpectral { .. }) {
                    if let Some((face, b)) = boundaries.faces().into_iter().find(|(_, b)| *b != Bc::Periodic) {
                        return bad(
                            &format!("physics.boundaries.{face}"),
                            format!(
                                "navier_stokes_spectral solves periodic boxes only, got {b:?}; use periodic faces or kind = \"navier_stokes\" for walls"
                            ),
                        );
                    }
                }
                if let Some(Forcing::Kolmogorov { amplitude, wavenumber, drag }) = forcing {
                    if !amplitude.is_finite() {
                        return bad("physics.forcing.amplitude", format!("must be finite, got {amplitude}"));
                    }
                    if *wavenumber == 0 {
                        return bad("physics.forcing.wavenumber", "must be >= 1".into());
                    }
                    nonneg("physics.forcing.drag", *drag)?;
                }
            }
            Physics::Smoke {
                nu,
                buoyancy,
                boundaries,
                source,
                advection,
                density_advection,
                boundaries_z,
                obstacles3d,
                inflow_patch,
            } => {
                if g.nz == 1 && inflow_patch.is_some() {
                    return bad(
                        "physics.inflow_patch",
                        "the inflow patch is 3D only (grid.nz > 1); remove the key".into(),
                    );
                }
                nonneg("physics.nu", *nu)?;
                if g.nz == 1 && boundaries_z.is_some() {
                    return bad(
                        "physics.boundaries_z",
                        "the z faces exist only in 3D (grid.nz > 1); remove the key".into(),
                    );
                }
                if g.nz == 1 && !obstacles3d.is_empty() {
                    return bad(
                        "physics.obstacles3d",
                        "3D obstacles need a 3D grid (grid.nz > 1); use the top-level `obstacles` in 2D".into(),
                    );
                }
                if g.nz > 1 {
                    // 3D checks its faces itself (Smoke3dKind): outflow may sit on y_hi there.
                } else {
                    velocity_bc(boundaries)?;
                }
                if *advection == Advection::Conservative {
                    return bad(
                        "physics.advection",
                        "conservative is for the density: set `density_advection = \"conservative\"`; the \
                         velocity takes semi_lagrangian, mac_cormack or central_rk4"
                            .into(),
                    );
                }
                if *density_advection == Some(Advection::CentralRk4) {
                    return bad(
                        "physics.density_advection",
                        "central_rk4 is for the velocity; the density takes semi_lagrangian, mac_cormack or \
                         conservative"
                            .into(),
                    );
                }
                if !buoyancy.is_finite() {
                    return bad("physics.buoyancy", format!("must be finite, got {buoyancy}"));
                }
                if source.radius.is_nan() || source.radius <= 0.0 || !self.inside(source.center, source.radius) {
                    return bad(
                        "physics.source",
                        format!(
                            "the source disc (centre {:?}, radius {}) must lie inside the domain",
                            source.center, source.radius
                        ),
                    );
                }
                nonneg("physics.source.rate", source.rate)?;
            }
            Physics::Cylinder { nu, inflow, kick, walls, surface, .. } => {
                if !matches!(walls, Bc::NoSlip | Bc::FreeSlip) {
                    return bad("physics.walls", format!("must be no_slip or free_slip, got {walls:?}"));
                }
                if let crate::obstacle::ObstacleTreatment::ImmersedBoundary { iterations } = surface {
                    if *iterations == 0 {
                        return bad("physics.surface.iterations", "must be >= 1".into());
                    }
                }
                if !(*nu > 0.0 && nu.is_finite()) {
                    return bad("physics.nu", format!("the cylinder flow needs a positive viscosity, got {nu}"));
                }
                if !(*inflow > 0.0 && inflow.is_finite()) {
                    return bad("physics.inflow", format!("must be a positive speed, got {inflow}"));
                }
                if !kick.is_finite() {
                    return bad("physics.kick", format!("must be finite, got {kick}"));
                }
            }
        }
        for (k, o) in self.obstacles.iter().enumerate() {
            match *o {
                Obstacle::Circle { center, radius } => {
                    if !(radius > 0.0 && radius.is_finite()) {
                        return bad(&format!("obstacles[{k}].radius"), format!("must be positive, got {radius}"));
                    }
                    if !self.inside(center, radius) {
                        return bad(
                            &format!("obstacles[{k}].center"),
                            format!(
                                "the circle (centre {center:?}, radius {radius}) is not inside the domain [{}, {}] x [{}, {}]",
                                g.origin[0],
                                g.origin[0] + g.lx,
                                g.origin[1],
                                g.origin[1] + g.ly
                            ),
                        );
                    }
                }
                Obstacle::Box { lower, upper } => {
                    if !(lower[0] < upper[0] && lower[1] < upper[1]) {
                        return bad(
                            &format!("obstacles[{k}].upper"),
                            format!("must exceed lower {lower:?}, got {upper:?}"),
                        );
                    }
                    if !(self.inside(lower, 0.0) && self.inside(upper, 0.0)) {
                        return bad(&format!("obstacles[{k}]"), "the box is not inside the domain".into());
                    }
                }
            }
        }
        let t = &self.time;
        match (t.steps, t.t_end) {
            (Some(0), _) => return bad("time.steps", "must be >= 1".into()),
            (None, None) => return bad("time", "give `steps` or `t_end`".into()),
            (Some(_), Some(_)) => return bad("time", "give `steps` or `t_end`, not both".into()),
            (None, Some(te)) if !(te > 0.0 && te.is_finite()) => {
                return bad("time.t_end", format!("must be positive, got {te}"))
            }
            _ => {}
        }
        if let Some(dt) = t.dt {
            if !(dt > 0.0 && dt.is_finite()) {
                return bad("time.dt", format!("must be positive, got {dt}"));
            }
        }
        if !(t.cfl > 0.0 && t.cfl <= 2.0) {
            return bad("time.cfl", format!("must be in (0, 2], got {}", t.cfl));
        }
        if let Some(s) = t.speed {
            if !(s > 0.0 && s.is_finite()) {
                return bad("time.speed", format!("must be positive, got {s}"));
            }
        }
        if t.frames < 1 {
            return bad("time.frames", "must be >= 1".into());
        }
        self.init.validate(self)?;
        Ok(())
    }

    /// `true` when the disc (centre `c`, radius `r`) lies within the domain.
    fn inside(&self, c: [f64; 2], r: f64) -> bool {
        let g = &self.grid;
        let (x0, y0) = (g.origin[0], g.origin[1]);
        c.iter().all(|v| v.is_finite())
            && c[0] - r >= x0
            && c[0] + r <= x0 + g.lx
            && c[1] - r >= y0
            && c[1] + r <= y0 + g.ly
    }

    /// Builds the stepper and the initial state (see [`Simulation`]).
    pub fn build(&self) -> SceneResult<Simulation> {
        self.validate()?;
        Simulation::new(self.clone())
    }
}
