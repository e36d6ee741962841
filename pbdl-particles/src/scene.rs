//! Scenes: TOML descriptions of particle simulations (defaults embedded from
//! `pbdl-particles/scenes/*.toml`) that build a [`Stepper`] with only the terms they need, and
//! write trajectories (`.npz`) and renders (PNG, GIF).
//!
//! A scene has a `name`, `about`, `frames` (output frames after the initial one), `frame_dt`
//! (time between frames), a `seed` (noise scenes), a `precision` (`"f64"`, the default, or
//! `"f32"`: the solver's particle arrays, see [`Precision`]) and exactly one of the sections
//! `[shock_tube]`, `[dam_break]`, `[periodic_1d]`, `[periodic_2d]`. Unknown keys are errors
//! ([`Error::SceneField`] naming the key), and so are bad values (the field's full path, e.g.
//! `dam_break.geometry.dx`).
//!
//! | built-in | what |
//! |---|---|
//! | `shock_tube` | [`ShockTubeScene`]: 1D grad-h SPH between two states (Sod by default), fixed ghosts |
//! | `dam_break` | [`DamBreakScene`] with WCSPH: Martin & Moyce, H = 2a, wall particles |
//! | `dam_break_iisph` | the same with incompressible IISPH |
//! | `periodic_1d_noise` | [`Periodic1dScene`]: periodic 1D compressible SPH, Perlin-noise density (SFBC test case I style) |
//! | `periodic_2d_box` | [`Periodic2dScene`]: periodic 2D WCSPH, no walls, no gravity, noise-driven velocity (SFBC test case II style) |
//!
//! ```
//! use pbdl_particles::scene::Scene;
//! let scene = Scene::builtin("periodic_2d_box")?;
//! let sim = scene.build(0, None)?;
//! assert!(!sim.operators().contains(&"wall_pressure_extrapolation"));
//! // The same scene in single precision (what `precision = "f32"` or `--precision f32` asks for).
//! let sim32 = scene.build_as::<f32>(0, None)?;
//! assert_eq!(sim32.operators(), sim.operators());
//! # Ok::<(), pbdl_particles::Error>(())
//! ```

use crate::error::{Error, Result};
use crate::iisph::{Iisph, IisphParams};
use crate::neighbors::Domain;
use crate::riemann::GasState;
use crate::sph1d::{ShockTube, Sph1d, Sph1dParams};
use crate::wcsph::{DamBreak, Wcsph, WcsphParams, WcsphPhysics};
use candle_core::{DType, Device, Tensor};
use pbdl_core::Real;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

macro_rules! builtin {
    ($($name:literal),* $(,)?) => {
        &[$(($name, include_str!(concat!("../scenes/", $name, ".toml")))),*]
    };
}

/// The built-in scenes: `(name, TOML text)`.
pub const BUILTIN: &[(&str, &str)] =
    builtin!("shock_tube", "dam_break", "dam_break_iisph", "periodic_1d_noise", "periodic_2d_box");

/// Names of the built-in scenes.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|(n, _)| *n).collect()
}

/// A particle scene (see the module docs for the layout).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Name (output file stem).
    pub name: String,
    /// One line about the scene.
    #[serde(default)]
    pub about: String,
    /// Output frames after the initial one.
    pub frames: usize,
    /// Simulated time between frames.
    pub frame_dt: f64,
    /// Base seed of the noise scenes (run `k` of `--seeds` uses `seed + k`).
    #[serde(default)]
    pub seed: u64,
    /// Precision of the solver's particle arrays, `"f64"` (default) or `"f32"`.
    #[serde(default)]
    pub precision: Precision,
    /// A 1D shock tube.
    #[serde(default)]
    pub shock_tube: Option<ShockTubeScene>,
    /// A 2D dam break.
    #[serde(default)]
    pub dam_break: Option<DamBreakScene>,
    /// A periodic 1D compressible flow with noisy density.
    #[serde(default)]
    pub periodic_1d: Option<Periodic1dScene>,
    /// A periodic 2D weakly compressible box with noisy velocity.
    #[serde(default)]
    pub periodic_2d: Option<Periodic2dScene>,
}

/// The precision of a run (scene key `precision`, `cargo xtask sim particles --precision`).
///
/// Only the particle arrays change: the scene's geometry, noise and initial state are computed
/// in `f64` and rounded once, and the solvers keep time and constants in `f64` (see
/// [`DamBreak::build_as`]). Trajectories keep the run's dtype (see [`write_trajectory`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// Double precision (default).
    #[default]
    F64,
    /// Single precision: half the memory, round-off 6e-8 instead of 1e-16.
    F32,
}

impl Precision {
    /// `"f64"` or `"f32"`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F64 => "f64",
            Precision::F32 => "f32",
        }
    }

    /// Parses `"f64"` or `"f32"` (e.g. a command-line flag).
    ///
    /// Errors: [`Error::Invalid`] naming `precision` for anything else.
    pub fn parse(text: &str) -> Result<Self> {
        match text {
            "f64" => Ok(Precision::F64),
            "f32" => Ok(Precision::F32),
            other => Err(Error::invalid("precision", format!("`{other}`; use \"f64\" or \"f32\""))),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `[shock_tube]`: two gas states meeting at `x0`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShockTubeScene {
    /// Mobile particles (default 450).
    pub n: usize,
    /// State left of `x0` (default Sod: ρ = 1, u = 0, p = 1).
    pub left: GasState,
    /// State right of `x0` (default Sod: ρ = 0.125, u = 0, p = 0.1).
    pub right: GasState,
    /// Adiabatic index (default 1.4; replaces `sph.gamma`).
    pub gamma: f64,
    /// Left end (default -0.5).
    pub x_lo: f64,
    /// Right end (default 0.5).
    pub x_hi: f64,
    /// Initial discontinuity (default 0).
    pub x0: f64,
    /// Solver parameters.
    pub sph: Sph1dParams,
}

impl Default for ShockTubeScene {
    fn default() -> Self {
        let t = ShockTube::sod();
        ShockTubeScene {
            n: 450,
            left: t.left,
            right: t.right,
            gamma: t.gamma,
            x_lo: t.x_lo,
            x_hi: t.x_hi,
            x0: t.x0,
            sph: Sph1dParams::default(),
        }
    }
}

impl ShockTubeScene {
    /// The tube.
    pub fn tube(&self) -> ShockTube {
        ShockTube {
            left: self.left,
            right: self.right,
            gamma: self.gamma,
            x_lo: self.x_lo,
            x_hi: self.x_hi,
            x0: self.x0,
        }
    }
}

/// Which dam-break solver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DamSolver {
    /// Weakly compressible SPH ([`Wcsph`]).
    #[default]
    Wcsph,
    /// Implicit incompressible SPH ([`Iisph`]).
    Iisph,
}

/// `[dam_break]`: geometry and solver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DamBreakScene {
    /// `"wcsph"` (default) or `"iisph"`.
    pub solver: DamSolver,
    /// Geometry and physics.
    pub geometry: DamBreak,
    /// WCSPH parameters (used when `solver = "wcsph"`).
    pub wcsph: WcsphParams,
    /// IISPH parameters (used when `solver = "iisph"`).
    pub iisph: IisphParams,
}

/// `[periodic_1d]`: periodic 1D compressible SPH with a Perlin-noise density.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Periodic1dScene {
    /// Particles (default 2048).
    pub n: usize,
    /// Left end (default -1).
    pub x_lo: f64,
    /// Right end (default 1).
    pub x_hi: f64,
    /// Mean density (default 1000).
    pub rho0: f64,
    /// Sound speed at the mean density (default 10); sets the uniform internal energy
    /// `u0 = c0² / (γ (γ - 1))`.
    pub c0: f64,
    /// Relative density perturbation: `ρ = ρ0 (1 + amplitude n(x))`, `max |n| = 1` (default 0.25).
    pub amplitude: f64,
    /// Noise lattice cells over the domain at the first octave (default 4).
    pub base_cells: usize,
    /// Noise octaves, each with twice the cells and half the amplitude (default 4).
    pub octaves: usize,
    /// Solver parameters (`gamma` is the ideal-gas index).
    pub sph: Sph1dParams,
}

impl Default for Periodic1dScene {
    fn default() -> Self {
        Periodic1dScene {
            n: 2048,
            x_lo: -1.0,
            x_hi: 1.0,
            rho0: 1000.0,
            c0: 10.0,
            amplitude: 0.25,
            base_cells: 4,
            octaves: 4,
            sph: Sph1dParams { eta: 2.0, ..Default::default() },
        }
    }
}

/// `[periodic_2d]`: a periodic square of weakly compressible fluid, no walls, no gravity,
/// divergence-free initial velocity from a Perlin-noise stream function.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Periodic2dScene {
    /// Particles per side (default 48).
    pub n: usize,
    /// Side length (default 1).
    pub length: f64,
    /// Reference density (default 1000).
    pub rho0: f64,
    /// Speed of sound (default 100).
    pub c0: f64,
    /// Largest initial speed (default 2).
    pub u_max: f64,
    /// Noise lattice cells per side at the first octave (default 2).
    pub base_cells: usize,
    /// Noise octaves (default 3).
    pub octaves: usize,
    /// Solver parameters (default α = 0.02, δ = 0.1).
    pub wcsph: WcsphParams,
}

impl Default for Periodic2dScene {
    fn default() -> Self {
        Periodic2dScene {
            n: 48,
            length: 1.0,
            rho0: 1000.0,
            c0: 100.0,
            u_max: 2.0,
            base_cells: 2,
            octaves: 3,
            wcsph: WcsphParams { alpha: 0.02, ..Default::default() },
        }
    }
}

/// Initial particles from a file (`--init`), per particle, row-major `[n, dim]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InitState {
    /// Dimension of positions and velocities.
    pub dim: usize,
    /// Positions `[n * dim]`.
    pub positions: Vec<f64>,
    /// Velocities `[n * dim]` (zero when absent).
    pub velocities: Option<Vec<f64>>,
    /// Masses `[n]` (the scene's when absent).
    pub mass: Option<Vec<f64>>,
    /// Densities `[n]` (the scene's rest state when absent; used by WCSPH).
    pub density: Option<Vec<f64>>,
}

impl InitState {
    /// Reads `positions` (`[n, d]` or a trajectory `[T, n, d]`: its last frame), and optional
    /// `velocities`, `mass`, `density` (`[n]` / `[T, n]`) from `.npz` arrays, widened to `f64`
    /// (exact for `f32` and `f64` arrays).
    pub fn from_arrays(arrays: &[(String, Tensor)]) -> Result<Self> {
        let get = |name: &str| arrays.iter().find(|(n, _)| n == name).map(|(_, t)| t);
        let last = |t: &Tensor, rank: usize| -> Result<Tensor> {
            let t = t.to_dtype(DType::F64)?;
            Ok(if t.rank() == rank + 1 { t.get(t.dim(0)? - 1)? } else { t })
        };
        let pos = get("positions").ok_or_else(|| Error::SceneField {
            scene: "--init".into(),
            field: "positions".into(),
            reason: "missing array `positions` ([n, d] or [T, n, d])".into(),
        })?;
        let pos = last(pos, 2)?;
        let (n, dim) = pos.dims2().map_err(|_| Error::SceneField {
            scene: "--init".into(),
            field: "positions".into(),
            reason: format!("shape {:?}; expected [n, d] or [T, n, d]", pos.dims()),
        })?;
        let read = |name: &'static str, rank: usize, len: usize| -> Result<Option<Vec<f64>>> {
            match get(name) {
                None => Ok(None),
                Some(t) => {
                    let v = last(t, rank)?.flatten_all()?.to_vec1::<f64>()?;
                    if v.len() != len {
                        return Err(Error::Length { op: "--init", arg: name, expected: len, got: v.len() });
                    }
                    Ok(Some(v))
                }
            }
        };
        Ok(InitState {
            dim,
            positions: pos.flatten_all()?.to_vec1::<f64>()?,
            velocities: read("velocities", 2, n * dim)?,
            mass: read("mass", 1, n)?,
            density: read("density", 1, n)?,
        })
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.positions.len() / self.dim.max(1)
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn check(&self, dim: usize, scene: &str) -> Result<()> {
        if self.dim != dim {
            return Err(Error::SceneField {
                scene: scene.into(),
                field: "init.positions".into(),
                reason: format!("{}D positions for a {dim}D scene", self.dim),
            });
        }
        if let Some(m) = &self.mass {
            if let Some(i) = m.iter().position(|&v| !(v > 0.0 && v.is_finite())) {
                return Err(Error::SceneField {
                    scene: scene.into(),
                    field: "init.mass".into(),
                    reason: format!("particle {i} has mass {}; masses must be positive", m[i]),
                });
            }
        }
        Ok(())
    }

    fn points2(&self) -> Vec<[f64; 2]> {
        self.positions.chunks(2).map(|c| [c[0], c[1]]).collect()
    }

    fn velocities2(&self) -> Vec<[f64; 2]> {
        match &self.velocities {
            Some(v) => v.chunks(2).map(|c| [c[0], c[1]]).collect(),
            None => vec![[0.0; 2]; self.len()],
        }
    }

    /// The single mass of a 2D solver (all equal), or `default`.
    fn uniform_mass(&self, default: f64, scene: &str) -> Result<f64> {
        match &self.mass {
            None => Ok(default),
            Some(m) => {
                let m0 = m.first().copied().unwrap_or(default);
                if m.iter().any(|&v| (v - m0).abs() > 1e-12 * m0.abs()) {
                    return Err(Error::SceneField {
                        scene: scene.into(),
                        field: "init.mass".into(),
                        reason: "the 2D solvers need equal masses".into(),
                    });
                }
                Ok(m0)
            }
        }
    }
}

/// One output frame: per particle, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Simulated time.
    pub time: f64,
    /// Positions `[n * dim]`.
    pub positions: Vec<f64>,
    /// Velocities `[n * dim]`.
    pub velocities: Vec<f64>,
    /// Densities `[n]`.
    pub density: Vec<f64>,
    /// Masses `[n]`.
    pub mass: Vec<f64>,
}

/// A built stepper of one of the solvers, in precision `T` (`f32` or `f64`).
#[derive(Clone, Debug)]
pub enum Stepper<T: Real = f64> {
    /// 1D compressible SPH.
    Sph1d(Box<Sph1d<T>>),
    /// 2D weakly compressible SPH.
    Wcsph(Box<Wcsph<T>>),
    /// 2D incompressible SPH.
    Iisph(Box<Iisph<T>>),
}

/// `T` values widened to `f64` (exact).
fn wide<T: Real>(v: &[T]) -> Vec<f64> {
    v.iter().map(|a| a.wide()).collect()
}

/// `[T; 2]` points flattened and widened to `f64`.
fn wide2<T: Real>(v: &[[T; 2]]) -> Vec<f64> {
    v.iter().flat_map(|p| [p[0].wide(), p[1].wide()]).collect()
}

/// `f64` values rounded to `T`.
fn narrow<T: Real>(v: &[f64]) -> Vec<T> {
    v.iter().map(|&a| T::c(a)).collect()
}

/// `f64` points rounded to `T`.
fn narrow2<T: Real>(v: &[[f64; 2]]) -> Vec<[T; 2]> {
    v.iter().map(|p| [T::c(p[0]), T::c(p[1])]).collect()
}

impl<T: Real> Stepper<T> {
    /// Spatial dimension.
    pub fn dim(&self) -> usize {
        match self {
            Stepper::Sph1d(_) => 1,
            _ => 2,
        }
    }

    /// The terms the stepper evaluates (see each solver's `operators`).
    pub fn operators(&self) -> Vec<&'static str> {
        match self {
            Stepper::Sph1d(s) => s.operators(),
            Stepper::Wcsph(s) => s.operators(),
            Stepper::Iisph(s) => s.operators(),
        }
    }

    /// Simulated time.
    pub fn time(&self) -> f64 {
        match self {
            Stepper::Sph1d(s) => s.time(),
            Stepper::Wcsph(s) => s.time(),
            Stepper::Iisph(s) => s.time(),
        }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        match self {
            Stepper::Sph1d(s) => s.steps(),
            Stepper::Wcsph(s) => s.steps(),
            Stepper::Iisph(s) => s.steps(),
        }
    }

    /// Steps with each solver's adaptive stable step until `t_end`.
    pub fn run_until(&mut self, t_end: f64) -> Result<u64> {
        match self {
            Stepper::Sph1d(s) => s.run_until(t_end),
            Stepper::Wcsph(s) => s.run_until(t_end),
            Stepper::Iisph(s) => s.run_until(t_end),
        }
    }

    /// The moving particles now (fluid / mobile only; ghosts and walls are in
    /// [`Stepper::fixed_positions`]), widened to `f64`. IISPH densities are summation densities
    /// at the current positions.
    pub fn frame(&mut self) -> Result<Frame> {
        Ok(match self {
            Stepper::Sph1d(s) => {
                let n = s.n_mobile();
                Frame {
                    time: s.time(),
                    positions: wide(&s.x[..n]),
                    velocities: wide(&s.v[..n]),
                    density: wide(&s.rho[..n]),
                    mass: wide(&s.m[..n]),
                }
            }
            Stepper::Wcsph(s) => {
                let n = s.n_fluid();
                Frame {
                    time: s.time(),
                    positions: wide2(&s.x[..n]),
                    velocities: wide2(&s.v),
                    density: wide(&s.rho[..n]),
                    mass: vec![s.physics().mass; n],
                }
            }
            Stepper::Iisph(s) => {
                let n = s.n_fluid();
                let density = wide(&s.summation_density()?);
                Frame {
                    time: s.time(),
                    positions: wide2(&s.x[..n]),
                    velocities: wide2(&s.v),
                    density,
                    mass: vec![s.mass(); n],
                }
            }
        })
    }

    /// Fixed particles (shock-tube ghosts, walls), row-major `[n_fixed * dim]`, widened to `f64`.
    pub fn fixed_positions(&self) -> Vec<f64> {
        match self {
            Stepper::Sph1d(s) => wide(&s.x[s.n_mobile()..]),
            Stepper::Wcsph(s) => wide2(&s.x[s.n_fluid()..]),
            Stepper::Iisph(s) => wide2(&s.x[s.n_fluid()..]),
        }
    }

    /// The box to draw: `[lo, hi]` (1D: x range and density range are chosen by the renderer).
    pub fn view_box(&self) -> [[f64; 2]; 2] {
        match self {
            Stepper::Sph1d(s) => {
                let d = s.domain();
                [[d.lo[0].wide(), 0.0], [d.hi[0].wide(), 0.0]]
            }
            Stepper::Wcsph(s) => {
                if s.x.len() > s.n_fluid() {
                    let m = 3.0 * s.physics().dx;
                    let [lo, hi] = s.container();
                    [[lo[0] - m, lo[1] - m], [hi[0] + m, hi[1] + m]]
                } else {
                    let d = s.domain();
                    [d.lo.map(Real::wide), d.hi.map(Real::wide)]
                }
            }
            Stepper::Iisph(s) => {
                let m = 3.0 * s.dx();
                let [lo, hi] = s.container();
                [[lo[0] - m, lo[1] - m], [hi[0] + m, hi[1] + m]]
            }
        }
    }

    /// Particle spacing (for render disc sizes).
    pub fn spacing(&self) -> f64 {
        match self {
            Stepper::Sph1d(s) => {
                let d = s.domain();
                (d.hi[0].wide() - d.lo[0].wide()) / s.x.len().max(1) as f64
            }
            Stepper::Wcsph(s) => s.physics().dx,
            Stepper::Iisph(s) => s.dx(),
        }
    }
}

fn field_err(scene: &str, section: &str, e: Error) -> Error {
    match e {
        Error::Invalid { field, reason } => {
            Error::SceneField { scene: scene.into(), field: format!("{section}.{field}"), reason }
        }
        e => e,
    }
}

fn scene_err(scene: &str, field: &str, reason: impl Into<String>) -> Error {
    Error::SceneField { scene: scene.into(), field: field.into(), reason: reason.into() }
}

/// The key of the `key = value` whose value starts at byte `at` of `text` (where toml points
/// a bad value), if the text before it on that line ends in `key =`.
fn key_of_value_at(text: &str, at: usize) -> Option<String> {
    let before = text.get(..at)?;
    let line = &before[before.rfind('\n').map_or(0, |i| i + 1)..];
    let lhs = line.trim_end().strip_suffix('=')?.trim_end();
    let start = lhs.rfind(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '-')).map_or(0, |i| i + 1);
    let key = &lhs[start..];
    (!key.is_empty()).then(|| key.to_string())
}

impl Scene {
    /// Parses a scene from TOML text; `origin` names it in errors. An unknown key, or a bad
    /// value (e.g. `precision = "f16"`), gives [`Error::SceneField`] with that key.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self> {
        let scene: Scene = toml::from_str(text).map_err(|e| {
            let msg = e.message().to_string();
            let field = msg
                .strip_prefix("unknown field `")
                .and_then(|r| r.split('`').next())
                .map(str::to_string)
                .or_else(|| msg.strip_prefix("missing field `").and_then(|r| r.split('`').next()).map(str::to_string))
                .or_else(|| e.span().and_then(|span| key_of_value_at(text, span.start)));
            match field {
                Some(field) => Error::SceneField { scene: origin.into(), field, reason: e.to_string() },
                None => Error::Scene(format!("{origin}: {e}")),
            }
        })?;
        scene.validate()?;
        Ok(scene)
    }

    /// A built-in scene by name.
    pub fn builtin(name: &str) -> Result<Self> {
        match BUILTIN.iter().find(|(n, _)| *n == name) {
            Some((n, text)) => Self::from_toml_str(text, n),
            None => Err(Error::Scene(format!("unknown scene `{name}`; built-in: {}", builtin_names().join(", ")))),
        }
    }

    /// A built-in scene name or a path to a `.toml` file.
    pub fn load(name_or_path: &str) -> Result<Self> {
        if name_or_path.ends_with(".toml") || Path::new(name_or_path).is_file() {
            let text = std::fs::read_to_string(name_or_path)
                .map_err(|e| Error::Scene(format!("cannot read {name_or_path}: {e}")))?;
            Self::from_toml_str(&text, name_or_path)
        } else {
            Self::builtin(name_or_path)
        }
    }

    /// Checks the common fields and that exactly one section is present.
    pub fn validate(&self) -> Result<()> {
        let n = &self.name;
        if self.name.is_empty() {
            return Err(scene_err(n, "name", "must not be empty"));
        }
        if !(self.frame_dt > 0.0 && self.frame_dt.is_finite()) {
            return Err(scene_err(n, "frame_dt", format!("{}; must be positive", self.frame_dt)));
        }
        if self.frames == 0 {
            return Err(scene_err(n, "frames", "at least one frame"));
        }
        let count = [
            self.shock_tube.is_some(),
            self.dam_break.is_some(),
            self.periodic_1d.is_some(),
            self.periodic_2d.is_some(),
        ]
        .iter()
        .filter(|&&b| b)
        .count();
        if count != 1 {
            return Err(scene_err(
                n,
                "shock_tube",
                format!(
                    "{count} sections; give exactly one of [shock_tube], [dam_break], [periodic_1d], [periodic_2d]"
                ),
            ));
        }
        Ok(())
    }

    /// The end time `frames * frame_dt`.
    pub fn t_end(&self) -> f64 {
        self.frames as f64 * self.frame_dt
    }

    /// The same scene with `frames` output frames (the frame interval is kept).
    pub fn with_frames(mut self, frames: usize) -> Self {
        self.frames = frames.max(1);
        self
    }

    /// The same scene in `precision` (e.g. from `--precision`).
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    /// Builds the `f64` stepper for run `seed` (added to the scene's seed), optionally from
    /// initial particles (`--init`). This ignores [`Scene::precision`]: to honour it, match on
    /// it and call [`Scene::build_as`] with `f32` or `f64`.
    ///
    /// Errors: [`Error::SceneField`] naming the field for bad values,
    /// [`Error::OutsideDomain`] for initial particles outside the box.
    pub fn build(&self, seed: u64, init: Option<&InitState>) -> Result<Stepper> {
        self.build_as::<f64>(seed, init)
    }

    /// Builds the stepper in precision `T` (`f32` or `f64`); as [`Scene::build`] otherwise.
    /// Initial states (noise, layouts, `--init` arrays) are computed in `f64` and rounded once,
    /// so `f32` values read back from an `f32` trajectory are restored exactly.
    ///
    /// Errors: as [`Scene::build`].
    pub fn build_as<T: Real>(&self, seed: u64, init: Option<&InitState>) -> Result<Stepper<T>> {
        self.validate()?;
        let name = self.name.as_str();
        let seed = self.seed.wrapping_add(seed);
        if let Some(st) = &self.shock_tube {
            if init.is_some() {
                return Err(scene_err(name, "init", "--init is not supported for shock tubes (use periodic_1d)"));
            }
            let sim = st.tube().build_as::<T>(st.n, st.sph).map_err(|e| match e {
                Error::Invalid { field, reason } if ["eta", "alpha", "cfl", "kernel"].contains(&field) => {
                    scene_err(name, &format!("shock_tube.sph.{field}"), reason)
                }
                e => field_err(name, "shock_tube", e),
            })?;
            return Ok(Stepper::Sph1d(Box::new(sim)));
        }
        if let Some(db) = &self.dam_break {
            return build_dam_break(name, db, init);
        }
        if let Some(p) = &self.periodic_1d {
            return build_periodic_1d(name, p, seed, init);
        }
        if let Some(p) = &self.periodic_2d {
            return build_periodic_2d(name, p, seed, init);
        }
        unreachable!("validate checks that one section is present")
    }
}

fn build_dam_break<T: Real>(name: &str, db: &DamBreakScene, init: Option<&InitState>) -> Result<Stepper<T>> {
    let sec = "dam_break.geometry";
    let mut stepper =
        match db.solver {
            DamSolver::Wcsph => Stepper::Wcsph(Box::new(db.geometry.build_as::<T>(db.wcsph).map_err(|e| match e {
                Error::Invalid { field, reason } if ["h_over_dx", "alpha", "delta", "cfl"].contains(&field) => {
                    scene_err(name, &format!("dam_break.wcsph.{field}"), reason)
                }
                e => field_err(name, sec, e),
            })?)),
            DamSolver::Iisph => Stepper::Iisph(Box::new(db.geometry.build_iisph_as::<T>(db.iisph).map_err(|e| {
                match e {
                    Error::Invalid { field, reason }
                        if ["h_over_dx", "cfl", "dt_max", "tolerance", "max_iterations", "omega", "nu"]
                            .contains(&field) =>
                    {
                        Error::SceneField { scene: name.into(), field: format!("dam_break.iisph.{field}"), reason }
                    }
                    e => field_err(name, sec, e),
                }
            })?)),
        };
    if let Some(init) = init {
        init.check(2, name)?;
        let x = narrow2::<T>(&init.points2());
        let v = narrow2::<T>(&init.velocities2());
        stepper = match stepper {
            Stepper::Wcsph(s) => {
                let walls = s.x[s.n_fluid()..].to_vec();
                let nf = x.len();
                let mut phys = *s.physics();
                phys.mass = init.uniform_mass(phys.mass, name)?;
                let rho = match &init.density {
                    Some(d) => narrow(d),
                    None => vec![T::c(phys.rho0); nf],
                };
                let all: Vec<[T; 2]> = x.into_iter().chain(walls).collect();
                let rho: Vec<T> = rho.into_iter().chain(std::iter::repeat_n(T::c(phys.rho0), all.len() - nf)).collect();
                Stepper::Wcsph(Box::new(Wcsph::new(
                    *s.params(),
                    phys,
                    all,
                    v,
                    rho,
                    nf,
                    container_domain(s.container()),
                    s.container(),
                )?))
            }
            Stepper::Iisph(s) => {
                let walls = s.x[s.n_fluid()..].to_vec();
                let nf = x.len();
                let all: Vec<[T; 2]> = x.into_iter().chain(walls).collect();
                Stepper::Iisph(Box::new(Iisph::new(
                    *s.params(),
                    s.rho0(),
                    s.dx(),
                    [0.0, -db.geometry.g],
                    all,
                    v,
                    nf,
                    container_domain(s.container()),
                    s.container(),
                )?))
            }
            s => s,
        };
        // Fluid must start inside the tank.
        let [lo, hi] = match &stepper {
            Stepper::Wcsph(s) => s.container(),
            Stepper::Iisph(s) => s.container(),
            Stepper::Sph1d(_) => unreachable!(),
        };
        for (i, p) in init.points2().iter().enumerate() {
            if !(p[0] >= lo[0] && p[0] <= hi[0] && p[1] >= lo[1] && p[1] <= hi[1]) {
                return Err(Error::OutsideDomain { index: i, position: p.to_vec(), lo: lo.to_vec(), hi: hi.to_vec() });
            }
        }
    }
    Ok(stepper)
}

/// The search box around a tank (walls included).
fn container_domain<T: Real>(c: [[f64; 2]; 2]) -> Domain<T, 2> {
    let m = 0.2 * (c[1][0] - c[0][0]).max(c[1][1] - c[0][1]);
    Domain::bounded([T::c(c[0][0] - m), T::c(c[0][1] - m)], [T::c(c[1][0] + m), T::c(c[1][1] + m)])
}

fn build_periodic_1d<T: Real>(
    name: &str,
    p: &Periodic1dScene,
    seed: u64,
    init: Option<&InitState>,
) -> Result<Stepper<T>> {
    let sec = "periodic_1d";
    let f = |field: &str, reason: String| scene_err(name, &format!("{sec}.{field}"), reason);
    if !(p.x_lo.is_finite() && p.x_hi.is_finite() && p.x_hi > p.x_lo) {
        return Err(f("x_hi", format!("need x_lo < x_hi, got {} {}", p.x_lo, p.x_hi)));
    }
    if !(p.rho0 > 0.0 && p.rho0.is_finite()) {
        return Err(f("rho0", format!("{}; must be positive", p.rho0)));
    }
    if !(p.c0 > 0.0 && p.c0.is_finite()) {
        return Err(f("c0", format!("{}; must be positive", p.c0)));
    }
    if !(0.0..1.0).contains(&p.amplitude) {
        return Err(f("amplitude", format!("{}; use 0 <= amplitude < 1", p.amplitude)));
    }
    if p.n < 16 {
        return Err(f("n", format!("{}; use at least 16 particles", p.n)));
    }
    if p.base_cells == 0 || p.octaves == 0 {
        return Err(f("base_cells", "base_cells and octaves must be at least 1".into()));
    }
    let gamma = p.sph.gamma;
    if !(gamma > 1.0 && gamma.is_finite()) {
        return Err(f("sph.gamma", format!("{gamma}; the adiabatic index must exceed 1")));
    }
    let u0 = p.c0 * p.c0 / (gamma * (gamma - 1.0));
    let len = p.x_hi - p.x_lo;
    let domain = Domain::periodic([T::c(p.x_lo)], [T::c(p.x_hi)]);
    let (x, v, m) = match init {
        Some(init) => {
            init.check(1, name)?;
            let n = init.len();
            let mass = init.mass.clone().unwrap_or_else(|| vec![p.rho0 * len / n as f64; n]);
            (init.positions.clone(), init.velocities.clone().unwrap_or_else(|| vec![0.0; n]), mass)
        }
        None => {
            // Equal masses placed by inverting the cumulative mass of ρ(x).
            let noise = |x: f64| {
                let mut s = 0.0;
                for o in 0..p.octaves {
                    let cells = p.base_cells << o;
                    s += 0.5f64.powi(o as i32) * perlin1(seed, o as u64, (x - p.x_lo) / len * cells as f64, cells);
                }
                s
            };
            let fine = 64 * p.n;
            let samples: Vec<f64> = (0..fine).map(|k| noise(p.x_lo + (k as f64 + 0.5) * len / fine as f64)).collect();
            let nmax = samples.iter().fold(0.0f64, |a, &b| a.max(b.abs())).max(1e-300);
            let rho: Vec<f64> = samples.iter().map(|s| p.rho0 * (1.0 + p.amplitude * s / nmax)).collect();
            let cell = len / fine as f64;
            let total: f64 = rho.iter().sum::<f64>() * cell;
            let mass = total / p.n as f64;
            let mut x = Vec::with_capacity(p.n);
            let (mut k, mut acc) = (0usize, 0.0);
            for i in 0..p.n {
                let target = (i as f64 + 0.5) * mass;
                while k < fine - 1 && acc + rho[k] * cell < target {
                    acc += rho[k] * cell;
                    k += 1;
                }
                let frac = ((target - acc) / (rho[k] * cell)).clamp(0.0, 1.0);
                x.push(p.x_lo + (k as f64 + frac) * cell);
            }
            (x, vec![0.0; p.n], vec![mass; p.n])
        }
    };
    let n = x.len();
    let sim = Sph1d::new(p.sph, narrow(&x), narrow(&v), vec![T::c(u0); n], narrow(&m), None, n, domain).map_err(
        |e| match e {
            Error::Invalid { field: "m", reason } => scene_err(name, "init.mass", reason),
            e => field_err(name, "periodic_1d.sph", e),
        },
    )?;
    Ok(Stepper::Sph1d(Box::new(sim)))
}

fn build_periodic_2d<T: Real>(
    name: &str,
    p: &Periodic2dScene,
    seed: u64,
    init: Option<&InitState>,
) -> Result<Stepper<T>> {
    let sec = "periodic_2d";
    let f = |field: &str, reason: String| scene_err(name, &format!("{sec}.{field}"), reason);
    if !(p.length > 0.0 && p.length.is_finite()) {
        return Err(f("length", format!("{}; must be positive", p.length)));
    }
    if !(p.rho0 > 0.0 && p.rho0.is_finite()) {
        return Err(f("rho0", format!("{}; must be positive", p.rho0)));
    }
    if !(p.c0 > 0.0 && p.c0.is_finite()) {
        return Err(f("c0", format!("{}; must be positive", p.c0)));
    }
    if !(p.u_max >= 0.0 && p.u_max.is_finite()) {
        return Err(f("u_max", format!("{}; must be non-negative", p.u_max)));
    }
    if p.n < 8 {
        return Err(f("n", format!("{}; use at least 8 particles per side", p.n)));
    }
    if p.base_cells == 0 || p.octaves == 0 {
        return Err(f("base_cells", "base_cells and octaves must be at least 1".into()));
    }
    let l = p.length;
    let dx = l / p.n as f64;
    let domain = Domain::periodic([T::zero(); 2], [T::c(l); 2]);
    let mut phys = WcsphPhysics { rho0: p.rho0, c0: p.c0, gravity: [0.0, 0.0], mass: p.rho0 * dx * dx, dx };
    let (x, v, rho) = match init {
        Some(init) => {
            init.check(2, name)?;
            phys.mass = init.uniform_mass(phys.mass, name)?;
            let n = init.len();
            (init.points2(), init.velocities2(), init.density.clone().unwrap_or_else(|| vec![p.rho0; n]))
        }
        None => {
            let psi = |x: [f64; 2]| {
                let mut s = 0.0;
                for o in 0..p.octaves {
                    let cells = p.base_cells << o;
                    let c = cells as f64 / l;
                    s += 0.5f64.powi(o as i32) * perlin2(seed, o as u64, [x[0] * c, x[1] * c], cells);
                }
                s
            };
            let eps = 1e-5 * l;
            let mut x = Vec::with_capacity(p.n * p.n);
            let mut v = Vec::with_capacity(p.n * p.n);
            for j in 0..p.n {
                for i in 0..p.n {
                    let q = [(i as f64 + 0.5) * dx, (j as f64 + 0.5) * dx];
                    let dpy = (psi([q[0], q[1] + eps]) - psi([q[0], q[1] - eps])) / (2.0 * eps);
                    let dpx = (psi([q[0] + eps, q[1]]) - psi([q[0] - eps, q[1]])) / (2.0 * eps);
                    x.push(q);
                    v.push([dpy, -dpx]);
                }
            }
            let n = v.len() as f64;
            let mean = v.iter().fold([0.0; 2], |a, w| [a[0] + w[0] / n, a[1] + w[1] / n]);
            let vmax =
                v.iter().fold(0.0f64, |a, w| a.max(((w[0] - mean[0]).powi(2) + (w[1] - mean[1]).powi(2)).sqrt()));
            let s = if vmax > 0.0 { p.u_max / vmax } else { 0.0 };
            for w in &mut v {
                *w = [(w[0] - mean[0]) * s, (w[1] - mean[1]) * s];
            }
            let nn = x.len();
            (x, v, vec![p.rho0; nn])
        }
    };
    let nf = x.len();
    let sim = Wcsph::new(p.wcsph, phys, narrow2(&x), narrow2(&v), narrow(&rho), nf, domain, [[0.0, 0.0], [l, l]])
        .map_err(|e| field_err(name, "periodic_2d.wcsph", e))?;
    Ok(Stepper::Wcsph(Box::new(sim)))
}

/// SplitMix64 hash of `(seed, octave, lattice index)` to `[-1, 1)`.
fn hash(seed: u64, octave: u64, i: u64, j: u64) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(octave.wrapping_mul(0xBF58_476D_1CE4_E5B9))
        .wrapping_add(i.wrapping_mul(0x94D0_49BB_1331_11EB))
        .wrapping_add(j.wrapping_mul(0x2545_F491_4F6C_DD1D));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Periodic 1D Perlin gradient noise at `u` in lattice units (period `cells`).
fn perlin1(seed: u64, octave: u64, u: f64, cells: usize) -> f64 {
    let i0 = u.floor();
    let t = u - i0;
    let c = cells as i64;
    let k0 = (i0 as i64).rem_euclid(c) as u64;
    let k1 = ((i0 as i64) + 1).rem_euclid(c) as u64;
    let (g0, g1) = (hash(seed, octave, k0, 0), hash(seed, octave, k1, 0));
    let (a, b) = (g0 * t, g1 * (t - 1.0));
    a + fade(t) * (b - a)
}

/// Periodic 2D Perlin gradient noise at `u` in lattice units (period `cells` per side).
fn perlin2(seed: u64, octave: u64, u: [f64; 2], cells: usize) -> f64 {
    let c = cells as i64;
    let i0 = [u[0].floor(), u[1].floor()];
    let t = [u[0] - i0[0], u[1] - i0[1]];
    let corner = |di: i64, dj: i64| {
        let i = ((i0[0] as i64) + di).rem_euclid(c) as u64;
        let j = ((i0[1] as i64) + dj).rem_euclid(c) as u64;
        let ang = std::f64::consts::PI * hash(seed, octave, i, j);
        let (gx, gy) = (ang.cos(), ang.sin());
        gx * (t[0] - di as f64) + gy * (t[1] - dj as f64)
    };
    let (sx, sy) = (fade(t[0]), fade(t[1]));
    let a = corner(0, 0) + sx * (corner(1, 0) - corner(0, 0));
    let b = corner(0, 1) + sx * (corner(1, 1) - corner(0, 1));
    a + sy * (b - a)
}

/// Runs `stepper` for the scene's frames and returns the initial frame plus one per
/// `frame_dt`; `on_frame(k)` is called after frame `k`.
pub fn run_frames<T: Real>(
    scene: &Scene,
    stepper: &mut Stepper<T>,
    mut on_frame: impl FnMut(usize),
) -> Result<Vec<Frame>> {
    let mut frames = vec![stepper.frame()?];
    let t0 = stepper.time();
    for k in 1..=scene.frames {
        stepper.run_until(t0 + k as f64 * scene.frame_dt)?;
        frames.push(stepper.frame()?);
        on_frame(k);
    }
    Ok(frames)
}

/// Writes `<dir>/<stem>.npz` with `positions` `[T, N, D]`, `velocities` `[T, N, D]`,
/// `density` `[T, N]`, `mass` `[T, N]`, `time` `[T]` and `fixed_positions` `[F, D]` (walls,
/// ghosts; absent when there are none); plus, with the `viz` feature (on by default),
/// `<stem>.png` (last frame) and `<stem>.gif` (all frames): particles coloured by speed (2D) or
/// density against x coloured by velocity (1D).
/// Returns the files written.
///
/// Dtypes: the particle arrays have the stepper's precision (`f64`, or `f32` for an `f32` run:
/// the solver's own values, so [`InitState::from_arrays`] and [`Scene::build_as`] in the same
/// precision restore positions, velocities and densities exactly; the 2D solvers' mass is an
/// `f64` constant, written rounded to `f32`, the value the `f32` solver computes with).
/// `time` is always `f64` (the solvers keep time in `f64`).
pub fn write_trajectory<T: Real>(
    stepper: &Stepper<T>,
    frames: &[Frame],
    dir: &Path,
    stem: &str,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::Scene(format!("cannot create {}: {e}", dir.display())))?;
    let dim = stepper.dim();
    let t = frames.len();
    let n = frames.first().map(|f| f.mass.len()).unwrap_or(0);
    let dev = Device::Cpu;
    let stack = |get: &dyn Fn(&Frame) -> &[f64], shape: Vec<usize>| -> Result<Tensor> {
        let data: Vec<f64> = frames.iter().flat_map(|f| get(f).iter().copied()).collect();
        Ok(Tensor::from_vec(data, shape, &dev)?.to_dtype(T::DTYPE)?)
    };
    let mut arrays = vec![
        ("positions".to_string(), stack(&|f| &f.positions, vec![t, n, dim])?),
        ("velocities".to_string(), stack(&|f| &f.velocities, vec![t, n, dim])?),
        ("density".to_string(), stack(&|f| &f.density, vec![t, n])?),
        ("mass".to_string(), stack(&|f| &f.mass, vec![t, n])?),
        ("time".to_string(), Tensor::from_vec(frames.iter().map(|f| f.time).collect::<Vec<_>>(), t, &dev)?),
    ];
    let fixed = stepper.fixed_positions();
    if !fixed.is_empty() {
        let nf = fixed.len() / dim;
        let fixed_t = Tensor::from_vec(fixed.clone(), vec![nf, dim], &dev)?.to_dtype(T::DTYPE)?;
        arrays.push(("fixed_positions".to_string(), fixed_t));
    }
    let npz = dir.join(format!("{stem}.npz"));
    pbdl_core::io::write_npz(&npz, &arrays)?;
    #[cfg(not(feature = "viz"))]
    return Ok(vec![npz]);
    #[cfg(feature = "viz")]
    {
        let [png, gif] = render_png_gif(stepper, frames, &fixed, dir, stem)?;
        Ok(vec![npz, png, gif])
    }
}

/// The last frame as a PNG and the rollout as a GIF (scatter rasters, shared colour range).
#[cfg(feature = "viz")]
fn render_png_gif<T: Real>(
    stepper: &Stepper<T>,
    frames: &[Frame],
    fixed: &[f64],
    dir: &Path,
    stem: &str,
) -> Result<[PathBuf; 2]> {
    let rasters = render_frames(stepper, frames, fixed);
    let (h, w) = (rasters[0].h, rasters[0].w);
    let vmax = rasters.iter().flat_map(|r| r.data.iter()).filter(|v| v.is_finite()).fold(0.0f64, |a, &b| a.max(b));
    let vmin = rasters.iter().flat_map(|r| r.data.iter()).filter(|v| v.is_finite()).fold(vmax, |a, &b| a.min(b));
    let range = if vmax > vmin { (vmin, vmax) } else { (vmin - 1.0, vmin + 1.0) };
    let style = pbdl_core::viz::FieldStyle {
        range: pbdl_core::viz::ColorRange::Fixed(range.0, range.1),
        nan_color: [255, 255, 255],
        ..Default::default()
    };
    let png = dir.join(format!("{stem}.png"));
    let last = rasters.last().expect("at least one frame");
    pbdl_core::viz::field_to_png(&png, &last.data, h, w, &style)?;
    let gif = dir.join(format!("{stem}.gif"));
    let data: Vec<&[f64]> = rasters.iter().map(|r| r.data.as_slice()).collect();
    pbdl_core::viz::rollout_to_gif(
        &gif,
        &data,
        h,
        w,
        &pbdl_core::viz::GifStyle { field: style, frame_delay_ms: 80, repeat: true },
    )?;
    Ok([png, gif])
}

#[cfg(feature = "viz")]
/// Scatter rasters of the frames: 2D particles coloured by speed (walls at the lowest value);
/// 1D: density against x, coloured by velocity.
fn render_frames<T: Real>(stepper: &Stepper<T>, frames: &[Frame], fixed: &[f64]) -> Vec<crate::render::Raster> {
    let [lo, hi] = stepper.view_box();
    if stepper.dim() == 1 {
        let (rmin, rmax) = frames
            .iter()
            .flat_map(|f| f.density.iter())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &r| (a.min(r), b.max(r)));
        let span = (rmax - rmin).max(1e-12 * rmax.abs().max(1.0));
        let width = hi[0] - lo[0];
        let height = 0.5 * width;
        let ppu = 400.0 / width;
        frames
            .iter()
            .map(|f| {
                let pts: Vec<[f64; 2]> = f
                    .positions
                    .iter()
                    .zip(&f.density)
                    .map(|(&x, &r)| [x, 0.05 * height + 0.9 * height * (r - rmin) / span])
                    .collect();
                crate::render::scatter(&pts, &f.velocities, [lo[0], 0.0], [hi[0], height], ppu, 1.0)
            })
            .collect()
    } else {
        let ppu = 240.0 / (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let walls: Vec<[f64; 2]> = fixed.chunks(2).map(|c| [c[0], c[1]]).collect();
        let r = (0.75 * stepper.spacing() * ppu).max(0.6);
        frames
            .iter()
            .map(|f| {
                let mut pts = walls.clone();
                let mut vals = vec![0.0; walls.len()];
                pts.extend(f.positions.chunks(2).map(|c| [c[0], c[1]]));
                vals.extend(f.velocities.chunks(2).map(|c| (c[0] * c[0] + c[1] * c[1]).sqrt()));
                crate::render::scatter(&pts, &vals, lo, hi, ppu, r)
            })
            .collect()
    }
}
