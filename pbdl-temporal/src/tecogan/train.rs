//! A non-adversarial trainer for F and G.

use super::pingpong::{pingpong_loss, pingpong_sequence};
use super::recurrent::{TecoGan, TecoGanConfig};
use crate::data::Clip;
use crate::warp::backward_warp;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;

/// Settings of [`train_tecogan`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TecoTrainConfig {
    /// The networks.
    pub model: TecoGanConfig,
    /// Adam updates (>= 1). Default 300.
    pub steps: u64,
    /// Adam's learning rate (constant, > 0). Default 3e-4.
    pub lr: f64,
    /// Sequences per update (>= 1). Default 4.
    pub batch: usize,
    /// Frames per training sequence (>= 2; TecoGAN: 10). Default 6.
    pub frames: usize,
    /// Extend each training sequence to its ping-pong order (`2 frames - 1`, see
    /// [`pingpong_sequence`]); the content and warp losses then cover the backward half too.
    /// Default true. Needed for a non-zero `pingpong_weight`.
    pub pingpong_sequences: bool,
    /// Weight of the ping-pong loss (TecoGAN: 0.5; 0 turns the term off while keeping the
    /// sequences, so that "on" and "off" runs see the same data and updates). Default 0.5.
    pub pingpong_weight: f64,
    /// Weight of the L2 content loss `mean (g_t - y_t)^2`. Default 1.
    pub content_weight: f64,
    /// Weight of F's warp loss `mean (backward_warp(lr_{t-1}, F) - lr_t)^2`. Default 1.
    pub warp_weight: f64,
    /// Seed of the weights and of the sampled windows. Default 0.
    pub seed: u64,
}

impl Default for TecoTrainConfig {
    fn default() -> Self {
        Self {
            model: TecoGanConfig::default(),
            steps: 300,
            lr: 3e-4,
            batch: 4,
            frames: 6,
            pingpong_sequences: true,
            pingpong_weight: 0.5,
            content_weight: 1.0,
            warp_weight: 1.0,
            seed: 0,
        }
    }
}

impl TecoTrainConfig {
    /// Checks every field ([`Error::Config`] naming it).
    pub fn validate(&self) -> Result<()> {
        self.model.validate()?;
        if self.steps == 0 || self.batch == 0 {
            return Err(Error::config("steps / batch", format!("{} / {}; use at least 1", self.steps, self.batch)));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::config("lr", format!("{}; use a positive finite rate", self.lr)));
        }
        if self.frames < 2 {
            return Err(Error::config("frames", format!("{}; use at least 2 frames per sequence", self.frames)));
        }
        check_loss_weights(
            &[
                ("pingpong_weight", self.pingpong_weight),
                ("content_weight", self.content_weight),
                ("warp_weight", self.warp_weight),
            ],
            self.pingpong_weight,
            self.pingpong_sequences,
        )
    }
}

/// Every named weight finite and `>= 0`, and a ping-pong weight only with ping-pong sequences
/// (typed [`Error::Config`] naming the weight).
pub(crate) fn check_loss_weights(
    named: &[(&'static str, f64)],
    pingpong_weight: f64,
    pingpong_sequences: bool,
) -> Result<()> {
    for &(name, w) in named {
        if !(w >= 0.0 && w.is_finite()) {
            return Err(Error::config(name, format!("{w}; use a finite weight >= 0")));
        }
    }
    if pingpong_weight > 0.0 && !pingpong_sequences {
        return Err(Error::config(
            "pingpong_weight",
            format!("{pingpong_weight} without pingpong_sequences; turn pingpong_sequences on or set the weight to 0"),
        ));
    }
    Ok(())
}

/// What [`train_tecogan`] did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TecoTrainReport {
    /// Total loss per update.
    pub losses: Vec<f64>,
    /// Content loss per update.
    pub content: Vec<f64>,
    /// Warp loss per update.
    pub warp: Vec<f64>,
    /// Ping-pong loss per update (computed, and logged, even when its weight is 0).
    pub pingpong: Vec<f64>,
    /// Wall-clock seconds of the updates.
    pub seconds: f64,
}

/// Trains F and G on windows of `clips` (f32, CPU): per update `batch` windows of `frames`
/// consecutive frames, drawn uniformly (clip, start) from a stream of `seed` that does not
/// depend on the loss weights, so runs that differ only in a weight see the same windows; the
/// weights start from [`pbdl_nets::seeded_init`] with `seed`. Loss:
/// `content_weight * mean (g - y)^2 + warp_weight * mean (warp(lr_{t-1}, F) - lr_t)^2 +
/// pingpong_weight * pingpong_loss`, Adam with a constant rate on pbdl-core's [`TrainLoop`]
/// (in memory; a non-finite loss stops with a divergence error).
pub fn train_tecogan(clips: &[Clip], cfg: &TecoTrainConfig) -> Result<(TecoGan, VarMap, TecoTrainReport)> {
    cfg.validate()?;
    if clips.is_empty() {
        return Err(Error::input("clips", "none given; pass at least one training clip"));
    }
    let short = clips.iter().filter(|c| c.frames() < cfg.frames).count();
    if short == clips.len() {
        return Err(Error::config("frames", format!("{}; every clip is shorter", cfg.frames)));
    }
    let (n, factor) = (clips[0].lr_density.dim(2)?, cfg.model.generator.factor);
    for c in clips {
        let (l, h) = (c.lr_density.dims(), c.hr_density.dims());
        if l.len() != 4 || l[1] != 1 || h.len() != 4 || h[2] != l[2] * factor || h[3] != l[3] * factor {
            return Err(Error::input(
                "clip",
                format!("lr {l:?} and hr {h:?}: expected [T, 1, n, m] and [T, 1, {factor} n, {factor} m]"),
            ));
        }
        if l[2] % cfg.model.motion.size_multiple() != 0 || l[3] % cfg.model.motion.size_multiple() != 0 {
            return Err(Error::config(
                "model.motion.levels",
                format!("{}: the low resolution {n} is not divisible by 2^levels", cfg.model.motion.levels),
            ));
        }
    }
    let usable: Vec<&Clip> = clips.iter().filter(|c| c.frames() >= cfg.frames).collect();

    let varmap = VarMap::new();
    let model = TecoGan::new(cfg.model.clone(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
    pbdl_nets::seeded_init(&varmap, cfg.seed)?;

    let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed, 0x7ec0));
    let windows: Vec<(usize, usize)> = (0..cfg.steps as usize * cfg.batch)
        .map(|_| {
            let c = rng.random_range(0..usable.len());
            (c, rng.random_range(0..=usable[c].frames() - cfg.frames))
        })
        .collect();
    let report = RefCell::new(TecoTrainReport::default());
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, ..Default::default() });
    let lc = LoopConfig { steps: cfg.steps, progress: false, ..Default::default() };
    let looped = TrainLoop::resume(&varmap, lc)?.run::<Error>(
        &adam,
        |_| cfg.lr,
        CheckpointMeta::at,
        |step| {
            let picks = &windows[step as usize * cfg.batch..(step as usize + 1) * cfg.batch];
            let gather = |hr: bool| -> Result<Tensor> {
                let seqs = picks
                    .iter()
                    .map(|&(c, s)| {
                        let clip = usable[c];
                        let x = if hr { &clip.hr_density } else { &clip.lr_density };
                        let x = x.narrow(0, s, cfg.frames)?.to_dtype(DType::F32)?;
                        if cfg.pingpong_sequences {
                            pingpong_sequence(&x)
                        } else {
                            Ok(x)
                        }
                    })
                    .collect::<Result<Vec<_>>>()?;
                Ok(Tensor::stack(&seqs, 0)?)
            };
            let (lr, hr) = (gather(false)?, gather(true)?);
            let out = model.run_batch(&lr)?;
            let content = (&out.hr - &hr)?.sqr()?.mean_all()?;
            let t = lr.dim(1)?;
            let flows =
                out.lr_flows.as_ref().ok_or_else(|| Error::config("frames", "at least 2 frames per sequence"))?;
            let (b, n, m) = (lr.dim(0)?, lr.dim(3)?, lr.dim(4)?);
            let prev = lr.narrow(1, 0, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            let cur = lr.narrow(1, 1, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            let warped = backward_warp(&prev, &flows.reshape((b * (t - 1), 2, n, m))?)?;
            let warp = (warped - cur)?.sqr()?.mean_all()?;
            let pp = if cfg.pingpong_sequences { Some(pingpong_loss(&out.hr)?) } else { None };
            let mut loss = ((content.clone() * cfg.content_weight)? + (warp.clone() * cfg.warp_weight)?)?;
            if let Some(pp) = &pp {
                if cfg.pingpong_weight > 0.0 {
                    loss = (loss + (pp * cfg.pingpong_weight)?)?;
                }
            }
            let scalar = |x: &Tensor| -> Result<f64> { Ok(x.to_dtype(DType::F64)?.to_scalar::<f64>()?) };
            let mut r = report.borrow_mut();
            r.losses.push(scalar(&loss)?);
            r.content.push(scalar(&content)?);
            r.warp.push(scalar(&warp)?);
            r.pingpong.push(pp.as_ref().map(scalar).transpose()?.unwrap_or(f64::NAN));
            Ok(loss)
        },
    )?;
    let mut report = report.into_inner();
    report.seconds = looped.seconds;
    Ok((model, varmap, report))
}
