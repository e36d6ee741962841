//! The 3D convolutional autoencoder of a field (the pressure) to a flat latent code, its
//! training on pbdl-core's resumable [`TrainLoop`] and its held-out reconstruction error.
//!
//! Latent-space physics (Wiewel et al. 2019) compresses a 64^3 pressure 256-fold with six
//! stride-2 3D convolutions (widths `32 * {1, 2, 4, 8, 16, 32}`, the first kernel 4^3, the
//! others 2^3, leaky ReLU 0.2) to a 1024-code, and mirrors it with transposed convolutions. Here,
//! at CPU size:
//! * encoder: `widths.len()` stride-2 [`conv3d`](pbdl_core::conv::conv3d)s
//!   ([`Conv3dParams`]: the first with a `first_kernel^3` kernel and padding
//!   `(first_kernel - 2) / 2`, the others 2^3 unpadded), each followed by leaky ReLU (0.2), then
//!   a linear 1^3 convolution to `latent_channels`, flattened to the code;
//! * decoder: a 3^3 convolution from the latent map to the coarsest width (leaky ReLU), then per
//!   level nearest-neighbour 2x upsampling followed by a 3^3 convolution (leaky ReLU; the finest
//!   one to the field's channels, linear).
//!
//! The decoder upsamples by nearest neighbours and convolves instead of using transposed
//! convolutions. (pbdl-core's `conv_transpose` does accept three spatial axes; the
//! upsample-then-convolve decoder was chosen because it has no checkerboard artefacts, the
//! 2D model's transposed decoder aside.) No batch norm: the code of a frame must not depend on
//! its batch.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::VarMap;
//! use pbdl_latent::autoencoder3d::{Autoencoder3dConfig, LatentAutoencoder3d};
//!
//! let cfg = Autoencoder3dConfig { resolution: 8, widths: vec![4, 8], latent_channels: 2, ..Autoencoder3dConfig::default() };
//! let varmap = VarMap::new();
//! let ae = LatentAutoencoder3d::new(cfg, &varmap, 0)?;
//! assert_eq!(ae.code_size(), 2 * 2 * 2 * 2);
//! let p = Tensor::zeros((3, 1, 8, 8, 8), DType::F32, &Device::Cpu)?;
//! let z = ae.encode(&p)?;
//! assert_eq!(z.dims(), [3, 16]);
//! assert_eq!(ae.decode(&z)?.dims(), [3, 1, 8, 8, 8]);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::data3d::{Dataset3d, Sequence3d};
use crate::train::{run_phase, PhaseSettings};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::conv::{Conv3d, Conv3dParams, ConvLayerConfig};
use pbdl_core::nn::Activation;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

const LEAKY: Activation = Activation::LeakyRelu { negative_slope: 0.2 };

/// Layout of a [`LatentAutoencoder3d`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Autoencoder3dConfig {
    /// Channels of the field (1 for the pressure). Default 1.
    pub channels: usize,
    /// Cells per side of the (cubic) input; a multiple of `2^levels`. Default 32.
    pub resolution: usize,
    /// Widths of the stride-2 levels (their count halves the side that often). Default
    /// `[16, 32, 64]`: 32^3 -> 4^3.
    pub widths: Vec<usize>,
    /// Kernel side of the first stride-2 convolution (even, >= 2; the paper's 4). Default 4.
    pub first_kernel: usize,
    /// Channels of the latent map; the code has `latent_channels * (resolution / 2^levels)^3`
    /// entries. Default 8 (a 512-code at 32^3: 64x compression).
    pub latent_channels: usize,
}

impl Default for Autoencoder3dConfig {
    fn default() -> Self {
        Self { channels: 1, resolution: 32, widths: vec![16, 32, 64], first_kernel: 4, latent_channels: 8 }
    }
}

impl Autoencoder3dConfig {
    /// Side of the latent map.
    pub fn latent_side(&self) -> usize {
        self.resolution >> self.widths.len().min(usize::BITS as usize - 1)
    }

    /// Entries of the flat code.
    pub fn code_size(&self) -> usize {
        self.latent_channels * self.latent_side().pow(3)
    }

    /// Checks the layout (typed [`Error::Config`]).
    pub fn validate(&self) -> Result<()> {
        if self.widths.is_empty() || self.widths.len() >= 16 {
            return Err(Error::config("widths", format!("{} levels; use 1 to 15", self.widths.len())));
        }
        let m = 1usize << self.widths.len();
        if self.resolution == 0 || self.resolution % m != 0 {
            return Err(Error::config(
                "resolution / widths",
                format!(
                    "{} with {} levels; the side must be a positive multiple of 2^levels = {m}",
                    self.resolution,
                    self.widths.len()
                ),
            ));
        }
        if self.first_kernel < 2 || self.first_kernel % 2 != 0 || self.first_kernel > self.resolution {
            return Err(Error::config(
                "first_kernel",
                format!("{}; use an even side >= 2 and <= the resolution", self.first_kernel),
            ));
        }
        if self.channels == 0 || self.latent_channels == 0 || self.widths.contains(&0) {
            return Err(Error::config("channels / latent_channels / widths", "use positive sizes"));
        }
        Ok(())
    }
}

/// Nearest-neighbour 2x upsampling `[b, c, d, h, w] -> [b, c, 2d, 2h, 2w]` (its gradient sums
/// the eight copies).
pub fn upsample_nearest3d(x: &Tensor) -> Result<Tensor> {
    if x.rank() != 5 {
        return Err(Error::Shape {
            what: "upsample_nearest3d input",
            expected: "[batch, c, d, h, w]".into(),
            got: x.dims().to_vec(),
        });
    }
    let (b, c, d, h, w) = x.dims5()?;
    let y = x.reshape(vec![b * c, d, 1, h, 1, w, 1])?.broadcast_as(vec![b * c, d, 2, h, 2, w, 2])?;
    Ok(y.contiguous()?.reshape((b, c, 2 * d, 2 * h, 2 * w))?)
}

/// Encoder and decoder of one 3D field (see the module docs).
#[derive(Clone, Debug)]
pub struct LatentAutoencoder3d {
    encoder: Vec<Conv3d>,
    to_code: Conv3d,
    from_code: Conv3d,
    decoder: Vec<Conv3d>,
    config: Autoencoder3dConfig,
}

impl LatentAutoencoder3d {
    /// Builds the network with its variables in `varmap` (f32), initialised from `seed`.
    pub fn new(config: Autoencoder3dConfig, varmap: &VarMap, seed: u64) -> Result<Self> {
        config.validate()?;
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let w = &config.widths;
        let levels = w.len();
        let mut encoder = Vec::with_capacity(levels);
        let mut c_in = config.channels;
        for (i, &c) in w.iter().enumerate() {
            let k = if i == 0 { config.first_kernel } else { 2 };
            let p = Conv3dParams::default().stride(2).padding((k - 2) / 2);
            encoder.push(ConvLayerConfig::new(c_in, c, [k; 3]).with_params(p).init(vb.pp(format!("enc{i}")))?);
            c_in = c;
        }
        let to_code = ConvLayerConfig::new(c_in, config.latent_channels, [1; 3]).init(vb.pp("to_code"))?;
        let same = Conv3dParams::default().padding(1);
        let from_code = ConvLayerConfig::new(config.latent_channels, w[levels - 1], [3; 3])
            .with_params(same)
            .init(vb.pp("from_code"))?;
        let mut decoder = Vec::with_capacity(levels);
        for i in (0..levels).rev() {
            let out = if i == 0 { config.channels } else { w[i - 1] };
            decoder.push(ConvLayerConfig::new(w[i], out, [3; 3]).with_params(same).init(vb.pp(format!("dec{i}")))?);
        }
        pbdl_nets::seeded_init(varmap, seed)?;
        Ok(Self { encoder, to_code, from_code, decoder, config })
    }

    /// The layout.
    pub fn config(&self) -> &Autoencoder3dConfig {
        &self.config
    }

    /// Entries of the flat code.
    pub fn code_size(&self) -> usize {
        self.config.code_size()
    }

    /// `[B, channels, n, n, n]` (f32) -> codes `[B, code_size]`.
    pub fn encode(&self, x: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = x.dims();
        let n = c.resolution;
        if d.len() != 5 || d[0] == 0 || d[1] != c.channels || d[2..] != [n, n, n] || x.dtype() != DType::F32 {
            return Err(Error::Shape {
                what: "3D autoencoder input (f32)",
                expected: format!("[batch >= 1, {}, {n}, {n}, {n}] f32", c.channels),
                got: d.to_vec(),
            });
        }
        let mut h = x.clone();
        for layer in &self.encoder {
            h = layer.forward_act(&h, LEAKY)?;
        }
        Ok(self.to_code.forward_act(&h, Activation::Identity)?.flatten_from(1)?)
    }

    /// Codes `[B, code_size]` (f32) -> fields `[B, channels, n, n, n]`.
    pub fn decode(&self, z: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = z.dims();
        if d.len() != 2 || d[0] == 0 || d[1] != c.code_size() || z.dtype() != DType::F32 {
            return Err(Error::Shape {
                what: "3D latent code (f32)",
                expected: format!("[batch >= 1, {}] f32", c.code_size()),
                got: d.to_vec(),
            });
        }
        let s = c.latent_side();
        let mut h = self.from_code.forward_act(&z.reshape((d[0], c.latent_channels, s, s, s))?, LEAKY)?;
        let last = self.decoder.len() - 1;
        for (i, layer) in self.decoder.iter().enumerate() {
            let act = if i == last { Activation::Identity } else { LEAKY };
            h = layer.forward_act(&upsample_nearest3d(&h)?, act)?;
        }
        Ok(h)
    }

    /// `decode(encode(x))`.
    pub fn reconstruct(&self, x: &Tensor) -> Result<Tensor> {
        self.decode(&self.encode(x)?)
    }
}

/// A trained 3D pressure autoencoder with its variables and the pressure scale it divides by.
#[derive(Clone)]
pub struct Autoencoder3dModel {
    /// The network.
    pub autoencoder: LatentAutoencoder3d,
    /// Its variables.
    pub vars: VarMap,
    /// The 99.9th percentile of `|p|` over the training frames.
    pub pressure_scale: f32,
}

impl std::fmt::Debug for Autoencoder3dModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Autoencoder3dModel")
            .field("autoencoder", &self.autoencoder)
            .field("pressure_scale", &self.pressure_scale)
            .finish_non_exhaustive()
    }
}

impl Autoencoder3dModel {
    /// Codes `[B, code]` of pressures `[B, 1, n, n, n]` (in the solver's units; any float dtype).
    pub fn encode_pressure(&self, p: &Tensor) -> Result<Tensor> {
        self.autoencoder.encode(&(p.to_dtype(DType::F32)? / self.pressure_scale as f64)?)
    }

    /// Pressures `[B, 1, n, n, n]` (f32, in the solver's units) of codes `[B, code]`.
    pub fn decode_pressure(&self, z: &Tensor) -> Result<Tensor> {
        Ok((self.autoencoder.decode(z)? * self.pressure_scale as f64)?)
    }
}

/// Everything [`train_autoencoder3d`] needs besides the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Autoencoder3dTrainConfig {
    /// The layout (its `resolution` must be the data's).
    pub autoencoder: Autoencoder3dConfig,
    /// Updates, frames per update and Adam's learning rate (halved at 50% and again at 75% of
    /// the updates). Default: 600 updates of 8 frames at lr 1e-3.
    pub training: PhaseSettings,
    /// Seed of the initialisation and of the sampled frames.
    pub seed: u64,
}

impl Default for Autoencoder3dTrainConfig {
    fn default() -> Self {
        Self {
            autoencoder: Autoencoder3dConfig::default(),
            training: PhaseSettings { steps: 600, batch: 8, lr: 1e-3 },
            seed: 0,
        }
    }
}

/// The 99.9th percentile of `|p|` over the training frames after the first.
pub fn pressure_scale3d(train: &[Sequence3d]) -> Result<f32> {
    let mut all = Vec::new();
    for s in train {
        if s.frames() > 1 {
            all.extend(s.pressure.narrow(0, 1, s.frames() - 1)?.abs()?.flatten_all()?.to_vec1::<f32>()?);
        }
    }
    all.sort_by(f32::total_cmp);
    let q = all.get(((all.len() as f64 - 1.0).max(0.0) * 0.999).round() as usize).copied().unwrap_or(0.0);
    if !(q > 0.0 && q.is_finite()) {
        return Err(Error::config("data", format!("the training pressures have no scale ({q}); simulate more frames")));
    }
    Ok(q)
}

/// Trains the 3D autoencoder on the training pressures (every frame but the first of each
/// scene, divided by [`pressure_scale3d`]) with MSE and Adam on pbdl-core's [`TrainLoop`]. With
/// `run_dir` the loop writes `loss.csv` and checkpoints there and resumes a stopped run; a
/// directory holding a run of other settings is refused ([`pbdl_core::train::check_resume`]:
/// a typed error naming the first differing setting).
pub fn train_autoencoder3d(
    data: &Dataset3d,
    cfg: &Autoencoder3dTrainConfig,
    run_dir: Option<&Path>,
) -> Result<Autoencoder3dModel> {
    let t = &cfg.training;
    if t.steps == 0 || t.batch == 0 || !(t.lr > 0.0 && t.lr.is_finite()) {
        return Err(Error::config(
            "training",
            format!("{t:?}: steps and batch must be positive, lr positive and finite"),
        ));
    }
    if cfg.autoencoder.resolution != data.config.resolution {
        return Err(Error::config(
            "autoencoder.resolution",
            format!("{} but the data is {1}^3; use {1}", cfg.autoencoder.resolution, data.config.resolution),
        ));
    }
    let scale = pressure_scale3d(&data.train)?;
    let frames: Vec<Tensor> = data
        .train
        .iter()
        .filter(|s| s.frames() > 1)
        .map(|s| s.pressure.narrow(0, 1, s.frames() - 1))
        .collect::<candle_core::Result<_>>()?;
    let frames = (Tensor::cat(&frames, 0)? / scale as f64)?;
    let count = frames.dims()[0];
    let varmap = VarMap::new();
    let ae = LatentAutoencoder3d::new(cfg.autoencoder.clone(), &varmap, cfg.seed)?;
    let config = serde_json::json!({
        "phase": "autoencoder3d", "data": data.config, "autoencoder": cfg.autoencoder, "training": t, "seed": cfg.seed,
    });
    let config = pbdl_core::train::canonical(config)?;
    run_phase(&varmap, t, cfg.seed, &config, run_dir, |step| {
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(cfg.seed, step));
        let idx: Vec<u32> = (0..t.batch).map(|_| rng.random_range(0..count) as u32).collect();
        let x = frames.index_select(&Tensor::new(idx, &Device::Cpu)?, 0)?;
        Ok((ae.reconstruct(&x)? - &x)?.sqr()?.mean_all()?)
    })?;
    Ok(Autoencoder3dModel { autoencoder: ae, vars: varmap, pressure_scale: scale })
}

fn sum_sq(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()?)
}

/// The aggregate relative L2 reconstruction error of the pressure over all frames of `seqs` but
/// each scene's first: `sqrt(sum |AE(p) - p|^2 / sum |p|^2)` (frames in chunks of 8).
pub fn autoencoder3d_error(model: &Autoencoder3dModel, seqs: &[Sequence3d]) -> Result<f64> {
    let (mut err, mut den) = (0.0, 0.0);
    for s in seqs {
        let t = s.frames();
        for start in (1..t).step_by(8) {
            let p = s.pressure.narrow(0, start, (t - start).min(8))?;
            let r = model.decode_pressure(&model.encode_pressure(&p)?)?;
            err += sum_sq(&(r - p.to_dtype(DType::F32)?)?)?;
            den += sum_sq(&p)?;
        }
    }
    if den == 0.0 {
        return Err(Error::config("seqs", "no frame after the first, or all pressures zero: nothing to score"));
    }
    Ok((err / den).sqrt())
}
