//! The adversarial TecoGAN trainer: F and G against the spatio-temporal discriminator D_s,t
//! (documented on [`train_tecogan_gan`]).

use super::pingpong::{pingpong_loss, pingpong_sequence};
use super::recurrent::{TecoGan, TecoGanConfig};
use super::triplet::{spatio_temporal_discriminator, triplet_flows, triplet_input};
use crate::data::Clip;
use crate::gan::Balance;
use crate::train::vars_with_prefix;
use crate::warp::backward_warp;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, OptimizerConfig, TrainLoop, Update};
use pbdl_nets::discriminator::{bce_with_logits, Discriminator};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::path::Path;

/// Settings of [`train_tecogan_gan`]. Every field but `steps` is part of the run's identity:
/// a run directory written with other values is refused on resume.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TecoGanTrainConfig {
    /// F and G.
    pub model: TecoGanConfig,
    /// Updates (each one D update, if the balance allows, and one G + F update; >= 1).
    /// Default 300.
    pub steps: u64,
    /// Sequences per update (>= 1). Default 4.
    pub batch: usize,
    /// Frames per training sequence before the ping-pong extension (>= 2, >= 3 without
    /// ping-pong sequences, so that there is a triplet; TecoGAN: 10). Default 6 (11 with
    /// ping-pong).
    pub frames: usize,
    /// Adam's learning rate for all players (constant, > 0; TecoGAN: 5e-5). Default 1e-4.
    pub lr: f64,
    /// Extend each sequence to its ping-pong order (`2 frames - 1`). Default true. Needed for a
    /// non-zero `pingpong_weight`.
    pub pingpong_sequences: bool,
    /// Weight of the L2 content loss `mean (g - y)^2` over all generated frames (TecoGAN: 1).
    pub content_weight: f64,
    /// Weight of the ping-pong loss `mean |g_t - g'_t|` (TecoGAN: 0.5).
    pub pingpong_weight: f64,
    /// Weight of the non-saturating adversarial loss `-log D(fake)` (TecoGAN: 0.01).
    pub adversarial_weight: f64,
    /// Weight of each level's D-feature loss `mean_pixels sum_channels |phi_l(real) -
    /// phi_l(fake)| / norm_l` (TecoGAN's reduction and weight 0.02; real features detached).
    pub feature_weight: f64,
    /// The per-level normalisers `norm_l`, one per entry of `discriminator_widths` (> 0;
    /// TecoGAN: `[12, 14, 24, 100]` for its four levels). Default `[12, 14, 24, 100]`.
    pub feature_norms: Vec<f64>,
    /// Weight of F's low-resolution warp loss `mean (warp(lr_{t-1}, F) - lr_t)^2` (TecoGAN: 1).
    pub warp_weight: f64,
    /// Widths of D_s,t's stride-2 levels (the high resolution must be divisible by
    /// `2^levels`). Default `[16, 32, 64, 64]`.
    pub discriminator_widths: Vec<usize>,
    /// Skip D updates while the [`Balance`] average is at or above `balance_threshold`
    /// (TecoGAN). Default true.
    pub balance: bool,
    /// The balance threshold (finite; TecoGAN: 0.4). Default 0.4.
    pub balance_threshold: f64,
    /// Seed of the initial weights (F and G as [`super::train_tecogan`] with this seed, unless
    /// a start is given; D with a stream of it) and of the sampled windows. Default 0.
    pub seed: u64,
}

impl Default for TecoGanTrainConfig {
    fn default() -> Self {
        Self {
            model: TecoGanConfig::default(),
            steps: 300,
            batch: 4,
            frames: 6,
            lr: 1e-4,
            pingpong_sequences: true,
            content_weight: 1.0,
            pingpong_weight: 0.5,
            adversarial_weight: 0.01,
            feature_weight: 0.02,
            feature_norms: vec![12.0, 14.0, 24.0, 100.0],
            warp_weight: 1.0,
            discriminator_widths: vec![16, 32, 64, 64],
            balance: true,
            balance_threshold: 0.4,
            seed: 0,
        }
    }
}

impl TecoGanTrainConfig {
    /// Checks every field ([`Error::Config`] naming it).
    pub fn validate(&self) -> Result<()> {
        self.model.validate()?;
        if self.steps == 0 {
            return Err(Error::config("steps", "0; use at least 1 update"));
        }
        if self.batch == 0 {
            return Err(Error::config("batch", "0; use at least 1 sequence per update"));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::config("lr", format!("{}; use a positive finite rate", self.lr)));
        }
        let min_frames = if self.pingpong_sequences { 2 } else { 3 };
        if self.frames < min_frames {
            return Err(Error::config(
                "frames",
                format!("{}; use at least {min_frames} so that a sequence holds a frame triplet", self.frames),
            ));
        }
        super::train::check_loss_weights(
            &[
                ("content_weight", self.content_weight),
                ("pingpong_weight", self.pingpong_weight),
                ("adversarial_weight", self.adversarial_weight),
                ("feature_weight", self.feature_weight),
                ("warp_weight", self.warp_weight),
            ],
            self.pingpong_weight,
            self.pingpong_sequences,
        )?;
        if self.discriminator_widths.is_empty() || self.discriminator_widths.contains(&0) {
            return Err(Error::config(
                "discriminator_widths",
                format!("{:?}; use at least one positive width", self.discriminator_widths),
            ));
        }
        if self.feature_norms.len() != self.discriminator_widths.len() {
            return Err(Error::config(
                "feature_norms",
                format!(
                    "{:?}: {} normalisers for {} discriminator levels; give one per level",
                    self.feature_norms,
                    self.feature_norms.len(),
                    self.discriminator_widths.len()
                ),
            ));
        }
        if self.feature_norms.iter().any(|n| !(*n > 0.0 && n.is_finite())) {
            return Err(Error::config(
                "feature_norms",
                format!("{:?}; use positive finite values", self.feature_norms),
            ));
        }
        if !self.balance_threshold.is_finite() {
            return Err(Error::config("balance_threshold", format!("{}; use a finite value", self.balance_threshold)));
        }
        Ok(())
    }

    /// Frames per (extended) training sequence: `2 frames - 1` with ping-pong sequences.
    pub fn sequence_frames(&self) -> usize {
        if self.pingpong_sequences {
            2 * self.frames - 1
        } else {
            self.frames
        }
    }

    /// Frame triplets per sequence that D_s,t sees (`sequence_frames / 3`).
    pub fn triplets_per_sequence(&self) -> usize {
        self.sequence_frames() / 3
    }
}

/// What [`train_tecogan_gan`] did in this call (a resumed call covers the updates after the
/// checkpoint only; `loss.csv` holds the whole run).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TecoGanTrainReport {
    /// The first update of this call (0 unless resumed).
    pub resumed_from: u64,
    /// G + F loss per update.
    pub losses: Vec<f64>,
    /// D loss `-log D(real) - log(1 - D(fake))` per update (computed even when D skips).
    pub d_loss: Vec<f64>,
    /// `exp(mean log D(real))` per update.
    pub d_real: Vec<f64>,
    /// Whether D updated (the balance allowed it).
    pub d_trained: Vec<bool>,
    /// The balance average after each update.
    pub balance: Vec<f64>,
    /// Content loss per update.
    pub content: Vec<f64>,
    /// Ping-pong loss per update (NaN without ping-pong sequences; computed even at weight 0).
    pub pingpong: Vec<f64>,
    /// `-log D(fake)` per update.
    pub adversarial: Vec<f64>,
    /// The normalised D-feature loss `sum_l mean |phi_l(real) - phi_l(fake)| / norm_l` per
    /// update (before `feature_weight`).
    pub feature: Vec<f64>,
    /// F's warp loss per update.
    pub warp: Vec<f64>,
    /// Wall-clock seconds of this call's updates.
    pub seconds: f64,
}

/// The three players in one `VarMap`, as [`train_tecogan_gan`] trains and checkpoints them.
pub struct TecoGanPlayers {
    /// F and G, on the variables of `model_varmap`.
    pub model: TecoGan,
    /// F's and G's variables (`fnet.*`, `generator.*`, as [`super::train_tecogan`] returns).
    pub model_varmap: VarMap,
    /// D_s,t.
    pub discriminator: Discriminator,
    /// All variables, the same `Var`s: `g.<F and G name>` and `d.<D name>`; the layout of the
    /// checkpoints (load one with `pbdl_core::train::load_train_checkpoint`).
    pub varmap: VarMap,
}

/// Builds the players of `cfg` with their initial weights: F and G from `start` (a `VarMap`
/// of a [`TecoGan`] with `cfg.model`, e.g. from [`super::train_tecogan`]; every variable must
/// be there with its shape) or, without one, [`pbdl_nets::seeded_init`] with `cfg.seed`; D
/// with a stream of `cfg.seed`.
pub fn tecogan_gan_players(cfg: &TecoGanTrainConfig, start: Option<&VarMap>) -> Result<TecoGanPlayers> {
    cfg.validate()?;
    let dev = Device::Cpu;
    let model_varmap = VarMap::new();
    let model = TecoGan::new(cfg.model.clone(), VarBuilder::from_varmap(&model_varmap, DType::F32, &dev))?;
    pbdl_nets::seeded_init(&model_varmap, cfg.seed)?;
    if let Some(src) = start {
        let s = src.data().lock().unwrap_or_else(|e| e.into_inner());
        let d = model_varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        if let Some(extra) = s.keys().find(|k| !d.contains_key(*k)) {
            return Err(Error::config("start", format!("has `{extra}`, which a TecoGan of `model` has not")));
        }
        for (name, var) in d.iter() {
            let from = s
                .get(name)
                .ok_or_else(|| Error::config("start", format!("has no `{name}`; pass the VarMap of a TecoGan")))?;
            if from.dims() != var.dims() {
                return Err(Error::config(
                    "start",
                    format!("`{name}` is {:?}, `model` needs {:?}; use the same model config", from.dims(), var.dims()),
                ));
            }
            var.set(&from.as_tensor().to_dtype(DType::F32)?)?;
        }
    }
    let d_varmap = VarMap::new();
    let discriminator = Discriminator::new(
        spatio_temporal_discriminator(cfg.discriminator_widths.clone()),
        VarBuilder::from_varmap(&d_varmap, DType::F32, &dev),
    )?;
    pbdl_nets::seeded_init(&d_varmap, pbdl_core::noise::stream_seed(cfg.seed, 0xd15c))?;
    let varmap = VarMap::new();
    {
        let mut all = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        for (prefix, map) in [("g", &model_varmap), ("d", &d_varmap)] {
            for (name, var) in map.data().lock().unwrap_or_else(|e| e.into_inner()).iter() {
                all.insert(format!("{prefix}.{name}"), var.clone());
            }
        }
    }
    Ok(TecoGanPlayers { model, model_varmap, discriminator, varmap })
}

/// FNV-1a over the names and the bits of the tensors (as f32), for the resume guard.
fn digest<'a>(tensors: impl IntoIterator<Item = (&'a str, &'a Tensor)>) -> Result<String> {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for b in bytes {
            h = (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for (name, t) in tensors {
        eat(name.as_bytes());
        for d in t.dims() {
            eat(&(*d as u64).to_le_bytes());
        }
        for v in t.flatten_all()?.to_dtype(DType::F32)?.to_vec1::<f32>()? {
            eat(&v.to_bits().to_le_bytes());
        }
    }
    Ok(format!("{h:016x}"))
}

fn varmap_digest(map: &VarMap) -> Result<String> {
    let d = map.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut named: Vec<(&String, &Var)> = d.iter().collect();
    named.sort_by(|a, b| a.0.cmp(b.0));
    digest(named.iter().map(|(n, v)| (n.as_str(), v.as_tensor())))
}

fn scalar(x: &Tensor) -> Result<f64> {
    Ok(x.to_dtype(DType::F64)?.to_scalar::<f64>()?)
}

/// Checks the clips against `cfg` and returns those long enough for a window.
fn usable_clips<'a>(clips: &'a [Clip], cfg: &TecoGanTrainConfig) -> Result<Vec<&'a Clip>> {
    if clips.is_empty() {
        return Err(Error::input("clips", "none given; pass at least one training clip"));
    }
    let factor = cfg.model.generator.factor;
    let (k, m) = (cfg.model.motion.size_multiple(), 1usize << cfg.discriminator_widths.len());
    for c in clips {
        let (l, h) = (c.lr_density.dims(), c.hr_density.dims());
        if l.len() != 4 || l[1] != 1 || h.len() != 4 || h[0] != l[0] || h[2] != l[2] * factor || h[3] != l[3] * factor {
            return Err(Error::input(
                "clip",
                format!("lr {l:?} and hr {h:?}: expected [T, 1, n, m] and [T, 1, {factor} n, {factor} m]"),
            ));
        }
        if l[2] % k != 0 || l[3] % k != 0 {
            return Err(Error::config(
                "model.motion.levels",
                format!("{}: the low resolution {:?} is not divisible by {k}", cfg.model.motion.levels, &l[2..]),
            ));
        }
        if h[2] % m != 0 || h[3] % m != 0 {
            return Err(Error::config(
                "discriminator_widths",
                format!("{:?}: the high resolution {:?} is not divisible by {m}", cfg.discriminator_widths, &h[2..]),
            ));
        }
    }
    let usable: Vec<&Clip> = clips.iter().filter(|c| c.frames() >= cfg.frames).collect();
    if usable.is_empty() {
        return Err(Error::config("frames", format!("{}; every clip is shorter", cfg.frames)));
    }
    Ok(usable)
}

/// `[B, T', 1, y, x]` training sequences of step `step`: window starts drawn from
/// `(seed, step)`, extended to ping-pong order if asked.
fn draw_sequences(clips: &[&Clip], cfg: &TecoGanTrainConfig, step: u64) -> Result<(Tensor, Tensor)> {
    let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed ^ 0x7ec0_6a4e, step));
    let picks: Vec<(usize, usize)> = (0..cfg.batch)
        .map(|_| {
            let c = rng.random_range(0..clips.len());
            (c, rng.random_range(0..=clips[c].frames() - cfg.frames))
        })
        .collect();
    let gather = |hr: bool| -> Result<Tensor> {
        let seqs = picks
            .iter()
            .map(|&(c, s)| {
                let x = if hr { &clips[c].hr_density } else { &clips[c].lr_density };
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
    Ok((gather(false)?, gather(true)?))
}

/// `[B K, 3, y, x]`: the first `3 K` frames of `seq` `[B, T', 1, y, x]` as `K` triplets per
/// sequence.
fn triplets(seq: &Tensor, k: usize) -> Result<Tensor> {
    let (b, y, x) = (seq.dim(0)?, seq.dim(3)?, seq.dim(4)?);
    Ok(seq.narrow(1, 0, 3 * k)?.contiguous()?.reshape((b * k, 3, y, x))?)
}

/// Trains F and G adversarially against D_s,t on windows of `clips` (f32, CPU), starting F and
/// G from `start` (the `VarMap` of a [`TecoGan`] with `cfg.model`, e.g. the pre-training of
/// [`super::train_tecogan`]: pre-train non-adversarially, then fine-tune adversarially) or from
/// seeded weights. `run_dir` makes the run resumable; a directory written with other settings
/// is refused with `pbdl_core::Error::ResumeMismatch` naming the setting (e.g. `seed`).
///
/// Returns F and G, their `VarMap` (`fnet.*`, `generator.*`, loadable as a `start` or by
/// [`TecoGan::new`]), and the report of this call.
///
/// Per update: `batch` windows of `frames` consecutive frames (drawn from `(seed, step)`, so a
/// resumed run draws what the uninterrupted one would), extended to the ping-pong order
/// (`2 frames - 1`); F and G run over them recurrently ([`TecoGan::run_batch`]); the generated
/// and the real high-resolution sequences are cut into non-overlapping frame triplets
/// (`3k, 3k+1, 3k+2`, `k < len / 3`; with ping-pong these include backward frames, the real
/// triplets in the same order), each turned into D_s,t's 9-channel input ([`triplet_input`]:
/// the triplet, the triplet warped onto its middle frame by F's stop-gradient flows of the
/// low-resolution triplet with a 75% centre crop, the upsampled low-resolution triplet).
///
/// 1. **D update** on `-log D(real) - log(1 - D(fake))` with the generated triplets detached,
///    only while [`Balance`] allows it (TecoGAN: a moving average, decay 0.99, of
///    `mean log D(real) + L_adv` below 0.4) when `balance` is on; G's and F's gradients are
///    dropped before the step.
/// 2. **G + F update** on the weighted sum of the content loss `mean (g - y)^2`, the ping-pong
///    loss `mean |g_t - g'_t|`, the adversarial loss `-log D(fake)`, the D-feature loss
///    `sum_l mean |phi_l(real) - phi_l(fake)| / norm_l` and F's warp loss
///    `mean (warp(lr_{t-1}, F) - lr_t)^2` (TecoGAN's weights 1, 0.5, 0.01, 0.02 per level, 1;
///    norms `[12, 14, 24, 100]`, one per discriminator level); D's gradients are
///    dropped before the step. **No VGG term** (TecoGAN's 0.2 VGG feature loss needs ImageNet
///    weights that are not available here, and single-channel densities are not photographs).
///
/// One Adam (`beta1 = 0.5`, as tempoGAN's and [`crate::train`]'s adversarial phase) holds the
/// moments of all three networks; each update applies only its own player's gradients. The
/// players share one `VarMap` (`g.fnet.*`, `g.generator.*`, `d.*`, see [`TecoGanPlayers`]) so
/// that one checkpoint holds them with the optimiser's moments and the balance average.
///
/// With a run directory: `loss.csv` (columns `loss` (the G + F loss), `d_loss`, `d_real`
/// (`exp(mean log D(real))`), `d_trained`, `balance`, `content`, `pingpong`, `adversarial`,
/// `feature`, `warp`), atomic checkpoints every tenth of the run, exact resume, and a refusal
/// to resume a directory written with other settings (anything but `steps`, including a
/// digest of the clips and of the start weights), naming the first differing setting.
///
/// Deviations from TecoGAN at CPU scale: see [`crate::tecogan`] for F and G; D_s,t has no
/// batch norm and a head on the spatial mean instead of a per-pixel one, widths
/// `[16, 32, 64, 64]` instead of `[64, 64, 128, 256]` and no leading stride-1 conv; one D and
/// one G update per iteration; one Adam for all players (TecoGAN has one per network: here the
/// bias-correction counter advances on D and G updates alike, the moments are per variable);
/// the balance average starts at 0 without bias correction, so it holds D back only after
/// roughly the first 50 updates.
pub fn train_tecogan_gan(
    clips: &[Clip],
    cfg: &TecoGanTrainConfig,
    start: Option<&VarMap>,
    run_dir: Option<&Path>,
) -> Result<(TecoGan, VarMap, TecoGanTrainReport)> {
    cfg.validate()?;
    let usable = usable_clips(clips, cfg)?;
    let players = tecogan_gan_players(cfg, start)?;
    let TecoGanPlayers { model, model_varmap, discriminator, varmap } = players;
    let dev = Device::Cpu;
    let factor = cfg.model.generator.factor;

    let mut identity = serde_json::to_value(cfg).map_err(|e| Error::config("settings", format!("{e}")))?;
    if let Some(o) = identity.as_object_mut() {
        o.remove("steps");
        o.insert("trainer".into(), "tecogan_gan".into());
        let data = clips.iter().flat_map(|c| [("lr", &c.lr_density), ("hr", &c.hr_density)]);
        o.insert("clips_digest".into(), digest(data)?.into());
        let start_digest = match start {
            Some(s) => varmap_digest(s)?,
            None => "seeded".into(),
        };
        o.insert("start_digest".into(), start_digest.into());
    }
    let identity = pbdl_core::train::canonical(identity)?;
    let lc = pbdl_core::train::guarded_loop_config(cfg.steps, run_dir, &identity)?;
    let run = TrainLoop::resume(&varmap, lc)?;
    let all_vars: Vec<Var> = ["g", "d"].iter().flat_map(|p| vars_with_prefix(&varmap, p)).collect();
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, beta1: 0.5, ..Default::default() });
    let opt = RefCell::new(adam.build(all_vars)?);
    let mut balance = Balance { threshold: cfg.balance_threshold, ..Balance::default() };
    if let Some(ck) = run.resumed() {
        ck.restore_optimizer(&mut opt.borrow_mut(), &varmap)?;
        balance.average = ck.extra_tensor("balance_average")?.to_vec1::<f64>()?[0];
    }
    let balance = RefCell::new(balance);
    let g_vars = vars_with_prefix(&varmap, "g");
    let d_vars = vars_with_prefix(&varmap, "d");
    let meta = |step| CheckpointMeta { step, seed: Some(cfg.seed), config: identity.clone() };
    let state = |_| -> Result<Vec<(String, Tensor)>> {
        let mut s = pbdl_core::train::state::optimizer_state_tensors(&opt.borrow(), &varmap)?;
        s.push(("balance_average".into(), Tensor::new(&[balance.borrow().average], &dev)?));
        Ok(s)
    };
    let report = RefCell::new(TecoGanTrainReport { resumed_from: run.start(), ..Default::default() });
    let k = cfg.triplets_per_sequence();
    let looped = run.run_custom_with_state::<Error>(
        |_| cfg.lr,
        meta,
        state,
        |step, _lr| {
            let (lr, hr) = draw_sequences(&usable, cfg, step)?;
            let out = model.run_batch(&lr)?;
            // Triplets and their stop-gradient flows (from the low-resolution triplets).
            let lr_t = triplets(&lr, k)?;
            let real_t = triplets(&hr, k)?;
            let fake_t = triplets(&out.hr, k)?;
            let flows = triplet_flows(model.motion(), &lr_t, factor)?;
            let real_in = triplet_input(&real_t, &lr_t, &flows)?;

            // D update on real vs detached fake.
            let d_real_out = discriminator.forward(&real_in)?;
            let d_fake_out = discriminator.forward(&triplet_input(&fake_t.detach(), &lr_t, &flows)?)?;
            let real_bce = bce_with_logits(&d_real_out.logits, 1.0)?;
            let d_loss = (&real_bce + bce_with_logits(&d_fake_out.logits, 0.0)?)?;
            let log_d_real = -scalar(&real_bce)?;
            let d_value = scalar(&d_loss)?;
            let trained = !cfg.balance || balance.borrow().train_discriminator();
            if trained {
                let mut grads = d_loss.backward()?;
                for v in &g_vars {
                    grads.remove(v.as_tensor());
                }
                opt.borrow_mut().step(&grads)?;
            }

            // G + F update.
            let content = (&out.hr - &hr)?.sqr()?.mean_all()?;
            let t = lr.dim(1)?;
            let flows_lr = out.lr_flows.as_ref().ok_or_else(|| Error::config("frames", "at least 2 frames"))?;
            let (b, n, m) = (lr.dim(0)?, lr.dim(3)?, lr.dim(4)?);
            let prev = lr.narrow(1, 0, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            let cur = lr.narrow(1, 1, t - 1)?.reshape((b * (t - 1), 1, n, m))?;
            let warp = (backward_warp(&prev, &flows_lr.reshape((b * (t - 1), 2, n, m))?)? - cur)?.sqr()?.mean_all()?;
            let pp = if cfg.pingpong_sequences { Some(pingpong_loss(&out.hr)?) } else { None };
            let real_feats = discriminator.forward(&real_in)?.features;
            let fake_out = discriminator.forward(&triplet_input(&fake_t, &lr_t, &flows)?)?;
            let adversarial = bce_with_logits(&fake_out.logits, 1.0)?;
            let mut feature = Tensor::zeros((), DType::F32, &dev)?;
            for ((r, f), norm) in real_feats.iter().zip(&fake_out.features).zip(&cfg.feature_norms) {
                // TecoGAN: mean over batch and pixels of the channel sum of |diff|, over the norm.
                feature = (feature + ((r.detach() - f)?.abs()?.sum_keepdim(1)?.mean_all()? / *norm)?)?;
            }
            let mut loss = ((&content * cfg.content_weight)? + (&warp * cfg.warp_weight)?)?;
            if let Some(pp) = &pp {
                loss = (loss + (pp * cfg.pingpong_weight)?)?;
            }
            loss = (loss + (&adversarial * cfg.adversarial_weight)? + (&feature * cfg.feature_weight)?)?;
            let adv_value = scalar(&adversarial)?;
            balance.borrow_mut().observe(log_d_real, adv_value);
            let mut grads = loss.backward()?;
            for v in &d_vars {
                grads.remove(v.as_tensor());
            }
            opt.borrow_mut().step(&grads)?;

            let mut r = report.borrow_mut();
            let avg = balance.borrow().average;
            let values = [
                ("content", scalar(&content)?),
                ("pingpong", pp.as_ref().map(scalar).transpose()?.unwrap_or(f64::NAN)),
                ("adversarial", adv_value),
                ("feature", scalar(&feature)?),
                ("warp", scalar(&warp)?),
            ];
            r.losses.push(scalar(&loss)?);
            r.d_loss.push(d_value);
            r.d_real.push(log_d_real.exp());
            r.d_trained.push(trained);
            r.balance.push(avg);
            r.content.push(values[0].1);
            r.pingpong.push(values[1].1);
            r.adversarial.push(values[2].1);
            r.feature.push(values[3].1);
            r.warp.push(values[4].1);
            let mut update = Update::loss(scalar(&loss)?)
                .with("d_loss", d_value)
                .with("d_real", log_d_real.exp())
                .with("d_trained", trained as u8 as f64)
                .with("balance", avg);
            for (name, v) in values {
                if v.is_finite() {
                    update = update.with(name, v);
                }
            }
            Ok(update)
        },
    )?;
    let mut report = report.into_inner();
    report.seconds = looped.seconds;
    Ok((model, model_varmap, report))
}
