//! Training the three models that [`crate::eval`] compares, all with the same generator:
//!
//! 1. **Pre-training** (shared): L1 to the truth on random frames, from seeded weights.
//! 2. From the pre-trained weights, the same number of updates of each objective:
//!    [`ModelKind::Baseline`] (L1 only), [`ModelKind::PerFrame`] (L1 + spatial discriminator),
//!    [`ModelKind::Temporal`] (L1 + spatial + temporal discriminators, tempoGAN).
//!
//! A GAN update draws a batch of frame triplets `t-1, t, t+1`, updates the discriminators on
//! real vs generated (detached) samples — only while [`Balance`] allows it, if enabled — and
//! then the generator on the weighted sum of L1, the adversarial terms and the feature loss
//! ([`LossWeights`]). One Adam (tempoGAN's `beta1 = 0.5`) holds the moments of all networks;
//! each update applies only its own player's gradients.
//!
//! Every phase runs pbdl-core's [`TrainLoop`]: with a run directory it writes `loss.csv`
//! (with `d_loss`, `d_real` and `balance` columns for the GANs), atomic checkpoints holding the
//! weights, the optimiser's moments and the balance average, and resumes a stopped run exactly;
//! a directory of a run with other settings is refused, naming the first differing setting.
//!
//! Deviations from tempoGAN for CPU scale: narrower 3x3 generator (see
//! [`crate::generator`]), one discriminator and one generator update per iteration instead of
//! two each, discriminators without batch norm, L1 pre-training before the adversarial phase,
//! one Adam for all players (its bias-correction counter advances on every player's update).
//! The balance gates both discriminators but is computed from `D_s` alone (`mean log D_s(real)`
//! and the generator's spatial adversarial loss); its average starts at 0 without bias
//! correction. The feature loss averages over channels (`gan::feature_loss`).

use crate::data::{Clip, Dataset};
use crate::gan::{feature_loss, spatial_input, temporal_input, Balance, LossWeights};
use crate::generator::{FrameGenerator, GeneratorConfig};
use crate::model::{ModelInfo, ModelKind, TemporalModel};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, OptimizerConfig, TrainLoop, Update};
use pbdl_nets::discriminator::{bce_with_logits, Discriminator, DiscriminatorConfig};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::path::Path;

/// Updates, batch and learning rate of one phase.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseSettings {
    /// Updates (> 0).
    pub steps: u64,
    /// Samples per update (> 0): frames in pre-training, frame triplets in the GAN phase.
    pub batch: usize,
    /// Adam learning rate (> 0).
    pub lr: f64,
}

impl PhaseSettings {
    fn validate(&self, name: &'static str) -> Result<()> {
        if self.steps == 0 || self.batch == 0 || !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::config(
                name,
                format!("{self:?}: steps and batch must be positive, lr positive and finite"),
            ));
        }
        Ok(())
    }
}

/// Everything that decides a training run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// The generator (shared by all three models).
    pub generator: GeneratorConfig,
    /// L1 pre-training. Default 1500 updates of 16 frames, lr 1e-3.
    pub pretrain: PhaseSettings,
    /// The objective phase of each model. Default 1000 updates of 4 triplets, lr 2e-4
    /// (tempoGAN's rate).
    pub finetune: PhaseSettings,
    /// Generator loss weights.
    pub loss: LossWeights,
    /// Widths of both discriminators' stride-2 levels. Default `[16, 32, 64, 64]`.
    pub discriminator_widths: Vec<usize>,
    /// Skip discriminator updates while it is winning ([`Balance`], TecoGAN). Default true.
    pub balance: bool,
    /// Seed of the initial weights and the sampled batches. Default 0.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            generator: GeneratorConfig::default(),
            pretrain: PhaseSettings { steps: 1500, batch: 16, lr: 1e-3 },
            finetune: PhaseSettings { steps: 1000, batch: 4, lr: 2e-4 },
            loss: LossWeights::default(),
            discriminator_widths: vec![16, 32, 64, 64],
            balance: true,
            seed: 0,
        }
    }
}

impl TrainConfig {
    /// Checks the settings against the data.
    pub fn validate(&self, data: &Dataset) -> Result<()> {
        self.generator.validate()?;
        self.pretrain.validate("pretrain")?;
        self.finetune.validate("finetune")?;
        self.loss.validate()?;
        if self.generator.factor != data.config.factor {
            return Err(Error::config(
                "generator.factor",
                format!(
                    "{} but the data is downsampled by {}; use the data's factor",
                    self.generator.factor, data.config.factor
                ),
            ));
        }
        if data.train.is_empty() {
            return Err(Error::config("data.train", "no training clips; generate at least one scene"));
        }
        if data.train.iter().any(|c| c.frames() < 3) {
            return Err(Error::config("data.frames", "the GAN phase needs at least 3 frames per clip"));
        }
        let m = 1usize << self.discriminator_widths.len();
        let hr = data.config.hr_resolution();
        if self.discriminator_widths.is_empty() || hr % m != 0 {
            return Err(Error::config(
                "discriminator_widths",
                format!("{:?}: use 1..=log2 of the resolution {hr} levels", self.discriminator_widths),
            ));
        }
        Ok(())
    }
}

/// Loss and timing of a finished phase.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PhaseSummary {
    /// Mean generator loss over the last 10% of the updates.
    pub final_loss: f64,
    /// Median seconds per update of this run.
    pub median_step_seconds: f64,
    /// Updates this call ran (less than the phase's when it resumed).
    pub updates_run: usize,
}

fn json<T: Serialize>(t: &T) -> Result<serde_json::Value> {
    let v = serde_json::to_value(t).map_err(|e| Error::config("settings", format!("do not serialise: {e}")))?;
    Ok(pbdl_core::train::canonical(v)?)
}

fn summary(report: &pbdl_core::train::LoopReport) -> PhaseSummary {
    let l = &report.losses;
    let tail = &l[l.len() - (l.len() / 10).max(1).min(l.len())..];
    let final_loss = tail.iter().map(|(_, v)| v).sum::<f64>() / tail.len().max(1) as f64;
    let mut s = report.step_seconds.clone();
    s.sort_by(f64::total_cmp);
    PhaseSummary {
        final_loss,
        median_step_seconds: s.get(s.len() / 2).copied().unwrap_or(f64::NAN),
        updates_run: l.len(),
    }
}

/// Random frame indices `(clip, frame)` with `margin <= frame < T - margin`.
fn draw_frames(clips: &[Clip], count: usize, margin: usize, seed: u64, step: u64) -> Vec<(usize, usize)> {
    let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(seed, step));
    (0..count)
        .map(|_| {
            let c = rng.random_range(0..clips.len());
            (c, rng.random_range(margin..clips[c].frames() - margin))
        })
        .collect()
}

/// Stacks frame `t + offset` of the chosen clips' `pick` array.
fn gather(clips: &[Clip], idx: &[(usize, usize)], offsets: &[isize], pick: fn(&Clip) -> &Tensor) -> Result<Tensor> {
    let mut frames = Vec::with_capacity(idx.len() * offsets.len());
    for &(c, t) in idx {
        for &o in offsets {
            frames.push(pick(&clips[c]).narrow(0, (t as isize + o) as usize, 1)?);
        }
    }
    Ok(Tensor::cat(&frames, 0)?)
}

/// The shared L1 pre-training from seeded weights; `run_dir` makes it resumable.
pub fn pretrain(data: &Dataset, cfg: &TrainConfig, run_dir: Option<&Path>) -> Result<(TemporalModel, PhaseSummary)> {
    cfg.validate(data)?;
    let t = &cfg.pretrain;
    let model = TemporalModel::untrained(ModelKind::Baseline, cfg.generator.clone(), cfg.seed)?;
    let config = json(&serde_json::json!({
        "phase": "pretrain", "data": data.config, "generator": cfg.generator, "batch": t.batch, "lr": t.lr, "seed": cfg.seed,
    }))?;
    let lc = pbdl_core::train::guarded_loop_config(t.steps, run_dir, &config)?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr: t.lr, ..Default::default() });
    let meta = |step| CheckpointMeta { step, seed: Some(cfg.seed), config: config.clone() };
    let use_v = cfg.generator.use_velocity;
    let report = TrainLoop::resume(&model.varmap, lc)?.run::<Error>(
        &adam,
        |_| t.lr,
        meta,
        |step| {
            let idx = draw_frames(&data.train, t.batch, 0, cfg.seed, step);
            let lr = gather(&data.train, &idx, &[0], |c| &c.lr_density)?;
            let hr = gather(&data.train, &idx, &[0], |c| &c.hr_density)?;
            let v = if use_v { Some(gather(&data.train, &idx, &[0], |c| &c.lr_velocity)?) } else { None };
            Ok((model.generator.forward(&lr, v.as_ref())? - hr)?.abs()?.mean_all()?)
        },
    )?;
    let mut model = model;
    model.info.updates = t.steps;
    Ok((model, summary(&report)))
}

/// Copies every variable of `src` into the variable `prefix.<name>` of `dst`.
fn copy_into(src: &VarMap, dst: &VarMap, prefix: &str) -> Result<()> {
    let s = src.data().lock().unwrap_or_else(|e| e.into_inner());
    let d = dst.data().lock().unwrap_or_else(|e| e.into_inner());
    for (name, var) in s.iter() {
        let key = format!("{prefix}.{name}");
        let target = d.get(&key).ok_or_else(|| Error::config("model", format!("variable `{key}` missing")))?;
        target.set(var.as_tensor())?;
    }
    Ok(())
}

/// The variables of `map` whose names start with `prefix.`, in name order.
pub(crate) fn vars_with_prefix(map: &VarMap, prefix: &str) -> Vec<Var> {
    let d = map.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut named: Vec<(&String, &Var)> = d.iter().filter(|(n, _)| n.starts_with(&format!("{prefix}."))).collect();
    named.sort_by(|a, b| a.0.cmp(b.0));
    named.into_iter().map(|(_, v)| v.clone()).collect()
}

/// Trains `kind` for [`TrainConfig::finetune`] updates from the pre-trained generator `start`;
/// `run_dir` makes it resumable.
pub fn finetune(
    data: &Dataset,
    cfg: &TrainConfig,
    kind: ModelKind,
    start: &TemporalModel,
    run_dir: Option<&Path>,
) -> Result<(TemporalModel, PhaseSummary)> {
    cfg.validate(data)?;
    let t = &cfg.finetune;
    let f = cfg.generator.factor;
    let dev = Device::Cpu;
    // All players in one VarMap (`gen.*`, `ds.*`, `dt.*`) so that one checkpoint holds them.
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let generator = FrameGenerator::new(cfg.generator.clone(), vb.pp("gen"))?;
    let widths = cfg.discriminator_widths.clone();
    let d_s = (kind != ModelKind::Baseline)
        .then(|| Discriminator::new(DiscriminatorConfig::new(2, widths.clone()), vb.pp("ds")))
        .transpose()?;
    let d_t = (kind == ModelKind::Temporal)
        .then(|| Discriminator::new(DiscriminatorConfig::new(3, widths.clone()), vb.pp("dt")))
        .transpose()?;
    pbdl_nets::seeded_init(&varmap, cfg.seed ^ 0xd15c)?;
    copy_into(&start.varmap, &varmap, "gen")?;
    // Only the settings this objective depends on, so that e.g. another temporal weight
    // retrains the temporal GAN but resumes the other two.
    let mut settings = serde_json::json!({
        "phase": kind.name(), "data": data.config, "generator": cfg.generator, "pretrain": cfg.pretrain,
        "batch": t.batch, "lr": t.lr, "seed": cfg.seed, "loss": { "l1": cfg.loss.l1 },
    });
    if kind != ModelKind::Baseline {
        settings["loss"]["spatial"] = cfg.loss.spatial.into();
        settings["loss"]["feature"] = cfg.loss.feature.into();
        settings["discriminator_widths"] = serde_json::json!(widths);
        settings["balance"] = cfg.balance.into();
    }
    if kind == ModelKind::Temporal {
        settings["loss"]["temporal"] = cfg.loss.temporal.into();
    }
    let config = json(&settings)?;
    let lc = pbdl_core::train::guarded_loop_config(t.steps, run_dir, &config)?;
    let run = TrainLoop::resume(&varmap, lc)?;
    let all_vars: Vec<Var> = ["gen", "ds", "dt"].iter().flat_map(|p| vars_with_prefix(&varmap, p)).collect();
    let adam = OptimizerConfig::Adam(AdamConfig { lr: t.lr, beta1: 0.5, ..Default::default() });
    let opt = RefCell::new(adam.build(all_vars)?);
    let mut balance = Balance::default();
    if let Some(ck) = run.resumed() {
        ck.restore_optimizer(&mut opt.borrow_mut(), &varmap)?;
        balance.average = ck.extra_tensor("balance_average")?.to_vec1::<f64>()?[0];
    }
    let balance = RefCell::new(balance);
    let gen_vars: Vec<Var> = vars_with_prefix(&varmap, "gen");
    let disc_vars: Vec<Var> = ["ds", "dt"].iter().flat_map(|p| vars_with_prefix(&varmap, p)).collect();
    let w = &cfg.loss;
    let meta = |step| CheckpointMeta { step, seed: Some(cfg.seed), config: config.clone() };
    let state = |_| -> Result<Vec<(String, Tensor)>> {
        let mut s = pbdl_core::train::state::optimizer_state_tensors(&opt.borrow(), &varmap)?;
        s.push(("balance_average".into(), Tensor::new(&[balance.borrow().average], &dev)?));
        Ok(s)
    };
    let use_v = cfg.generator.use_velocity;
    let report = run.run_custom_with_state::<Error>(
        |_| t.lr,
        meta,
        state,
        |step, _lr| {
            let idx = draw_frames(&data.train, t.batch, 1, cfg.seed ^ 0x6a7e, step);
            let trip = [-1, 0, 1];
            let lr = gather(&data.train, &idx, &trip, |c| &c.lr_density)?;
            let hr = gather(&data.train, &idx, &trip, |c| &c.hr_density)?;
            let vel = gather(&data.train, &idx, &trip, |c| &c.lr_velocity)?;
            let fake = generator.forward(&lr, use_v.then_some(&vel))?;
            let l1 = (&fake - &hr)?.abs()?.mean_all()?;
            let mut update = Update::loss(0.0);
            // Discriminators: real vs generated (detached).
            let mut log_d_real = f64::NAN;
            if let Some(ds) = &d_s {
                let real_s = ds.forward(&spatial_input(&lr, &hr, f)?)?;
                let fake_s = ds.forward(&spatial_input(&lr, &fake.detach(), f)?)?;
                let mut d_loss = (bce_with_logits(&real_s.logits, 1.0)? + bce_with_logits(&fake_s.logits, 0.0)?)?;
                log_d_real = -bce_with_logits(&real_s.logits, 1.0)?.to_scalar::<f32>()? as f64;
                if let Some(dt) = &d_t {
                    let real_t = dt.forward(&temporal_input(&hr, &vel, f)?)?;
                    let fake_t = dt.forward(&temporal_input(&fake.detach(), &vel, f)?)?;
                    d_loss = (d_loss + bce_with_logits(&real_t.logits, 1.0)? + bce_with_logits(&fake_t.logits, 0.0)?)?;
                }
                let d_value = d_loss.to_scalar::<f32>()? as f64;
                let trained = !cfg.balance || balance.borrow().train_discriminator();
                if trained {
                    let mut grads = d_loss.backward()?;
                    for v in &gen_vars {
                        grads.remove(v.as_tensor());
                    }
                    opt.borrow_mut().step(&grads)?;
                }
                update = update
                    .with("d_loss", d_value)
                    .with("d_real", log_d_real.exp())
                    .with("d_trained", trained as u8 as f64);
            }
            // Generator.
            let mut g_loss = (&l1 * w.l1)?;
            let mut adversarial = 0.0;
            if let Some(ds) = &d_s {
                let real_s = ds.forward(&spatial_input(&lr, &hr, f)?)?;
                let fake_s = ds.forward(&spatial_input(&lr, &fake, f)?)?;
                let adv = bce_with_logits(&fake_s.logits, 1.0)?;
                adversarial += adv.to_scalar::<f32>()? as f64;
                g_loss = (g_loss + (adv * w.spatial)?)?;
                if w.feature != 0.0 {
                    let real_feats: Vec<Tensor> = real_s.features.iter().map(|x| x.detach()).collect();
                    g_loss = (g_loss + (feature_loss(&real_feats, &fake_s.features)? * w.feature)?)?;
                }
                if let Some(dt) = &d_t {
                    let adv_t = bce_with_logits(&dt.forward(&temporal_input(&fake, &vel, f)?)?.logits, 1.0)?;
                    g_loss = (g_loss + (adv_t * w.temporal)?)?;
                }
                balance.borrow_mut().observe(log_d_real, adversarial);
                update = update.with("balance", balance.borrow().average);
            }
            let mut grads = g_loss.backward()?;
            for v in &disc_vars {
                grads.remove(v.as_tensor());
            }
            opt.borrow_mut().step(&grads)?;
            update.loss = g_loss.to_scalar::<f32>()? as f64;
            Ok(update.with("l1", l1.to_scalar::<f32>()? as f64))
        },
    )?;
    // The generator alone, as a model file holds it.
    let model = TemporalModel::untrained(kind, cfg.generator.clone(), 0)?;
    {
        let src = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        let dst = model.varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        for (name, var) in dst.iter() {
            let s = src
                .get(&format!("gen.{name}"))
                .ok_or_else(|| Error::config("model", format!("`gen.{name}` missing")))?;
            var.set(s.as_tensor())?;
        }
    }
    let model = TemporalModel {
        info: ModelInfo { kind, generator: cfg.generator.clone(), updates: cfg.pretrain.steps + t.steps },
        ..model
    };
    Ok((model, summary(&report)))
}

/// Pre-training and then the three objectives; with `run_dir`, each phase in its own
/// subdirectory (`pretrain/`, `baseline/`, `per_frame/`, `temporal/`) and the models as
/// `models/<kind>.safetensors`.
pub fn train_all(
    data: &Dataset,
    cfg: &TrainConfig,
    run_dir: Option<&Path>,
) -> Result<Vec<(TemporalModel, PhaseSummary)>> {
    let sub = |name: &str| run_dir.map(|d| d.join(name));
    let (start, _) = pretrain(data, cfg, sub("pretrain").as_deref())?;
    let mut out = Vec::with_capacity(3);
    for kind in ModelKind::ALL {
        let (model, s) = finetune(data, cfg, kind, &start, sub(kind.name()).as_deref())?;
        if let Some(d) = run_dir {
            let models = d.join("models");
            std::fs::create_dir_all(&models).map_err(|e| pbdl_core::Error::io(&models, e))?;
            model.save(&models.join(format!("{}.safetensors", kind.name())))?;
        }
        out.push((model, s));
    }
    Ok(out)
}
