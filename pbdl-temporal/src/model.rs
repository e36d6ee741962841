//! A trained super-resolution model: which objective trained it, its generator, and upscaling
//! of whole density sequences, from tensors or `.npz` files.
//!
//! Two kinds of model file, both a pbdl checkpoint (`<path>` safetensors with the variables and
//! a JSON sidecar), written atomically:
//! * [`TemporalModel`]: a per-frame generator (baseline, per-frame GAN or temporal GAN), sidecar
//!   [`ModelInfo`];
//! * [`RecurrentModel`]: TecoGAN's F and G (`fnet.*`, `generator.*`), sidecar
//!   [`RecurrentModelInfo`].
//!
//! [`LoadedModel::load`] tells them apart by the sidecar, and every kind upscales through the
//! [`Upscale`] trait.
//!
//! `.npz` interface of [`upscale_npz`] (the `cargo xtask temporal upscale` command): the input
//! holds `density` `[T, 1, Y, X]` (f32 or f64, cell centres, row 0 at the bottom, values
//! roughly in `[0, 1]`) and may hold `velocity` `[T, 2, Y, X]` in cells per frame; the output
//! gets `density` `[T, 1, F Y, F X]` (f32).
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use pbdl_temporal::model::{ModelKind, TemporalModel};
//! use pbdl_temporal::generator::GeneratorConfig;
//!
//! let model = TemporalModel::untrained(ModelKind::Baseline, GeneratorConfig::default(), 0)?;
//! let lr = Tensor::rand(0f32, 1.0, (5, 1, 16, 16), &Device::Cpu)?;
//! let hr = model.upscale(&lr, None)?;
//! assert_eq!(hr.dims(), [5, 1, 64, 64]);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

use crate::generator::{FrameGenerator, GeneratorConfig};
use crate::tecogan::{TecoGan, TecoGanConfig};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::io::CheckpointMeta;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Which objective trained a generator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// L1 to the truth only (no discriminator).
    Baseline,
    /// L1 + a spatial discriminator (each frame judged alone).
    PerFrame,
    /// L1 + spatial and temporal discriminators (tempoGAN).
    Temporal,
}

impl ModelKind {
    /// All kinds, in the order of the tables.
    pub const ALL: [ModelKind; 3] = [ModelKind::Baseline, ModelKind::PerFrame, ModelKind::Temporal];

    /// The name used in file names, tables and the CLI.
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Baseline => "baseline",
            ModelKind::PerFrame => "per_frame",
            ModelKind::Temporal => "temporal",
        }
    }

    /// The kind named `name` ([`ModelKind::name`]).
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| Error::config("kind", format!("`{name}`; use one of baseline, per_frame, temporal")))
    }
}

/// What a model file records besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelInfo {
    /// The training objective.
    pub kind: ModelKind,
    /// The generator's layout.
    pub generator: GeneratorConfig,
    /// Generator updates it was trained with.
    pub updates: u64,
}

/// A generator with its [`ModelInfo`].
pub struct TemporalModel {
    /// What it is.
    pub info: ModelInfo,
    /// The generator.
    pub generator: FrameGenerator,
    /// Its variables.
    pub varmap: VarMap,
}

impl std::fmt::Debug for TemporalModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TemporalModel").field("info", &self.info).finish_non_exhaustive()
    }
}

impl TemporalModel {
    /// A generator with seeded initial weights (`pbdl_nets::seeded_init`).
    pub fn untrained(kind: ModelKind, generator: GeneratorConfig, seed: u64) -> Result<Self> {
        let varmap = VarMap::new();
        let g = FrameGenerator::new(generator.clone(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
        pbdl_nets::seeded_init(&varmap, seed)?;
        Ok(Self { info: ModelInfo { kind, generator, updates: 0 }, generator: g, varmap })
    }

    /// Saves weights and info to `path` (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        save_with_info(path, &self.varmap, &self.info, self.info.updates)
    }

    /// Loads a model saved by [`TemporalModel::save`]; a file of another kind or a corrupt one
    /// is a typed error naming the path.
    pub fn load(path: &Path) -> Result<Self> {
        let meta = pbdl_core::io::read_checkpoint_info(path)?;
        if meta.config.get("tecogan").is_some() {
            return Err(Error::input(
                path.display().to_string(),
                "a recurrent TecoGAN model, not a per-frame generator; load it with RecurrentModel::load or LoadedModel::load",
            ));
        }
        let info: ModelInfo = serde_json::from_value(meta.config.clone()).map_err(|e| Error::Input {
            array: path.display().to_string(),
            reason: format!("not a pbdl-temporal model ({e}); pass a model written by `cargo xtask temporal train`"),
        })?;
        let varmap = VarMap::new();
        let generator =
            FrameGenerator::new(info.generator.clone(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
        pbdl_core::io::load_varmap(path, &varmap)?;
        Ok(Self { info, generator, varmap })
    }

    /// The upscaling factor.
    pub fn factor(&self) -> usize {
        self.info.generator.factor
    }

    /// Upscales a sequence: `density` `[T, 1, Y, X]` (and `velocity` `[T, 2, Y, X]` in cells
    /// per frame, needed only by generators trained with it) to `[T, 1, F Y, F X]`, frame by
    /// frame in chunks. Errors name the array: wrong rank or channels, frame counts that
    /// differ, non-finite values, a missing velocity the generator needs.
    pub fn upscale(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor> {
        let density = check_sequence("density", density, 1)?;
        let velocity = velocity.map(|v| check_sequence("velocity", v, 2)).transpose()?;
        let d = density.dims();
        if let Some(v) = &velocity {
            if v.dims()[0] != d[0] || v.dims()[2..] != d[2..] {
                return Err(Error::input(
                    "velocity",
                    format!("{:?}: expected [{}, 2, {}, {}] to match the density", v.dims(), d[0], d[2], d[3]),
                ));
            }
        }
        if self.info.generator.use_velocity && velocity.is_none() {
            return Err(Error::input("velocity", "missing: this model was trained with the low-resolution velocity"));
        }
        // Up to 8 frames per forward, fewer for large frames (memory grows with f^2 Y X).
        let chunk = ((1usize << 16) / (d[2] * d[3]).max(1)).clamp(1, 8);
        let mut out = Vec::with_capacity(d[0].div_ceil(chunk));
        for start in (0..d[0]).step_by(chunk) {
            let n = chunk.min(d[0] - start);
            let v = velocity.as_ref().map(|v| v.narrow(0, start, n)).transpose()?;
            let v = if self.info.generator.use_velocity { v } else { None };
            out.push(self.generator.forward(&density.narrow(0, start, n)?, v.as_ref())?.detach());
        }
        Ok(Tensor::cat(&out, 0)?)
    }
}

/// Checks a `[T, channels, Y, X]` sequence (finite, f32 or f64) and returns it as f32.
fn check_sequence(name: &str, x: &Tensor, channels: usize) -> Result<Tensor> {
    let d = x.dims();
    if d.len() != 4 || d[1] != channels || d.contains(&0) {
        return Err(Error::input(name, format!("shape {d:?}: expected [T, {channels}, Y, X] with T, Y, X > 0")));
    }
    let x = match x.dtype() {
        DType::F32 => x.clone(),
        DType::F64 | DType::F16 | DType::BF16 => x.to_dtype(DType::F32)?,
        other => return Err(Error::input(name, format!("dtype {other:?}: use float32 or float64"))),
    };
    let bad = x.flatten_all()?.to_vec1::<f32>()?.iter().position(|v| !v.is_finite());
    if let Some(i) = bad {
        return Err(Error::input(name, format!("holds a non-finite value at flat index {i}; clean the input first")));
    }
    Ok(x)
}

/// What a recurrent model file records besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecurrentModelInfo {
    /// F's and G's layout.
    pub tecogan: TecoGanConfig,
    /// How it was trained, e.g. `"content+pingpong"` or `"adversarial"` (free text for tables).
    pub objective: String,
    /// Generator updates it was trained with.
    pub updates: u64,
}

/// TecoGAN's motion network F and recurrent generator G with their [`RecurrentModelInfo`].
pub struct RecurrentModel {
    /// What it is.
    pub info: RecurrentModelInfo,
    /// F and G.
    pub model: TecoGan,
    /// Their variables (`fnet.*`, `generator.*`).
    pub varmap: VarMap,
}

impl std::fmt::Debug for RecurrentModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecurrentModel").field("info", &self.info).finish_non_exhaustive()
    }
}

impl RecurrentModel {
    /// Wraps trained variables (the `VarMap` that [`crate::tecogan::train_tecogan`] or
    /// [`crate::tecogan::train_tecogan_gan`] returns); errors if `varmap` lacks a variable of
    /// `info.tecogan`'s layout or holds one of another shape.
    pub fn new(info: RecurrentModelInfo, varmap: VarMap) -> Result<Self> {
        let expected = {
            let probe = VarMap::new();
            TecoGan::new(info.tecogan.clone(), VarBuilder::from_varmap(&probe, DType::F32, &Device::Cpu))?;
            let data = probe.data().lock().expect("fresh VarMap").clone();
            data.into_iter().map(|(name, var)| (name, var.dims().to_vec())).collect::<Vec<_>>()
        };
        {
            let data = varmap.data().lock().map_err(|_| Error::config("varmap", "poisoned lock"))?;
            for (name, dims) in &expected {
                match data.get(name) {
                    Some(v) if v.dims() == dims.as_slice() => {}
                    Some(v) => {
                        return Err(Error::config(
                            "varmap",
                            format!("`{name}` has shape {:?}, the configured TecoGAN needs {dims:?}", v.dims()),
                        ))
                    }
                    None => {
                        return Err(Error::config(
                            "varmap",
                            format!("has no `{name}`; pass the VarMap a TecoGAN trainer returned with this config"),
                        ))
                    }
                }
            }
        }
        let model = TecoGan::new(info.tecogan.clone(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
        Ok(Self { info, model, varmap })
    }

    /// Saves weights and info to `path` (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        save_with_info(path, &self.varmap, &self.info, self.info.updates)
    }

    /// Loads a model saved by [`RecurrentModel::save`]; another kind of file is a typed error
    /// naming the path.
    pub fn load(path: &Path) -> Result<Self> {
        match LoadedModel::load(path)? {
            LoadedModel::Recurrent(m) => Ok(*m),
            LoadedModel::PerFrame(_) => Err(Error::input(
                path.display().to_string(),
                "a per-frame generator, not a recurrent TecoGAN model; load it with TemporalModel::load",
            )),
        }
    }

    /// The upscaling factor.
    pub fn factor(&self) -> usize {
        self.model.factor()
    }
}

/// Writes `varmap` with `info` as the checkpoint sidecar's config (atomically).
fn save_with_info(path: &Path, varmap: &VarMap, info: &impl Serialize, updates: u64) -> Result<()> {
    let config = serde_json::to_value(info).map_err(|e| Error::config("model info", e.to_string()))?;
    pbdl_core::io::save_varmap(path, varmap, &CheckpointMeta { step: updates, seed: None, config })?;
    Ok(())
}

/// Anything that upscales a low-resolution density sequence.
pub trait Upscale {
    /// The upscaling factor `F`.
    fn factor(&self) -> usize;

    /// `density` `[T, 1, Y, X]` (and `velocity` `[T, 2, Y, X]` in cells per frame where the model
    /// uses it) to `[T, 1, F Y, F X]`, f32, without a graph.
    fn upscale(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor>;
}

impl Upscale for TemporalModel {
    fn factor(&self) -> usize {
        TemporalModel::factor(self)
    }

    fn upscale(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor> {
        TemporalModel::upscale(self, density, velocity)
    }
}

impl Upscale for RecurrentModel {
    fn factor(&self) -> usize {
        RecurrentModel::factor(self)
    }

    /// Frame by frame through a [`crate::tecogan::Rollout`] (memory independent of `T`); F
    /// estimates the motion itself, so a given `velocity` is checked but not used.
    fn upscale(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor> {
        let density = check_sequence("density", density, 1)?;
        if let Some(v) = velocity {
            let v = check_sequence("velocity", v, 2)?;
            let (d, vd) = (density.dims(), v.dims());
            if vd[0] != d[0] || vd[2..] != d[2..] {
                return Err(Error::input(
                    "velocity",
                    format!("{vd:?}: expected [{}, 2, {}, {}] to match the density", d[0], d[2], d[3]),
                ));
            }
        }
        self.model.infer_sequence(&density)
    }
}

/// A model file of either kind, told apart by its sidecar.
#[derive(Debug)]
pub enum LoadedModel {
    /// A per-frame generator ([`TemporalModel`]).
    PerFrame(Box<TemporalModel>),
    /// TecoGAN's F and G ([`RecurrentModel`]).
    Recurrent(Box<RecurrentModel>),
}

impl LoadedModel {
    /// Loads `path`, whichever kind it is; a file that is neither is a typed error naming it.
    pub fn load(path: &Path) -> Result<Self> {
        let meta = pbdl_core::io::read_checkpoint_info(path)?;
        if meta.config.get("tecogan").is_some() {
            let info: RecurrentModelInfo = serde_json::from_value(meta.config.clone()).map_err(|e| Error::Input {
                array: path.display().to_string(),
                reason: format!("a recurrent model file with an unreadable sidecar ({e})"),
            })?;
            let varmap = VarMap::new();
            let model = TecoGan::new(info.tecogan.clone(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
            pbdl_core::io::load_varmap(path, &varmap)?;
            return Ok(LoadedModel::Recurrent(Box::new(RecurrentModel { info, model, varmap })));
        }
        Ok(LoadedModel::PerFrame(Box::new(TemporalModel::load(path)?)))
    }

    /// A short name of what it is, for messages.
    pub fn describe(&self) -> String {
        match self {
            LoadedModel::PerFrame(m) => format!("per-frame generator ({})", m.info.kind.name()),
            LoadedModel::Recurrent(m) => format!("recurrent TecoGAN ({})", m.info.objective),
        }
    }
}

impl Upscale for LoadedModel {
    fn factor(&self) -> usize {
        match self {
            LoadedModel::PerFrame(m) => m.factor(),
            LoadedModel::Recurrent(m) => m.factor(),
        }
    }

    fn upscale(&self, density: &Tensor, velocity: Option<&Tensor>) -> Result<Tensor> {
        match self {
            LoadedModel::PerFrame(m) => Upscale::upscale(m.as_ref(), density, velocity),
            LoadedModel::Recurrent(m) => Upscale::upscale(m.as_ref(), density, velocity),
        }
    }
}

/// Reads `input` (`density` and optionally `velocity`, see the module docs), upscales it with
/// `model` (any [`Upscale`]: a [`TemporalModel`], a [`RecurrentModel`] or a [`LoadedModel`])
/// and writes `density` to `output` (atomically). Returns the output shape.
pub fn upscale_npz(model: &impl Upscale, input: &Path, output: &Path) -> Result<Vec<usize>> {
    let arrays = pbdl_core::io::read_npz(input)?;
    let find = |name: &str| arrays.iter().find(|(n, _)| n == name || n == &format!("{name}.npy")).map(|(_, t)| t);
    let density = find("density").ok_or_else(|| {
        let names: Vec<&str> = arrays.iter().map(|(n, _)| n.as_str()).collect();
        Error::input(
            "density",
            format!(
                "missing from {} (it holds {names:?}); store the low-resolution density as `density` [T, 1, Y, X]",
                input.display()
            ),
        )
    })?;
    let hr = model.upscale(density, find("velocity"))?;
    pbdl_core::io::write_npz(output, &[("density", &hr)])?;
    Ok(hr.dims().to_vec())
}
