//! Checkpoints: named tensors in a `.safetensors` file plus a JSON sidecar describing the run.
//!
//! A checkpoint `runs/a/step-00000100` is two files:
//!
//! - `step-00000100.safetensors`: the tensors (readable by any safetensors reader; the header's
//!   metadata carries the checkpoint id and step);
//! - `step-00000100.json`: a [`CheckpointInfo`]: config, step, seed, crate version, creation
//!   time, tensor names with shapes and dtypes.
//!
//! **Write order.** Both files are written atomically ([`super::write_atomic`]): first the
//! weights, then the sidecar. The sidecar is the commit marker: a crash before it leaves weights
//! without a sidecar, which [`latest_checkpoint`] and [`list_checkpoints`] ignore, so a reader
//! never sees a sidecar without its weights. Give each checkpoint a new name (e.g. by step); if
//! a name is overwritten and the process dies between the two writes, the old sidecar no longer
//! matches the new weights, and loading reports that ([`Error::Format`]) through the checkpoint
//! id shared by both files instead of mixing runs.
//!
//! ```
//! use candle_core::{DType, Device};
//! use candle_nn::{Init, VarMap};
//! use pbdl_core::io::{latest_checkpoint, load_varmap, save_varmap, CheckpointMeta};
//! # fn main() -> pbdl_core::Result<()> {
//! let dir = tempfile::tempdir().unwrap();
//! let varmap = VarMap::new();
//! varmap.get((2, 3), "layer.weight", Init::Const(0.5), DType::F32, &Device::Cpu)?;
//! for step in [100, 200] {
//!     let meta = CheckpointMeta { step, seed: Some(7), config: serde_json::json!({ "lr": 1e-3 }) };
//!     save_varmap(dir.path().join(format!("step-{step:08}")), &varmap, &meta)?;
//! }
//!
//! // Resume: find the newest checkpoint and load it into a freshly built model.
//! let fresh = VarMap::new();
//! fresh.get((2, 3), "layer.weight", Init::Const(0.0), DType::F32, &Device::Cpu)?;
//! let latest = latest_checkpoint(dir.path())?.expect("a checkpoint was saved");
//! let info = load_varmap(&latest, &fresh)?;
//! assert_eq!(info.step, 200);
//! assert_eq!(info.config["lr"], 1e-3);
//! # Ok(())
//! # }
//! ```

use super::atomic::{is_temp_file, write_atomic};
use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use safetensors::{tensor::TensorView, Dtype as StDtype, SafeTensors};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::ffi::OsString;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The `format` field of every pbdl sidecar.
pub const CHECKPOINT_FORMAT: &str = "pbdl-checkpoint";
/// The sidecar layout version this crate writes; it reads this one and older ones.
pub const CHECKPOINT_FORMAT_VERSION: u32 = 1;

/// What the caller records next to the weights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CheckpointMeta {
    /// Training step (or epoch) the weights belong to; [`latest_checkpoint`] picks the largest.
    pub step: u64,
    /// The run's seed, if it has one.
    pub seed: Option<u64>,
    /// The run's configuration, typically `serde_json::to_value(&config)`. Default: `null`.
    pub config: serde_json::Value,
}

impl CheckpointMeta {
    /// Metadata that records only the step.
    pub fn at(step: u64) -> Self {
        Self { step, ..Default::default() }
    }
}

/// Name, dtype and shape of one stored tensor.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TensorEntry {
    /// The tensor's name, e.g. `"layer1.weight"`.
    pub name: String,
    /// Its dtype as candle spells it (`"f32"`, `"f64"`, ...).
    pub dtype: String,
    /// Its shape.
    pub shape: Vec<usize>,
}

/// The JSON sidecar of a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointInfo {
    /// Always [`CHECKPOINT_FORMAT`].
    pub format: String,
    /// [`CHECKPOINT_FORMAT_VERSION`] at the time of writing.
    pub format_version: u32,
    /// A unique id, also stored in the weights' metadata, that ties the two files together.
    pub id: String,
    /// See [`CheckpointMeta::step`].
    pub step: u64,
    /// See [`CheckpointMeta::seed`].
    pub seed: Option<u64>,
    /// See [`CheckpointMeta::config`].
    pub config: serde_json::Value,
    /// The version of `pbdl-core` that wrote the checkpoint.
    pub crate_version: String,
    /// Creation time, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// Creation time as an ISO 8601 UTC string, e.g. `"2025-03-01T12:00:00Z"`.
    pub created_utc: String,
    /// File name of the weights, next to the sidecar.
    pub weights_file: String,
    /// Size of the weights file in bytes.
    pub weights_bytes: u64,
    /// The stored tensors, sorted by name.
    pub tensors: Vec<TensorEntry>,
}

/// The two files of the checkpoint `path`: `(<name>.safetensors, <name>.json)`.
///
/// `path` may name either file or neither (`runs/a/step-100`); only a `.safetensors` or `.json`
/// extension is replaced, so `model.v2` becomes `model.v2.safetensors`.
pub fn checkpoint_files(path: impl AsRef<Path>) -> (PathBuf, PathBuf) {
    let path = path.as_ref();
    let stem = match path.extension().and_then(|e| e.to_str()) {
        Some("safetensors" | "json") => path.with_extension(""),
        _ => path.to_path_buf(),
    };
    let with = |ext: &str| {
        let mut s = OsString::from(stem.as_os_str());
        s.push(ext);
        PathBuf::from(s)
    };
    (with(".safetensors"), with(".json"))
}

/// Saves named tensors (any device, any dtype safetensors knows) as the checkpoint `path`, see
/// the [module docs](self) for the files and their order. Creates the directory if needed.
///
/// Accepts anything that iterates over `(name, tensor)` pairs, e.g. `&HashMap<String, Tensor>`.
pub fn save_checkpoint<K, T>(
    path: impl AsRef<Path>,
    tensors: impl IntoIterator<Item = (K, T)>,
    meta: &CheckpointMeta,
) -> Result<CheckpointInfo>
where
    K: AsRef<str>,
    T: AsRef<Tensor>,
{
    let (weights_path, sidecar_path) = checkpoint_files(path);
    if let Some(dir) = weights_path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }

    let mut stored: Vec<(String, DType, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, t) in tensors {
        let (name, t) = (name.as_ref().to_string(), t.as_ref());
        let mut bytes = Vec::with_capacity(t.elem_count() * t.dtype().size_in_bytes());
        t.write_bytes(&mut bytes)?;
        stored.push((name, t.dtype(), t.dims().to_vec(), bytes));
    }
    stored.sort_by(|a, b| a.0.cmp(&b.0));
    if let Some(w) = stored.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(Error::invalid("save_checkpoint", "tensors", format!("the name `{}` appears twice", w[0].0)));
    }

    let (created_unix_s, created_utc) = now_utc();
    let id = unique_id();
    let metadata = HashMap::from([
        ("format".to_string(), CHECKPOINT_FORMAT.to_string()),
        ("id".to_string(), id.clone()),
        ("step".to_string(), meta.step.to_string()),
    ]);
    let views = stored
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            let view = TensorView::new(st_dtype(*dtype)?, shape.clone(), bytes)
                .map_err(|e| Error::invalid("save_checkpoint", "tensors", format!("`{name}`: {e}")))?;
            Ok((name.as_str(), view))
        })
        .collect::<Result<Vec<_>>>()?;
    let buffer = safetensors::serialize(views, Some(metadata))
        .map_err(|e| Error::invalid("save_checkpoint", "tensors", e.to_string()))?;

    let info = CheckpointInfo {
        format: CHECKPOINT_FORMAT.to_string(),
        format_version: CHECKPOINT_FORMAT_VERSION,
        id,
        step: meta.step,
        seed: meta.seed,
        config: meta.config.clone(),
        crate_version: env!("CARGO_PKG_VERSION").to_string(),
        created_unix_s,
        created_utc,
        weights_file: file_name(&weights_path),
        weights_bytes: buffer.len() as u64,
        tensors: stored
            .iter()
            .map(|(name, dtype, shape, _)| TensorEntry {
                name: name.clone(),
                dtype: dtype.as_str().to_string(),
                shape: shape.clone(),
            })
            .collect(),
    };
    // Weights first, sidecar last: the sidecar's presence means the weights are complete.
    write_atomic(&weights_path, |w| w.write_all(&buffer))?;
    let json =
        serde_json::to_vec_pretty(&info).map_err(|e| Error::invalid("save_checkpoint", "meta", e.to_string()))?;
    write_atomic(&sidecar_path, |w| w.write_all(&json))?;
    Ok(info)
}

/// Saves every variable of `varmap` as the checkpoint `path`; see [`save_checkpoint`].
pub fn save_varmap(path: impl AsRef<Path>, varmap: &VarMap, meta: &CheckpointMeta) -> Result<CheckpointInfo> {
    let tensors: Vec<(String, Tensor)> = {
        let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        data.iter().map(|(name, var)| (name.clone(), var.as_tensor().clone())).collect()
    };
    save_checkpoint(path, tensors, meta)
}

/// Reads the sidecar of the checkpoint `path` without touching the weights.
///
/// A missing sidecar is [`Error::Io`] (kind `NotFound`); a JSON file that is not a pbdl
/// sidecar, or one from a newer format version, is [`Error::Format`].
pub fn read_checkpoint_info(path: impl AsRef<Path>) -> Result<CheckpointInfo> {
    let (_, sidecar) = checkpoint_files(path);
    let bytes = std::fs::read(&sidecar).map_err(|e| Error::io(&sidecar, e))?;
    let bad = |reason: String| Error::Format { path: sidecar.clone(), reason };
    let info: CheckpointInfo =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a pbdl checkpoint sidecar: {e}")))?;
    if info.format != CHECKPOINT_FORMAT {
        return Err(bad(format!("format is {:?}, expected {CHECKPOINT_FORMAT:?}", info.format)));
    }
    if info.format_version > CHECKPOINT_FORMAT_VERSION {
        return Err(bad(format!(
            "format version {} was written by a newer pbdl (this is {}, reading up to version {CHECKPOINT_FORMAT_VERSION})",
            info.format_version,
            env!("CARGO_PKG_VERSION")
        )));
    }
    Ok(info)
}

/// Loads all tensors of the checkpoint `path` onto `device`, with its sidecar.
///
/// Errors: [`Error::Io`] for a missing file, [`Error::Format`] for a file that is not a
/// safetensors file or a pbdl sidecar, or weights that do not belong to the sidecar.
pub fn load_checkpoint(path: impl AsRef<Path>, device: &Device) -> Result<(HashMap<String, Tensor>, CheckpointInfo)> {
    let info = read_checkpoint_info(&path)?;
    let (weights_path, _) = checkpoint_files(&path);
    let bytes = std::fs::read(&weights_path).map_err(|e| Error::io(&weights_path, e))?;
    let bad = |reason: String| Error::Format { path: weights_path.clone(), reason };
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    let id = header.metadata().as_ref().and_then(|m| m.get("id"));
    if id != Some(&info.id) {
        return Err(bad(format!(
            "these weights do not belong to the sidecar (checkpoint id {:?} vs {:?}); \
             was the checkpoint overwritten by a process that died before writing its sidecar?",
            id, info.id
        )));
    }
    let st = SafeTensors::deserialize(&bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    let mut out = HashMap::with_capacity(st.len());
    for (name, view) in st.tensors() {
        let dtype = candle_dtype(view.dtype())
            .ok_or_else(|| bad(format!("tensor `{name}` has unsupported dtype {}", view.dtype())))?;
        let t = Tensor::from_raw_buffer(view.data(), dtype, view.shape(), device)?;
        out.insert(name, t);
    }
    Ok((out, info))
}

/// Loads the checkpoint `path` into the variables of `varmap`, converting dtype and device to
/// each variable's.
///
/// Every variable of `varmap` must be in the file with the same shape, else
/// [`Error::MissingTensors`] (all missing names) or [`Error::TensorShape`] (the first mismatch,
/// with both shapes). Everything is checked before the first variable is set, so a failed load
/// leaves `varmap` unchanged. Tensors in the file that `varmap` lacks are ignored.
pub fn load_varmap(path: impl AsRef<Path>, varmap: &VarMap) -> Result<CheckpointInfo> {
    let (tensors, info) = load_checkpoint(&path, &Device::Cpu)?;
    let (weights_path, _) = checkpoint_files(&path);
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let missing: Vec<String> =
        names.iter().filter(|n| !tensors.contains_key(n.as_str())).map(|n| n.to_string()).collect();
    if !missing.is_empty() {
        let mut available: Vec<String> = tensors.keys().cloned().collect();
        available.sort();
        return Err(Error::MissingTensors { path: weights_path, missing, available });
    }
    for name in &names {
        let (stored, var) = (&tensors[name.as_str()], &data[name.as_str()]);
        if stored.dims() != var.dims() {
            return Err(Error::TensorShape {
                path: weights_path,
                name: name.to_string(),
                stored: stored.dims().to_vec(),
                expected: var.dims().to_vec(),
            });
        }
    }
    for name in names {
        let var = &data[name.as_str()];
        var.set(&tensors[name.as_str()].to_dtype(var.dtype())?.to_device(var.device())?)?;
    }
    Ok(info)
}

/// All complete checkpoints in `dir` (those with a readable sidecar and a weights file of the
/// recorded size), sorted by step, then creation time. A missing `dir` gives an empty list.
///
/// Other files (other JSON files, weights without a sidecar, temporary files of interrupted
/// writes) are skipped.
pub fn list_checkpoints(dir: impl AsRef<Path>) -> Result<Vec<(PathBuf, CheckpointInfo)>> {
    let dir = dir.as_ref();
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut found = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        if is_temp_file(&path) || path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let Ok(info) = read_checkpoint_info(&path) else { continue };
        let (weights, _) = checkpoint_files(&path);
        let complete = std::fs::metadata(&weights).is_ok_and(|m| m.len() == info.weights_bytes);
        if complete {
            found.push((weights, info));
        }
    }
    found.sort_by(|a, b| (a.1.step, a.1.created_unix_s, &a.0).cmp(&(b.1.step, b.1.created_unix_s, &b.0)));
    Ok(found)
}

/// The weights path of the complete checkpoint in `dir` with the largest step, for resuming;
/// `None` if there is none (or `dir` does not exist). See [`list_checkpoints`].
pub fn latest_checkpoint(dir: impl AsRef<Path>) -> Result<Option<PathBuf>> {
    Ok(list_checkpoints(dir)?.pop().map(|(path, _)| path))
}

fn st_dtype(dtype: DType) -> Result<StDtype> {
    Ok(match dtype {
        DType::U8 => StDtype::U8,
        DType::U32 => StDtype::U32,
        DType::I16 => StDtype::I16,
        DType::I32 => StDtype::I32,
        DType::I64 => StDtype::I64,
        DType::BF16 => StDtype::BF16,
        DType::F16 => StDtype::F16,
        DType::F32 => StDtype::F32,
        DType::F64 => StDtype::F64,
        DType::F8E4M3 => StDtype::F8_E4M3,
        got => {
            return Err(Error::DType {
                op: "save_checkpoint",
                arg: "tensors",
                expected: "an integer or float dtype of 8 bits or more",
                got,
            })
        }
    })
}

fn candle_dtype(dtype: StDtype) -> Option<DType> {
    Some(match dtype {
        StDtype::U8 => DType::U8,
        StDtype::U32 => DType::U32,
        StDtype::I16 => DType::I16,
        StDtype::I32 => DType::I32,
        StDtype::I64 => DType::I64,
        StDtype::BF16 => DType::BF16,
        StDtype::F16 => DType::F16,
        StDtype::F32 => DType::F32,
        StDtype::F64 => DType::F64,
        StDtype::F8_E4M3 => DType::F8E4M3,
        _ => return None,
    })
}

fn file_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// Unique enough across processes and calls: time in nanoseconds, process id and a counter.
fn unique_id() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    format!("{nanos:x}-{:x}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed))
}

/// Seconds since the epoch and the matching ISO 8601 UTC string (no date crate needed).
fn now_utc() -> (u64, String) {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    (secs, format_utc(secs))
}

/// Formats Unix seconds as `YYYY-MM-DDThh:mm:ssZ` (proleptic Gregorian calendar).
fn format_utc(secs: u64) -> String {
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    // Howard Hinnant's civil-from-days algorithm.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem / 60 % 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_formatting_matches_known_dates() {
        assert_eq!(format_utc(0), "1970-01-01T00:00:00Z");
        // 2000-02-29 (leap day) 12:34:56 UTC.
        assert_eq!(format_utc(951_827_696), "2000-02-29T12:34:56Z");
        // 2024-12-31 23:59:59 UTC.
        assert_eq!(format_utc(1_735_689_599), "2024-12-31T23:59:59Z");
    }

    #[test]
    fn checkpoint_files_keep_dotted_names() {
        let (w, s) = checkpoint_files("runs/model.v2");
        assert_eq!(w, PathBuf::from("runs/model.v2.safetensors"));
        assert_eq!(s, PathBuf::from("runs/model.v2.json"));
        assert_eq!(checkpoint_files("a/b.json").0, PathBuf::from("a/b.safetensors"));
        assert_eq!(checkpoint_files("a/b.safetensors").1, PathBuf::from("a/b.json"));
    }
}
