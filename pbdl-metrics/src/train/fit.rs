//! The training loop: calibration epoch, then Adam over single sequences (batch of one
//! sequence, as both papers), the published LSiM augmentation (random flips, quarter turns and
//! crops; channel shuffling does not apply to scalar frames) and dropout, the LSiM or VolSiM
//! loss on all 55 pairs.
//!
//! The published training draws a flip, turn and crop per pair. By default here one per
//! sequence, so that the 11 frames pass the network once per step instead of 110 times;
//! [`TrainConfig::pair_groups`] splits the 55 pairs into random groups with one draw each (55
//! groups: the published per-pair augmentation, at up to ten times the cost).

use super::data::Sequence;
use super::loss::{ground_truth, metric_loss, pairs, GroundTruth, LossConfig};
use super::model::{to_byte_range, MetricNet};
use crate::{Error, Result};
use candle_core::{Device, Tensor};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, OptimizerConfig, ScalarLog, StepInfo, TrainLoop};
use rand::seq::SliceRandom;
use rand::Rng;
use std::cell::RefCell;
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
        }
    }
}

/// What [`train`] measured.
#[derive(Clone, Debug)]
pub struct TrainReport {
    /// Mean loss of each epoch (over its sequences, before each step's update).
    pub epoch_loss: Vec<f64>,
    /// Per-step scalars: `loss`, `grad_norm`.
    pub log: ScalarLog,
    /// Seconds of the calibration pass.
    pub calibration_seconds: f64,
    /// Seconds of the optimisation epochs.
    pub train_seconds: f64,
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
    let (h, w) = (frames.dim(2)?, frames.dim(3)?);
    if side == 0 || side > h || side > w {
        return Err(Error::invalid("random_crop", "side", format!("need 1 <= side <= {}, got {side}", h.min(w))));
    }
    let top = rng.random_range(0..=h - side);
    let left = rng.random_range(0..=w - side);
    Ok(frames.narrow(2, top, side)?.narrow(3, left, side)?.contiguous()?)
}

/// The crop side for `frames` and a crop fraction (at least 1 cell).
fn crop_side(frames: &Tensor, fraction: f64) -> Result<usize> {
    let n = frames.dim(2)?.min(frames.dim(3)?);
    Ok(((n as f64 * fraction).round() as usize).clamp(1, n))
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

/// One calibration pass of `net` over one random crop (fraction `crop`) of every sequence.
fn calibrate_on_crops(net: &mut MetricNet, data: &[Sequence], crop: f64, rng: &mut impl Rng) -> Result<()> {
    let inputs: Vec<Tensor> = data
        .iter()
        .map(|s| {
            let f =
                if crop < 1.0 { random_crop(&s.frames, crop_side(&s.frames, crop)?, rng)? } else { s.frames.clone() };
            to_byte_range(&f)
        })
        .collect::<Result<_>>()?;
    net.calibrate(inputs.iter())
}

/// Calibrates `net` on `data` (if it has no statistics yet) and trains it.
pub fn train(net: &mut MetricNet, data: &[Sequence], cfg: &TrainConfig) -> Result<TrainReport> {
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
    let mut rng = pbdl_core::seed::rng(cfg.seed);
    if net.stats().is_none() {
        calibrate_on_crops(net, data, cfg.crop, &mut rng)?;
    }
    let calibration_seconds = t0.elapsed().as_secs_f64();
    let gts: Vec<Vec<f64>> = data.iter().map(|s| ground_truth(cfg.ground_truth, &s.frames)).collect::<Result<_>>()?;
    let vars = if cfg.train_base { net.vars() } else { net.channel_weights() };
    let n = data.len() as u64;
    let loop_cfg = LoopConfig {
        steps: cfg.epochs as u64 * n,
        checkpoint_every: 0,
        dir: None,
        clip: cfg.clip,
        progress: cfg.progress,
        ..Default::default()
    };
    // The loss reads the network, the hook clamps and recalibrates it; both draw from `rng`.
    let net = RefCell::new(net);
    let rng = RefCell::new(rng);
    let mut order: Vec<usize> = (0..data.len()).collect();
    let mut log = ScalarLog::new();
    let t1 = Instant::now();
    let report = TrainLoop::in_memory(vars, loop_cfg)?
        .after_step(|step, info: &StepInfo| -> Result<()> {
            net.borrow().clamp_weights()?;
            log.log(step, &[("loss", info.loss), ("grad_norm", info.grad_norm)])?;
            if cfg.recalibrate && cfg.train_base && (step + 1) % n == 0 {
                calibrate_on_crops(&mut net.borrow_mut(), data, cfg.crop, &mut *rng.borrow_mut())?;
            }
            Ok(())
        })
        .run::<Error>(
            &OptimizerConfig::Adam(cfg.adam),
            |_| cfg.adam.lr,
            CheckpointMeta::at,
            |step| {
                let net = net.borrow();
                let mut rng = rng.borrow_mut();
                let rng = &mut *rng;
                // Each epoch starts with a new order of the sequences.
                if step % n == 0 {
                    order.shuffle(rng);
                }
                let i = order[(step % n) as usize];
                if cfg.pair_groups > 1 {
                    let f = &data[i].frames;
                    let side = crop_side(f, cfg.crop)?;
                    let plan = random_pair_groups(cfg.pair_groups, f.dim(2)?.min(f.dim(3)?), side, cfg.augment, rng);
                    let d = grouped_distances(&net, f, side, &plan, cfg.dropout, rng.random())?;
                    let g = Tensor::from_slice(&gts[i], gts[i].len(), &Device::Cpu)?.to_dtype(d.dtype())?;
                    metric_loss(&d, &g, &cfg.loss)
                } else {
                    let mut frames = if cfg.augment {
                        augment(&data[i].frames, rng.random_range(0..8))?
                    } else {
                        data[i].frames.clone()
                    };
                    if cfg.crop < 1.0 {
                        frames = random_crop(&frames, crop_side(&frames, cfg.crop)?, rng)?;
                    }
                    sequence_loss_dropout(&net, &frames, &gts[i], &cfg.loss, cfg.dropout, rng.random())
                }
            },
        )?;
    // Summed in step order, as the per-epoch running sum was.
    let epoch_loss = report
        .losses
        .chunks(data.len())
        .map(|epoch| epoch.iter().fold(0.0, |sum, &(_, l)| sum + l) / data.len() as f64)
        .collect();
    Ok(TrainReport { epoch_loss, log, calibration_seconds, train_seconds: t1.elapsed().as_secs_f64() })
}
