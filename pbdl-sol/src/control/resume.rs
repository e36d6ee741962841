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
//! refused with [`Error::ResumeMismatch`] naming the first differing setting. The random
//! stream is not stored: every draw follows from the seed and the step, and a resumed run
//! replays the draws of the steps before its checkpoint.

use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::io::{latest_checkpoint, read_checkpoint_info};
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

/// `v` as it reads back from a sidecar: serialised and parsed once, so that floats compare
/// equal to a stored copy of the same value (serde_json's parser may round differently from
/// the value it printed, but it rounds the same text the same way every time).
pub(crate) fn canonical(v: Value) -> Result<Value> {
    let text = serde_json::to_string(&v)
        .map_err(|e| Error::invalid("run directory", "config", format!("does not serialise: {e}")))?;
    serde_json::from_str(&text)
        .map_err(|e| Error::invalid("run directory", "config", format!("does not read back: {e}")))
}

/// Every leaf where `stored` and `given` differ, as `(dotted path, stored, given)`, in key
/// order.
fn differences(path: &str, stored: &Value, given: &Value, out: &mut Vec<(String, String, String)>) {
    let join = |k: &str| if path.is_empty() { k.to_string() } else { format!("{path}.{k}") };
    match (stored, given) {
        (Value::Object(a), Value::Object(b)) => {
            let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                match (a.get(k), b.get(k)) {
                    (Some(x), Some(y)) => differences(&join(k), x, y, out),
                    (x, y) => out.push((
                        join(k),
                        x.map_or("(absent)".into(), Value::to_string),
                        y.map_or("(absent)".into(), Value::to_string),
                    )),
                }
            }
        }
        (Value::Array(a), Value::Array(b)) if a.len() == b.len() => {
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                differences(&format!("{path}[{i}]"), x, y, out);
            }
        }
        (a, b) if a == b => {}
        (a, b) => out.push((if path.is_empty() { "config".into() } else { path.into() }, a.to_string(), b.to_string())),
    }
}

/// The difference to report: another trainer first (then every setting differs), then the
/// first setting, then derived values (digests, the normalisation computed from the data),
/// which differ whenever the data does.
fn first_difference(stored: &Value, given: &Value) -> Option<(String, String, String)> {
    let mut all = Vec::new();
    differences("", stored, given, &mut all);
    let rank = |p: &str| match p {
        "trainer" => 0,
        _ if p.ends_with("digest") || p.ends_with("shapes") || p.starts_with("normalisation") => 2,
        _ => 1,
    };
    all.into_iter().enumerate().min_by_key(|(i, d)| (rank(&d.0), *i)).map(|(_, d)| d)
}

/// Refuses to resume `dir` when its newest checkpoint was written with another `config`
/// (compared after [`canonical`]), or holds more than `iterations` updates; nothing is loaded.
/// A directory without checkpoints passes. `context` names the trainer in the errors.
pub(crate) fn check_resume(context: &'static str, dir: &Path, config: &Value, iterations: usize) -> Result<()> {
    let Some(path) = latest_checkpoint(dir)? else { return Ok(()) };
    let info = read_checkpoint_info(&path)?;
    if let Some((field, stored, given)) = first_difference(&info.config, config) {
        return Err(Error::ResumeMismatch { dir: dir.to_path_buf(), field, stored, given });
    }
    if info.step > iterations as u64 {
        return Err(Error::invalid(
            context,
            "iterations",
            format!(
                "{} already holds {} updates, more than the {iterations} asked for; ask for at least {}",
                dir.display(),
                info.step,
                info.step
            ),
        ));
    }
    Ok(())
}

/// The `loss` column of `dir/loss.csv`, in step order (empty without the file): the whole
/// run's losses, those before a resume included (logged with `{:?}`, they read back exactly).
pub(crate) fn logged_losses(dir: &Path) -> Result<Vec<f64>> {
    let path = dir.join("loss.csv");
    if !path.exists() {
        return Ok(Vec::new());
    }
    Ok(pbdl_core::train::ScalarLog::read(&path)?.column("loss").into_iter().map(|(_, l)| l).collect())
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_first_difference_is_named_by_its_path() {
        let a = json!({"train": {"lr": 0.001, "batch": 2}, "data": {"re": [1.0, 2.0]}});
        assert_eq!(first_difference(&a, &a.clone()), None);
        let b = json!({"train": {"lr": 0.01, "batch": 2}, "data": {"re": [1.0, 2.0]}});
        assert_eq!(first_difference(&a, &b), Some(("train.lr".into(), "0.001".into(), "0.01".into())));
        let c = json!({"train": {"lr": 0.001, "batch": 2}, "data": {"re": [1.0, 3.0]}});
        assert_eq!(first_difference(&a, &c).unwrap().0, "data.re[1]");
        let d = json!({"train": {"lr": 0.001}, "data": {"re": [1.0, 2.0]}});
        assert_eq!(first_difference(&a, &d), Some(("train.batch".into(), "2".into(), "(absent)".into())));
        // A setting is named before the digests that differ with it; a digest alone is named.
        let e = json!({"data": {"digest": "1", "re": [1.0]}});
        let f = json!({"data": {"digest": "2", "re": [2.0]}});
        assert_eq!(first_difference(&e, &f).unwrap().0, "data.re[0]");
        let g = json!({"data": {"digest": "2", "re": [1.0]}});
        assert_eq!(first_difference(&e, &g).unwrap().0, "data.digest");
        let h = json!({"trainer": "b", "data": {"re": [2.0]}});
        assert_eq!(first_difference(&f, &h).unwrap().0, "trainer");
        // Floats survive the canonical round trip.
        let x = canonical(json!({"x": 0.1 + 0.2, "y": 1.0 / 3.0})).unwrap();
        assert_eq!(canonical(x.clone()).unwrap(), x);
    }
}
