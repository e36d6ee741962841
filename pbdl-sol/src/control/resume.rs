//! Run directories of pbdl-sol's trainers: where a resumable training writes, and the check
//! that a resumed call continues the run it finds there.
//!
//! Both trainers ([`super::train::pretrain_supervised_resumable`],
//! [`super::train::train_end_to_end_resumable`] and
//! [`crate::sil::train_resumable`]) run pbdl-core's [`pbdl_core::train::TrainLoop`]: `loss.csv`
//! (one row per update) and atomic checkpoints `step-<n>` (safetensors + JSON sidecar), each one
//! commit of the weights and Adam's moments and update count. The sidecar's `config` records
//! what the run's numbers depend on (the training settings except the number of updates, the
//! data's digest, the network's layout); a call that finds a checkpoint of other settings is
//! refused with [`Error::ResumeMismatch`] naming the first differing setting (the check is
//! pbdl-core's [`pbdl_core::train::check_resume`], its errors mapped to this crate's). The random
//! stream is not stored: every draw follows from the seed and the step, and a resumed run
//! replays the draws of the steps before its checkpoint.

use crate::{Error, Result};
use candle_core::Tensor;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Where a resumable control training writes and how often it commits a checkpoint.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunDir {
    /// The run directory: `loss.csv` and the checkpoints `step-<n>`. One trainer per directory
    /// (and one directory per training phase).
    pub dir: PathBuf,
    /// Updates between checkpoints; one is always written after the last update (0: only that
    /// one). Default 50.
    pub checkpoint_every: u64,
}

impl RunDir {
    /// `dir` with a checkpoint every 50 updates.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into(), checkpoint_every: 50 }
    }

    /// The same directory with a checkpoint every `every` updates.
    pub fn every(mut self, every: u64) -> Self {
        self.checkpoint_every = every;
        self
    }
}

/// [`pbdl_core::train::canonical`], with a failure as this crate's [`Error::InvalidConfig`].
pub(crate) fn canonical(v: Value) -> Result<Value> {
    pbdl_core::train::canonical(v).map_err(|e| match e {
        pbdl_core::Error::InvalidArgument { reason, .. } => Error::invalid("run directory", "config", reason),
        e => e.into(),
    })
}

/// [`pbdl_core::train::check_resume`] with this crate's errors: refuses to resume `dir` when
/// its newest checkpoint was written with another `config` (compared after [`canonical`]),
/// [`Error::ResumeMismatch`] naming the first differing setting, or holds more than
/// `iterations` updates, [`Error::InvalidConfig`] on `iterations`; nothing is loaded. A
/// directory without checkpoints passes. `context` names the trainer in the errors.
pub(crate) fn check_resume(context: &'static str, dir: &Path, config: &Value, iterations: usize) -> Result<()> {
    pbdl_core::train::check_resume(dir, config, iterations as u64).map_err(|e| match e {
        pbdl_core::Error::ResumeMismatch { dir, field, stored, given } => {
            Error::ResumeMismatch { dir: dir.into(), field, stored, given }
        }
        pbdl_core::Error::InvalidArgument { op: "check_resume", arg: "steps", reason } => {
            Error::invalid(context, "iterations", reason)
        }
        e => e.into(),
    })
}

/// The `loss` column of `dir/loss.csv`, in step order (empty without the file); see
/// [`pbdl_core::train::logged_losses`].
pub(crate) use pbdl_core::train::logged_losses;

/// A 64-bit FNV-1a digest (hex) of tensors' dtypes, shapes and bytes: different data in a run
/// directory is refused on resume.
pub(crate) fn digest<'a>(tensors: impl IntoIterator<Item = &'a Tensor>) -> Result<String> {
    let mut h = FNV_OFFSET;
    let mut buf = Vec::new();
    for t in tensors {
        fnv1a(&mut h, format!("{:?}{:?}", t.dtype(), t.dims()).as_bytes());
        buf.clear();
        t.write_bytes(&mut buf)?;
        fnv1a(&mut h, &buf);
    }
    Ok(format!("{h:016x}"))
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

fn fnv1a(h: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *h ^= u64::from(*b);
        *h = h.wrapping_mul(0x0100_0000_01b3);
    }
}

/// The network's layout: its parameter count and a digest of its variables' names and shapes.
pub(crate) fn layout(varmap: &candle_nn::VarMap) -> Value {
    let vars = pbdl_core::train::sorted_vars(varmap);
    let mut text = String::new();
    for (name, v) in &vars {
        text.push_str(&format!("{name}{:?};", v.dims()));
    }
    let mut h = FNV_OFFSET;
    fnv1a(&mut h, text.as_bytes());
    serde_json::json!({
        "parameters": vars.iter().map(|(_, v)| v.elem_count()).sum::<usize>(),
        "variables": vars.len(),
        "shapes": format!("{h:016x}"),
    })
}
