//! The compared models, all on the same [`AcdmUnet`]: ACDM (noisy or clean conditioning on two
//! previous frames) and the deterministic U-Net baselines (one previous frame; trained one-step,
//! unrolled, or with training noise). Each is a [`FramePredictor`].

use super::data::CHANNELS;
use super::rollout::{check_conditioning, FramePredictor};
use crate::ddpm::{Conditioning, Diffusion};
use crate::schedule::NoiseSchedule;
use crate::unet::{count_parameters, AcdmUnet, AcdmUnetConfig};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use serde::{Deserialize, Serialize};

/// How a model is trained and what it is conditioned on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Method {
    /// ACDM: conditioned on 2 previous frames, noisy conditioning, Huber epsilon loss.
    Acdm,
    /// ACDM_ncn: the same with a clean condition.
    AcdmNcn,
    /// U-Net trained on the one-step MSE.
    Unet,
    /// U-Net_ut: MSE over `m` autoregressive steps, backpropagated through all of them.
    UnetUnrolled {
        /// Unrolled steps (official: 8).
        m: usize,
    },
    /// U-Net_tn: one-step MSE with Gaussian noise of std `sigma` on the input frame.
    UnetNoise {
        /// Noise standard deviation (official: 0.01).
        sigma: f64,
    },
}

impl Method {
    /// Previous frames the model is conditioned on.
    pub fn history(&self) -> usize {
        match self {
            Method::Acdm | Method::AcdmNcn => 2,
            _ => 1,
        }
    }

    /// Whether the model is a diffusion model (sampled) rather than a direct predictor.
    pub fn is_diffusion(&self) -> bool {
        matches!(self, Method::Acdm | Method::AcdmNcn)
    }

    /// A short name, e.g. `"acdm"`, `"unet_ut8"`.
    pub fn name(&self) -> String {
        match self {
            Method::Acdm => "acdm".into(),
            Method::AcdmNcn => "acdm_ncn".into(),
            Method::Unet => "unet".into(),
            Method::UnetUnrolled { m } => format!("unet_ut{m}"),
            Method::UnetNoise { sigma } => format!("unet_tn{sigma}"),
        }
    }
}

/// How a diffusion model draws a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Sampler {
    /// Ancestral DDPM over all `R` steps.
    Ddpm,
    /// Deterministic DDIM (`eta = 0`) on `k` evenly spaced steps.
    Ddim(usize),
}

impl Sampler {
    /// A short name, e.g. `"ddpm"`, `"ddim5"`.
    pub fn name(&self) -> String {
        match self {
            Sampler::Ddpm => "ddpm".into(),
            Sampler::Ddim(k) => format!("ddim{k}"),
        }
    }
}

/// Architecture and method of a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    /// The method.
    pub method: Method,
    /// U-Net width (official 128; CPU-sized 16 or 24).
    pub dim: usize,
    /// Diffusion steps `R` of the `acdm(R)` schedule (official Inc: 20); unused by the U-Nets.
    pub diffusion_steps: usize,
}

impl ModelConfig {
    /// ACDM with `R = 20` at width `dim`.
    pub fn acdm(dim: usize) -> Self {
        Self { method: Method::Acdm, dim, diffusion_steps: 20 }
    }

    /// A U-Net baseline of `method` at width `dim`.
    pub fn baseline(method: Method, dim: usize) -> Self {
        Self { method, dim, diffusion_steps: 20 }
    }

    /// Checks the settings; the error names the one to change.
    pub fn validate(&self) -> Result<()> {
        match self.method {
            Method::UnetUnrolled { m: 0 } => {
                return Err(Error::InvalidConfig {
                    name: "unrolled steps m",
                    value: "0".into(),
                    hint: "use m >= 1 (the official U-Net_ut uses 8)",
                })
            }
            Method::UnetNoise { sigma } if !(sigma >= 0.0 && sigma.is_finite()) => {
                return Err(Error::InvalidConfig {
                    name: "training noise sigma",
                    value: sigma.to_string(),
                    hint: "use a finite sigma >= 0 (the official U-Net_tn uses 0.01)",
                })
            }
            _ => {}
        }
        if self.method.is_diffusion() && self.diffusion_steps < 2 {
            return Err(Error::InvalidConfig {
                name: "diffusion_steps",
                value: self.diffusion_steps.to_string(),
                hint: "use R >= 2 diffusion steps (ACDM on Inc: 20)",
            });
        }
        Ok(())
    }

    /// The U-Net configuration.
    pub fn unet(&self) -> AcdmUnetConfig {
        let frame = CHANNELS;
        match self.method {
            Method::Acdm => AcdmUnetConfig::acdm(self.dim, 3 * frame),
            Method::AcdmNcn => AcdmUnetConfig { out_channels: frame, ..AcdmUnetConfig::acdm(self.dim, 3 * frame) },
            _ => AcdmUnetConfig::unet_baseline(self.dim, frame, frame),
        }
    }
}

/// A model with its weights.
pub struct Model {
    config: ModelConfig,
    varmap: VarMap,
    unet: AcdmUnet,
    diffusion: Option<Diffusion>,
    sampler: Sampler,
}

impl std::fmt::Debug for Model {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Model").field("config", &self.config).field("sampler", &self.sampler).finish()
    }
}

impl Model {
    /// A freshly initialised model, weights from seed 0: [`Model::with_seed`].
    pub fn new(config: ModelConfig) -> Result<Self> {
        Self::with_seed(config, 0)
    }

    /// A freshly initialised model whose weights are drawn from `seed` (PyTorch's default
    /// layer initialisation, [`pbdl_nets::seeded_init`]): the same seed gives the same weights,
    /// so a training run is reproducible from its configuration (candle's own initialisers
    /// cannot be seeded).
    pub fn with_seed(config: ModelConfig, seed: u64) -> Result<Self> {
        config.validate()?;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let unet = AcdmUnet::new(config.unet(), vb)?;
        pbdl_nets::seeded_init(&varmap, seed)?;
        let diffusion = if config.method.is_diffusion() {
            let cond = if config.method == Method::Acdm { Conditioning::Noisy } else { Conditioning::Clean };
            Some(Diffusion::new(NoiseSchedule::acdm(config.diffusion_steps)?, cond))
        } else {
            None
        };
        Ok(Self { config, varmap, unet, diffusion, sampler: Sampler::Ddpm })
    }

    /// The configuration.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The variables (for the optimiser and checkpoints).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The network.
    pub fn unet(&self) -> &AcdmUnet {
        &self.unet
    }

    /// The diffusion process (`None` for the U-Net baselines).
    pub fn diffusion(&self) -> Option<&Diffusion> {
        self.diffusion.as_ref()
    }

    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        count_parameters(&self.varmap)
    }

    /// The same model drawing frames with `sampler` (diffusion models only; a typed error for a
    /// U-Net or a DDIM step count outside `1..=R`).
    pub fn set_sampler(&mut self, sampler: Sampler) -> Result<()> {
        let Some(d) = &self.diffusion else {
            return Err(Error::InvalidConfig {
                name: "sampler",
                value: sampler.name(),
                hint: "only diffusion models (acdm, acdm_ncn) sample; the U-Nets predict directly",
            });
        };
        if let Sampler::Ddim(k) = sampler {
            d.ddim_steps(k)?;
        }
        self.sampler = sampler;
        Ok(())
    }

    /// The sampler in use.
    pub fn sampler(&self) -> Sampler {
        self.sampler
    }

    /// Loads weights from a checkpoint written by [`super::train::train`].
    pub fn load(&mut self, path: &std::path::Path) -> Result<u64> {
        Ok(pbdl_core::io::load_varmap(path, &self.varmap)?.step)
    }
}

impl FramePredictor for Model {
    fn history(&self) -> usize {
        self.config.method.history()
    }

    fn predict(&self, prev: &Tensor, seed: u64) -> Result<Tensor> {
        let d = prev.dims();
        let (ny, nx) = if d.len() == 5 { (d[3], d[4]) } else { (0, 0) };
        check_conditioning(prev, self.history(), ny, nx)?;
        let b = d[0];
        let cond = prev.reshape((b, self.history() * CHANNELS, ny, nx))?;
        match &self.diffusion {
            None => Ok(self.unet.forward(&cond, None)?),
            Some(diff) => {
                let x = Diffusion::noise(&[b, CHANNELS, ny, nx], DType::F32, prev.device(), seed)?;
                match self.sampler {
                    Sampler::Ddpm => diff.sample_ddpm(&self.unet, Some(&cond), &x, seed),
                    Sampler::Ddim(k) => diff.sample_ddim(&self.unet, Some(&cond), &x, &diff.ddim_steps(k)?, 0.0, seed),
                }
            }
        }
    }

    fn name(&self) -> String {
        let base = format!("{}_d{}", self.config.method.name(), self.config.dim);
        match &self.diffusion {
            Some(_) => format!("{base}-{}", self.sampler.name()),
            None => base,
        }
    }
}
