//! The converted weight files of LSiM and VolSiM: reading them with typed errors, and where the
//! default files live.
//!
//! The files are safetensors converted tensor for tensor from the official PyTorch checkpoints
//! (see `../shared/weights/README.md` in the project): network weights as
//! `model.<state-dict key>`, normalisation maps as `norm.mean.<i>` and `norm.m2.<i>` per feature
//! layer `i`, and the metadata keys `normCount` (a JSON list, one sample count per layer) and
//! `hyperparams` (JSON). The files are MIT licensed by TUM (keep `LICENSE-LSIM.txt` /
//! `LICENSE-VOLSIM.txt` with them) and are not part of this repository.
//!
//! **Getting them**: download the official checkpoints (tum-pbs/LSIM `Models/LSiM.pth`,
//! tum-pbs/VOLSIM `models/MS_3scales.pth`) and convert them with
//! `cargo xtask weights convert IN.pth OUT.safetensors` ([`crate::convert`]); the result is
//! bit-identical in every tensor, with equal metadata, to the reference conversion.
//!
//! **Where the weights are looked up** ([`weights_dir`]): the directory in the environment
//! variable `PBDL_WEIGHTS_DIR` if set, otherwise `../shared/weights` relative to the current
//! directory (the project's layout: the shared folder beside the checkout).

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Environment variable naming the directory with `LSiM.safetensors` and
/// `VolSiM_MS_3scales.safetensors`.
pub const WEIGHTS_DIR_ENV: &str = "PBDL_WEIGHTS_DIR";

/// File name of the LSiM weights.
pub const LSIM_FILE: &str = "LSiM.safetensors";

/// File name of the VolSiM weights (3-scale model).
pub const VOLSIM_FILE: &str = "VolSiM_MS_3scales.safetensors";

/// The weight directory: `$PBDL_WEIGHTS_DIR`, else `../shared/weights` from the working
/// directory, else the `shared/weights` folder beside this workspace's checkout (so tests,
/// benches and examples find it whatever directory cargo runs them in); `None` if none is there.
pub fn weights_dir() -> Option<PathBuf> {
    if let Some(dir) = std::env::var_os(WEIGHTS_DIR_ENV) {
        return Some(PathBuf::from(dir));
    }
    let beside_checkout = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/weights");
    [PathBuf::from("../shared/weights"), beside_checkout].into_iter().find(|d| d.is_dir())
}

/// The tensors and metadata of one weight file, taken out by name with shape checks.
pub struct WeightFile {
    path: PathBuf,
    tensors: HashMap<String, Tensor>,
    metadata: HashMap<String, String>,
}

impl WeightFile {
    /// Reads a safetensors file onto the CPU.
    ///
    /// Errors: [`Error::Io`] if it cannot be read, [`Error::Weights`] if it is not a safetensors file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let bytes = std::fs::read(&path).map_err(|source| Error::Io { path: path.clone(), source })?;
        let bad = |reason: String| Error::Weights { path: path.clone(), reason };
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)
            .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let metadata = meta.metadata().clone().unwrap_or_default();
        let tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu)
            .map_err(|e| bad(format!("cannot read the tensors ({e})")))?;
        Ok(Self { path, tensors, metadata })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Names of all tensors, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut v: Vec<String> = self.tensors.keys().cloned().collect();
        v.sort();
        v
    }

    /// The tensor `name` as `f32`, checked to have shape `shape`.
    ///
    /// Errors: [`Error::Weights`] naming the tensor if it is missing or has another shape.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<Tensor> {
        let t = self.tensors.get(name).ok_or_else(|| Error::Weights {
            path: self.path.clone(),
            reason: format!("tensor `{name}` is missing; is this the right weight file?"),
        })?;
        if t.dims() != shape {
            return Err(Error::Weights {
                path: self.path.clone(),
                reason: format!("tensor `{name}` has shape {:?}, expected {shape:?}", t.dims()),
            });
        }
        Ok(t.to_dtype(DType::F32)?)
    }

    /// The tensor `name` with whatever shape it has (for layer sizes read from the file).
    pub fn get_any(&self, name: &str) -> Result<Tensor> {
        let t = self.tensors.get(name).ok_or_else(|| Error::Weights {
            path: self.path.clone(),
            reason: format!("tensor `{name}` is missing; is this the right weight file?"),
        })?;
        Ok(t.to_dtype(DType::F32)?)
    }

    /// Whether the file has a tensor `name`.
    pub fn contains(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    /// The metadata value `key`, if present.
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }

    /// The `normCount` metadata: one sample count per feature layer, checked to have `layers`
    /// entries, each at least 2 (the variance divides by `count - 1`).
    pub fn norm_counts(&self, layers: usize) -> Result<Vec<f64>> {
        let bad = |reason: String| Error::Weights { path: self.path.clone(), reason };
        let raw = self.metadata("normCount").ok_or_else(|| bad("metadata `normCount` is missing".into()))?;
        let counts: Vec<f64> = serde_json::from_str(raw)
            .map_err(|e| bad(format!("metadata `normCount` is not a JSON list of numbers ({e}): {raw}")))?;
        if counts.len() != layers {
            return Err(bad(format!("metadata `normCount` has {} entries, expected {layers}", counts.len())));
        }
        if let Some(c) = counts.iter().find(|&&c| !(c >= 2.0 && c.is_finite())) {
            return Err(bad(format!("metadata `normCount` has the count {c}; every count must be >= 2")));
        }
        Ok(counts)
    }
}
