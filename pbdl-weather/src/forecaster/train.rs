//! Training the forecaster as Rasp & Thuerey did: Adam on a latitude-weighted MSE, the
//! learning rate cut by `plateau_factor` after `plateau_patience` epochs without a better
//! validation loss (Keras' ReduceLROnPlateau, min_delta 1e-4), early stopping after
//! `stop_patience` epochs without improvement with the best weights restored (Keras'
//! EarlyStopping with restore_best_weights). With a run directory, every epoch commits one
//! training checkpoint `train-<epochs done>` (weights, Adam's moments and update count, the
//! best weights so far, and the plateau / early-stopping state and history in its sidecar;
//! older ones are then removed) and exports the weights as `last` (with the state) and, when
//! they improved, `best`. A later call with the same directory resumes from the newest
//! training checkpoint; since the sample order, leads and dropout masks follow from the seed
//! and the epoch, a run killed at any point (`kill -9` included) resumes to the same history
//! and weights, bit for bit, as one that never stopped. A directory written before training
//! checkpoints existed (only `last` and `best`) still resumes, with Adam's moments restarted.

use crate::error::{Error, Result};
use crate::field::LeadForecast;
use crate::forecaster::data::{Dataset, Lead, Normalizer, SampleSpec};
use crate::forecaster::model::core_err;
use crate::forecaster::Forecaster;
use crate::grid::lat_weights;
use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarMap};
use pbdl_core::io::{list_checkpoints, load_varmap, save_checkpoint, save_varmap, CheckpointMeta};
use pbdl_core::train::{
    load_train_checkpoint, remove_checkpoint, remove_interrupted_writes, save_train_checkpoint, AdamConfig,
    OptimizerConfig, Progress,
};
use rand::seq::SliceRandom;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// File-name prefix of the training checkpoints, `train-<epochs done>`.
const TRAIN_CHECKPOINT: &str = "train-";
/// Name prefix of the best-weights snapshot inside a training checkpoint.
const BEST_PREFIX: &str = "best/";

/// Training settings (defaults: the paper's batch 32, patience 2 and 5, factor 0.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Samples per update.
    pub batch: usize,
    /// Initial learning rate (the paper: 5e-5 pretraining, 5e-7 fine-tuning on ERA5).
    pub lr: f64,
    /// Most epochs.
    pub max_epochs: usize,
    /// Updates per epoch; `None` is one pass over the training samples.
    pub steps_per_epoch: Option<usize>,
    /// Epochs without improvement before the learning rate drops.
    pub plateau_patience: usize,
    /// Factor of each drop.
    pub plateau_factor: f64,
    /// Epochs without improvement before training stops.
    pub stop_patience: usize,
    /// Seed of the sample order, the leads and the dropout masks.
    pub seed: u64,
    /// Run directory for checkpoints and resume; `None` keeps everything in memory.
    pub dir: Option<PathBuf>,
    /// Show a progress bar (where a terminal is attached).
    pub progress: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            batch: 32,
            lr: 1e-4,
            max_epochs: 20,
            steps_per_epoch: None,
            plateau_patience: 2,
            plateau_factor: 0.2,
            stop_patience: 5,
            seed: 0,
            dir: None,
            progress: true,
        }
    }
}

/// One epoch's record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    /// Epoch number (from 0).
    pub epoch: usize,
    /// Mean training loss of the epoch.
    pub train_loss: f64,
    /// Validation loss after the epoch.
    pub valid_loss: f64,
    /// Learning rate used in the epoch.
    pub lr: f64,
}

/// Everything needed to continue a run, stored with each `last` checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Epochs done.
    pub epochs_done: usize,
    /// Learning rate for the next epoch.
    pub lr: f64,
    /// Best validation loss so far and its epoch.
    pub best_valid: f64,
    /// Epoch of the best validation loss.
    pub best_epoch: usize,
    /// Epochs since the early-stopping best improved.
    pub stop_wait: usize,
    /// Best validation loss as the plateau rule sees it (needs an improvement of 1e-4).
    pub plateau_best: f64,
    /// Epochs since the plateau best improved.
    pub plateau_wait: usize,
    /// Whether early stopping ended the run.
    pub stopped_early: bool,
    /// Per-epoch records.
    pub history: Vec<EpochRecord>,
}

impl TrainState {
    fn new(lr: f64) -> Self {
        Self {
            epochs_done: 0,
            lr,
            best_valid: f64::INFINITY,
            best_epoch: 0,
            stop_wait: 0,
            plateau_best: f64::INFINITY,
            plateau_wait: 0,
            stopped_early: false,
            history: Vec::new(),
        }
    }
}

/// Latitude-weighted MSE `mean(w_lat (pred - target)^2)` with weights of mean 1.
pub fn lat_weighted_mse(pred: &Tensor, target: &Tensor, lat: &[f64]) -> Result<Tensor> {
    let w: Vec<f32> = lat_weights(lat).iter().map(|&x| x as f32).collect();
    let w = Tensor::from_vec(w, (1, 1, lat.len(), 1), pred.device())
        .map_err(core_err)?
        .to_dtype(pred.dtype())
        .map_err(core_err)?;
    (pred - target).and_then(|d| d.sqr()).and_then(|d| d.broadcast_mul(&w)).and_then(|d| d.mean_all()).map_err(core_err)
}

/// Deterministic leads for evaluation: the fixed one, or cycling through the range.
fn eval_leads(spec: &SampleSpec, n: usize) -> Vec<usize> {
    match spec.lead {
        Lead::Fixed(l) => vec![l; n],
        Lead::Continuous { min, max } => (0..n).map(|i| min + i % (max - min + 1)).collect(),
    }
}

/// Mean latitude-weighted MSE of the network (evaluation mode) over all samples of `data`.
pub fn evaluate(
    net: &dyn Forecaster,
    data: &Dataset,
    norm: &Normalizer,
    spec: &SampleSpec,
    batch: usize,
) -> Result<f64> {
    let inits = spec.init_indices(data);
    if inits.is_empty() {
        return Err(Error::InvalidArgument(format!(
            "no samples: {} times are too few for the history and lead",
            data.len()
        )));
    }
    let leads = eval_leads(spec, inits.len());
    let (mut sum, mut n) = (0.0, 0usize);
    for (ib, lb) in inits.chunks(batch).zip(leads.chunks(batch)) {
        let (x, y) = spec.batch(data, norm, ib, lb, &Device::Cpu)?;
        let loss = lat_weighted_mse(&net.forward(&x, false, 0)?, &y, &data.grid.lat)?;
        sum += loss.to_dtype(DType::F64).and_then(|l| l.to_scalar::<f64>()).map_err(core_err)? * ib.len() as f64;
        n += ib.len();
    }
    Ok(sum / n as f64)
}

fn snapshot(varmap: &VarMap) -> Result<HashMap<String, Tensor>> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    data.iter().map(|(k, v)| Ok((k.clone(), v.as_tensor().copy().map_err(core_err)?))).collect()
}

fn restore(varmap: &VarMap, snap: &HashMap<String, Tensor>) -> Result<()> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    for (k, v) in data.iter() {
        if let Some(t) = snap.get(k) {
            v.set(t).map_err(core_err)?;
        }
    }
    Ok(())
}

/// The newest training checkpoint of `dir`, if any.
fn latest_train_checkpoint(dir: &Path) -> Result<Option<PathBuf>> {
    let all = list_checkpoints(dir).map_err(core_err)?;
    let is_train = |p: &PathBuf| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with(TRAIN_CHECKPOINT));
    Ok(all.into_iter().map(|(p, _)| p).rfind(is_train))
}

/// Writes the checkpoint `path` with `save`, removing the old one under that name first (so
/// that a kill between the new weights and the new sidecar cannot pair them with the old ones).
fn replace(path: &Path, save: impl FnOnce(&Path) -> pbdl_core::Result<pbdl_core::io::CheckpointInfo>) -> Result<()> {
    remove_checkpoint(path).map_err(core_err)?;
    save(path).map_err(core_err)?;
    Ok(())
}

/// Trains `net` (its variables in `varmap`) on `train`, validating on `valid` after every
/// epoch; returns the final state (history, best epoch). The best weights are in `varmap`
/// afterwards. See the [module docs](self) for the run directory and resuming.
pub fn train(
    net: &dyn Forecaster,
    varmap: &VarMap,
    train: &Dataset,
    valid: &Dataset,
    norm: &Normalizer,
    spec: &SampleSpec,
    cfg: &TrainConfig,
) -> Result<TrainState> {
    if cfg.batch == 0
        || cfg.lr.is_nan()
        || cfg.lr <= 0.0
        || !(0.0..1.0).contains(&cfg.plateau_factor)
        || cfg.plateau_factor == 0.0
    {
        return Err(Error::InvalidArgument(format!("batch must be >= 1, lr > 0, plateau factor in (0, 1): {cfg:?}")));
    }
    let inits = spec.init_indices(train);
    if inits.is_empty() {
        return Err(Error::InvalidArgument(format!("no training samples in {} times", train.len())));
    }
    let ckpt = |name: &str| cfg.dir.as_ref().map(|d| d.join(name));
    let meta = |state: &TrainState| CheckpointMeta {
        step: state.epochs_done as u64,
        seed: Some(cfg.seed),
        config: serde_json::json!({ "state": state, "train": cfg, "spec": spec, "normalizer": norm, "net": net.describe() }),
    };
    let parse_state = |info: &pbdl_core::io::CheckpointInfo, path: &Path| -> Result<TrainState> {
        serde_json::from_value(info.config.get("state").cloned().unwrap_or_default())
            .map_err(|e| Error::InvalidArgument(format!("{}: not a pbdl-weather training state ({e})", path.display())))
    };
    let mut state = TrainState::new(cfg.lr);
    let mut best: Option<HashMap<String, Tensor>> = None;
    let mut resumed = None;
    if let Some(d) = &cfg.dir {
        std::fs::create_dir_all(d).map_err(|source| Error::Io { file: d.clone(), source })?;
        // Leftovers of a killed write: temporary files, weights whose sidecar never came.
        remove_interrupted_writes(d).map_err(core_err)?;
        if let Some(path) = latest_train_checkpoint(d)? {
            let ck = load_train_checkpoint(&path, varmap).map_err(core_err)?;
            state = parse_state(&ck.info, &path)?;
            let snap: HashMap<String, Tensor> = ck
                .extra
                .iter()
                .filter_map(|(k, t)| k.strip_prefix(BEST_PREFIX).map(|n| (n.to_string(), t.clone())))
                .collect();
            best = (!snap.is_empty()).then_some(snap);
            resumed = Some(ck);
        } else if let Some(last) = ckpt("last").filter(|l| l.with_extension("json").is_file()) {
            // A run directory from before training checkpoints: weights and state, no moments.
            let info = load_varmap(&last, varmap).map_err(core_err)?;
            state = parse_state(&info, &last)?;
            let best_path = ckpt("best").expect("dir set");
            if best_path.with_extension("json").is_file() {
                let current = snapshot(varmap)?;
                load_varmap(&best_path, varmap).map_err(core_err)?;
                best = Some(snapshot(varmap)?);
                restore(varmap, &current)?;
            }
        }
        // A kill while `last` or `best` was being replaced leaves none: export them again.
        if resumed.is_some() {
            if let Some(p) = ckpt("last").filter(|p| !p.with_extension("json").exists()) {
                replace(&p, |p| save_varmap(p, varmap, &meta(&state)))?;
            }
            if let (Some(p), Some(b)) = (ckpt("best").filter(|p| !p.with_extension("json").exists()), &best) {
                replace(&p, |p| save_checkpoint(p, b, &CheckpointMeta::at(state.best_epoch as u64)))?;
            }
        }
    }
    let vars = pbdl_core::nn::batch_norm::trainable_vars(varmap);
    let mut opt =
        OptimizerConfig::Adam(AdamConfig { lr: state.lr, ..Default::default() }).build(vars).map_err(core_err)?;
    if let Some(ck) = &resumed {
        ck.restore_optimizer(&mut opt, varmap).map_err(core_err)?;
    }
    let steps = cfg.steps_per_epoch.unwrap_or(inits.len().div_ceil(cfg.batch));
    let progress = Progress::new(((cfg.max_epochs.saturating_sub(state.epochs_done)) * steps) as u64);
    let mut step_count = 0u64;
    while state.epochs_done < cfg.max_epochs && !state.stopped_early {
        let epoch = state.epochs_done;
        opt.set_learning_rate(state.lr);
        let mut rng = pbdl_core::seed::rng(cfg.seed.wrapping_add(epoch as u64 * 1_000_003));
        let mut order = inits.clone();
        order.shuffle(&mut rng);
        let mut loss_sum = 0.0;
        for s in 0..steps {
            let batch: Vec<usize> = (0..cfg.batch).map(|k| order[(s * cfg.batch + k) % order.len()]).collect();
            let leads: Vec<usize> = match spec.lead {
                Lead::Fixed(l) => vec![l; batch.len()],
                Lead::Continuous { min, max } => (0..batch.len()).map(|_| rng.random_range(min..=max)).collect(),
            };
            let (x, y) = spec.batch(train, norm, &batch, &leads, &Device::Cpu)?;
            let dropout_seed = cfg.seed ^ ((epoch * steps + s) as u64).wrapping_mul(0x2545_F491_4F6C_DD1D);
            let loss = lat_weighted_mse(&net.forward(&x, true, dropout_seed)?, &y, &train.grid.lat)?;
            opt.backward_step(&loss).map_err(core_err)?;
            let l = loss.to_dtype(DType::F64).and_then(|l| l.to_scalar::<f64>()).map_err(core_err)?;
            if !l.is_finite() {
                return Err(Error::Model(format!(
                    "training loss is {l} at epoch {epoch}, step {s}: lower the learning rate"
                )));
            }
            loss_sum += l;
            step_count += 1;
            progress.update(step_count, l);
        }
        let valid_loss = evaluate(net, valid, norm, spec, cfg.batch)?;
        state.history.push(EpochRecord { epoch, train_loss: loss_sum / steps as f64, valid_loss, lr: state.lr });
        if valid_loss < state.best_valid {
            state.best_valid = valid_loss;
            state.best_epoch = epoch;
            state.stop_wait = 0;
            best = Some(snapshot(varmap)?);
            if let Some(p) = ckpt("best") {
                replace(&p, |p| save_varmap(p, varmap, &CheckpointMeta::at(epoch as u64)))?;
            }
        } else {
            state.stop_wait += 1;
        }
        if valid_loss < state.plateau_best - 1e-4 {
            state.plateau_best = valid_loss;
            state.plateau_wait = 0;
        } else {
            state.plateau_wait += 1;
            if state.plateau_wait >= cfg.plateau_patience {
                state.lr *= cfg.plateau_factor;
                state.plateau_wait = 0;
            }
        }
        state.stopped_early = state.stop_wait >= cfg.stop_patience;
        state.epochs_done += 1;
        if let Some(d) = &cfg.dir {
            // The commit point of the epoch: weights, Adam state and best weights in one file,
            // the plateau / early-stopping state in its sidecar.
            let name = format!("{TRAIN_CHECKPOINT}{}", state.epochs_done);
            let snap = best.iter().flatten().map(|(k, t)| (format!("{BEST_PREFIX}{k}"), t.clone())).collect();
            save_train_checkpoint(d.join(&name), varmap, &opt, snap, &meta(&state)).map_err(core_err)?;
            for (old, _) in list_checkpoints(d).map_err(core_err)? {
                let stem = old.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                if stem.starts_with(TRAIN_CHECKPOINT) && stem != name {
                    remove_checkpoint(&old).map_err(core_err)?;
                }
            }
            replace(&d.join("last"), |p| save_varmap(p, varmap, &meta(&state)))?;
        }
    }
    progress.finish();
    if let Some(b) = &best {
        restore(varmap, b)?;
    }
    Ok(state)
}

/// Forecasts at `lead` steps from each of `inits` (evaluation mode, in batches), one
/// [`LeadForecast`] per target variable in physical units.
pub fn predict(
    net: &dyn Forecaster,
    data: &Dataset,
    norm: &Normalizer,
    spec: &SampleSpec,
    inits: &[usize],
    lead: usize,
    batch: usize,
) -> Result<Vec<LeadForecast>> {
    match spec.lead {
        Lead::Fixed(l) if l != lead => {
            return Err(Error::InvalidArgument(format!("this network predicts {l} steps ahead, not {lead}")));
        }
        Lead::Continuous { min, max } if !(min..=max).contains(&lead) => {
            return Err(Error::InvalidArgument(format!(
                "lead {lead} steps is outside the trained range {min}..={max}"
            )));
        }
        _ => {}
    }
    let mut parts: Vec<Vec<LeadForecast>> = Vec::new();
    for ib in inits.chunks(batch.max(1)) {
        let leads = vec![lead; ib.len()];
        let (x, _) = spec.batch(data, norm, ib, &leads, &Device::Cpu)?;
        let out = net.forward(&x, false, 0)?;
        parts.push(spec.to_forecasts(data, norm, ib, lead, &out)?);
    }
    // Concatenate the batches per target variable.
    let mut merged = parts.first().cloned().unwrap_or_default();
    for part in parts.iter().skip(1) {
        for (m, p) in merged.iter_mut().zip(part) {
            m.init_times.extend_from_slice(&p.init_times);
            if let (crate::field::Values::F64(a), crate::field::Values::F64(b)) = (&mut m.values, &p.values) {
                a.extend_from_slice(b);
            }
        }
    }
    Ok(merged)
}
