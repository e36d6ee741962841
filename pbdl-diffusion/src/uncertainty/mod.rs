//! Diffusion surrogate for the mean and spread of an unsteady flow: the method of Liu, Thuerey
//! et al. ("Uncertainty-aware surrogate models for airfoil flow simulations with denoising
//! diffusion probabilistic models") on a cylinder wake that we simulate ourselves.
//!
//! **Problem.** For each Reynolds number the unsteady wake is a *distribution* of flow fields:
//! its snapshots ([`data::simulate_wake`]). The ground truth of a case is the per-pixel mean and
//! standard deviation over its snapshots ([`FieldStats::of`]).
//!
//! **Method.** A DDPM is trained to sample a random snapshot given the case: the condition
//! `(inflow field, obstacle mask, Re field)` is concatenated *clean* to the noisy target
//! ([`Conditioning::Clean`]); cosine schedule with `T = 200`; epsilon-MSE loss. At test time
//! `n` samples are drawn for an unseen Reynolds number and their mean and standard deviation are
//! the prediction ([`predict_stats`]). Targets are normalised per channel with the training
//! snapshots' mean and standard deviation ([`Normalizer`]).
//!
//! **Scores** ([`compare`], over fluid cells): relative L2 error of the mean field, Pearson
//! correlation of predicted and true standard-deviation fields, and the mean standard deviation
//! `sigma_{y,a}` of each case (the paper plots it against the Reynolds number).
//!
//! The acceptance run is the ignored test `tests/uncertainty_wake.rs` (AifNet from
//! [`crate::unet`]; our samplers put the condition channels *before* the noisy target, the
//! airfoil code after it: irrelevant when training from scratch, it matters only for imported
//! weights). Its last numbers are in that file.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_diffusion::uncertainty::FieldStats;
//! // Two snapshots 0 and 2: mean 1, standard deviation 1 in every pixel.
//! let s = Tensor::stack(&[Tensor::zeros((1, 2, 2), candle_core::DType::F32, &Device::Cpu)?,
//!                         Tensor::full(2f32, (1, 2, 2), &Device::Cpu)?], 0)?;
//! let stats = FieldStats::of(&s)?;
//! assert_eq!(stats.std.flatten_all()?.to_vec1::<f64>()?, vec![1.0; 4]);
//! # Ok::<(), pbdl_diffusion::Error>(())
//! ```

pub mod data;

pub use data::{condition, simulate_wake, FieldStats, WakeCase, WakeConfig};

use crate::ddpm::{Conditioning, Diffusion, Loss, NoisePredictor};
use crate::schedule::{NoiseSchedule, COSINE_S};
use crate::{Error, Result};
use candle_core::{DType, Tensor, Var};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{
    AdamWConfig, ClipConfig, LoopConfig, LrScheduler, OptimizerConfig, ScheduleConfig, StepInfo, TrainLoop,
};
use rand::seq::SliceRandom;
use rand::Rng;

/// The airfoil paper's diffusion process: cosine schedule, `T = 200`, clean conditioning.
pub fn diffusion() -> Result<Diffusion> {
    Ok(Diffusion::new(NoiseSchedule::cosine(200, COSINE_S)?, Conditioning::Clean))
}

/// Per-channel affine normalisation of the targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Normalizer {
    /// Per-channel offset.
    pub mean: Vec<f64>,
    /// Per-channel scale.
    pub std: Vec<f64>,
}

impl Normalizer {
    /// Mean and standard deviation per channel over all snapshots of `cases` (`[N, C, H, W]` each).
    pub fn fit(cases: &[&Tensor]) -> Result<Self> {
        let all = Tensor::cat(cases, 0)?.to_dtype(DType::F64)?;
        let c = all.dim(1)?;
        let per_ch = all.transpose(0, 1)?.flatten_from(1)?;
        let mean = per_ch.mean(1)?;
        let std = per_ch.broadcast_sub(&mean.unsqueeze(1)?)?.sqr()?.mean(1)?.sqrt()?;
        let (mean, std) = (mean.to_vec1::<f64>()?, std.to_vec1::<f64>()?);
        if std.iter().any(|s| s.is_nan() || *s <= 0.0) || mean.len() != c {
            return Err(Error::InvalidConfig {
                name: "Normalizer data",
                value: format!("per-channel std {std:?}"),
                hint: "every target channel must vary over the training snapshots",
            });
        }
        Ok(Self { mean, std })
    }

    fn coefficients(&self, like: &Tensor) -> Result<(Tensor, Tensor)> {
        let c = self.mean.len();
        let shape: Vec<usize> = match like.rank() {
            3 => vec![c, 1, 1],
            _ => vec![1, c, 1, 1],
        };
        let m = Tensor::from_vec(self.mean.clone(), shape.as_slice(), like.device())?.to_dtype(like.dtype())?;
        let s = Tensor::from_vec(self.std.clone(), shape.as_slice(), like.device())?.to_dtype(like.dtype())?;
        Ok((m, s))
    }

    /// `(x - mean) / std` per channel (`[N, C, H, W]` or `[C, H, W]`).
    pub fn normalize(&self, x: &Tensor) -> Result<Tensor> {
        let (m, s) = self.coefficients(x)?;
        Ok(x.broadcast_sub(&m)?.broadcast_div(&s)?)
    }

    /// `x * std + mean` per channel.
    pub fn denormalize(&self, x: &Tensor) -> Result<Tensor> {
        let (m, s) = self.coefficients(x)?;
        Ok(x.broadcast_mul(&s)?.broadcast_add(&m)?)
    }
}

/// Training pairs: conditions `[N, 3, H, W]` and normalised targets `[N, C, H, W]`.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Conditions.
    pub cond: Tensor,
    /// Normalised targets.
    pub target: Tensor,
}

impl Dataset {
    /// `per_case` snapshots drawn without replacement from each case (the paper: 25), with the
    /// case's condition; targets normalised by `norm`.
    pub fn new(
        cfg: &WakeConfig,
        cases: &[WakeCase],
        per_case: usize,
        re_scale: f64,
        norm: &Normalizer,
        seed: u64,
    ) -> Result<Self> {
        let mut rng = pbdl_core::seed::rng(seed);
        let (mut conds, mut targets) = (Vec::new(), Vec::new());
        for case in cases {
            let n = case.snapshots.dim(0)?;
            if per_case == 0 || per_case > n {
                return Err(Error::InvalidConfig {
                    name: "snapshots per case",
                    value: per_case.to_string(),
                    hint: "use between 1 and the number of snapshots of a case",
                });
            }
            let mut idx: Vec<usize> = (0..n).collect();
            idx.shuffle(&mut rng);
            let idx: Vec<u32> = idx[..per_case].iter().map(|&i| i as u32).collect();
            let idx = Tensor::from_vec(idx, per_case, case.snapshots.device())?;
            targets.push(norm.normalize(&case.snapshots.index_select(&idx, 0)?)?);
            let c = condition(cfg, case.re, re_scale, case.snapshots.device())?;
            conds.push(c.unsqueeze(0)?.repeat((per_case, 1, 1, 1))?);
        }
        Ok(Self { cond: Tensor::cat(&conds, 0)?, target: Tensor::cat(&targets, 0)? })
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.target.dim(0).unwrap_or(0)
    }

    /// Whether there are no pairs.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Training settings.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainConfig {
    /// Optimisation steps.
    pub steps: usize,
    /// Batch size (the paper: 25).
    pub batch: usize,
    /// Peak learning rate of AdamW (cosine decay to `lr / 100`).
    pub lr: f64,
    /// Seed of batches, diffusion steps and noise.
    pub seed: u64,
}

/// Trains `model` (with trainable `vars`, in this order) on `data` with the epsilon-MSE
/// objective on [`pbdl_core::train::TrainLoop`] (in memory: AdamW, cosine learning rate down to
/// `lr / 100`, clipping at global norm 1, a non-finite loss or gradient stops with
/// `Diverged`); calls `on_step(step, loss)` after each step and returns the loss of every step.
pub fn train<M: NoisePredictor + ?Sized>(
    model: &M,
    vars: Vec<Var>,
    diffusion: &Diffusion,
    data: &Dataset,
    cfg: &TrainConfig,
    mut on_step: impl FnMut(usize, f64),
) -> Result<Vec<f64>> {
    if cfg.steps == 0 || cfg.batch == 0 || data.is_empty() {
        return Err(Error::InvalidConfig {
            name: "TrainConfig",
            value: format!("{} steps, batch {}, {} pairs", cfg.steps, cfg.batch, data.len()),
            hint: "use at least one step, a batch of at least 1 and a non-empty dataset",
        });
    }
    let opt_cfg = OptimizerConfig::AdamW(AdamWConfig { lr: cfg.lr, ..Default::default() });
    let sched = LrScheduler::new(
        ScheduleConfig::Cosine { total_steps: cfg.steps as u64, warmup_steps: 0, min_lr: cfg.lr / 100.0 },
        cfg.lr,
    )?;
    let loop_cfg = LoopConfig {
        steps: cfg.steps as u64,
        clip: ClipConfig::Norm { max_norm: 1.0 },
        progress: false,
        ..Default::default()
    };
    let mut rng = pbdl_core::seed::rng(cfg.seed);
    let n = data.len();
    let report = TrainLoop::in_memory(vars, loop_cfg)?
        .after_step(|step, info: &StepInfo| -> Result<()> {
            on_step(step as usize, info.loss);
            Ok(())
        })
        .run::<Error>(
            &opt_cfg,
            |step| sched.lr(step),
            CheckpointMeta::at,
            |_| {
                let idx: Vec<u32> = (0..cfg.batch.min(n)).map(|_| rng.random_range(0..n) as u32).collect();
                let idx = Tensor::from_vec(idx, cfg.batch.min(n), data.target.device())?;
                let x0 = data.target.index_select(&idx, 0)?;
                let c = data.cond.index_select(&idx, 0)?;
                diffusion.loss(model, &x0, Some(&c), Loss::Mse, rng.random())
            },
        )?;
    Ok(report.losses.into_iter().map(|(_, loss)| loss).collect())
}

/// How many samples [`predict_stats`] draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleConfig {
    /// Number of samples (the paper: 500 per case).
    pub n: usize,
    /// Samples per sampler call.
    pub batch: usize,
    /// Seed of the start noise and the step noise.
    pub seed: u64,
}

/// Draws DDPM samples for one condition `[3, H, W]` and returns their statistics in physical
/// units (the target has as many channels as `norm`).
pub fn predict_stats<M: NoisePredictor + ?Sized>(
    model: &M,
    diffusion: &Diffusion,
    cond: &Tensor,
    norm: &Normalizer,
    sampling: &SampleConfig,
) -> Result<FieldStats> {
    let SampleConfig { n, batch, seed } = *sampling;
    let channels = norm.mean.len();
    if n < 2 || batch == 0 {
        return Err(Error::InvalidConfig {
            name: "samples",
            value: format!("{n} in batches of {batch}"),
            hint: "draw at least 2 samples in batches of at least 1",
        });
    }
    let (_, h, w) = cond.dims3().map_err(|_| Error::shape("condition (layout [C, H, W])", "rank 3", cond.dims()))?;
    let mut samples = Vec::new();
    let mut done = 0;
    while done < n {
        let b = batch.min(n - done);
        let c = cond.unsqueeze(0)?.repeat((b, 1, 1, 1))?;
        let x = Diffusion::noise(&[b, channels, h, w], cond.dtype(), cond.device(), seed.wrapping_add(done as u64))?;
        let s = diffusion.sample_ddpm(model, Some(&c), &x, seed.wrapping_add(1 << 32).wrapping_add(done as u64))?;
        samples.push(norm.denormalize(&s)?);
        done += b;
    }
    FieldStats::of(&Tensor::cat(&samples, 0)?)
}

/// Scores of a predicted mean/std pair against the ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatsScores {
    /// `||mean_pred - mean_true|| / ||mean_true||` over fluid cells and channels.
    pub mean_rel_error: f64,
    /// `||mean_pred - mean_true|| / ||mean_true - U||`, relative to the mean's deviation from the
    /// uniform inflow `U = (1, 0)` (the harder score: the inflow dominates the plain one).
    pub mean_rel_error_vs_deficit: f64,
    /// Pearson correlation of the predicted and true std fields (fluid cells, channels joined).
    pub std_correlation: f64,
    /// Mean of the predicted std field over fluid cells and channels (`sigma_{y,a}`).
    pub mean_std_pred: f64,
    /// Mean of the true std field.
    pub mean_std_true: f64,
}

/// Scores `pred` against `truth` (`[C, H, W]` fields) over the cells where `mask` is 0.
pub fn compare(pred: &FieldStats, truth: &FieldStats, mask: &[f32]) -> Result<StatsScores> {
    let v = |t: &Tensor| -> Result<Vec<f64>> { Ok(t.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?) };
    if pred.mean.dims() != truth.mean.dims() || pred.std.dims() != truth.std.dims() {
        return Err(Error::shape("predicted statistics", truth.mean.dims(), pred.mean.dims()));
    }
    let (c, h, w) = truth.mean.dims3()?;
    if mask.len() != h * w {
        return Err(Error::shape("mask", h * w, mask.len()));
    }
    let (pm, tm, ps, ts) = (v(&pred.mean)?, v(&truth.mean)?, v(&pred.std)?, v(&truth.std)?);
    let fluid: Vec<usize> =
        (0..c).flat_map(|ch| (0..h * w).filter(|&p| mask[p] == 0.0).map(move |p| ch * h * w + p)).collect();
    let inflow = |i: usize| if i / (h * w) == 0 { 1.0 } else { 0.0 };
    let (mut err, mut norm, mut deficit) = (0.0, 0.0, 0.0);
    for &i in &fluid {
        err += (pm[i] - tm[i]).powi(2);
        norm += tm[i].powi(2);
        deficit += (tm[i] - inflow(i)).powi(2);
    }
    let nf = fluid.len() as f64;
    let (mp, mt) = (fluid.iter().map(|&i| ps[i]).sum::<f64>() / nf, fluid.iter().map(|&i| ts[i]).sum::<f64>() / nf);
    let (mut cov, mut vp, mut vt) = (0.0, 0.0, 0.0);
    for &i in &fluid {
        cov += (ps[i] - mp) * (ts[i] - mt);
        vp += (ps[i] - mp).powi(2);
        vt += (ts[i] - mt).powi(2);
    }
    Ok(StatsScores {
        mean_rel_error: (err / norm).sqrt(),
        mean_rel_error_vs_deficit: (err / deficit).sqrt(),
        std_correlation: cov / (vp * vt).sqrt(),
        mean_std_pred: mp,
        mean_std_true: mt,
    })
}
