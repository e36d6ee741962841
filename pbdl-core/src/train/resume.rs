//! The resume guard of a training run directory: refuses to continue a run that was started
//! with other settings, before anything is loaded.
//!
//! A [`TrainLoop`](super::TrainLoop) with a run directory writes `loss.csv` and atomic
//! checkpoints `step-<n>` whose JSON sidecar carries a
//! [`CheckpointMeta::config`](crate::io::CheckpointMeta::config): what the run's numbers depend
//! on (its settings except the number of updates, digests of its data, the network's layout).
//! A trainer that resumes calls [`check_resume`] with the config it would write: a directory
//! whose newest checkpoint holds another config is refused with [`Error::ResumeMismatch`]
//! naming the first differing setting as a dotted path (`train.lr`, `data.re[1]`), and one that
//! holds more updates than asked for is refused with [`Error::InvalidArgument`] (`steps`).
//! [`logged_losses`] reads the whole run's losses back from `loss.csv`.
//!
//! Which difference is named when several differ: a top-level `trainer` key first (another
//! trainer's directory differs everywhere), then settings in key order, and last the values
//! derived from the data (paths ending in `digest` or `shapes`, or under `normalisation`),
//! which differ whenever the data does.
//!
//! ```
//! use pbdl_core::io::{save_checkpoint, CheckpointMeta};
//! use pbdl_core::train::{canonical, check_resume};
//! use serde_json::json;
//!
//! let dir = tempfile::tempdir().unwrap();
//! check_resume(dir.path(), &json!({"lr": 0.1}), 10)?; // nothing to resume: passes
//! let config = canonical(json!({"lr": 0.1, "batch": 4}))?;
//! let w = candle_core::Tensor::zeros(2, candle_core::DType::F32, &candle_core::Device::Cpu)?;
//! let meta = CheckpointMeta { step: 5, seed: Some(1), config: config.clone() };
//! save_checkpoint(dir.path().join("step-5"), [("w", &w)], &meta)?;
//! check_resume(dir.path(), &config, 10)?; // the same settings: passes
//! let other = canonical(json!({"lr": 0.2, "batch": 4}))?;
//! let err = check_resume(dir.path(), &other, 10).unwrap_err();
//! assert!(matches!(err, pbdl_core::Error::ResumeMismatch { ref field, .. } if field == "lr"));
//! assert!(check_resume(dir.path(), &config, 4).is_err()); // fewer updates than stored
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::io::{latest_checkpoint, read_checkpoint_info};
use crate::{Error, Result};
use serde_json::Value;
use std::path::Path;

/// `v` as it reads back from a checkpoint sidecar: serialised and parsed once, so that floats
/// compare equal to a stored copy of the same value (serde_json's parser may round differently
/// from the value it printed, but it rounds the same text the same way every time).
///
/// Pass a config through it before comparing it with [`check_resume`] and before storing it.
/// Errors: [`Error::InvalidArgument`] (`config`) when the value does not serialise or read back.
pub fn canonical(v: Value) -> Result<Value> {
    let text = serde_json::to_string(&v)
        .map_err(|e| Error::invalid("canonical", "config", format!("does not serialise: {e}")))?;
    serde_json::from_str(&text).map_err(|e| Error::invalid("canonical", "config", format!("does not read back: {e}")))
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
/// first setting, then derived values (digests, shapes, the normalisation computed from the
/// data), which differ whenever the data does.
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

/// The [`LoopConfig`](super::LoopConfig) of one training phase of `steps` updates: without a
/// run directory an in-memory run without a progress bar; with one, the directory is first
/// checked by [`check_resume`] against `config`, then the run writes a checkpoint every tenth of
/// its updates and shows its progress. The settings a method's resumable phases share.
pub fn guarded_loop_config(steps: u64, dir: Option<&Path>, config: &Value) -> Result<super::LoopConfig> {
    Ok(match dir {
        None => super::LoopConfig { steps, progress: false, ..Default::default() },
        Some(d) => {
            check_resume(d, config, steps)?;
            super::LoopConfig {
                steps,
                checkpoint_every: (steps / 10).max(1),
                dir: Some(d.to_path_buf()),
                progress: true,
                ..Default::default()
            }
        }
    })
}

/// Refuses to resume `dir` when its newest checkpoint was written with another `config` than
/// the given one, or holds more than `steps` updates; nothing is loaded. A directory without
/// checkpoints (or no directory) passes.
///
/// `config` is compared after [`canonical`] with the sidecar's
/// [`CheckpointMeta::config`](crate::io::CheckpointMeta::config), so a config that was
/// stored as written compares equal; the first difference is chosen as the
/// [module docs](self) say.
///
/// Errors: [`Error::ResumeMismatch`] naming the first differing setting;
/// [`Error::InvalidArgument`] (op `check_resume`, argument `steps`) saying to ask for at least
/// the stored number of updates; IO and format errors reading the newest sidecar.
pub fn check_resume(dir: &Path, config: &Value, steps: u64) -> Result<()> {
    let Some(path) = latest_checkpoint(dir)? else { return Ok(()) };
    let info = read_checkpoint_info(&path)?;
    let given = canonical(config.clone())?;
    if let Some((field, stored, given)) = first_difference(&info.config, &given) {
        return Err(Error::ResumeMismatch { dir: dir.into(), field, stored, given });
    }
    if info.step > steps {
        return Err(Error::invalid(
            "check_resume",
            "steps",
            format!(
                "{} already holds {} updates, more than the {steps} asked for; ask for at least {}",
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
///
/// Errors: IO and format errors reading the file.
pub fn logged_losses(dir: &Path) -> Result<Vec<f64>> {
    let path = dir.join("loss.csv");
    if !path.exists() {
        return Ok(Vec::new());
    }
    Ok(super::ScalarLog::read(&path)?.column("loss").into_iter().map(|(_, l)| l).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{save_checkpoint, CheckpointMeta};
    use candle_core::{DType, Device, Tensor};
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
        // Arrays of other lengths and whole-value differences.
        assert_eq!(first_difference(&json!({"x": [1]}), &json!({"x": [1, 2]})).unwrap().0, "x");
        assert_eq!(first_difference(&json!(1), &json!(2)).unwrap().0, "config");
        // Floats survive the canonical round trip.
        let x = canonical(json!({"x": 0.1 + 0.2, "y": 1.0 / 3.0})).unwrap();
        assert_eq!(canonical(x.clone()).unwrap(), x);
    }

    fn checkpoint(dir: &Path, step: u64, config: Value) {
        let w = Tensor::zeros(3, DType::F32, &Device::Cpu).unwrap();
        let meta = CheckpointMeta { step, seed: Some(7), config };
        save_checkpoint(dir.join(format!("step-{step}")), [("w", &w)], &meta).unwrap();
    }

    #[test]
    fn resuming_checks_the_newest_checkpoint() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("run");
        let cfg = json!({"train": {"lr": 0.1 + 0.2, "batch": 4}, "seed": 3});
        // No directory, then an empty one: nothing to resume.
        check_resume(&dir, &cfg, 0).unwrap();
        std::fs::create_dir_all(&dir).unwrap();
        check_resume(&dir, &cfg, 0).unwrap();
        assert_eq!(logged_losses(&dir).unwrap(), Vec::<f64>::new());

        checkpoint(&dir, 2, json!({"train": {"lr": 1.0}}));
        checkpoint(&dir, 5, cfg.clone());
        // Only the newest checkpoint counts; the config is compared after `canonical`.
        check_resume(&dir, &cfg, 5).unwrap();
        check_resume(&dir, &canonical(cfg.clone()).unwrap(), 9).unwrap();
        let other = json!({"train": {"lr": 0.3, "batch": 4}, "seed": 3});
        match check_resume(&dir, &other, 9).unwrap_err() {
            e @ Error::ResumeMismatch { .. } => {
                let msg = e.to_string();
                assert!(msg.contains("`train.lr`") && msg.contains("new run directory"), "{msg}");
                let Error::ResumeMismatch { dir: d, field, given, .. } = e else { unreachable!() };
                assert_eq!((&*d, field.as_str(), given.as_str()), (dir.as_path(), "train.lr", "0.3"));
            }
            other => panic!("expected ResumeMismatch, got {other:?}"),
        }
        // Fewer updates than stored.
        match check_resume(&dir, &cfg, 4).unwrap_err() {
            Error::InvalidArgument { op: "check_resume", arg: "steps", reason } => {
                assert!(reason.contains("ask for at least 5"), "{reason}");
            }
            other => panic!("expected InvalidArgument, got {other:?}"),
        }
    }

    #[test]
    fn logged_losses_read_the_loss_column_back_exactly() {
        let tmp = tempfile::tempdir().unwrap();
        let mut log = super::super::ScalarLog::new();
        let losses = [0.1 + 0.2, 1.0 / 3.0, 2.5e-7];
        for (step, l) in losses.iter().enumerate() {
            log.log(step as u64, &[("loss", *l), ("lr", 0.01)]).unwrap();
        }
        log.save(tmp.path().join("loss.csv")).unwrap();
        assert_eq!(logged_losses(tmp.path()).unwrap(), losses.to_vec());
    }
}
