//! The correction network `C(s, Re | theta)` of Um et al. (2020): inputs `(u, v, Re)`
//! normalised, a 5x5 conv to 32 channels, 5 residual blocks of two 5x5 conv-32 with
//! LeakyReLU, a 5x5 conv to 2 channels (260,354 parameters), built from pbdl-nets'
//! [`ResNet`]. The MAC arrays `u` and `v` (each `[ny, nx]`) are the input channels as they are,
//! and the output is a MAC correction in velocity units.
//!
//! A scene with scalar channels (the plume's density, [`Corrector::with_scalars`]) adds each
//! scalar, divided by its own scale, as an input channel after `v`, and the network corrects
//! it too (one more output channel each). A scalar's correction has zero mean over the domain:
//! the correction moves the density but does not create or remove any, so the corrected solver
//! conserves it as the source solver does (the inflow is the only source in both).

use super::data::ReferenceSet;
use super::scene::SilScene;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::nn::Activation;
use pbdl_nets::resnet::{ResNet, ResNetConfig};
use serde::{Deserialize, Serialize};

/// Size of the correction network. The default is the paper's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrectorConfig {
    /// Channels of the residual blocks. Default 32.
    pub width: usize,
    /// Residual blocks. Default 5.
    pub blocks: usize,
    /// Odd kernel size. Default 5.
    pub kernel: usize,
    /// LeakyReLU slope. Default 0.3 (Keras' default, as in the paper's code).
    pub negative_slope: f64,
    /// Start the output conv at zero, so that the corrected solver starts as the source solver
    /// (not the paper's: its output conv is initialised like every other). Default false.
    #[serde(default)]
    pub zero_output: bool,
}

impl Default for CorrectorConfig {
    fn default() -> Self {
        Self { width: 32, blocks: 5, kernel: 5, negative_slope: 0.3, zero_output: false }
    }
}

impl CorrectorConfig {
    /// Parameters of the network this config builds (`3 -> width -> ... -> 2`).
    pub fn parameter_count(&self) -> usize {
        self.parameter_count_with_scalars(0)
    }

    /// Parameters of the network for a state with `scalars` scalar channels after the velocity
    /// (`3 + scalars -> width -> ... -> 2 + scalars`).
    pub fn parameter_count_with_scalars(&self, scalars: usize) -> usize {
        let conv = |i: usize, o: usize| i * o * self.kernel * self.kernel + o;
        conv(3 + scalars, self.width) + 2 * self.blocks * conv(self.width, self.width) + conv(self.width, 2 + scalars)
    }
}

/// Input and loss scaling: velocities are divided by `sigma` per component, the scene's
/// parameter (the Reynolds number of the wake, the buoyancy factor of the plume; named `re`
/// from the first scene) is standardised over the training set. The scales of scalar channels
/// are kept next to it ([`scalar_sigma`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    /// Standard deviation of `u` and `v` over the training frames.
    pub sigma: [f64; 2],
    /// Mean of the training parameter values (Reynolds numbers of the wake).
    pub re_mean: f64,
    /// Standard deviation of the training parameter values (1 when there is only one).
    pub re_std: f64,
}

fn channel_std<S>(data: &ReferenceSet<S>, c: usize) -> Result<f64> {
    let all: Vec<Tensor> =
        data.train.iter().map(|r| r.frames.narrow(1, c, 1)?.flatten_all()).collect::<candle_core::Result<_>>()?;
    let x = Tensor::cat(&all, 0)?.to_dtype(DType::F64)?;
    let mean = x.mean_all()?.to_scalar::<f64>()?;
    Ok(x.affine(1.0, -mean)?.sqr()?.mean_all()?.to_scalar::<f64>()?.sqrt().max(1e-6))
}

/// The standard deviation over the training frames of each scalar channel of the scene
/// (channels `2..2 + scalars`; empty for the wake): the scales [`Corrector::with_scalars`]
/// divides them by.
pub fn scalar_sigma<S: SilScene>(data: &ReferenceSet<S>) -> Result<Vec<f64>> {
    if data.train.is_empty() {
        return Err(Error::invalid("scalar_sigma", "train", "no training simulations"));
    }
    (0..data.wake.scalars()).map(|k| channel_std(data, 2 + k)).collect()
}

impl Normalisation {
    /// Statistics of the training part of `data`.
    pub fn from_data<S>(data: &ReferenceSet<S>) -> Result<Self> {
        if data.train.is_empty() {
            return Err(Error::invalid("Normalisation::from_data", "train", "no training simulations"));
        }
        let mut sigma = [0.0; 2];
        for (c, s) in sigma.iter_mut().enumerate() {
            *s = channel_std(data, c)?;
        }
        let re: Vec<f64> = data.train.iter().map(|r| r.re).collect();
        let re_mean = re.iter().sum::<f64>() / re.len() as f64;
        let var = re.iter().map(|r| (r - re_mean).powi(2)).sum::<f64>() / re.len() as f64;
        Ok(Self { sigma, re_mean, re_std: if var > 0.0 { var.sqrt() } else { 1.0 } })
    }
}

/// The correction network with its variables and normalisation.
pub struct Corrector {
    net: ResNet,
    varmap: VarMap,
    config: CorrectorConfig,
    norm: Normalisation,
    scalar_sigma: Vec<f64>,
    dtype: DType,
}

impl std::fmt::Debug for Corrector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Corrector").field("config", &self.config).field("norm", &self.norm).finish()
    }
}

impl Corrector {
    /// Builds the network with seeded PyTorch-style initialisation ([`pbdl_nets::seeded_init`]).
    pub fn new(config: CorrectorConfig, norm: Normalisation, dtype: DType, seed: u64) -> Result<Self> {
        Self::with_scalars(config, norm, &[], dtype, seed)
    }

    /// [`Corrector::new`] for states with scalar channels after the velocity (the plume's
    /// density), `scalar_sigma[k]` the scale of scalar `k` ([`scalar_sigma`]): inputs
    /// `3 + scalars` channels, outputs `2 + scalars`. With no scalars it is
    /// [`Corrector::new`], weight for weight.
    pub fn with_scalars(
        config: CorrectorConfig,
        norm: Normalisation,
        scalar_sigma: &[f64],
        dtype: DType,
        seed: u64,
    ) -> Result<Self> {
        if !(norm.sigma.iter().all(|s| *s > 0.0 && s.is_finite()) && norm.re_std > 0.0 && norm.re_mean.is_finite()) {
            return Err(Error::invalid("Corrector::new", "norm", format!("scales must be positive, got {norm:?}")));
        }
        if !scalar_sigma.iter().all(|s| *s > 0.0 && s.is_finite()) {
            return Err(Error::invalid(
                "Corrector::with_scalars",
                "scalar_sigma",
                format!("scales must be positive and finite, got {scalar_sigma:?}"),
            ));
        }
        let k = scalar_sigma.len();
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, dtype, &Device::Cpu);
        let rc = ResNetConfig {
            kernel: config.kernel,
            activation: Activation::LeakyRelu { negative_slope: config.negative_slope },
            ..ResNetConfig::new(3 + k, 2 + k, config.width, config.blocks)
        };
        let net = ResNet::new(rc, vb)?;
        pbdl_nets::seeded_init(&varmap, seed)?;
        if config.zero_output {
            let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
            for (name, var) in data.iter().filter(|(n, _)| n.starts_with("output.")) {
                var.set(&var.zeros_like()?)
                    .map_err(|e| Error::invalid("Corrector::new", "zero_output", format!("{name}: {e}")))?;
            }
        }
        Ok(Self { net, varmap, config, norm, scalar_sigma: scalar_sigma.to_vec(), dtype })
    }

    /// Its variables.
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// Number of trainable scalars, counted from the built variables.
    pub fn parameters(&self) -> usize {
        pbdl_nets::count_parameters(&self.varmap)
    }

    /// The configuration.
    pub fn config(&self) -> &CorrectorConfig {
        &self.config
    }

    /// The normalisation.
    pub fn normalisation(&self) -> &Normalisation {
        &self.norm
    }

    /// The scales of the scalar channels (empty for a velocity-only corrector).
    pub fn scalar_sigma(&self) -> &[f64] {
        &self.scalar_sigma
    }

    /// Channels of the states it corrects: 2 plus the scalars.
    pub fn channels(&self) -> usize {
        2 + self.scalar_sigma.len()
    }

    /// The scale of every state channel: `sigma[0], sigma[1]`, then the scalars'.
    pub fn channel_sigma(&self) -> Vec<f64> {
        let mut s = self.norm.sigma.to_vec();
        s.extend_from_slice(&self.scalar_sigma);
        s
    }

    /// The correction `C(s, p)` (in the units of each channel) of a state `s`
    /// `[B, channels, ny, nx]` (MAC velocity, then the scalars) at parameter `p` (the Reynolds
    /// number of the wake). The scalar channels' corrections have zero mean over the domain.
    pub fn correction(&self, u: &Tensor, re: f64) -> Result<Tensor> {
        let d = u.dims();
        let c = self.channels();
        if d.len() != 4 || d[1] != c {
            return Err(Error::Shape {
                context: "Corrector::correction",
                expected: format!("[batch, {c}, ny, nx]"),
                got: d.to_vec(),
            });
        }
        let u = u.to_dtype(self.dtype)?;
        let scale =
            Tensor::new(self.channel_sigma().as_slice(), &Device::Cpu)?.to_dtype(self.dtype)?.reshape((1, c, 1, 1))?;
        let x = u.broadcast_div(&scale)?;
        let r =
            Tensor::full(((re - self.norm.re_mean) / self.norm.re_std) as f32, (d[0], 1, d[2], d[3]), &Device::Cpu)?
                .to_dtype(self.dtype)?;
        let y = self.net.forward(&Tensor::cat(&[&x, &r], 1)?)?.broadcast_mul(&scale)?;
        if c == 2 {
            return Ok(y);
        }
        // Scalars: remove the domain mean of their correction (no mass created or removed).
        let vel = y.narrow(1, 0, 2)?;
        let sc = y.narrow(1, 2, c - 2)?;
        let mean = sc.mean_keepdim(3)?.mean_keepdim(2)?;
        Ok(Tensor::cat(&[&vel, &sc.broadcast_sub(&mean)?], 1)?)
    }

    /// One corrected step's correction added: `s + C(s, Re)`.
    pub fn apply(&self, s: &Tensor, re: f64) -> Result<Tensor> {
        Ok((s + self.correction(s, re)?)?)
    }

    /// Saves the weights (safetensors).
    pub fn save(&self, path: impl AsRef<std::path::Path>) -> Result<()> {
        self.varmap.save(path)?;
        Ok(())
    }

    /// Loads weights saved by [`Corrector::save`] into this network.
    pub fn load(&mut self, path: impl AsRef<std::path::Path>) -> Result<()> {
        self.varmap.load(path)?;
        Ok(())
    }
}
