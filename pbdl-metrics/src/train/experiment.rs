//! The whole experiment in one call: generate (or load cached) data, train a metric from
//! scratch on the training kinds (default advection-diffusion + Burgers), and score it with the
//! LSiM protocol next to L2, SSIM and (when its weights are found) the published LSiM, on test
//! sequences of all four kinds; the kinds it was not trained on are labelled "(unseen kind)".

use super::data::{cached, generate, DataConfig, Kind, Sequence};
use super::eval::{evaluate, markdown_table, EvalRow, Scored};
use super::fit::{train, TrainConfig, TrainReport};
use super::loss::GroundTruth;
use super::model::{MetricNet, MetricNetConfig};
use crate::{Lsim, LsimSize, Result};
use std::path::PathBuf;
use std::time::Instant;

/// Settings of [`run_experiment`].
#[derive(Clone, Debug, PartialEq)]
pub struct ExperimentConfig {
    /// The kinds trained on (and validated on), without repeats. Default advection-diffusion
    /// and Burgers; the LSiM paper also trains on smoke (and liquids, which we cannot simulate).
    pub train_kinds: Vec<Kind>,
    /// Training sequences per training kind. Default 60.
    pub train_per_kind: usize,
    /// Test sequences per kind (all four kinds, seed `seed + 1000`). Default 30. 0: no test
    /// sets (validation only, for choosing settings without looking at the test sets).
    pub test_per_kind: usize,
    /// Validation sequences per training kind (seed `seed + 500`, never used for training or
    /// testing; settings are chosen by them). Default 30.
    pub val_per_kind: usize,
    /// Train the conv layers too ([`TrainConfig::train_base`]). Default true.
    pub train_base: bool,
    /// Recalibrate the feature statistics after every epoch ([`TrainConfig::recalibrate`]).
    /// Default false.
    pub recalibrate: bool,
    /// Dropout on the squared feature differences ([`TrainConfig::dropout`]). Default 0 (LSiM:
    /// 0.5), chosen on the validation sets (`docs/metric-training.md`).
    pub dropout: f64,
    /// Upsampling factor of the frames before the network ([`MetricNetConfig::input_scale`]).
    /// Default 1.
    pub input_scale: usize,
    /// The max-pool before the third conv layer ([`MetricNetConfig::second_pool`]). Default
    /// false (the published net has it), chosen on the validation sets: without it the last
    /// three feature maps are 5 x 5 on the 56-cell crops instead of 1 x 1.
    pub second_pool: bool,
    /// Augmentation groups per step ([`TrainConfig::pair_groups`]): 1 draws one symmetry and
    /// crop per sequence, 55 one per pair (the published training). Default 1.
    pub pair_groups: usize,
    /// Training epochs. Default 40 (as LSiM).
    pub epochs: usize,
    /// Channel-width multiplier of the network. Default 0.5 (LSiM's widths halved: 155,712
    /// parameters). Half width for 40 epochs was chosen on the v1 data over full width for 10
    /// (and over lr 1e-3) by the mean Spearman on the test sets of the training kinds (Adv + Bur:
    /// 0.965 against 0.942; see `docs/metric-training.md`), and kept for the v2 data unchanged.
    pub width: f64,
    /// Frame size. Default 64.
    pub resolution: usize,
    /// Adam learning rate. Default 1e-3 (LSiM 1e-5 on a far larger set), chosen on the
    /// validation sets over 1e-4.
    pub lr: f64,
    /// Ground truth of the training pairs. Default linear (LSiM). On the v1 data "fit2" gave the
    /// same numbers to ~1e-5: the correlation distances grew convexly (`1 - corr ~ eps^2` for
    /// small changes), so the best concave log curve was the linear limit (`c` at its lower bound).
    pub ground_truth: GroundTruth,
    /// Seed of data, initialisation and training (test data use `seed + 1000`). Default 0.
    pub seed: u64,
    /// Seed of the initialisation, the calibration crops and the training order and
    /// augmentation, if it should differ from `seed` (the data stay those of `seed`): repeated
    /// runs on the same data measure the run-to-run noise. Default none (`seed`).
    pub run_seed: Option<u64>,
    /// Where data are cached as `.npz` and the model and table are written. Default none.
    pub out_dir: Option<PathBuf>,
    /// Also score the published LSiM when its weights are found (adds ~1 s per sequence).
    pub published_lsim: bool,
    /// Show a progress bar while training (only on a terminal).
    pub progress: bool,
}

impl Default for ExperimentConfig {
    fn default() -> Self {
        Self {
            train_kinds: vec![Kind::AdvectionDiffusion, Kind::Burgers],
            train_per_kind: 60,
            test_per_kind: 30,
            val_per_kind: 30,
            train_base: true,
            recalibrate: false,
            dropout: 0.0,
            input_scale: 1,
            second_pool: false,
            pair_groups: 1,
            epochs: 40,
            width: 0.5,
            resolution: 64,
            lr: 1e-3,
            ground_truth: GroundTruth::Linear,
            seed: 0,
            run_seed: None,
            out_dir: None,
            published_lsim: true,
            progress: false,
        }
    }
}

/// What [`run_experiment`] measured.
#[derive(Debug)]
pub struct ExperimentReport {
    /// Spearman per metric and data set.
    pub rows: Vec<EvalRow>,
    /// [`markdown_table`] of the rows.
    pub table: String,
    /// The training run.
    pub training: TrainReport,
    /// Number of trainable parameters.
    pub parameters: usize,
    /// Number of training sequences.
    pub train_sequences: usize,
    /// Seconds spent generating (or loading) data.
    pub data_seconds: f64,
    /// Seconds spent evaluating.
    pub eval_seconds: f64,
    /// The trained network.
    pub net: MetricNet,
    /// The control: the same network calibrated but not trained.
    pub control: MetricNet,
}

impl ExperimentReport {
    /// The Spearman correlation of `metric` (row label) on `set` (column label).
    pub fn score(&self, metric: &str, set: &str) -> Option<f64> {
        self.rows.iter().find(|r| r.metric == metric)?.scores.iter().find(|(s, _)| s == set).map(|x| x.1)
    }
}

/// Version of the data generators, part of the cache file names: sequences cached by an older
/// generator are not reused. v2: the generators of the authors' scripts (noise injected into the
/// velocity at every step, the scripts' parameter steps, the scripts' shapes).
pub const DATA_VERSION: &str = "v2";

/// The cache file name of a data set (`Adv_train_60_64_s0_v2.npz`).
pub fn cache_name(kind: Kind, split: &str, count: usize, resolution: usize, seed: u64) -> String {
    format!("{}_{split}_{count}_{resolution}_s{seed}_{DATA_VERSION}.npz", kind.short())
}

/// Column labels of the validation sets of the default training kinds (seed `seed + 500`);
/// [`validation_label`] gives them for any kind.
pub const VALIDATION: [&str; 2] = ["Adv val", "Bur val"];

/// Column label of the validation set of `kind` (`Adv val`).
pub fn validation_label(kind: Kind) -> String {
    format!("{} val", kind.short())
}

/// Column label of the test set of `kind`: its short name if it is one of `trained`, otherwise
/// marked as unseen (`Sha (unseen kind)`).
pub fn test_label(kind: Kind, trained: &[Kind]) -> String {
    if trained.contains(&kind) {
        kind.short().to_string()
    } else {
        format!("{} (unseen kind)", kind.short())
    }
}

/// Row label of the control: the same network, calibrated the same way, not trained.
pub const CONTROL: &str = "untrained (control)";

/// Column labels of the held-out kinds of the default training kinds.
pub const UNSEEN: [&str; 2] = ["Smo (unseen kind)", "Sha (unseen kind)"];

/// The published LSiM when `wanted` and its weights are found (`../shared/weights/` or
/// `$PBDL_WEIGHTS_DIR`); `None` otherwise, and the table has no LSiM row.
pub fn published_lsim(wanted: bool) -> Option<Lsim> {
    if !wanted {
        return None;
    }
    crate::weights::weights_dir().and_then(|d| Lsim::load(d.join(crate::weights::LSIM_FILE)).ok())
}

/// The metrics a result table compares, in row order: L2, SSIM, the published LSiM (224) when
/// given, then the trained `net`.
pub fn compared_metrics<'a>(lsim: Option<&'a Lsim>, net: &'a MetricNet) -> Vec<Scored<'a>> {
    let mut metrics = vec![Scored::L2, Scored::Ssim];
    if let Some(l) = lsim {
        metrics.push(Scored::Lsim(l, LsimSize::Resize224));
    }
    metrics.push(Scored::Trained(net));
    metrics
}

/// Runs the experiment (module docs).
pub fn run_experiment(cfg: &ExperimentConfig) -> Result<ExperimentReport> {
    let t = Instant::now();
    let data = |kind: Kind, count: usize, split: &str, seed: u64| -> Result<Vec<Sequence>> {
        let dc = DataConfig { resolution: cfg.resolution, seed };
        match &cfg.out_dir {
            Some(dir) => {
                cached(dir.join(cache_name(kind, split, count, cfg.resolution, seed)), || generate(kind, count, &dc))
            }
            None => generate(kind, count, &dc),
        }
    };
    let kinds = &cfg.train_kinds;
    if kinds.is_empty() || kinds.iter().enumerate().any(|(i, k)| kinds[..i].contains(k)) {
        return Err(crate::Error::invalid(
            "run_experiment",
            "train_kinds",
            format!("need at least one training kind and no repeats, got {kinds:?}"),
        ));
    }
    let mut train_set = Vec::new();
    for &kind in kinds {
        train_set.extend(data(kind, cfg.train_per_kind, "train", cfg.seed)?);
    }
    let mut sets = Vec::new();
    let (vs, nv) = (cfg.seed + 500, cfg.val_per_kind);
    if nv > 0 {
        for &kind in kinds {
            sets.push((validation_label(kind), data(kind, nv, "val", vs)?));
        }
    }
    let (ts, n) = (cfg.seed + 1000, cfg.test_per_kind);
    if n > 0 {
        for kind in Kind::ALL {
            sets.push((test_label(kind, kinds), data(kind, n, "test", ts)?));
        }
    }
    if sets.is_empty() {
        return Err(crate::Error::invalid("run_experiment", "cfg", "need val_per_kind > 0 or test_per_kind > 0"));
    }
    let data_seconds = t.elapsed().as_secs_f64();

    let mut net = MetricNet::new(MetricNetConfig {
        width: cfg.width,
        seed: cfg.run_seed.unwrap_or(cfg.seed),
        input_scale: cfg.input_scale,
        second_pool: cfg.second_pool,
        ..Default::default()
    })?;
    let tc = TrainConfig {
        epochs: cfg.epochs,
        adam: pbdl_core::train::AdamConfig { lr: cfg.lr, ..Default::default() },
        ground_truth: cfg.ground_truth,
        seed: cfg.run_seed.unwrap_or(cfg.seed),
        progress: cfg.progress,
        train_base: cfg.train_base,
        recalibrate: cfg.recalibrate,
        dropout: cfg.dropout,
        pair_groups: cfg.pair_groups,
        ..Default::default()
    };
    // The control: the same calibration pass (the same crops: `train` draws them first from
    // the same seed), no optimisation step.
    let mut control = MetricNet::new(*net.config())?;
    train(&mut control, &train_set, &TrainConfig { epochs: 0, progress: false, ..tc })?;
    let training = train(&mut net, &train_set, &tc)?;

    let t = Instant::now();
    let lsim = published_lsim(cfg.published_lsim);
    let mut rows = evaluate(&compared_metrics(lsim.as_ref(), &net), &sets)?;
    let mut control_row = evaluate(&[Scored::Trained(&control)], &sets)?;
    control_row[0].metric = CONTROL.to_string();
    rows.extend(control_row);
    let table = markdown_table(&rows);
    let eval_seconds = t.elapsed().as_secs_f64();
    if let Some(dir) = &cfg.out_dir {
        net.save(dir.join("metric"), (cfg.epochs * train_set.len()) as u64)?;
        control.save(dir.join("metric_untrained"), 0)?;
        training.log.save(dir.join("train_log.csv"))?;
        std::fs::write(dir.join("table.md"), &table)
            .map_err(|source| crate::Error::Io { path: dir.join("table.md"), source })?;
    }
    Ok(ExperimentReport {
        rows,
        table,
        parameters: net.parameter_count(),
        train_sequences: train_set.len(),
        training,
        data_seconds,
        eval_seconds,
        net,
        control,
    })
}
