//! Scenes: TOML descriptions of particle simulations (defaults embedded from
//! `pbdl-particles/scenes/*.toml`) that build a [`Stepper`] with only the terms they need, and
//! write trajectories (`.npz`) and renders (PNG, GIF).
//!
//! A scene has a `name`, `about`, `frames` (output frames after the initial one), `frame_dt`
//! (time between frames), a `seed` (noise scenes), a `precision` (`"f64"`, the default, or
//! `"f32"`: the solver's particle arrays, see [`Precision`]) and exactly one of the sections
//! `[shock_tube]`, `[dam_break]`, `[periodic_1d]`, `[periodic_2d]`, `[dam_break_3d]`,
//! `[block_drop_3d]`. Unknown keys are errors
//! ([`Error::SceneField`] naming the key), and so are bad values (the field's full path, e.g.
//! `dam_break.geometry.dx`).
//!
//! | built-in | what |
//! |---|---|
//! | `shock_tube` | [`ShockTubeScene`]: 1D grad-h SPH between two states (Sod by default), fixed ghosts or, when an end state moves, buffers moving with it |
//! | `dam_break` | [`DamBreakScene`] with WCSPH: Martin & Moyce, H = 2a, wall particles |
//! | `dam_break_iisph` | the same with incompressible IISPH |
//! | `dam_break_dfsph` | the same with divergence-free SPH (DFSPH) |
//! | `periodic_1d_noise` | [`Periodic1dScene`]: periodic 1D compressible SPH, Perlin-noise density (SFBC test case I style) |
//! | `periodic_2d_box` | [`Periodic2dScene`]: periodic 2D WCSPH, no walls, no gravity, noise-driven velocity (SFBC test case II style) |
//! | `dam_break_3d` | [`DamBreak3dScene`]: the 3D dam break (quasi-2D column between free-slip side walls) with 3D WCSPH, coarse (dx = a/10) |
//! | `block_drop_3d` | [`BlockDrop3dScene`]: a block of water dropped into a closed box, 3D WCSPH |
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
//!
//! | file | what |
//! |---|---|
//! | `mod.rs` | the serde scene types ([`Scene`], its sections, [`Precision`]) and loading ([`Scene::load`], [`Scene::builtin`]) |
//! | `init.rs` | [`InitState`]: initial particles read from `.npz` arrays (`--init`) |
//! | `build.rs` | [`Scene::build`] / [`Scene::build_as`]: the solvers built from the sections (the noise scenes' Perlin noise is [`pbdl_core::noise::perlin_1d`] / [`perlin_2d`](pbdl_core::noise::perlin_2d)) |
//! | `stepper.rs` | [`Stepper`] (one of the solvers; implements [`Evolve`](pbdl_core::stepper::Evolve)), [`Frame`], [`run_frames`] |
//! | `output.rs` | [`write_trajectory`]: `.npz` and, with the `viz` feature, PNG/GIF renders |

mod build;
mod init;
mod output;
mod stepper;

pub use init::InitState;
pub use output::write_trajectory;
pub use stepper::{run_frames, Frame, Stepper};

use crate::dfsph::DfsphParams;
use crate::error::{Error, Result};
use crate::iisph::IisphParams;
use crate::riemann::GasState;
use crate::sph1d::{ShockTube, Sph1dParams};
use crate::wcsph::{DamBreak, WcsphParams};
use crate::wcsph3d::{BlockDrop3d, DamBreak3d, Wcsph3dParams};
use serde::{Deserialize, Serialize};
use std::path::Path;

macro_rules! builtin {
    ($($name:literal),* $(,)?) => {
        &[$(($name, include_str!(concat!("../../scenes/", $name, ".toml")))),*]
    };
}

/// The built-in scenes: `(name, TOML text)`.
pub const BUILTIN: &[(&str, &str)] = builtin!(
    "shock_tube",
    "dam_break",
    "dam_break_iisph",
    "dam_break_dfsph",
    "periodic_1d_noise",
    "periodic_2d_box",
    "dam_break_3d",
    "block_drop_3d",
);

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
    /// A 3D dam break.
    #[serde(default)]
    pub dam_break_3d: Option<DamBreak3dScene>,
    /// Fluid bodies dropped into a closed 3D box.
    #[serde(default)]
    pub block_drop_3d: Option<BlockDrop3dScene>,
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

/// `[shock_tube]`: two gas states meeting at `x0`; end states may move (velocities of either
/// sign: the buffers beyond the ends move with them, see [`crate::sph1d`]).
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
    /// Weakly compressible SPH ([`Wcsph`](crate::Wcsph)).
    #[default]
    Wcsph,
    /// Implicit incompressible SPH ([`Iisph`](crate::Iisph)).
    Iisph,
    /// Divergence-free SPH ([`Dfsph`](crate::dfsph::Dfsph)).
    Dfsph,
}

/// `[dam_break]`: geometry and solver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DamBreakScene {
    /// `"wcsph"` (default), `"iisph"` or `"dfsph"`.
    pub solver: DamSolver,
    /// Geometry and physics.
    pub geometry: DamBreak,
    /// WCSPH parameters (used when `solver = "wcsph"`).
    pub wcsph: WcsphParams,
    /// IISPH parameters (used when `solver = "iisph"`).
    pub iisph: IisphParams,
    /// DFSPH parameters (used when `solver = "dfsph"`).
    pub dfsph: DfsphParams,
}

/// `[dam_break_3d]`: the 3D dam break ([`DamBreak3d`]) with 3D WCSPH or DFSPH.
///
/// `solver = "iisph"` is an error naming `dam_break_3d.solver` (IISPH has no 3D stepper).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DamBreak3dScene {
    /// `"wcsph"` (default) or `"dfsph"`.
    pub solver: DamSolver,
    /// Geometry and physics (`[dam_break_3d.geometry]`, the fields of [`DamBreak3d`]).
    pub geometry: DamBreak3d,
    /// 3D WCSPH parameters (used when `solver = "wcsph"`).
    pub wcsph: Wcsph3dParams,
    /// DFSPH parameters (used when `solver = "dfsph"`): keys not given keep
    /// [`DfsphParams::default_3d`]'s values (so a partial table keeps the 3D `omega`).
    #[serde(deserialize_with = "dfsph_over_default_3d")]
    pub dfsph: DfsphParams,
}

/// A `[dam_break_3d.dfsph]` table over [`DfsphParams::default_3d`] (its keys replace the
/// defaults'; unknown keys and bad values are errors as for any table).
fn dfsph_over_default_3d<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<DfsphParams, D::Error> {
    use serde::de::Error as _;
    let given = toml::Table::deserialize(d)?;
    let table = toml::Table::try_from(DfsphParams::default_3d()).map_err(D::Error::custom)?;
    let over = |keys: toml::Table| {
        let mut t = table.clone();
        t.extend(keys);
        DfsphParams::deserialize(t)
    };
    over(given.clone()).map_err(|e| {
        // Name the key whose value is bad (the span is the table's, not the value's).
        let bad = given
            .iter()
            .find_map(|(k, v)| over(toml::Table::from_iter([(k.clone(), v.clone())])).err().map(|e| (k.clone(), e)));
        match bad {
            Some((key, e)) if !e.message().starts_with("unknown field") => {
                D::Error::custom(format!("{VALUE_ERROR_PREFIX}{key}`: {}", e.message()))
            }
            _ => D::Error::custom(e.message()),
        }
    })
}

/// How [`dfsph_over_default_3d`] starts an error naming a key with a bad value (read back by
/// [`Scene::from_toml_str`]).
const VALUE_ERROR_PREFIX: &str = "invalid value for `";

impl Default for DamBreak3dScene {
    fn default() -> Self {
        DamBreak3dScene {
            solver: DamSolver::Wcsph,
            geometry: DamBreak3d::default(),
            wcsph: Wcsph3dParams::default(),
            dfsph: DfsphParams::default_3d(),
        }
    }
}

/// `[block_drop_3d]`: fluid blocks and balls dropped into a closed box ([`BlockDrop3d`]) with
/// 3D WCSPH. `[block_drop_3d.geometry]` has every field of [`BlockDrop3d`] (`wall_layers`
/// optional), the bodies as an array of tables:
///
/// ```toml
/// [[block_drop_3d.geometry.bodies]]
/// velocity = [0.0, 0.0, 0.0]
/// shape = { block = { lo = [0.3, 0.5, 0.3], hi = [0.7, 0.9, 0.7] } }
/// # or: shape = { sphere = { center = [0.5, 0.5, 0.5], radius = 0.2 } }
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BlockDrop3dScene {
    /// Box, spacing, bodies and physics (default [`BlockDrop3d::default`]).
    pub geometry: BlockDrop3d,
    /// 3D WCSPH parameters.
    pub wcsph: Wcsph3dParams,
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

fn scene_err(scene: &str, field: &str, reason: impl Into<String>) -> Error {
    Error::SceneField { scene: scene.into(), field: field.into(), reason: reason.into() }
}

/// The key of the `key = value` whose value starts at byte `at` of `text` (where toml points
/// a bad value), if the text before it on that line ends in `key =`.
fn key_of_value_at(text: &str, at: usize) -> Option<String> {
    let before = text.get(..at)?;
    let line = &before[before.rfind('\n').map_or(0, |i| i + 1)..];
    let lhs = line.trim_end().strip_suffix('=')?.trim_end();
    // The byte after the last character that cannot be in a bare key (which may be multi-byte).
    let start = lhs
        .char_indices()
        .rfind(|&(_, c)| !(c.is_ascii_alphanumeric() || c == '_' || c == '-'))
        .map_or(0, |(i, c)| i + c.len_utf8());
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
                .or_else(|| msg.strip_prefix(VALUE_ERROR_PREFIX).and_then(|r| r.split('`').next()).map(str::to_string))
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
            self.dam_break_3d.is_some(),
            self.block_drop_3d.is_some(),
        ]
        .iter()
        .filter(|&&b| b)
        .count();
        if count != 1 {
            return Err(scene_err(
                n,
                "shock_tube",
                format!(
                    "{count} sections; give exactly one of [shock_tube], [dam_break], [periodic_1d], [periodic_2d], \
                     [dam_break_3d], [block_drop_3d]"
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
}

#[cfg(test)]
mod tests {
    use super::key_of_value_at;

    /// Found by `cargo xtask stress fuzz`: the byte after a multi-byte character was taken as
    /// `index + 1`, inside the character.
    #[test]
    fn key_lookup_steps_over_multibyte_characters() {
        assert_eq!(key_of_value_at("xé= 1", 4), None);
        assert_eq!(key_of_value_at("é dx= 1", 6), Some("dx".into()));
        assert_eq!(key_of_value_at("[a]\ndx = 1", 9), Some("dx".into()));
    }
}
