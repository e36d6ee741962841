//! Latent space subdivision (Wiewel, Kim, Solenthaler & Thuerey, CGF 2020) at CPU scale: one
//! autoencoder of velocity and density whose 16-entry code is split into a velocity part
//! (`z[0..10]`), a density part (`z[10..15]`) and one supervised scene parameter (`z[15]`, the
//! inflow disc's `x` position, [`Sequence::param`]), a recurrent predictor over the codes, and a
//! rollout that re-encodes the density advected with the predicted velocity.
//!
//! * [`LssAutoencoder`]: `(u, v, density)`, each divided by a per-channel scale of the training
//!   data ([`LssNormalization`]), through pbdl-nets' strided-conv
//!   [`ConvEncoder`] to a small map, flattened and
//!   mapped by a [`Linear`] layer to the code; the decoder mirrors it (a [`Linear`] back to the
//!   map, then [`ConvDecoder`]).
//! * Autoencoder training ([`train_lss_autoencoder`]): MAE of the velocity and of its spatial
//!   derivatives (the paper's "Jacobian" loss, forward differences in `x` and `y`), MSE of the
//!   density, the split loss (encode `(velocity, 0)` and `(0, density)` separately:
//!   `MAE(z_vel[density part]) + MAE(z_den[velocity part])`) and the MSE of `z[15]` against the
//!   parameter mapped to `[-1, 1]` over [`PlumeData::source_x`](crate::data::PlumeData).
//! * Predictor training ([`train_lss_predictor`]): the crate's [`LatentPredictor`] with a window
//!   of 2 codes, trained end to end through the (frozen) decoder on windows of `window +
//!   rollout` frames: `window` encoded codes in, one code out, fed back `rollout` times, with
//!   backpropagation through the whole rollout. Losses: MAE of the predicted code (without the
//!   parameter slot) against the encoded frame, and the autoencoder's losses of the decoded
//!   prediction against the true frame. The fed-back code gets the true parameter and (with
//!   [`LssConfig::teacher_density`]) the encoded true density part, as inference overwrites both.
//! * Inference ([`lss_rollout`]): from encoded frames, predict the next code, advect the density
//!   with the decoded velocity by the scene's own solver (pbdl-grid's MacCormack transport and
//!   the inflow disc, via [`Fluid::step_unprojected`](pbdl_grid::Fluid::step_unprojected)),
//!   re-encode `(0, density)` into the density part and put the true parameter into `z[15]`.
//! * Scores: [`swap_score`] (density part of scene A replaced by scene B's), [`param_score`],
//!   [`reconstruction_score`], [`split_leak`] and the rollout errors.
//!
//! Deviations from the paper, for CPU scale: a square `n x n` box instead of 32x64, the
//! autoencoder trained first and then frozen while the predictor trains (the paper fine-tunes
//! both end to end), a training rollout of [`LssConfig::rollout`] = 6 steps by default (the
//! paper: 14-frame windows, 2 in and 12 rolled out), the crate's encoder/decoder LSTM instead
//! of the paper's stack, Adam with the learning rate halved at 50% and 75% of the updates, and a
//! fixed number of updates of random frames or windows instead of epochs.
//!
//! ```no_run
//! use pbdl_latent::data::{generate, PlumeData};
//! use pbdl_latent::lss::{lss_rollout, param_score, swap_score, train_lss, LssConfig};
//!
//! let data = generate(&PlumeData { frames: 80, ..PlumeData::default() })?;
//! let model = train_lss(&data, &LssConfig::default(), None)?;
//! println!("{:?}", swap_score(&model.autoencoder, &data.test)?);
//! println!("{:?}", param_score(&model.autoencoder, &data.test)?);
//! let seq = &data.test[0];
//! let r = lss_rollout(&model, &data.config.scene(seq.param), seq, 20, 40)?;
//! println!("density error after 40 steps {:.3}", r.density_error_final);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::data::{Dataset, PlumeScene, Sequence};
use crate::predictor::{LatentPredictor, PredictorConfig};
use crate::train::{json, run_phase, PhaseSettings};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::nn::Activation;
use pbdl_grid::{CenteredField, FluidState, MacField};
use pbdl_nets::encoder_decoder::{ConvDecoder, ConvEncoder, EncoderDecoderConfig, Upsampling};
use pbdl_nets::{Linear, Padding};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Weights of the loss terms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LssLossWeights {
    /// MAE of the (scaled) velocity. Default 1.
    pub velocity: f64,
    /// MAE of the velocity's forward differences in `x` and `y` (the "Jacobian" loss).
    /// Default 1.
    pub jacobian: f64,
    /// MSE of the (scaled) density. Default 1.
    pub density: f64,
    /// The split loss `MAE(z_vel[density part]) + MAE(z_den[velocity part])`. Default 1.
    pub split: f64,
    /// MSE of `z[15]` against the parameter mapped to `[-1, 1]`. Default 1.
    pub param: f64,
    /// Predictor: MAE of the predicted code (parameter slot excluded). Default 1.
    pub latent: f64,
    /// Predictor: factor on the velocity / Jacobian / density losses of the decoded
    /// predictions. Default 1.
    pub prediction: f64,
}

impl Default for LssLossWeights {
    fn default() -> Self {
        Self { velocity: 1.0, jacobian: 1.0, density: 1.0, split: 1.0, param: 1.0, latent: 1.0, prediction: 1.0 }
    }
}

/// Everything [`train_lss`] needs besides the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LssConfig {
    /// Cells per side (the data's resolution; a multiple of `2^widths.len()`). Default 32.
    pub resolution: usize,
    /// Widths of the stride-2 conv levels. Default `[16, 32, 64]` (32^2 -> 4^2).
    pub widths: Vec<usize>,
    /// Channels of the conv latent map (flattened, then mapped to the code). Default 8.
    pub latent_channels: usize,
    /// Entries of the code: `velocity_part + density_part + 1`. Default 16 (the paper's).
    pub code_size: usize,
    /// Entries of the velocity part `z[0..velocity_part]`. Default 10 (`int(16 * 0.66)`).
    pub velocity_part: usize,
    /// Entries of the density part (after the velocity part); the last entry of the code is
    /// the parameter. Default 5.
    pub density_part: usize,
    /// Units of the predictor's encoder LSTM. Default 64.
    pub encoder_units: usize,
    /// Units of the predictor's decoder LSTM. Default 64.
    pub decoder_units: usize,
    /// Codes the predictor reads. Default 2 (the paper's).
    pub window: usize,
    /// Predicted steps per training window (backpropagated through). Default 6, a CPU-size
    /// choice (the paper rolls out 12).
    pub rollout: usize,
    /// In the training rollout, feed back the encoded true density part instead of the
    /// predicted one (as inference overwrites it with the re-encoded advected density).
    /// Default `true`.
    pub teacher_density: bool,
    /// Loss weights.
    pub weights: LssLossWeights,
    /// Autoencoder training. Default 2000 updates of 16 frames at lr 1e-3.
    pub autoencoder_training: PhaseSettings,
    /// Predictor training. Default 1000 updates of 8 windows at lr 1e-3.
    pub predictor_training: PhaseSettings,
    /// Seed of the initialisations and of the sampled frames and windows.
    pub seed: u64,
}

impl Default for LssConfig {
    fn default() -> Self {
        Self {
            resolution: 32,
            widths: vec![16, 32, 64],
            latent_channels: 8,
            code_size: 16,
            velocity_part: 10,
            density_part: 5,
            encoder_units: 64,
            decoder_units: 64,
            window: 2,
            rollout: 6,
            teacher_density: true,
            weights: LssLossWeights::default(),
            autoencoder_training: PhaseSettings::default(),
            predictor_training: PhaseSettings { steps: 1000, batch: 8, lr: 1e-3 },
            seed: 0,
        }
    }
}

impl LssConfig {
    /// Checks every field (typed [`Error::Config`] naming it).
    pub fn validate(&self) -> Result<()> {
        let m = 1usize.checked_shl(self.widths.len() as u32).unwrap_or(0);
        if self.widths.is_empty()
            || self.widths.contains(&0)
            || m == 0
            || self.resolution == 0
            || self.resolution % m != 0
        {
            return Err(Error::config(
                "resolution / widths",
                format!(
                    "{} with widths {:?}; use positive widths and a side that is a positive multiple of 2^levels",
                    self.resolution, self.widths
                ),
            ));
        }
        if self.latent_channels == 0 {
            return Err(Error::config("latent_channels", "0; use at least 1"));
        }
        if self.velocity_part == 0
            || self.density_part == 0
            || self.code_size != self.velocity_part + self.density_part + 1
        {
            return Err(Error::config(
                "code_size / velocity_part / density_part",
                format!(
                    "{} / {} / {}; both parts must be positive and code_size = velocity_part + density_part + 1 (the parameter)",
                    self.code_size, self.velocity_part, self.density_part
                ),
            ));
        }
        if self.encoder_units == 0 || self.decoder_units == 0 {
            return Err(Error::config("encoder_units / decoder_units", "use positive sizes"));
        }
        if self.window == 0 || self.rollout == 0 {
            return Err(Error::config(
                "window / rollout",
                format!("{} / {}; use at least 1", self.window, self.rollout),
            ));
        }
        let w = &self.weights;
        let all = [w.velocity, w.jacobian, w.density, w.split, w.param, w.latent, w.prediction];
        if all.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err(Error::config("weights", format!("{w:?}; every weight must be finite and >= 0")));
        }
        self.autoencoder_training.validate("autoencoder_training")?;
        self.predictor_training.validate("predictor_training")?;
        Ok(())
    }

    /// Side of the conv latent map.
    pub fn latent_side(&self) -> usize {
        self.resolution >> self.widths.len()
    }

    fn nets_config(&self) -> EncoderDecoderConfig {
        EncoderDecoderConfig {
            in_channels: 3,
            out_channels: 3,
            widths: self.widths.clone(),
            latent_channels: self.latent_channels,
            activation: Activation::LeakyRelu { negative_slope: 0.2 },
            norm_groups: None,
            upsampling: Upsampling::Transposed,
            padding: Padding::Zeros,
        }
    }

    /// Index of the parameter slot (the code's last entry).
    pub fn param_slot(&self) -> usize {
        self.code_size - 1
    }
}

/// The scales between solver values and network values, and the parameter range.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LssNormalization {
    /// The network sees `u / velocity[0]` and `v / velocity[1]`: the 99.9th percentiles of
    /// `|u|` and `|v|` over the training frames.
    pub velocity: [f32; 2],
    /// The network sees `density / density`: the 99.9th percentile of the training densities.
    pub density: f32,
    /// The parameter range mapped to `z[15]` in `[-1, 1]` (the data's `source_x`).
    pub param_range: [f64; 2],
}

impl LssNormalization {
    /// The per-channel scales of the training frames and the data's parameter range.
    pub fn from_data(data: &Dataset) -> Result<Self> {
        let q = |channel: &dyn Fn(&Sequence) -> candle_core::Result<Tensor>, name: &'static str| -> Result<f32> {
            let mut all = Vec::new();
            for s in &data.train {
                all.extend(channel(s)?.abs()?.flatten_all()?.to_vec1::<f32>()?);
            }
            all.sort_by(f32::total_cmp);
            let v = all.get(((all.len() as f64 - 1.0) * 0.999).round() as usize).copied().unwrap_or(0.0);
            if !(v > 0.0 && v.is_finite()) {
                return Err(Error::config(
                    "data",
                    format!("the training {name} has no scale ({v}); simulate more frames"),
                ));
            }
            Ok(v)
        };
        Ok(Self {
            velocity: [q(&|s| s.velocity.narrow(1, 0, 1), "u")?, q(&|s| s.velocity.narrow(1, 1, 1), "v")?],
            density: q(&|s| Ok(s.density.clone()), "density")?,
            param_range: data.config.source_x,
        })
    }

    fn span(&self) -> f64 {
        let s = self.param_range[1] - self.param_range[0];
        if s > 0.0 {
            s
        } else {
            1.0
        }
    }

    /// The parameter as `z[15]` holds it: `2 (p - lo) / (hi - lo) - 1` (a zero range maps to
    /// `-1`).
    pub fn param_to_code(&self, p: f64) -> f64 {
        2.0 * (p - self.param_range[0]) / self.span() - 1.0
    }

    /// Inverse of [`LssNormalization::param_to_code`].
    pub fn code_to_param(&self, z: f64) -> f64 {
        self.param_range[0] + (z + 1.0) * 0.5 * self.span()
    }
}

/// The split autoencoder (see the module docs). Its input and output are in solver units; the
/// `*_normalized` methods take and give the scaled 3-channel frames.
#[derive(Clone, Debug)]
pub struct LssAutoencoder {
    encoder: ConvEncoder,
    decoder: ConvDecoder,
    to_code: Linear,
    from_code: Linear,
    config: LssConfig,
    norm: LssNormalization,
}

impl LssAutoencoder {
    /// Builds the network with its variables in `varmap` (f32), initialised from `seed`.
    pub fn new(config: &LssConfig, norm: LssNormalization, varmap: &VarMap, seed: u64) -> Result<Self> {
        config.validate()?;
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let s = config.latent_side();
        let flat = config.latent_channels * s * s;
        let encoder = ConvEncoder::new(config.nets_config(), vb.pp("encoder"))?;
        let decoder = ConvDecoder::new(config.nets_config(), vb.pp("decoder"))?;
        let to_code = Linear::new(flat, config.code_size, vb.pp("to_code"))?;
        let from_code = Linear::new(config.code_size, flat, vb.pp("from_code"))?;
        pbdl_nets::seeded_init(varmap, seed)?;
        Ok(Self { encoder, decoder, to_code, from_code, config: config.clone(), norm })
    }

    /// The layout.
    pub fn config(&self) -> &LssConfig {
        &self.config
    }

    /// The scales and the parameter range.
    pub fn normalization(&self) -> &LssNormalization {
        &self.norm
    }

    fn check_field(&self, what: &'static str, t: &Tensor, channels: usize) -> Result<usize> {
        let n = self.config.resolution;
        let d = t.dims();
        if d.len() != 4 || d[1] != channels || d[2] != n || d[3] != n {
            return Err(Error::Shape { what, expected: format!("[batch, {channels}, {n}, {n}]"), got: d.to_vec() });
        }
        Ok(d[0])
    }

    /// The scaled 3-channel frames `[B, 3, n, n]` of a MAC velocity `[B, 2, n, n]` and a density
    /// `[B, 1, n, n]` in solver units.
    pub fn normalize(&self, velocity: &Tensor, density: &Tensor) -> Result<Tensor> {
        let b = self.check_field("velocity", velocity, 2)?;
        if self.check_field("density", density, 1)? != b {
            return Err(Error::Shape {
                what: "density (batch of the velocity)",
                expected: format!("[{b}, 1, n, n]"),
                got: density.dims().to_vec(),
            });
        }
        let s = &self.norm;
        let u = (velocity.narrow(1, 0, 1)? / s.velocity[0] as f64)?;
        let v = (velocity.narrow(1, 1, 1)? / s.velocity[1] as f64)?;
        let r = (density / s.density as f64)?;
        Ok(Tensor::cat(&[u, v, r], 1)?.to_dtype(DType::F32)?)
    }

    /// Velocity `[B, 2, n, n]` and density `[B, 1, n, n]` in solver units of scaled frames.
    pub fn denormalize(&self, x: &Tensor) -> Result<(Tensor, Tensor)> {
        self.check_field("scaled frames", x, 3)?;
        let s = &self.norm;
        let u = (x.narrow(1, 0, 1)? * s.velocity[0] as f64)?;
        let v = (x.narrow(1, 1, 1)? * s.velocity[1] as f64)?;
        Ok((Tensor::cat(&[u, v], 1)?, (x.narrow(1, 2, 1)? * s.density as f64)?))
    }

    /// Scaled frames `[B, 3, n, n]` -> codes `[B, code_size]`.
    pub fn encode_normalized(&self, x: &Tensor) -> Result<Tensor> {
        self.check_field("scaled frames", x, 3)?;
        let h = self.encoder.forward(x)?.flatten_from(1)?;
        self.to_code.forward(&h).map_err(Error::from)
    }

    /// Codes `[B, code_size]` -> scaled frames `[B, 3, n, n]`.
    pub fn decode_normalized(&self, z: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = z.dims();
        if d.len() != 2 || d[1] != c.code_size {
            return Err(Error::Shape {
                what: "lss code",
                expected: format!("[batch, {}]", c.code_size),
                got: d.to_vec(),
            });
        }
        let s = c.latent_side();
        let h = self.from_code.forward(z)?.reshape((d[0], c.latent_channels, s, s))?;
        Ok(self.decoder.forward(&h)?)
    }

    /// Codes `[B, code_size]` of a velocity `[B, 2, n, n]` and density `[B, 1, n, n]` in solver
    /// units.
    pub fn encode(&self, velocity: &Tensor, density: &Tensor) -> Result<Tensor> {
        self.encode_normalized(&self.normalize(velocity, density)?)
    }

    /// Velocity `[B, 2, n, n]` and density `[B, 1, n, n]` in solver units of codes.
    pub fn decode(&self, z: &Tensor) -> Result<(Tensor, Tensor)> {
        self.denormalize(&self.decode_normalized(z)?)
    }

    /// The codes `[T, code]` of all frames of a sequence (in chunks of 64 frames).
    pub fn encode_sequence(&self, seq: &Sequence) -> Result<Tensor> {
        let t = seq.velocity.dims().first().copied().unwrap_or(0);
        let mut out = Vec::new();
        for start in (0..t).step_by(64) {
            let len = (t - start).min(64);
            out.push(self.encode(&seq.velocity.narrow(0, start, len)?, &seq.density.narrow(0, start, len)?)?);
        }
        if out.is_empty() {
            return Err(Error::config("sequence", "has no frames"));
        }
        Ok(Tensor::cat(&out, 0)?)
    }

    /// The velocity part of codes `[B, code]`.
    pub fn velocity_part(&self, z: &Tensor) -> Result<Tensor> {
        Ok(z.narrow(1, 0, self.config.velocity_part)?)
    }

    /// The density part of codes `[B, code]`.
    pub fn density_part(&self, z: &Tensor) -> Result<Tensor> {
        Ok(z.narrow(1, self.config.velocity_part, self.config.density_part)?)
    }
}

/// The autoencoder's loss terms of scaled frames `x` and their reconstruction `y`:
/// velocity MAE, Jacobian MAE, density MSE (each a scalar tensor).
fn field_losses(y: &Tensor, x: &Tensor) -> Result<(Tensor, Tensor, Tensor)> {
    let e = (y - x)?;
    let ev = e.narrow(1, 0, 2)?;
    let n = ev.dims()[3];
    let dx = (ev.narrow(3, 1, n - 1)? - ev.narrow(3, 0, n - 1)?)?;
    let dy = (ev.narrow(2, 1, n - 1)? - ev.narrow(2, 0, n - 1)?)?;
    let jac = (dx.abs()?.mean_all()? + dy.abs()?.mean_all()?)?;
    Ok((ev.abs()?.mean_all()?, jac, e.narrow(1, 2, 1)?.sqr()?.mean_all()?))
}

fn check_data(data: &Dataset, cfg: &LssConfig) -> Result<()> {
    cfg.validate()?;
    if cfg.resolution != data.config.resolution {
        return Err(Error::config(
            "resolution",
            format!("{} but the data is {1}^2; use {1}", cfg.resolution, data.config.resolution),
        ));
    }
    Ok(())
}

/// Scaled frames of every training scene (all frames, `[T, 3, n, n]` each).
fn scaled_scenes(ae: &LssAutoencoder, seqs: &[Sequence]) -> Result<Vec<Tensor>> {
    seqs.iter().map(|s| ae.normalize(&s.velocity, &s.density)).collect()
}

/// Trains the autoencoder (reconstruction, split and parameter losses; see the module docs) on
/// random training frames after the first (at rest). With `run_dir`: `loss.csv`, checkpoints,
/// resume, and a typed refusal of a directory holding a run of other settings.
pub fn train_lss_autoencoder(
    data: &Dataset,
    cfg: &LssConfig,
    run_dir: Option<&Path>,
) -> Result<(LssAutoencoder, VarMap)> {
    check_data(data, cfg)?;
    let t = &cfg.autoencoder_training;
    let norm = LssNormalization::from_data(data)?;
    let varmap = VarMap::new();
    let ae = LssAutoencoder::new(cfg, norm, &varmap, cfg.seed)?;
    let scenes = scaled_scenes(&ae, &data.train)?;
    let frames: Vec<(usize, usize)> =
        scenes.iter().enumerate().flat_map(|(s, x)| (1..x.dims()[0]).map(move |k| (s, k))).collect();
    if frames.is_empty() {
        return Err(Error::config("frames", "the training scenes have no frame after the first; simulate more"));
    }
    let params: Vec<f32> = data.train.iter().map(|s| norm.param_to_code(s.param) as f32).collect();
    let config = json(&serde_json::json!({ "phase": "lss_autoencoder", "data": data.config, "lss": cfg }))?;
    let (vp, dp, ps) = (cfg.velocity_part, cfg.density_part, cfg.param_slot());
    let w = &cfg.weights;
    run_phase(&varmap, t, cfg.seed, &config, run_dir, |step| {
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed, step));
        let (mut xs, mut ps_true) = (Vec::with_capacity(t.batch), Vec::with_capacity(t.batch));
        for _ in 0..t.batch {
            let (s, k) = frames[rng.random_range(0..frames.len())];
            xs.push(scenes[s].narrow(0, k, 1)?);
            ps_true.push(params[s]);
        }
        let x = Tensor::cat(&xs, 0)?;
        let b = x.dims()[0];
        let vel = x.narrow(1, 0, 2)?;
        let den = x.narrow(1, 2, 1)?;
        let x_v = Tensor::cat(&[vel.clone(), den.zeros_like()?], 1)?;
        let x_d = Tensor::cat(&[vel.zeros_like()?, den], 1)?;
        let z_all = ae.encode_normalized(&Tensor::cat(&[x.clone(), x_v, x_d], 0)?)?;
        let z = z_all.narrow(0, 0, b)?;
        let (z_v, z_d) = (z_all.narrow(0, b, b)?, z_all.narrow(0, 2 * b, b)?);
        let y = ae.decode_normalized(&z)?;
        let (l_vel, l_jac, l_den) = field_losses(&y, &x)?;
        let split = (z_v.narrow(1, vp, dp)?.abs()?.mean_all()? + z_d.narrow(1, 0, vp)?.abs()?.mean_all()?)?;
        let p_true = Tensor::new(ps_true, &Device::Cpu)?.reshape((b, 1))?;
        let l_par = (z.narrow(1, ps, 1)? - p_true)?.sqr()?.mean_all()?;
        let loss = ((l_vel * w.velocity)? + (l_jac * w.jacobian)? + (l_den * w.density)?)?;
        Ok(((loss + (split * w.split)?)? + (l_par * w.param)?)?)
    })?;
    Ok((ae, varmap))
}

/// The predictor's layout for `cfg`.
pub fn predictor_config(cfg: &LssConfig) -> PredictorConfig {
    PredictorConfig {
        code_size: cfg.code_size,
        window: cfg.window,
        encoder_units: cfg.encoder_units,
        decoder_units: cfg.decoder_units,
        residual: false,
    }
}

/// `z` with its parameter slot replaced by `p` (`[B, 1]`).
fn with_param(z: &Tensor, p: &Tensor, slot: usize) -> Result<Tensor> {
    Ok(Tensor::cat(&[z.narrow(1, 0, slot)?, p.clone()], 1)?)
}

/// `z` with its density part replaced by that of `other`.
fn with_density_part(z: &Tensor, other: &Tensor, cfg: &LssConfig) -> Result<Tensor> {
    let (vp, dp) = (cfg.velocity_part, cfg.density_part);
    let rest = cfg.code_size - vp - dp;
    Ok(Tensor::cat(&[z.narrow(1, 0, vp)?, other.narrow(1, vp, dp)?, z.narrow(1, vp + dp, rest)?], 1)?)
}

/// Trains the predictor end to end through the frozen autoencoder `ae` (see the module docs)
/// on windows of `window + rollout` frames of the training scenes. Run directory as
/// [`train_lss_autoencoder`].
pub fn train_lss_predictor(
    ae: &LssAutoencoder,
    data: &Dataset,
    cfg: &LssConfig,
    run_dir: Option<&Path>,
) -> Result<(LatentPredictor, VarMap)> {
    check_data(data, cfg)?;
    // The autoencoder's layout must be the config's (the training settings may differ).
    let a = ae.config();
    if (a.resolution, &a.widths, a.latent_channels, a.code_size, a.velocity_part)
        != (cfg.resolution, &cfg.widths, cfg.latent_channels, cfg.code_size, cfg.velocity_part)
    {
        return Err(Error::config(
            "autoencoder",
            "was built with another layout than the config; train it with this config",
        ));
    }
    let t = &cfg.predictor_training;
    let (w, r, slot) = (cfg.window, cfg.rollout, cfg.param_slot());
    let norm = *ae.normalization();
    let scenes = scaled_scenes(ae, &data.train)?;
    let mut codes = Vec::with_capacity(scenes.len());
    for (x, s) in scenes.iter().zip(&data.train) {
        let mut out = Vec::new();
        let n = x.dims()[0];
        for start in (0..n).step_by(64) {
            out.push(ae.encode_normalized(&x.narrow(0, start, (n - start).min(64))?)?.detach());
        }
        let z = Tensor::cat(&out, 0)?;
        let p = Tensor::full(norm.param_to_code(s.param) as f32, (n, 1), &Device::Cpu)?;
        codes.push(with_param(&z, &p, slot)?);
    }
    let windows: Vec<(usize, usize)> = codes
        .iter()
        .enumerate()
        .flat_map(|(s, c)| (0..(c.dims()[0] + 1).saturating_sub(w + r)).map(move |k| (s, k)))
        .collect();
    if windows.is_empty() {
        return Err(Error::config(
            "window / rollout",
            format!("{w} + {r} frames leave no training window; simulate more frames or shorten the rollout"),
        ));
    }
    let varmap = VarMap::new();
    let predictor = LatentPredictor::new(predictor_config(cfg), &varmap, cfg.seed)?;
    let config = json(&serde_json::json!({ "phase": "lss_predictor", "data": data.config, "lss": cfg }))?;
    let wt = &cfg.weights;
    let n = cfg.resolution;
    run_phase(&varmap, t, cfg.seed, &config, run_dir, |step| {
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed ^ 0x155, step));
        let (mut hs, mut ts, mut xs) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..t.batch {
            let (s, k) = windows[rng.random_range(0..windows.len())];
            hs.push(codes[s].narrow(0, k, w)?);
            ts.push(codes[s].narrow(0, k + w, r)?);
            xs.push(scenes[s].narrow(0, k + w, r)?);
        }
        let mut hist = Tensor::stack(&hs, 0)?; // [B, w, code]
        let target = Tensor::stack(&ts, 0)?; // [B, r, code]
        let b = hist.dims()[0];
        let mut preds = Vec::with_capacity(r);
        for step in 0..r {
            let tgt = target.narrow(1, step, 1)?.squeeze(1)?;
            let p = with_param(&predictor.forward(&hist)?, &tgt.narrow(1, slot, 1)?, slot)?;
            let fed = if cfg.teacher_density { with_density_part(&p, &tgt, cfg)? } else { p.clone() };
            preds.push(p);
            hist = if w > 1 {
                Tensor::cat(&[hist.narrow(1, 1, w - 1)?, fed.unsqueeze(1)?], 1)?
            } else {
                fed.unsqueeze(1)?
            };
        }
        let pred = Tensor::stack(&preds, 1)?; // [B, r, code]
        let latent = (pred.narrow(2, 0, slot)? - target.narrow(2, 0, slot)?)?.abs()?.mean_all()?;
        let y = ae.decode_normalized(&pred.reshape((b * r, cfg.code_size))?)?;
        let x = Tensor::stack(&xs, 0)?.reshape((b * r, 3, n, n))?;
        let (l_vel, l_jac, l_den) = field_losses(&y, &x)?;
        let fields = ((l_vel * wt.velocity)? + (l_jac * wt.jacobian)? + (l_den * wt.density)?)?;
        Ok(((latent * wt.latent)? + (fields * wt.prediction)?)?)
    })?;
    Ok((predictor, varmap))
}

/// A trained latent-space-subdivision model.
#[derive(Clone)]
pub struct LssModel {
    /// The split autoencoder (with its scales).
    pub autoencoder: LssAutoencoder,
    /// Its variables.
    pub autoencoder_vars: VarMap,
    /// The predictor over codes.
    pub predictor: LatentPredictor,
    /// Its variables.
    pub predictor_vars: VarMap,
}

impl std::fmt::Debug for LssModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LssModel")
            .field("autoencoder", &self.autoencoder)
            .field("predictor", &self.predictor)
            .finish_non_exhaustive()
    }
}

/// Both phases: the autoencoder (in `run_dir/autoencoder`), then the predictor through it (in
/// `run_dir/predictor`).
pub fn train_lss(data: &Dataset, cfg: &LssConfig, run_dir: Option<&Path>) -> Result<LssModel> {
    let (autoencoder, autoencoder_vars) =
        train_lss_autoencoder(data, cfg, run_dir.map(|d| d.join("autoencoder")).as_deref())?;
    let (predictor, predictor_vars) =
        train_lss_predictor(&autoencoder, data, cfg, run_dir.map(|d| d.join("predictor")).as_deref())?;
    Ok(LssModel { autoencoder, autoencoder_vars, predictor, predictor_vars })
}

fn sum_sq(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()?)
}

fn ratio(num: f64, den: f64) -> f64 {
    (num / den.max(f64::MIN_POSITIVE)).sqrt()
}

/// The frames after the first (at rest) of a sequence, checked against the autoencoder.
fn scored_frames(ae: &LssAutoencoder, s: &Sequence) -> Result<(Tensor, Tensor)> {
    let t = s.velocity.dims().first().copied().unwrap_or(0);
    if t < 2 {
        return Err(Error::config(
            "frames",
            format!("{t} frames; scores use the frames after the first, simulate at least 2"),
        ));
    }
    let (v, d) = (s.velocity.narrow(0, 1, t - 1)?, s.density.narrow(0, 1, t - 1)?);
    ae.normalize(&v, &d)?;
    Ok((v, d))
}

/// Encodes in chunks of 64 frames.
fn encode_chunks(ae: &LssAutoencoder, v: &Tensor, d: &Tensor) -> Result<Tensor> {
    let t = v.dims()[0];
    let mut out = Vec::new();
    for start in (0..t).step_by(64) {
        let len = (t - start).min(64);
        out.push(ae.encode(&v.narrow(0, start, len)?, &d.narrow(0, start, len)?)?);
    }
    Ok(Tensor::cat(&out, 0)?)
}

/// Decodes in chunks of 64 codes.
fn decode_chunks(ae: &LssAutoencoder, z: &Tensor) -> Result<(Tensor, Tensor)> {
    let t = z.dims()[0];
    let (mut vs, mut ds) = (Vec::new(), Vec::new());
    for start in (0..t).step_by(64) {
        let (v, d) = ae.decode(&z.narrow(0, start, (t - start).min(64))?)?;
        vs.push(v);
        ds.push(d);
    }
    Ok((Tensor::cat(&vs, 0)?, Tensor::cat(&ds, 0)?))
}

/// Relative L2 reconstruction errors on held-out frames.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReconstructionScore {
    /// `||AE(u) - u|| / ||u||` over all frames but the first of every sequence.
    pub velocity: f64,
    /// The same for the density.
    pub density: f64,
}

/// [`ReconstructionScore`] of `ae` on `seqs`.
pub fn reconstruction_score(ae: &LssAutoencoder, seqs: &[Sequence]) -> Result<ReconstructionScore> {
    let (mut ev, mut nv, mut ed, mut nd) = (0.0, 0.0, 0.0, 0.0);
    for s in seqs {
        let (v, d) = scored_frames(ae, s)?;
        let (rv, rd) = decode_chunks(ae, &encode_chunks(ae, &v, &d)?)?;
        ev += sum_sq(&(rv - &v)?)?;
        nv += sum_sq(&v)?;
        ed += sum_sq(&(rd - &d)?)?;
        nd += sum_sq(&d)?;
    }
    Ok(ReconstructionScore { velocity: ratio(ev, nv), density: ratio(ed, nd) })
}

/// The swap test: how much the decoded velocity of scene A changes when the density part of its
/// code is replaced by scene B's at the same frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SwapScore {
    /// `||u(z_A with B's density part) - u(z_A)|| / ||u(z_A)||` over all ordered pairs of
    /// distinct sequences and frames after the first (the paper's claim: small; bar 5%).
    pub velocity_change: f64,
    /// For scale: `||u(z_B) - u(z_A)|| / ||u(z_A)||`, how much the decoded velocities of the
    /// two scenes differ.
    pub scene_velocity_difference: f64,
    /// Ordered pairs of sequences.
    pub pairs: usize,
    /// Frames per pair.
    pub frames: usize,
}

/// [`SwapScore`] of `ae` on `seqs` (at least two sequences of equal length).
pub fn swap_score(ae: &LssAutoencoder, seqs: &[Sequence]) -> Result<SwapScore> {
    if seqs.len() < 2 {
        return Err(Error::config("test scenes", format!("{}; the swap test needs at least 2", seqs.len())));
    }
    let frames = seqs[0].velocity.dims().first().copied().unwrap_or(0);
    if seqs.iter().any(|s| s.velocity.dims().first().copied() != Some(frames)) {
        return Err(Error::config("test scenes", "have different frame counts; the swap test pairs frames by index"));
    }
    let mut codes = Vec::with_capacity(seqs.len());
    let mut vels = Vec::with_capacity(seqs.len());
    for s in seqs {
        let (v, d) = scored_frames(ae, s)?;
        let z = encode_chunks(ae, &v, &d)?;
        vels.push(decode_chunks(ae, &z)?.0);
        codes.push(z);
    }
    let cfg = ae.config();
    let (mut num, mut diff, mut den, mut pairs) = (0.0, 0.0, 0.0, 0);
    for a in 0..seqs.len() {
        for b in 0..seqs.len() {
            if a == b {
                continue;
            }
            let swapped = with_density_part(&codes[a], &codes[b], cfg)?;
            let (vs, _) = decode_chunks(ae, &swapped)?;
            num += sum_sq(&(vs - &vels[a])?)?;
            diff += sum_sq(&(&vels[b] - &vels[a])?)?;
            den += sum_sq(&vels[a])?;
            pairs += 1;
        }
    }
    Ok(SwapScore {
        velocity_change: ratio(num, den),
        scene_velocity_difference: ratio(diff, den),
        pairs,
        frames: frames - 1,
    })
}

/// How well `z[15]` recovers the scene parameter.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamScore {
    /// Mean `|p(z[15]) - p|` over all frames after the first, in disc positions (fractions of
    /// the width).
    pub mae: f64,
    /// `mae` as a fraction of the parameter range (bar: 10%; NaN for an empty range).
    pub range_fraction: f64,
    /// The same over the second half of the frames (the early plume carries little of it).
    pub mae_late: f64,
}

/// [`ParamScore`] of `ae` on `seqs`.
pub fn param_score(ae: &LssAutoencoder, seqs: &[Sequence]) -> Result<ParamScore> {
    let norm = ae.normalization();
    let slot = ae.config().param_slot();
    let (mut sum, mut count, mut late, mut late_count) = (0.0, 0usize, 0.0, 0usize);
    for s in seqs {
        let (v, d) = scored_frames(ae, s)?;
        let z = encode_chunks(ae, &v, &d)?.narrow(1, slot, 1)?.flatten_all()?.to_vec1::<f32>()?;
        let half = z.len() / 2;
        for (k, zk) in z.iter().enumerate() {
            let e = (norm.code_to_param(*zk as f64) - s.param).abs();
            sum += e;
            count += 1;
            if k >= half {
                late += e;
                late_count += 1;
            }
        }
    }
    let mae = sum / count.max(1) as f64;
    let range = norm.param_range[1] - norm.param_range[0];
    Ok(ParamScore {
        mae,
        range_fraction: if range > 0.0 { mae / range } else { f64::NAN },
        mae_late: late / late_count.max(1) as f64,
    })
}

/// Leakage between the code's parts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplitLeak {
    /// Mean `|z|` of the density part of `encode(velocity, 0)`.
    pub density_part_of_velocity: f64,
    /// Mean `|z|` of the velocity part of `encode(0, density)`.
    pub velocity_part_of_density: f64,
    /// For scale: mean `|z|` of the density part of `encode(velocity, density)`.
    pub density_part_of_full: f64,
}

/// [`SplitLeak`] of `ae` on all frames but the first of `seqs`.
pub fn split_leak(ae: &LssAutoencoder, seqs: &[Sequence]) -> Result<SplitLeak> {
    let (mut a, mut b, mut c, mut count) = (0.0, 0.0, 0.0, 0usize);
    for s in seqs {
        let (v, d) = scored_frames(ae, s)?;
        let zv = encode_chunks(ae, &v, &d.zeros_like()?)?;
        let zd = encode_chunks(ae, &v.zeros_like()?, &d)?;
        let z = encode_chunks(ae, &v, &d)?;
        let mean = |t: Tensor| -> Result<f64> { Ok(t.to_dtype(DType::F64)?.abs()?.mean_all()?.to_scalar::<f64>()?) };
        a += mean(ae.density_part(&zv)?)?;
        b += mean(ae.velocity_part(&zd)?)?;
        c += mean(ae.density_part(&z)?)?;
        count += 1;
    }
    let n = count.max(1) as f64;
    Ok(SplitLeak { density_part_of_velocity: a / n, velocity_part_of_density: b / n, density_part_of_full: c / n })
}

/// Errors of an [`lss_rollout`] against the reference sequence, per predicted step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LssRollout {
    /// The last encoded reference frame.
    pub start: usize,
    /// `||rho - rho_ref|| / ||rho_ref||` of the advected density after each step.
    pub density_error: Vec<f64>,
    /// The same for the decoded velocity.
    pub velocity_error: Vec<f64>,
    /// The same for the density the decoder gives from the raw predicted code (before the
    /// density part is overwritten): what the advection replaces.
    pub decoded_density_error: Vec<f64>,
    /// `density_error` after the last step.
    pub density_error_final: f64,
    /// Its mean over the steps.
    pub density_error_mean: f64,
    /// Whether every state stayed finite (a non-finite state ends the rollout early).
    pub finite: bool,
}

/// Rolls the model out `steps` steps from frame `start` of `seq` (the scene `scene`): the
/// codes of frames `start - window + 1 ..= start` are encoded from the reference, the density
/// starts at the reference density of frame `start`. Each step advects the density with the
/// velocity decoded from the current code (the scene's MacCormack transport and inflow),
/// predicts the next code, overwrites its density part with the code of `(0, density)` and its
/// parameter slot with the true parameter, and compares with the reference.
pub fn lss_rollout(
    model: &LssModel,
    scene: &PlumeScene,
    seq: &Sequence,
    start: usize,
    steps: usize,
) -> Result<LssRollout> {
    let ae = &model.autoencoder;
    let cfg = ae.config();
    let (w, slot) = (model.predictor.config().window, cfg.param_slot());
    let t = seq.velocity.dims().first().copied().unwrap_or(0);
    if start + 1 < w || start + steps >= t || steps == 0 {
        return Err(Error::config(
            "start / steps",
            format!("{start} / {steps} with window {w} and {t} frames; need window - 1 <= start and start + steps < frames, steps >= 1"),
        ));
    }
    if scene.data.resolution != cfg.resolution {
        return Err(Error::config(
            "scene.resolution",
            format!("{} but the model is {}^2", scene.data.resolution, cfg.resolution),
        ));
    }
    let fluid = scene.fluid()?;
    let rate = scene.rate()?;
    let grid = *fluid.grid();
    let bc = *fluid.boundaries();
    let start_state = scene.start(&fluid)?;
    let density_bc = *start_state.density.as_ref().ok_or_else(|| Error::config("scene", "has no density"))?.bc();
    // Faces fixed by the walls: zero in the mask.
    let mask = MacField::from_fn(grid, bc, DType::F32, |_, _| [1.0, 1.0])?.into_values();
    let p = Tensor::full(ae.normalization().param_to_code(seq.param) as f32, (1, 1), &Device::Cpu)?;
    let first = start + 1 - w;
    let z0 = ae.encode(&seq.velocity.narrow(0, first, w)?, &seq.density.narrow(0, first, w)?)?;
    let mut hist = with_param(&z0, &p.repeat((w, 1))?, slot)?.unsqueeze(0)?; // [1, w, code]
    let mut rho = seq.density.narrow(0, start, 1)?;
    let mut z = hist.narrow(1, w - 1, 1)?.squeeze(1)?;
    let (mut de, mut ve, mut dde, mut finite) = (Vec::new(), Vec::new(), Vec::new(), true);
    for k in 1..=steps {
        let u = ae.decode(&z)?.0.broadcast_mul(&mask)?;
        let state = FluidState {
            velocity: MacField::new(u, grid, bc)?,
            density: Some(CenteredField::new(rho.clone(), grid, density_bc)?),
        };
        rho = fluid
            .step_unprojected(&state, Some(&rate))?
            .density
            .ok_or_else(|| Error::config("scene", "has no density"))?
            .into_values();
        let raw = with_param(&model.predictor.forward(&hist)?, &p, slot)?;
        let z_rho = ae.encode(&MacField::zeros(grid, bc, 1, DType::F32)?.into_values(), &rho)?;
        z = with_density_part(&raw, &z_rho, cfg)?;
        hist = if w > 1 { Tensor::cat(&[hist.narrow(1, 1, w - 1)?, z.unsqueeze(1)?], 1)? } else { z.unsqueeze(1)? };
        let (u_next, _) = ae.decode(&z)?;
        let (_, rho_raw) = ae.decode(&raw)?;
        let (u_ref, rho_ref) = (seq.velocity.narrow(0, start + k, 1)?, seq.density.narrow(0, start + k, 1)?);
        let ok = [&rho, &u_next]
            .iter()
            .all(|x| x.abs().and_then(|a| a.max_all()).and_then(|m| m.to_scalar::<f32>()).is_ok_and(|m| m.is_finite()));
        if !ok {
            finite = false;
            de.push(f64::INFINITY);
            ve.push(f64::INFINITY);
            dde.push(f64::INFINITY);
            break;
        }
        de.push(ratio(sum_sq(&(&rho - &rho_ref)?)?, sum_sq(&rho_ref)?));
        ve.push(ratio(sum_sq(&(&u_next.broadcast_mul(&mask)? - &u_ref)?)?, sum_sq(&u_ref)?));
        dde.push(ratio(sum_sq(&(rho_raw - &rho_ref)?)?, sum_sq(&rho_ref)?));
    }
    let density_error_final = de.last().copied().unwrap_or(f64::NAN);
    let density_error_mean = de.iter().sum::<f64>() / de.len().max(1) as f64;
    Ok(LssRollout {
        start,
        density_error: de,
        velocity_error: ve,
        decoded_density_error: dde,
        density_error_final,
        density_error_mean,
        finite,
    })
}
