//! Exact resume: the optimiser's state checkpointed with the weights, in one atomic commit.
//!
//! A resumed run repeats the uninterrupted one bit for bit only if it restarts from all the
//! state its updates depend on: the weights, the optimiser's moments and update count (Adam's
//! bias correction), and whatever the method draws at random (derive those draws from the seed
//! and the step, or replay them). [`save_train_checkpoint`] writes the variables of a `VarMap`
//! and the state of an [`Optim`] as tensors of one checkpoint (the optimiser's under
//! [`OPTIM_PREFIX`]), so the checkpoint's single commit (its sidecar, see
//! [`crate::io::checkpoint`]) covers both: a reader never sees weights of one step with moments
//! of another. [`load_train_checkpoint`] reads it back; [`TrainCheckpoint::restore_optimizer`]
//! puts the moments into a freshly built optimiser. Loaders that only want the weights
//! ([`crate::io::load_varmap`]) ignore the extra tensors.
//!
//! ```
//! use candle_core::{DType, Device};
//! use candle_nn::{Init, Optimizer, VarMap};
//! use pbdl_core::io::CheckpointMeta;
//! use pbdl_core::train::{load_train_checkpoint, save_train_checkpoint, sorted_vars, AdamConfig, OptimizerConfig};
//!
//! let dir = tempfile::tempdir().unwrap();
//! let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.1, ..Default::default() });
//! let model = |w0: f64| -> pbdl_core::Result<(VarMap, candle_core::Tensor)> {
//!     let varmap = VarMap::new();
//!     let w = varmap.get(2, "w", Init::Const(w0), DType::F64, &Device::Cpu)?;
//!     Ok((varmap, w))
//! };
//! let (varmap, w) = model(0.0)?;
//! let mut opt = adam.build(sorted_vars(&varmap).into_iter().map(|(_, v)| v).collect())?;
//! for _ in 0..3 {
//!     opt.backward_step(&(&w - 3.0)?.sqr()?.sum_all()?)?;
//! }
//! save_train_checkpoint(dir.path().join("step-3"), &varmap, &opt, Vec::new(), &CheckpointMeta::at(3))?;
//! opt.backward_step(&(&w - 3.0)?.sqr()?.sum_all()?)?;
//!
//! // A fresh process: new variables, new optimiser, state from the checkpoint.
//! let (varmap2, w2) = model(7.0)?;
//! let ck = load_train_checkpoint(dir.path().join("step-3"), &varmap2)?;
//! let mut opt2 = adam.build(sorted_vars(&varmap2).into_iter().map(|(_, v)| v).collect())?;
//! assert!(ck.restore_optimizer(&mut opt2, &varmap2)?);
//! opt2.backward_step(&(&w2 - 3.0)?.sqr()?.sum_all()?)?;
//! assert_eq!(w2.to_vec1::<f64>()?, w.to_vec1::<f64>()?); // the same fourth update, bit for bit
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use super::{Optim, OptimState};
use crate::io::{checkpoint_files, is_temp_file, load_checkpoint, load_varmap, save_checkpoint};
use crate::io::{CheckpointInfo, CheckpointMeta, CHECKPOINT_FORMAT};
use crate::{Error, Result};
use candle_core::{Device, Tensor, TensorId, Var};
use candle_nn::VarMap;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The name prefix of optimiser state in a checkpoint: `__optim__/<kind>/<slot>/<variable>`
/// (e.g. `__optim__/adamw/m/layer.weight`) and `__optim__/<kind>/steps`.
pub const OPTIM_PREFIX: &str = "__optim__/";

/// The variables of `varmap` sorted by name: a fixed order across processes (`VarMap::all_vars`
/// follows a `HashMap`, and the order of a gradient-norm sum changes its last bits).
pub fn sorted_vars(varmap: &VarMap) -> Vec<(String, Var)> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut named: Vec<(String, Var)> = data.iter().map(|(n, v)| (n.clone(), v.clone())).collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

fn names_by_id(varmap: &VarMap) -> HashMap<TensorId, String> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    data.iter().map(|(n, v)| (v.as_tensor().id(), n.clone())).collect()
}

fn kind_of(opt: &Optim) -> &'static str {
    match opt {
        Optim::AdamW(_) => "adamw",
        Optim::Sgd(_) => "sgd",
    }
}

fn slots_of(kind: &str) -> &'static [&'static str] {
    match kind {
        "adamw" => &["m", "v"],
        _ => &["momentum"],
    }
}

fn steps_name(kind: &str) -> String {
    format!("{OPTIM_PREFIX}{kind}/steps")
}

/// The optimiser's state as named tensors (see [`OPTIM_PREFIX`]); every optimised variable must
/// be a variable of `varmap` (that is where the names come from).
fn optimizer_tensors(opt: &Optim, varmap: &VarMap) -> Result<Vec<(String, Tensor)>> {
    let ids = names_by_id(varmap);
    let vars = opt.vars();
    let state = opt.state()?;
    let mut out = Vec::with_capacity(state.slots.len() + 1);
    for (i, slot, t) in state.slots {
        let name = ids.get(&vars[i].as_tensor().id()).ok_or_else(|| {
            Error::invalid(
                "save_train_checkpoint",
                "opt",
                format!("optimised variable {i} (shape {:?}) is not in the VarMap; build the optimiser from the VarMap's variables", vars[i].dims()),
            )
        })?;
        out.push((format!("{OPTIM_PREFIX}{}/{slot}/{name}", state.kind), t));
    }
    // i64: safetensors has no unsigned 64-bit type that candle reads.
    out.push((steps_name(state.kind), Tensor::new(&[state.steps as i64], &Device::Cpu)?));
    Ok(out)
}

/// Saves the checkpoint `path` ([`save_checkpoint`]): every variable of `varmap`, the state of
/// `opt` (built over variables of `varmap`) and `extra` named tensors (e.g. a best-weights
/// snapshot; names must not collide with the variables or start with [`OPTIM_PREFIX`]), all in
/// one file under one commit.
pub fn save_train_checkpoint(
    path: impl AsRef<Path>,
    varmap: &VarMap,
    opt: &Optim,
    extra: Vec<(String, Tensor)>,
    meta: &CheckpointMeta,
) -> Result<CheckpointInfo> {
    if let Some((name, _)) = extra.iter().find(|(n, _)| n.starts_with(OPTIM_PREFIX)) {
        return Err(Error::invalid(
            "save_train_checkpoint",
            "extra",
            format!("`{name}` starts with the reserved prefix {OPTIM_PREFIX}; rename it"),
        ));
    }
    let mut tensors: Vec<(String, Tensor)> =
        sorted_vars(varmap).into_iter().map(|(n, v)| (n, v.as_tensor().clone())).collect();
    tensors.extend(optimizer_tensors(opt, varmap)?);
    tensors.extend(extra);
    save_checkpoint(path, tensors, meta)
}

/// The state of `opt` (built over variables of `varmap`) as the named tensors that
/// [`save_train_checkpoint`] stores (under [`OPTIM_PREFIX`]): moments, momentum buffers and the
/// update count. For a method that runs its own [`Optim`] inside
/// [`super::TrainLoop::run_custom_with_state`]: return these from its state closure, and on
/// resume put them back with [`TrainCheckpoint::restore_optimizer`].
pub fn optimizer_state_tensors(opt: &Optim, varmap: &VarMap) -> Result<Vec<(String, Tensor)>> {
    optimizer_tensors(opt, varmap)
}

/// Saves the checkpoint `path` ([`save_checkpoint`]): every variable of `varmap` and the named
/// `state` tensors (a method's own state: parameters outside the `VarMap`, optimiser moments,
/// running averages, counters), all in one file under one commit. Names must not collide with
/// the variables (nor with each other); names under [`OPTIM_PREFIX`] should come from
/// [`optimizer_state_tensors`] (they load as optimiser state, the others as
/// [`TrainCheckpoint::extra`]). This is the checkpoint of
/// [`super::TrainLoop::run_custom_with_state`].
pub fn save_state_checkpoint(
    path: impl AsRef<Path>,
    varmap: &VarMap,
    state: Vec<(String, Tensor)>,
    meta: &CheckpointMeta,
) -> Result<CheckpointInfo> {
    let mut tensors: Vec<(String, Tensor)> =
        sorted_vars(varmap).into_iter().map(|(n, v)| (n, v.as_tensor().clone())).collect();
    if let Some((name, _)) = state.iter().find(|(n, _)| tensors.iter().any(|(v, _)| v == n)) {
        return Err(Error::invalid(
            "save_state_checkpoint",
            "state",
            format!("`{name}` is also a variable of the VarMap; give the state tensor another name"),
        ));
    }
    tensors.extend(state);
    save_checkpoint(path, tensors, meta)
}

/// A checkpoint loaded by [`load_train_checkpoint`]: its sidecar, the optimiser state (apply
/// it with [`TrainCheckpoint::restore_optimizer`]) and the other tensors.
#[derive(Clone, Debug)]
pub struct TrainCheckpoint {
    /// The sidecar (step, seed, config).
    pub info: CheckpointInfo,
    /// The tensors under [`OPTIM_PREFIX`].
    optim: HashMap<String, Tensor>,
    /// Tensors that are neither variables of the `VarMap` nor optimiser state (e.g. the
    /// `extra` of [`save_train_checkpoint`]).
    pub extra: HashMap<String, Tensor>,
}

impl TrainCheckpoint {
    /// Whether the checkpoint holds optimiser state (checkpoints of [`crate::io::save_varmap`],
    /// and those of pbdl before exact resume, do not).
    pub fn has_optimizer_state(&self) -> bool {
        !self.optim.is_empty()
    }

    /// The extra tensor `name` (see [`TrainCheckpoint::extra`]); a [`Error::Format`] naming the
    /// checkpoint and the stored extras when it is absent (a checkpoint of another method or
    /// version).
    pub fn extra_tensor(&self, name: &str) -> Result<&Tensor> {
        self.extra.get(name).ok_or_else(|| {
            let mut stored: Vec<&String> = self.extra.keys().collect();
            stored.sort();
            Error::Format {
                path: PathBuf::from(&self.info.weights_file),
                reason: format!(
                    "the checkpoint of step {} has no `{name}` (extra tensors: {stored:?}); was it written by another method or version? resume with the same trainer, or start a new run directory",
                    self.info.step
                ),
            }
        })
    }

    /// Restores the stored state into `opt`, built over the variables of `varmap` with the
    /// configuration the run was started with. `Ok(false)` when the checkpoint holds no
    /// optimiser state (the optimiser keeps its fresh state: moments restart, and the resumed
    /// run is close to, not equal to, an uninterrupted one). Errors (all before `opt` changes):
    /// the state of another optimiser kind, a variable without its stored slots, or stored
    /// slots of a variable the optimiser does not train.
    pub fn restore_optimizer(&self, opt: &mut Optim, varmap: &VarMap) -> Result<bool> {
        if self.optim.is_empty() {
            return Ok(false);
        }
        let kind = kind_of(opt);
        let bad = |reason: String| Error::Format { path: PathBuf::from(&self.info.weights_file), reason };
        let Some(steps) = self.optim.get(&steps_name(kind)) else {
            let mut stored: Vec<&String> = self.optim.keys().collect();
            stored.sort();
            return Err(bad(format!(
                "the checkpoint holds the state of another optimiser ({:?}), not {kind}; resume with the optimiser the run was started with, or start a new run directory",
                stored.first()
            )));
        };
        let steps = steps.flatten_all()?.to_vec1::<i64>()?.first().copied().unwrap_or(0);
        let ids = names_by_id(varmap);
        let mut slots = Vec::new();
        let mut used = 1; // the steps entry
        for (i, var) in opt.vars().iter().enumerate() {
            let name = ids.get(&var.as_tensor().id()).ok_or_else(|| {
                Error::invalid("restore_optimizer", "opt", format!("optimised variable {i} is not in the VarMap"))
            })?;
            let stored: Vec<(&'static str, &Tensor)> = slots_of(kind)
                .iter()
                .filter_map(|slot| self.optim.get(&format!("{OPTIM_PREFIX}{kind}/{slot}/{name}")).map(|t| (*slot, t)))
                .collect();
            // Adam has both moments for every variable; SGD's momentum buffer appears with the
            // first gradient of its variable, so it may be absent.
            if kind == "adamw" && stored.len() != 2 {
                return Err(bad(format!("no Adam moments for `{name}`: was the model changed since the checkpoint?")));
            }
            used += stored.len();
            slots.extend(stored.into_iter().map(|(slot, t)| (i, slot, t.clone())));
        }
        let of_kind = self.optim.keys().filter(|k| k.starts_with(&format!("{OPTIM_PREFIX}{kind}/"))).count();
        if used != of_kind {
            return Err(bad(format!(
                "{} optimiser tensors belong to no trained variable: was the model changed since the checkpoint?",
                of_kind - used
            )));
        }
        opt.set_state(&OptimState { kind, steps: steps as u64, slots })?;
        Ok(true)
    }
}

/// Loads the checkpoint `path` into the variables of `varmap` ([`load_varmap`]: all checked
/// before any is set) and returns its sidecar, optimiser state and other tensors.
pub fn load_train_checkpoint(path: impl AsRef<Path>, varmap: &VarMap) -> Result<TrainCheckpoint> {
    let path = path.as_ref();
    let info = load_varmap(path, varmap)?;
    let (tensors, again) = load_checkpoint(path, &Device::Cpu)?;
    if again.id != info.id {
        // Only a second writer in the same run directory can do this.
        return Err(Error::Format {
            path: checkpoint_files(path).0,
            reason: "the checkpoint was replaced while it was being loaded; run one trainer per run directory".into(),
        });
    }
    let vars = varmap.data().lock().unwrap_or_else(|e| e.into_inner()).keys().cloned().collect::<Vec<_>>();
    let (mut optim, mut extra) = (HashMap::new(), HashMap::new());
    for (name, t) in tensors {
        if name.starts_with(OPTIM_PREFIX) {
            optim.insert(name, t);
        } else if !vars.contains(&name) {
            extra.insert(name, t);
        }
    }
    Ok(TrainCheckpoint { info, optim, extra })
}

/// Removes the checkpoint `path` if it exists: its sidecar first (the checkpoint is gone from
/// then on, atomically), then its weights. Before a checkpoint is rewritten under the same
/// name, this keeps a kill between the two files of the new one from pairing the new weights
/// with the old sidecar: a reader finds the old checkpoint, none, or the new one.
pub fn remove_checkpoint(path: impl AsRef<Path>) -> Result<()> {
    let (weights, sidecar) = checkpoint_files(path);
    for p in [sidecar, weights] {
        match std::fs::remove_file(&p) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(Error::io(&p, e)),
            _ => {}
        }
    }
    Ok(())
}

/// Removes what a killed checkpoint writer leaves in the run directory `dir`: temporary files
/// of [`crate::io::write_atomic`] and pbdl checkpoint weights whose sidecar was never written
/// (the commit did not happen, so they are not a checkpoint). Returns the removed paths.
/// Call it only while no other process writes into `dir` (a run directory has one trainer).
pub fn remove_interrupted_writes(dir: impl AsRef<Path>) -> Result<Vec<PathBuf>> {
    let dir = dir.as_ref();
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut removed = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        let orphan = || {
            path.extension().is_some_and(|e| e == "safetensors")
                && !checkpoint_files(&path).1.exists()
                && is_pbdl_weights(&path)
        };
        if is_temp_file(&path) || orphan() {
            std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
            removed.push(path);
        }
    }
    removed.sort();
    Ok(removed)
}

/// Whether `path` is a safetensors file written by [`save_checkpoint`] (its header metadata
/// says so); other safetensors files in a run directory are left alone.
fn is_pbdl_weights(path: &Path) -> bool {
    let Ok(bytes) = std::fs::read(path) else { return false };
    let Ok((_, header)) = safetensors::SafeTensors::read_metadata(&bytes) else { return false };
    header.metadata().as_ref().and_then(|m| m.get("format")).is_some_and(|f| f == CHECKPOINT_FORMAT)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::{AdamConfig, OptimizerConfig, SgdConfig};
    use candle_core::DType;
    use candle_nn::{Init, Optimizer};

    fn two_vars(v: f64) -> VarMap {
        let varmap = VarMap::new();
        varmap.get((2, 3), "a.weight", Init::Const(v), DType::F32, &Device::Cpu).unwrap();
        varmap.get(3, "a.bias", Init::Const(v), DType::F32, &Device::Cpu).unwrap();
        varmap
    }

    fn loss(varmap: &VarMap) -> Tensor {
        let v = sorted_vars(varmap);
        let s = |t: &Var| t.as_tensor().sqr().unwrap().sum_all().unwrap();
        (s(&v[0].1) + (&v[1].1.as_tensor().sum_all().unwrap() * 3.0).unwrap()).unwrap()
    }

    fn build(cfg: &OptimizerConfig, varmap: &VarMap) -> Optim {
        cfg.build(sorted_vars(varmap).into_iter().map(|(_, v)| v).collect()).unwrap()
    }

    fn bits(varmap: &VarMap) -> Vec<(String, Vec<u32>)> {
        sorted_vars(varmap)
            .into_iter()
            .map(|(n, v)| {
                (
                    n,
                    v.as_tensor()
                        .flatten_all()
                        .unwrap()
                        .to_vec1::<f32>()
                        .unwrap()
                        .iter()
                        .map(|x| x.to_bits())
                        .collect(),
                )
            })
            .collect()
    }

    /// Adam and SGD-momentum resumed from a checkpoint take the same next updates, bit for bit,
    /// as the optimiser that kept running; without the state they do not.
    #[test]
    fn restored_optimizers_continue_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        for cfg in [
            OptimizerConfig::Adam(AdamConfig { lr: 0.05, ..Default::default() }),
            OptimizerConfig::Sgd(SgdConfig { lr: 0.05, momentum: 0.9, ..Default::default() }),
        ] {
            let path = dir.path().join("ck");
            let varmap = two_vars(1.0);
            let mut opt = build(&cfg, &varmap);
            for _ in 0..4 {
                opt.backward_step(&loss(&varmap)).unwrap();
            }
            save_train_checkpoint(&path, &varmap, &opt, vec![], &CheckpointMeta::at(4)).unwrap();
            for _ in 0..3 {
                opt.backward_step(&loss(&varmap)).unwrap();
            }
            let (resumed, cold) = (two_vars(-5.0), two_vars(-5.0));
            let ck = load_train_checkpoint(&path, &resumed).unwrap();
            load_train_checkpoint(&path, &cold).unwrap();
            assert!(ck.has_optimizer_state() && ck.extra.is_empty());
            let mut opt2 = build(&cfg, &resumed);
            assert!(ck.restore_optimizer(&mut opt2, &resumed).unwrap());
            let mut opt3 = build(&cfg, &cold);
            for _ in 0..3 {
                opt2.backward_step(&loss(&resumed)).unwrap();
                opt3.backward_step(&loss(&cold)).unwrap();
            }
            assert_eq!(bits(&resumed), bits(&varmap), "{cfg:?}");
            assert_ne!(bits(&cold), bits(&varmap), "{cfg:?}: restarting the moments must show");
            // The state does not load into another optimiser kind.
            let other = match cfg {
                OptimizerConfig::Sgd(_) => OptimizerConfig::Adam(AdamConfig::default()),
                _ => OptimizerConfig::Sgd(SgdConfig::default()),
            };
            let e = ck.restore_optimizer(&mut build(&other, &resumed), &resumed).unwrap_err();
            assert!(e.to_string().contains("another optimiser"), "{e}");
        }
    }

    /// A plain weights checkpoint loads, with no optimiser state to restore; extra tensors come
    /// back by name; interrupted writes are removed, complete checkpoints kept.
    #[test]
    fn weights_only_checkpoints_extras_and_cleanup() {
        let dir = tempfile::tempdir().unwrap();
        let varmap = two_vars(2.0);
        crate::io::save_varmap(dir.path().join("plain"), &varmap, &CheckpointMeta::at(1)).unwrap();
        let ck = load_train_checkpoint(dir.path().join("plain"), &two_vars(0.0)).unwrap();
        let mut opt = build(&OptimizerConfig::default(), &varmap);
        assert!(!ck.has_optimizer_state());
        assert!(!ck.restore_optimizer(&mut opt, &varmap).unwrap());

        let snap = Tensor::new(&[1.5f32, 2.5], &Device::Cpu).unwrap();
        save_train_checkpoint(
            dir.path().join("full"),
            &varmap,
            &opt,
            vec![("best/x".into(), snap)],
            &CheckpointMeta::at(2),
        )
        .unwrap();
        let ck = load_train_checkpoint(dir.path().join("full"), &two_vars(0.0)).unwrap();
        assert_eq!(ck.extra["best/x"].to_vec1::<f32>().unwrap(), [1.5, 2.5]);
        let bad = vec![(format!("{OPTIM_PREFIX}x"), Tensor::new(&[1f32], &Device::Cpu).unwrap())];
        assert!(save_train_checkpoint(dir.path().join("bad"), &varmap, &opt, bad, &CheckpointMeta::at(3)).is_err());

        // A killed writer's leftovers: weights without a sidecar, a temporary file.
        crate::io::save_varmap(dir.path().join("step-9"), &varmap, &CheckpointMeta::at(9)).unwrap();
        std::fs::remove_file(dir.path().join("step-9.json")).unwrap();
        std::fs::write(dir.path().join(".step-10.safetensors.1.0.tmp"), b"half").unwrap();
        std::fs::write(dir.path().join("other.safetensors"), b"not pbdl").unwrap();
        let removed = remove_interrupted_writes(dir.path()).unwrap();
        let names: Vec<String> =
            removed.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert_eq!(names, [".step-10.safetensors.1.0.tmp", "step-9.safetensors"]);
        assert!(dir.path().join("full.json").exists() && dir.path().join("other.safetensors").exists());
    }
}
