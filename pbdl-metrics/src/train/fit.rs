//! The training loop: calibration epoch, then Adam over single sequences (batch of one
//! sequence, as both papers), the published LSiM augmentation (random flips, quarter turns and
//! crops; channel shuffling does not apply to scalar frames) and dropout, the LSiM or VolSiM
//! loss on all 55 pairs.
//!
//! The published training draws a flip, turn and crop per pair. By default here one per
//! sequence, so that the 11 frames pass the network once per step instead of 110 times;
//! [`TrainConfig::pair_groups`] splits the 55 pairs into random groups with one draw each (55
//! groups: the published per-pair augmentation, at up to ten times the cost).
//!
//! [`train_resumable`] is the same training in a run directory: `loss.csv` and atomic
//! checkpoints, each one commit of the weights, Adam's state, the step and the normalisation
//! statistics; a second call with the same directory resumes from the newest checkpoint and
//! ends with the same `loss.csv` and checkpoints, bit for bit, as a run that never stopped
//! (kill -9 included; `tests/crash_resume.rs`). No draw of the training depends on the network
//! (sequence order, symmetries, crop windows, dropout seeds, calibration crops), so a resumed
//! run replays the draws of the steps before its checkpoint from the seed instead of storing
//! the random generator.

use super::data::Sequence;
use super::loss::{ground_truth, metric_loss, pairs, GroundTruth, LossConfig};
use super::model::{to_byte_range, LayerStats, MetricNet};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::VarMap;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, OptimizerConfig, ScalarLog, StepInfo, TrainLoop};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::Rng;
use std::cell::RefCell;
use std::path::Path;
use std::time::Instant;

/// Settings of [`train`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainConfig {
    /// Passes over the training sequences after the calibration epoch. Default 10.
    pub epochs: usize,
    /// Adam settings. Default: lr 1e-4 (LSiM 1e-5 over 40 epochs of a much larger set, VolSiM
    /// 1e-4).
    pub adam: AdamConfig,
    /// Ground truth of the pairs. Default linear (LSiM).
    pub ground_truth: GroundTruth,
    /// Loss weights. Default LSiM's.
    pub loss: LossConfig,
    /// Random flips and 90-degree rotations of each sequence. Default on.
    pub augment: bool,
    /// Side of the random square crop of each training sequence, as a fraction of the frame
    /// (LSiM: 224 of 256 = 0.875; 64-cell frames give 56). 1.0: no crop. Default 0.875. The
    /// calibration pass sees one random crop per sequence too (as the published calibration,
    /// which runs on the training loader).
    pub crop: f64,
    /// Dropout probability on the squared feature differences during training (LSiM: 0.5).
    /// Default 0.5.
    pub dropout: f64,
    /// Gradient clipping. Default none.
    pub clip: ClipConfig,
    /// Train the conv layers of the base network too (LSiM trains its base network from
    /// scratch). `false`: only the channel weights train, on the random features. Default true.
    pub train_base: bool,
    /// Recompute the normalisation statistics after every epoch with the current conv weights
    /// (on new random crops). `false`: the statistics of the calibration pass before training
    /// stay frozen while the features they normalise change. Default false.
    pub recalibrate: bool,
    /// Number of random groups the 55 pairs of a step are split into, each group with its own
    /// symmetry and crop window ([`random_pair_groups`]); 1: one draw for the whole sequence,
    /// 55: one per pair as the published training. Default 1.
    pub pair_groups: usize,
    /// Seed of the shuffling and the augmentation. Default 0.
    pub seed: u64,
    /// Show a progress bar (only on a terminal). Default off.
    pub progress: bool,
    /// Updates between the checkpoints of a run directory ([`train_resumable`]), which also
    /// writes one after the last update; 0: only that one. Ignored by [`train`]. Default 0.
    pub checkpoint_every: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            epochs: 10,
            adam: AdamConfig { lr: 1e-4, ..Default::default() },
            ground_truth: GroundTruth::Linear,
            loss: LossConfig::LSIM,
            augment: true,
            crop: 0.875,
            dropout: 0.5,
            clip: ClipConfig::None,
            train_base: true,
            recalibrate: false,
            pair_groups: 1,
            seed: 0,
            progress: false,
            checkpoint_every: 0,
        }
    }
}

/// What [`train`] measured.
#[derive(Clone, Debug)]
pub struct TrainReport {
    /// Mean loss of each epoch (over its sequences, before each step's update); with a run
    /// directory, of the whole run (the steps before a resume read back from `loss.csv`).
    pub epoch_loss: Vec<f64>,
    /// Per-step scalars: `loss`, `grad_norm` (with a run directory: of the whole run, as for
    /// `epoch_loss`).
    pub log: ScalarLog,
    /// Seconds of the calibration pass (of a resumed run: of restoring its checkpoint's
    /// statistics and replaying the draws before it).
    pub calibration_seconds: f64,
    /// Seconds of the optimisation epochs (of this call).
    pub train_seconds: f64,
    /// The step this call started from: the resumed checkpoint's, 0 for a fresh run.
    pub resumed_from: u64,
}

/// One of the eight symmetries of the square applied to every frame of `[n, c, y, x]`:
/// `code & 3` quarter turns, then a flip along x if `code & 4`.
pub fn augment(frames: &Tensor, code: u8) -> Result<Tensor> {
    let flip_x = |t: &Tensor| -> Result<Tensor> {
        let n = t.dim(3)?;
        let idx = Tensor::from_vec((0..n as u32).rev().collect::<Vec<_>>(), n, &Device::Cpu)?;
        Ok(t.index_select(&idx, 3)?)
    };
    let mut t = frames.clone();
    for _ in 0..(code & 3) {
        // A quarter turn: transpose, then mirror.
        t = flip_x(&t.transpose(2, 3)?.contiguous()?)?;
    }
    if code & 4 != 0 {
        t = flip_x(&t)?;
    }
    Ok(t)
}

/// A random `side x side` window of every frame of `[n, c, y, x]` (the same window for all).
pub fn random_crop(frames: &Tensor, side: usize, rng: &mut impl Rng) -> Result<Tensor> {
    let window = crop_window(frames.dim(2)?, frames.dim(3)?, side, rng)?;
    apply_crop(frames, window)
}

/// A crop window `(top, left, side)` in `h x w` frames: the draws of [`random_crop`].
fn crop_window(h: usize, w: usize, side: usize, rng: &mut impl Rng) -> Result<(usize, usize, usize)> {
    if side == 0 || side > h || side > w {
        return Err(Error::invalid("random_crop", "side", format!("need 1 <= side <= {}, got {side}", h.min(w))));
    }
    let top = rng.random_range(0..=h - side);
    let left = rng.random_range(0..=w - side);
    Ok((top, left, side))
}

/// The window `(top, left, side)` of every frame of `[n, c, y, x]`.
fn apply_crop(frames: &Tensor, (top, left, side): (usize, usize, usize)) -> Result<Tensor> {
    Ok(frames.narrow(2, top, side)?.narrow(3, left, side)?.contiguous()?)
}

/// The crop side for `h x w` frames and a crop fraction (at least 1 cell).
fn side_of(h: usize, w: usize, fraction: f64) -> usize {
    let n = h.min(w);
    ((n as f64 * fraction).round() as usize).clamp(1, n)
}

/// The training loss of one sequence `[11, 1, y, x]` against its 55 ground truth distances.
pub fn sequence_loss(net: &MetricNet, frames: &Tensor, gt: &[f64], loss: &LossConfig) -> Result<Tensor> {
    sequence_loss_dropout(net, frames, gt, loss, 0.0, 0)
}

/// [`sequence_loss`] with dropout `p` on the squared feature differences (seeded).
pub fn sequence_loss_dropout(
    net: &MetricNet,
    frames: &Tensor,
    gt: &[f64],
    loss: &LossConfig,
    p: f64,
    seed: u64,
) -> Result<Tensor> {
    let feats = net.features(&to_byte_range(frames)?)?;
    let d = net.pair_distances_dropout(&feats, &pairs(), p, seed)?;
    let g = Tensor::from_slice(gt, gt.len(), &Device::Cpu)?.to_dtype(d.dtype())?;
    metric_loss(&d, &g, loss)
}

/// One group of the per-pair augmentation: pairs (indices into [`pairs`]) that share one
/// symmetry of the square ([`augment`] code) and one crop window.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PairGroup {
    /// Indices into [`pairs`].
    pub pairs: Vec<usize>,
    /// The [`augment`] code (0: identity).
    pub symmetry: u8,
    /// Top row of the crop window (after the symmetry).
    pub top: usize,
    /// Left column of the crop window (after the symmetry).
    pub left: usize,
}

/// The 55 pairs shuffled and split into `groups` groups of near-equal size (at most 55), each
/// with a random symmetry (identity if `!augment`) and a random `side x side` window of
/// `n x n` frames.
pub fn random_pair_groups(groups: usize, n: usize, side: usize, augment: bool, rng: &mut impl Rng) -> Vec<PairGroup> {
    let mut order: Vec<usize> = (0..pairs().len()).collect();
    order.shuffle(rng);
    let g = groups.clamp(1, order.len());
    let side = side.min(n);
    (0..g)
        .map(|k| PairGroup {
            pairs: order[k * order.len() / g..(k + 1) * order.len() / g].to_vec(),
            symmetry: if augment { rng.random_range(0..8) } else { 0 },
            top: rng.random_range(0..=n - side),
            left: rng.random_range(0..=n - side),
        })
        .collect()
}

/// Distances of all 55 pairs of one sequence `[11, 1, n, n]` (in [`pairs`] order) when every
/// pair group of `plan` sees its own symmetry and `side x side` crop. The cropped frames of all
/// groups are mapped jointly to [0, 255] (as the published training normalises all pairs of a
/// sample together); each group passes only the frames its pairs use through the network.
/// Dropout `p` as [`MetricNet::pair_distances_dropout`]. Differentiable.
pub fn grouped_distances(
    net: &MetricNet,
    frames: &Tensor,
    side: usize,
    plan: &[PairGroup],
    p: f64,
    seed: u64,
) -> Result<Tensor> {
    let all = pairs();
    let mut covered: Vec<usize> = plan.iter().flat_map(|g| g.pairs.iter().copied()).collect();
    covered.sort_unstable();
    if covered != (0..all.len()).collect::<Vec<_>>() {
        return Err(Error::invalid(
            "grouped_distances",
            "plan",
            "every one of the 55 pairs must be in exactly one group",
        ));
    }
    let dev = Device::Cpu;
    let mut crops = Vec::with_capacity(plan.len());
    let mut locals = Vec::with_capacity(plan.len());
    for g in plan {
        let mut used: Vec<usize> = g.pairs.iter().flat_map(|&q| [all[q].0, all[q].1]).collect();
        used.sort_unstable();
        used.dedup();
        let idx = Tensor::from_vec(used.iter().map(|&u| u as u32).collect::<Vec<_>>(), used.len(), &dev)?;
        let sub = augment(&frames.index_select(&idx, 0)?, g.symmetry)?;
        let (h, w) = (sub.dim(2)?, sub.dim(3)?);
        if side == 0 || g.top + side > h || g.left + side > w {
            return Err(Error::invalid(
                "grouped_distances",
                "plan",
                format!("crop window {side} at ({}, {}) does not fit {h} x {w} frames", g.top, g.left),
            ));
        }
        crops.push(sub.narrow(2, g.top, side)?.narrow(3, g.left, side)?);
        let local = |f: usize| used.binary_search(&f).expect("listed");
        locals.push(g.pairs.iter().map(|&q| (local(all[q].0), local(all[q].1))).collect::<Vec<_>>());
    }
    let sizes: Vec<usize> = crops.iter().map(|c| c.dim(0)).collect::<candle_core::Result<_>>()?;
    let joint = to_byte_range(&Tensor::cat(&crops, 0)?)?;
    let mut dists = Vec::with_capacity(plan.len());
    let mut start = 0;
    for (k, (size, local)) in sizes.iter().zip(&locals).enumerate() {
        let feats = net.features(&joint.narrow(0, start, *size)?)?;
        dists.push(net.pair_distances_dropout(&feats, local, p, seed.wrapping_add(1000 * k as u64))?);
        start += size;
    }
    // Back to `pairs` order: position of pair q in the concatenation.
    let mut pos = vec![0u32; all.len()];
    for (i, q) in plan.iter().flat_map(|g| g.pairs.iter()).enumerate() {
        pos[*q] = i as u32;
    }
    Ok(Tensor::cat(&dists, 0)?.index_select(&Tensor::from_vec(pos, all.len(), &dev)?, 0)?)
}

/// A crop window `(top, left, side)`; `None`: the whole frame.
type Window = Option<(usize, usize, usize)>;

/// One calibration pass of `net` over the crops `windows` (one per sequence, from
/// [`Draws::calibration`]).
fn calibrate_on_crops(net: &mut MetricNet, data: &[Sequence], windows: &[Window]) -> Result<()> {
    let inputs: Vec<Tensor> = data
        .iter()
        .zip(windows)
        .map(|(s, w)| {
            let f = match w {
                Some(w) => apply_crop(&s.frames, *w)?,
                None => s.frames.clone(),
            };
            to_byte_range(&f)
        })
        .collect::<Result<_>>()?;
    net.calibrate(inputs.iter())
}

/// The random draws of one training step (see [`Draws`]).
enum StepDraw {
    /// Per-group augmentation ([`TrainConfig::pair_groups`] > 1): the plan, the crop side and
    /// the dropout seed.
    Grouped { plan: Vec<PairGroup>, side: usize, seed: u64 },
    /// One symmetry (`None` without augmentation) and one crop window for the whole sequence,
    /// and the dropout seed.
    Whole { symmetry: Option<u8>, window: Window, seed: u64 },
}

/// The random stream of a training run, drawn in the order the training uses it: a crop per
/// sequence for each calibration pass, a new order of the sequences at the start of each epoch,
/// and per step the symmetry, crop window(s) and dropout seed. Nothing here depends on the
/// network's values (only on the seed, the configuration and the frame sizes), so a resumed run
/// replays the draws of the steps before its checkpoint without computing anything.
struct Draws<'a> {
    rng: StdRng,
    order: Vec<usize>,
    data: &'a [Sequence],
    cfg: &'a TrainConfig,
}

impl<'a> Draws<'a> {
    fn new(data: &'a [Sequence], cfg: &'a TrainConfig) -> Self {
        Self { rng: pbdl_core::seed::rng(cfg.seed), order: (0..data.len()).collect(), data, cfg }
    }

    /// The crop of every sequence for one calibration pass (as the published calibration,
    /// which runs on the training loader).
    fn calibration(&mut self) -> Result<Vec<Window>> {
        let mut windows = Vec::with_capacity(self.data.len());
        for s in self.data {
            let (h, w) = (s.frames.dim(2)?, s.frames.dim(3)?);
            windows.push(if self.cfg.crop < 1.0 {
                Some(crop_window(h, w, side_of(h, w, self.cfg.crop), &mut self.rng)?)
            } else {
                None
            });
        }
        Ok(windows)
    }

    /// The sequence (index into the data) and the draws of `step`.
    fn step(&mut self, step: u64) -> Result<(usize, StepDraw)> {
        let n = self.data.len() as u64;
        let (cfg, rng) = (self.cfg, &mut self.rng);
        // Each epoch starts with a new order of the sequences.
        if step % n == 0 {
            self.order.shuffle(rng);
        }
        let i = self.order[(step % n) as usize];
        let f = &self.data[i].frames;
        let (h, w) = (f.dim(2)?, f.dim(3)?);
        let draw = if cfg.pair_groups > 1 {
            let side = side_of(h, w, cfg.crop);
            let plan = random_pair_groups(cfg.pair_groups, h.min(w), side, cfg.augment, rng);
            StepDraw::Grouped { plan, side, seed: rng.random() }
        } else {
            let symmetry = if cfg.augment { Some(rng.random_range(0u8..8)) } else { None };
            // An odd number of quarter turns swaps the sides of the frames.
            let (h, w) = if symmetry.is_some_and(|c| c & 1 == 1) { (w, h) } else { (h, w) };
            let window = if cfg.crop < 1.0 { Some(crop_window(h, w, side_of(h, w, cfg.crop), rng)?) } else { None };
            StepDraw::Whole { symmetry, window, seed: rng.random() }
        };
        Ok((i, draw))
    }
}

/// The loss of one step: sequence `i` with the draws `draw`.
fn step_loss(
    net: &MetricNet,
    data: &[Sequence],
    gts: &[Vec<f64>],
    cfg: &TrainConfig,
    i: usize,
    draw: &StepDraw,
) -> Result<Tensor> {
    match draw {
        StepDraw::Grouped { plan, side, seed } => {
            let d = grouped_distances(net, &data[i].frames, *side, plan, cfg.dropout, *seed)?;
            let g = Tensor::from_slice(&gts[i], gts[i].len(), &Device::Cpu)?.to_dtype(d.dtype())?;
            metric_loss(&d, &g, &cfg.loss)
        }
        StepDraw::Whole { symmetry, window, seed } => {
            let mut frames = match symmetry {
                Some(code) => augment(&data[i].frames, *code)?,
                None => data[i].frames.clone(),
            };
            if let Some(w) = window {
                frames = apply_crop(&frames, *w)?;
            }
            sequence_loss_dropout(net, &frames, &gts[i], &cfg.loss, cfg.dropout, *seed)
        }
    }
}

/// The state of a [`MetricNet`] that a run directory checkpoints, as the variables of one
/// `VarMap` (so that [`TrainLoop`]'s single atomic commit per checkpoint covers all of it):
///
/// - `net.<k>.conv<l>.weight|bias`, `net.<k>.lin<l>.weight`: the network's own variables (shared
///   storage), `k` their index in [`MetricNet::vars`], so that the `VarMap`'s name order (the
///   order the loop trains them and sums the gradient norm in) is the network's. With
///   [`TrainConfig::train_base`] off, the conv entries are copies, which get no gradient and so
///   are not trained (restored into the network on resume);
/// - `norm.mean.<l>`, `norm.m2.<l>`, `norm.count.<l>`: the normalisation statistics, written
///   after every calibration pass. They never enter a loss (the network reads copies), so no
///   gradient reaches them and the optimiser leaves them alone, as BatchNorm's running statistics
///   in pbdl-core.
struct NetState {
    varmap: VarMap,
    /// `(mean, m2, count)` of each feature layer.
    stats: Vec<(Var, Var, Var)>,
    /// `(checkpointed copy, the network's variable)` of the frozen conv weights.
    frozen: Vec<(Var, Var)>,
}

impl NetState {
    fn new(net: &MetricNet, data: &[Sequence], cfg: &TrainConfig) -> Result<Self> {
        let varmap = VarMap::new();
        let vars = net.vars();
        let layers = net.channel_weights().len();
        let mut frozen = Vec::new();
        let mut stats = Vec::new();
        {
            let mut map = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
            for (k, v) in vars.iter().enumerate() {
                let name = if k < 2 * layers {
                    format!("net.{k:02}.conv{}.{}", k / 2, if k % 2 == 0 { "weight" } else { "bias" })
                } else {
                    format!("net.{k:02}.lin{}.weight", k - 2 * layers)
                };
                let entry = if k >= 2 * layers || cfg.train_base {
                    v.clone()
                } else {
                    // `from_tensor` of a non-variable tensor copies the storage.
                    let copy = Var::from_tensor(&v.as_tensor().detach())?;
                    frozen.push((copy.clone(), v.clone()));
                    copy
                };
                map.insert(name, entry);
            }
            for (l, (h, w)) in stat_shapes(net, data, cfg)?.into_iter().enumerate() {
                let mean = Var::zeros((1, 1, h, w), DType::F32, &Device::Cpu)?;
                let m2 = Var::zeros((1, 1, h, w), DType::F32, &Device::Cpu)?;
                let count = Var::zeros(1, DType::F64, &Device::Cpu)?;
                map.insert(format!("norm.mean.{l}"), mean.clone());
                map.insert(format!("norm.m2.{l}"), m2.clone());
                map.insert(format!("norm.count.{l}"), count.clone());
                stats.push((mean, m2, count));
            }
        }
        Ok(Self { varmap, stats, frozen })
    }

    /// Writes the network's statistics into the checkpointed variables.
    fn store_stats(&self, net: &MetricNet) -> Result<()> {
        let stats = net.stats().ok_or_else(|| Error::invalid("train", "net", "no statistics to checkpoint"))?;
        if stats.len() != self.stats.len() {
            return Err(Error::invalid(
                "train",
                "net",
                format!("{} statistics layers, expected {}", stats.len(), self.stats.len()),
            ));
        }
        for ((mean, m2, count), s) in self.stats.iter().zip(stats) {
            mean.set(&s.mean)?;
            m2.set(&s.m2)?;
            count.set(&Tensor::new(&[s.count], &Device::Cpu)?)?;
        }
        Ok(())
    }

    /// Puts the loaded statistics and frozen conv weights into the network.
    fn restore(&self, net: &mut MetricNet) -> Result<()> {
        for (copy, own) in &self.frozen {
            own.set(copy.as_tensor())?;
        }
        let stats = self
            .stats
            .iter()
            .map(|(mean, m2, count)| -> Result<LayerStats> {
                Ok(LayerStats {
                    // Copies: the network's statistics never share storage with the variables.
                    mean: mean.as_tensor().detach().copy()?,
                    m2: m2.as_tensor().detach().copy()?,
                    count: count.as_tensor().to_vec1::<f64>()?[0],
                })
            })
            .collect::<Result<_>>()?;
        net.set_stats(stats)
    }
}

/// The `(h, w)` of each layer's statistics: those of the network's, or of the feature maps of a
/// calibration input (the crop of the first sequence).
fn stat_shapes(net: &MetricNet, data: &[Sequence], cfg: &TrainConfig) -> Result<Vec<(usize, usize)>> {
    if let Some(stats) = net.stats() {
        return stats.iter().map(|s| Ok((s.mean.dim(2)?, s.mean.dim(3)?))).collect();
    }
    let f = &data[0].frames;
    let (h, w) = (f.dim(2)?, f.dim(3)?);
    let (h, w) = if cfg.crop < 1.0 { (side_of(h, w, cfg.crop), side_of(h, w, cfg.crop)) } else { (h, w) };
    let x = Tensor::zeros((1, net.config().in_channels, h, w), DType::F64, &Device::Cpu)?;
    net.features(&x)?.iter().map(|t| Ok((t.dim(2)?, t.dim(3)?))).collect()
}

/// Calibrates `net` on `data` (if it has no statistics yet) and trains it, in memory. See
/// [`train_resumable`] for the same training in a run directory.
pub fn train(net: &mut MetricNet, data: &[Sequence], cfg: &TrainConfig) -> Result<TrainReport> {
    fit(net, data, cfg, None)
}

/// [`train`] in the run directory `dir`, crash-safe and resumable: logs every update to
/// `dir/loss.csv` and writes the checkpoint `dir/step-<n>` every
/// [`TrainConfig::checkpoint_every`] updates and after the last one, each one atomic commit of
/// the network's weights, Adam's moments and update count, the step and the normalisation
/// statistics (which calibration and [`TrainConfig::recalibrate`] change). A call on a
/// directory that holds checkpoints resumes from the newest: it loads them into `net` (whose
/// architecture must be the run's) and replays the random draws of the steps before it from the
/// seed (none depends on the network), so a run killed at any moment (`kill -9` included) and
/// resumed ends with the same `loss.csv` and checkpoints, bit for bit, as one that never
/// stopped. The report's `epoch_loss` and `log` cover the whole run (read back from
/// `loss.csv`). Errors: a directory written with another seed or number of sequences. One
/// trainer per directory.
///
/// ```
/// use pbdl_metrics::train::data::{generate, DataConfig};
/// use pbdl_metrics::train::{train_resumable, Kind, MetricNet, MetricNetConfig, TrainConfig};
///
/// let data = generate(Kind::Shapes, 2, &DataConfig { resolution: 56, seed: 1 })?;
/// let tiny = MetricNetConfig { width: 0.25, ..Default::default() };
/// let cfg = TrainConfig { epochs: 2, checkpoint_every: 2, ..Default::default() };
/// let dir = tempfile::tempdir().unwrap();
/// let mut net = MetricNet::new(tiny)?;
/// let report = train_resumable(&mut net, &data, &cfg, dir.path())?;
/// assert_eq!((report.resumed_from, report.epoch_loss.len()), (0, 2));
/// assert!(dir.path().join("step-4.safetensors").exists() && dir.path().join("loss.csv").exists());
/// // Called again (after a crash, say), it resumes: here from the last step, nothing left to do,
/// // and a fresh network gets the trained weights and statistics.
/// let mut again = MetricNet::new(tiny)?;
/// let resumed = train_resumable(&mut again, &data, &cfg, dir.path())?;
/// assert_eq!((resumed.resumed_from, resumed.epoch_loss), (4, report.epoch_loss));
/// let d = |n: &MetricNet| n.sequence_distances(&data[0].frames, &[(0, 5)]).unwrap().to_vec1::<f32>().unwrap();
/// assert_eq!(d(&again), d(&net));
/// # Ok::<(), pbdl_metrics::Error>(())
/// ```
pub fn train_resumable(
    net: &mut MetricNet,
    data: &[Sequence],
    cfg: &TrainConfig,
    dir: impl AsRef<Path>,
) -> Result<TrainReport> {
    fit(net, data, cfg, Some(dir.as_ref()))
}

/// [`train`] (`dir = None`) and [`train_resumable`].
fn fit(net: &mut MetricNet, data: &[Sequence], cfg: &TrainConfig, dir: Option<&Path>) -> Result<TrainReport> {
    if data.is_empty() {
        return Err(Error::invalid("train", "data", "no training sequences"));
    }
    if !(cfg.crop > 0.0 && cfg.crop <= 1.0) {
        return Err(Error::invalid("train", "crop", format!("need a fraction in (0, 1], got {}", cfg.crop)));
    }
    if !(0.0..1.0).contains(&cfg.dropout) {
        return Err(Error::invalid("train", "dropout", format!("need 0 <= dropout < 1, got {}", cfg.dropout)));
    }
    let t0 = Instant::now();
    let n = data.len() as u64;
    let state = NetState::new(net, data, cfg)?;
    let loop_cfg = LoopConfig {
        steps: cfg.epochs as u64 * n,
        checkpoint_every: cfg.checkpoint_every,
        dir: dir.map(Path::to_path_buf),
        clip: cfg.clip,
        progress: cfg.progress,
        ..Default::default()
    };
    let run = TrainLoop::resume(&state.varmap, loop_cfg)?;
    let start = run.start();
    let mut draws = Draws::new(data, cfg);
    let calibrated_here = match run.resumed() {
        Some(ck) => {
            let config = &ck.info.config;
            let bad = |reason: String| Error::invalid("train_resumable", "dir", reason);
            if ck.info.seed != Some(cfg.seed) {
                return Err(bad(format!(
                    "the run was started with seed {:?}, not {}; resume with its seed or start a new run directory",
                    ck.info.seed, cfg.seed
                )));
            }
            if config.get("sequences").and_then(|v| v.as_u64()) != Some(n) {
                return Err(bad(format!(
                    "the run was started on {} training sequences, not {n}; resume with its data or start a new run directory",
                    config.get("sequences").map_or("an unknown number of".into(), |v| v.to_string())
                )));
            }
            let calibrated = config.get("calibrated_at_start").and_then(|v| v.as_bool()).ok_or_else(|| {
                bad("the checkpoint was not written by the LSiM training (no `calibrated_at_start`); use another run directory".into())
            })?;
            state.restore(net)?;
            // Replay the draws before the checkpoint: the calibration pass, then each step and
            // each recalibration.
            if calibrated {
                draws.calibration()?;
            }
            for step in 0..start {
                draws.step(step)?;
                if cfg.recalibrate && cfg.train_base && (step + 1) % n == 0 {
                    draws.calibration()?;
                }
            }
            calibrated
        }
        None => {
            let calibrate = net.stats().is_none();
            if calibrate {
                let windows = draws.calibration()?;
                calibrate_on_crops(net, data, &windows)?;
            }
            state.store_stats(net)?;
            calibrate
        }
    };
    let calibration_seconds = t0.elapsed().as_secs_f64();
    let gts: Vec<Vec<f64>> = data.iter().map(|s| ground_truth(cfg.ground_truth, &s.frames)).collect::<Result<_>>()?;
    let net_cfg = *net.config();
    let meta = |step: u64| CheckpointMeta {
        step,
        seed: Some(cfg.seed),
        config: serde_json::json!({
            "net": {
                "width": net_cfg.width, "in_channels": net_cfg.in_channels, "lin_init": net_cfg.lin_init,
                "seed": net_cfg.seed, "input_scale": net_cfg.input_scale, "second_pool": net_cfg.second_pool,
            },
            "train": format!("{:?}", TrainConfig { progress: false, ..*cfg }),
            "sequences": n,
            "calibrated_at_start": calibrated_here,
        }),
    };
    // The loss reads the network, the hook clamps and recalibrates it; both draw from `draws`.
    let net = RefCell::new(net);
    let draws = RefCell::new(draws);
    let mut log = ScalarLog::new();
    let t1 = Instant::now();
    let report = run
        .after_step(|step, info: &StepInfo| -> Result<()> {
            net.borrow().clamp_weights()?;
            log.log(step, &[("loss", info.loss), ("grad_norm", info.grad_norm)])?;
            if cfg.recalibrate && cfg.train_base && (step + 1) % n == 0 {
                let windows = draws.borrow_mut().calibration()?;
                let mut net = net.borrow_mut();
                calibrate_on_crops(&mut net, data, &windows)?;
                state.store_stats(&net)?;
            }
            Ok(())
        })
        .run::<Error>(
            &OptimizerConfig::Adam(cfg.adam),
            |_| cfg.adam.lr,
            meta,
            |step| {
                let (i, draw) = draws.borrow_mut().step(step)?;
                step_loss(&net.borrow(), data, &gts, cfg, i, &draw)
            },
        )?;
    let train_seconds = t1.elapsed().as_secs_f64();
    let (losses, log) = match dir {
        // The whole run, the steps before a resume included.
        Some(dir) => {
            let whole = whole_log(&dir.join("loss.csv"))?;
            (whole.column("loss"), whole)
        }
        None => (report.losses, log),
    };
    // Summed in step order, as the per-epoch running sum was.
    let epoch_loss = losses
        .chunks(data.len())
        .map(|epoch| epoch.iter().fold(0.0, |sum, &(_, l)| sum + l) / data.len() as f64)
        .collect();
    Ok(TrainReport { epoch_loss, log, calibration_seconds, train_seconds, resumed_from: start })
}

/// The `loss` and `grad_norm` columns of a run directory's `loss.csv` (empty if there is none).
fn whole_log(path: &Path) -> Result<ScalarLog> {
    let mut log = ScalarLog::new();
    if !path.exists() {
        return Ok(log);
    }
    let file = ScalarLog::read(path)?;
    let index = |name: &str| file.columns().iter().position(|c| c == name);
    let (li, gi) = (index("loss"), index("grad_norm"));
    for row in file.rows() {
        let values: Vec<(&str, f64)> =
            [("loss", li), ("grad_norm", gi)].into_iter().filter_map(|(name, i)| Some((name, row.get(i?)?))).collect();
        log.log(row.step, &values)?;
    }
    Ok(log)
}
