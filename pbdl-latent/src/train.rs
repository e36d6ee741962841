//! Training of the two networks, one after the other, as the paper does: the autoencoder on
//! single pressure frames (MSE), then the LSTM on windows of the frozen autoencoder's codes
//! (MAE). Both run pbdl-core's [`TrainLoop`]: with a run directory they write `loss.csv`, atomic
//! checkpoints (weights and Adam's moments) and resume a stopped run; a directory holding a run
//! of other settings is refused with a typed error naming the first differing setting.
//!
//! Deviations from the paper, for CPU scale: Adam for both networks (the paper trains the LSTM
//! with RMSprop, which candle does not have), a fixed number of updates of random frames or
//! windows instead of epochs, and codes scaled by their standard deviation instead of 3.5.

use crate::autoencoder::{AutoencoderConfig, LatentAutoencoder};
use crate::data::{Dataset, Sequence};
use crate::model::{LatentModel, Scales};
use crate::predictor::{LatentPredictor, PredictorConfig};
use crate::{Error, Result};
use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Settings of one network's training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhaseSettings {
    /// Updates. Default 2000.
    pub steps: u64,
    /// Frames (autoencoder) or windows (predictor) per update. Default 16 (the paper's).
    pub batch: usize,
    /// Adam's learning rate, halved at 50% and again at 75% of the updates. Default 1e-3
    /// (the paper's for the autoencoder).
    pub lr: f64,
}

impl Default for PhaseSettings {
    fn default() -> Self {
        Self { steps: 2000, batch: 16, lr: 1e-3 }
    }
}

impl PhaseSettings {
    /// Checks the settings (typed [`Error::Config`] naming the phase).
    pub(crate) fn validate(&self, name: &'static str) -> Result<()> {
        if self.steps == 0 || self.batch == 0 || !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::config(
                name,
                format!("{self:?}: steps and batch must be positive, lr positive and finite"),
            ));
        }
        Ok(())
    }

    /// Adam's rate at `step`: halved at 50% and again at 75% of the updates.
    pub(crate) fn lr_at(&self, step: u64) -> f64 {
        let quarter = (4 * step / self.steps.max(1)).min(3) as i32;
        self.lr * 0.5f64.powi((quarter - 1).max(0))
    }
}

/// Everything [`train`] needs besides the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LatentTrainConfig {
    /// The autoencoder's layout (its `resolution` must be the data's).
    pub autoencoder: AutoencoderConfig,
    /// The predictor's window and units (its `code_size` is set from the autoencoder).
    pub predictor: PredictorConfig,
    /// Autoencoder training.
    pub autoencoder_training: PhaseSettings,
    /// Predictor training. Default: 3000 updates at lr 3e-4.
    pub predictor_training: PhaseSettings,
    /// Seed of the initialisations and of the sampled frames and windows.
    pub seed: u64,
    /// Weight of a loss on the pressure's finite-difference gradient (what the velocity
    /// correction uses), added to the autoencoder's MSE in the same units (scaled by the batch's
    /// `mean p^2 / mean |grad p|^2`). 0, the default, is the paper's plain MSE.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub gradient_loss_weight: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for LatentTrainConfig {
    fn default() -> Self {
        Self {
            autoencoder: AutoencoderConfig::default(),
            predictor: PredictorConfig::default(),
            autoencoder_training: PhaseSettings::default(),
            predictor_training: PhaseSettings { steps: 3000, batch: 16, lr: 3e-4 },
            seed: 0,
            gradient_loss_weight: 0.0,
        }
    }
}

/// The 99.9th percentile of `|p|` over the training frames (the autoencoder's scale).
pub fn pressure_scale(train: &[Sequence]) -> Result<f32> {
    let mut all = Vec::new();
    for s in train {
        all.extend(s.pressure.abs()?.flatten_all()?.to_vec1::<f32>()?);
    }
    all.sort_by(f32::total_cmp);
    let q = all.get(((all.len() as f64 - 1.0) * 0.999).round() as usize).copied().unwrap_or(0.0);
    if !(q > 0.0 && q.is_finite()) {
        return Err(Error::config("data", format!("the training pressures have no scale ({q}); simulate more frames")));
    }
    Ok(q)
}

/// Where a phase writes, and the loop settings for it.
pub(crate) fn loop_config(steps: u64, dir: Option<&Path>, config: &serde_json::Value) -> Result<LoopConfig> {
    Ok(pbdl_core::train::guarded_loop_config(steps, dir, config)?)
}

/// One training phase on pbdl-core's [`TrainLoop`]: Adam on `t`'s schedule; with a run
/// directory, checkpoints whose sidecar carries `config` (what [`pbdl_core::train::check_resume`]
/// compares on a resumed call) and `seed`.
pub(crate) fn run_phase(
    varmap: &VarMap,
    t: &PhaseSettings,
    seed: u64,
    config: &serde_json::Value,
    run_dir: Option<&Path>,
    loss: impl FnMut(u64) -> Result<Tensor>,
) -> Result<()> {
    let lc = loop_config(t.steps, run_dir, config)?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr: t.lr, ..Default::default() });
    let meta = |step| CheckpointMeta { step, seed: Some(seed), config: config.clone() };
    TrainLoop::resume(varmap, lc)?.run::<Error>(&adam, |s| t.lr_at(s), meta, loss)?;
    Ok(())
}

/// `t` as the canonical JSON value a checkpoint's sidecar stores.
pub(crate) fn json<T: Serialize>(t: &T) -> Result<serde_json::Value> {
    let v = serde_json::to_value(t).map_err(|e| Error::config("settings", format!("do not serialise: {e}")))?;
    Ok(pbdl_core::train::canonical(v)?)
}

/// Trains the autoencoder on the training pressures (frames after the first, which is at rest).
pub fn train_autoencoder(
    data: &Dataset,
    cfg: &LatentTrainConfig,
    run_dir: Option<&Path>,
) -> Result<(LatentAutoencoder, VarMap, f32)> {
    let t = &cfg.autoencoder_training;
    t.validate("autoencoder_training")?;
    if !(cfg.gradient_loss_weight >= 0.0 && cfg.gradient_loss_weight.is_finite()) {
        return Err(Error::config(
            "gradient_loss_weight",
            format!("{}; use a finite value >= 0", cfg.gradient_loss_weight),
        ));
    }
    if cfg.autoencoder.resolution != data.config.resolution {
        return Err(Error::config(
            "autoencoder.resolution",
            format!("{} but the data is {0}^2; use {1}", cfg.autoencoder.resolution, data.config.resolution),
        ));
    }
    let scale = pressure_scale(&data.train)?;
    let frames: Vec<Tensor> =
        data.train.iter().map(|s| s.pressure.narrow(0, 1, s.frames() - 1)).collect::<candle_core::Result<_>>()?;
    let frames = (Tensor::cat(&frames, 0)? / scale as f64)?;
    let count = frames.dims()[0];
    let varmap = VarMap::new();
    let ae = LatentAutoencoder::new(cfg.autoencoder.clone(), &varmap, cfg.seed)?;
    let mut settings = serde_json::json!({
        "phase": "autoencoder", "data": data.config, "autoencoder": cfg.autoencoder, "training": t, "seed": cfg.seed,
    });
    if cfg.gradient_loss_weight != 0.0 {
        settings["gradient_loss_weight"] = cfg.gradient_loss_weight.into();
    }
    let config = json(&settings)?;
    run_phase(&varmap, t, cfg.seed, &config, run_dir, |step| {
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed, step));
        let idx: Vec<u32> = (0..t.batch).map(|_| rng.random_range(0..count) as u32).collect();
        let x = frames.index_select(&Tensor::new(idx, &Device::Cpu)?, 0)?;
        let e = (ae.reconstruct(&x)? - &x)?;
        let mse = e.sqr()?.mean_all()?;
        if cfg.gradient_loss_weight == 0.0 {
            return Ok(mse);
        }
        let grad_sq = |f: &Tensor| -> Result<Tensor> {
            let n = f.dims()[3];
            let dx = (f.narrow(3, 1, n - 1)? - f.narrow(3, 0, n - 1)?)?;
            let dy = (f.narrow(2, 1, n - 1)? - f.narrow(2, 0, n - 1)?)?;
            Ok((dx.sqr()?.mean_all()? + dy.sqr()?.mean_all()?)?)
        };
        // The gradient term in the MSE's units: scaled by the batch's field / gradient ratio.
        let ratio = (x.sqr()?.mean_all()?.to_scalar::<f32>()? / grad_sq(&x)?.to_scalar::<f32>()?.max(1e-12)) as f64;
        Ok((mse + (grad_sq(&e)? * (cfg.gradient_loss_weight * ratio))?)?)
    })?;
    Ok((ae, varmap, scale))
}

/// The codes `[T, code]` of a sequence's pressures, divided by the pressure scale first.
pub fn encode_sequence(ae: &LatentAutoencoder, pressure_scale: f32, seq: &Sequence) -> Result<Tensor> {
    let mut out = Vec::new();
    let t = seq.frames();
    for start in (0..t).step_by(64) {
        let x = seq.pressure.narrow(0, start, (t - start).min(64))?;
        out.push(ae.encode(&(x / pressure_scale as f64)?)?);
    }
    Ok(Tensor::cat(&out, 0)?)
}

/// The standard deviation of all training codes (the predictor's scale).
pub fn code_scale(codes: &[Tensor]) -> Result<f32> {
    let all = Tensor::cat(codes, 0)?.flatten_all()?;
    let mean = all.mean_all()?;
    let var = all.broadcast_sub(&mean)?.sqr()?.mean_all()?.to_scalar::<f32>()?;
    if !(var > 0.0 && var.is_finite()) {
        return Err(Error::config(
            "codes",
            format!("the training codes have no spread ({var}); train the autoencoder longer"),
        ));
    }
    Ok(var.sqrt())
}

/// Trains the predictor on windows of normalised codes (`[T, code]` per training scene):
/// `window` codes in, the next one out, MAE.
pub fn train_predictor(
    codes: &[Tensor],
    cfg: &LatentTrainConfig,
    data_config: &serde_json::Value,
    run_dir: Option<&Path>,
) -> Result<(LatentPredictor, VarMap)> {
    let t = &cfg.predictor_training;
    t.validate("predictor_training")?;
    let code_size = codes.first().map(|c| c.dims()[1]).unwrap_or(0);
    let pc = PredictorConfig { code_size, ..cfg.predictor.clone() };
    let w = pc.window;
    let windows: Vec<(usize, usize)> =
        codes.iter().enumerate().flat_map(|(s, c)| (w..c.dims()[0]).map(move |t| (s, t))).collect();
    if windows.is_empty() {
        return Err(Error::config("predictor.window", format!("{w} leaves no training window; simulate more frames")));
    }
    let varmap = VarMap::new();
    let predictor = LatentPredictor::new(pc.clone(), &varmap, cfg.seed)?;
    let mut settings = serde_json::json!({
        "phase": "predictor", "data": data_config, "autoencoder": cfg.autoencoder, "predictor": pc,
        "autoencoder_training": cfg.autoencoder_training, "training": t, "seed": cfg.seed,
    });
    // The codes depend on how the autoencoder was trained.
    if cfg.gradient_loss_weight != 0.0 {
        settings["gradient_loss_weight"] = cfg.gradient_loss_weight.into();
    }
    let config = json(&settings)?;
    run_phase(&varmap, t, cfg.seed, &config, run_dir, |step| {
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed ^ 0x5eed, step));
        let (mut xs, mut ys) = (Vec::with_capacity(t.batch), Vec::with_capacity(t.batch));
        for _ in 0..t.batch {
            let (s, k) = windows[rng.random_range(0..windows.len())];
            xs.push(codes[s].narrow(0, k - w, w)?);
            ys.push(codes[s].narrow(0, k, 1)?.squeeze(0)?);
        }
        let (x, y) = (Tensor::stack(&xs, 0)?, Tensor::stack(&ys, 0)?);
        Ok((predictor.forward(&x)? - y)?.abs()?.mean_all()?)
    })?;
    Ok((predictor, varmap))
}

/// Both phases: the autoencoder (in `run_dir/autoencoder`), then the predictor on its codes
/// (in `run_dir/predictor`); the model is saved to `run_dir/model` when a directory is given.
pub fn train(data: &Dataset, cfg: &LatentTrainConfig, run_dir: Option<&Path>) -> Result<LatentModel> {
    let (autoencoder, autoencoder_vars, pressure) =
        train_autoencoder(data, cfg, run_dir.map(|d| d.join("autoencoder")).as_deref())?;
    let raw: Vec<Tensor> =
        data.train.iter().map(|s| encode_sequence(&autoencoder, pressure, s)).collect::<Result<_>>()?;
    let code = code_scale(&raw)?;
    let codes: Vec<Tensor> = raw.iter().map(|c| c / code as f64).collect::<candle_core::Result<_>>()?;
    let data_config = json(&data.config)?;
    let (predictor, predictor_vars) =
        train_predictor(&codes, cfg, &data_config, run_dir.map(|d| d.join("predictor")).as_deref())?;
    let model =
        LatentModel { autoencoder, autoencoder_vars, predictor, predictor_vars, scales: Scales { pressure, code } };
    if let Some(d) = run_dir {
        model.save(&d.join("model"))?;
    }
    Ok(model)
}
