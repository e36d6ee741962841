//! The epsilon-prediction objective and the DDPM / DDIM samplers, with conditioning by channel
//! concatenation.
//!
//! **Training.** For each sample one step `i ~ U{0..R-1}` and one `eps ~ N(0, I)` are drawn; the
//! target is noised in closed form, `x_i = sqrt(abar_i) x_0 + sqrt(1 - abar_i) eps`, and the
//! network is trained to predict `eps` from `x_i` and `i` with an MSE or Huber (SmoothL1,
//! `beta = 1`) loss ([`Diffusion::loss`]).
//!
//! **Conditioning** ([`Conditioning`]): a condition `c` (`[B, C_c, H, W]`) is concatenated in
//! front of the target channels.
//! - [`Conditioning::Noisy`] (ACDM's default): `z = [c, x_0]` is noised as a whole and the model
//!   predicts `eps` on all `C_c + C_x` channels. At sampling time one fixed `c_noise` is drawn per
//!   call and the condition enters step `i` as `c_i = sqrt(abar_i) c + sqrt(1 - abar_i) c_noise`.
//! - [`Conditioning::Clean`] (ACDM_ncn, airfoil paper): the model sees `[c, x_i]` with `c` clean and
//!   predicts `eps` of the `C_x` target channels only.
//!
//! **Ancestral DDPM** ([`Diffusion::sample_ddpm`]): from `x_{R-1} ~ N(0, I)`, for `i = R-1..0`
//! the posterior mean `mu = (x_i - beta_i eps_hat / sqrt(1 - abar_i)) / sqrt(alpha_i)` is taken
//! and, for `i > 0`, noise of variance `beta_i (1 - abar_{i-1}) / (1 - abar_i)` is added.
//!
//! **DDIM** ([`Diffusion::sample_ddim`]): on an increasing sub-sequence `tau_1 < .. < tau_k` of
//! steps, `x0_hat = (x - sqrt(1 - abar) eps_hat) / sqrt(abar)` and
//! `x_prev = sqrt(abar_prev) x0_hat + sqrt(1 - abar_prev - sigma^2) eps_hat + sigma xi`,
//! `sigma = eta sqrt((1 - abar_prev) / (1 - abar)) sqrt(1 - abar / abar_prev)`; `eta = 0` is the
//! deterministic DDIM, `eta = 1` on all steps is DDPM (same noise, same numbers). ACDM's "ddim"
//! mode is noise-free DDPM, not this.
//!
//! The samplers detach the model's output: samples carry no gradient (and no graph).
//!
//! [`GaussianOracle`] is the exact noise predictor for Gaussian data: the reference the samplers
//! are tested against.
//!
//! ```
//! use candle_core::{DType, Device};
//! use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle, Loss};
//! use pbdl_diffusion::schedule::NoiseSchedule;
//!
//! let schedule = NoiseSchedule::cosine(50, 0.008)?;
//! // x_0 ~ N(2, 0.5^2) in one channel: the oracle is the optimal noise predictor.
//! let oracle = GaussianOracle::diagonal(schedule.clone(), &[2.0], &[0.5])?;
//! let diffusion = Diffusion::new(schedule, Conditioning::Clean);
//! let x_t = Diffusion::noise(&[256, 1, 4, 4], DType::F32, &Device::Cpu, 1)?;
//! let x0 = diffusion.sample_ddim(&oracle, None, &x_t, &diffusion.ddim_steps(20)?, 0.0, 0)?;
//! let mean = x0.mean_all()?.to_scalar::<f32>()?;
//! assert!((mean - 2.0).abs() < 0.05, "{mean}");
//! let loss = diffusion.loss(&oracle, &x0, None, Loss::Mse, 3)?.to_scalar::<f32>()?;
//! assert!(loss > 0.0 && loss < 1.0);
//! # Ok::<(), pbdl_diffusion::Error>(())
//! ```

mod oracle;
mod sample;

pub use oracle::GaussianOracle;

use crate::schedule::NoiseSchedule;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use rand::Rng;

/// A network that predicts the noise `eps` from a noisy input and the diffusion step.
///
/// `x` is `[B, C_in, H, W]` (the noisy target with any conditioning channels concatenated in
/// front), `t` is `[B]` (`f32`, the step index `0..R`). The output has the channels of the
/// part the model denoises (for ACDM's noisy conditioning that is all of `C_in`).
pub trait NoisePredictor {
    /// Predicts the noise.
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor>;

    /// The number of input channels the model expects, if fixed; the samplers and the loss
    /// check the concatenated input against it and return [`Error::ShapeMismatch`] otherwise.
    fn input_channels(&self) -> Option<usize> {
        None
    }
}

impl<T: NoisePredictor + ?Sized> NoisePredictor for &T {
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor> {
        (**self).predict(x, t)
    }
    fn input_channels(&self) -> Option<usize> {
        (**self).input_channels()
    }
}

/// How a condition `c` enters the model (always by channel concatenation in front of the target).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Conditioning {
    /// ACDM's default: `[c, x]` is diffused as a whole, the model predicts `eps` on all channels.
    Noisy,
    /// ACDM_ncn / airfoil paper: `c` stays clean, the model predicts `eps` of the target only.
    Clean,
}

/// The regression loss between predicted and true noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// Mean squared error.
    Mse,
    /// SmoothL1 with `beta = 1` (torch's default): `0.5 d^2` for `|d| < 1`, `|d| - 0.5` otherwise.
    Huber,
}

impl Loss {
    /// The mean loss between `pred` and `target` (same shape).
    pub fn compute(&self, pred: &Tensor, target: &Tensor) -> Result<Tensor> {
        if pred.dims() != target.dims() {
            return Err(Error::shape("predicted noise", target.dims(), pred.dims()));
        }
        let d = (pred - target)?;
        Ok(match self {
            Loss::Mse => d.sqr()?.mean_all()?,
            Loss::Huber => {
                // 0.5 q^2 + (|d| - q) with q = min(|d|, 1) is SmoothL1 in one smooth expression.
                let a = d.abs()?;
                let q = a.clamp(0f64, 1f64)?;
                ((q.sqr()? * 0.5)? + (a - q)?)?.mean_all()?
            }
        })
    }
}

/// A noise schedule together with a conditioning mode: trains and samples noise predictors.
#[derive(Debug, Clone)]
pub struct Diffusion {
    schedule: NoiseSchedule,
    conditioning: Conditioning,
}

impl Diffusion {
    /// A diffusion process on `schedule` with the given conditioning mode (irrelevant when no
    /// condition is passed).
    pub fn new(schedule: NoiseSchedule, conditioning: Conditioning) -> Self {
        Self { schedule, conditioning }
    }

    /// The noise schedule.
    pub fn schedule(&self) -> &NoiseSchedule {
        &self.schedule
    }

    /// The conditioning mode.
    pub fn conditioning(&self) -> Conditioning {
        self.conditioning
    }

    /// Seeded standard-normal noise of `shape`, e.g. the start `x_{R-1}` of a sampler.
    pub fn noise(shape: &[usize], dtype: DType, device: &Device, seed: u64) -> Result<Tensor> {
        Ok(pbdl_core::seed::randn(shape, 0.0, 1.0, dtype, device, seed)?)
    }

    /// The step index tensor `[B]` (`f32`) that [`NoisePredictor::predict`] receives.
    pub fn step_tensor(steps: &[usize], device: &Device) -> Result<Tensor> {
        let v: Vec<f32> = steps.iter().map(|&s| s as f32).collect();
        Ok(Tensor::from_vec(v, steps.len(), device)?)
    }

    /// Forward noising `x_i = sqrt(abar_i) x_0 + sqrt(1 - abar_i) eps` with one step per sample.
    pub fn q_sample(&self, x0: &Tensor, steps: &[usize], eps: &Tensor) -> Result<Tensor> {
        let b = x0.dim(0)?;
        if steps.len() != b {
            return Err(Error::shape("number of diffusion steps (one per sample)", b, steps.len()));
        }
        if eps.dims() != x0.dims() {
            return Err(Error::shape("noise eps", x0.dims(), eps.dims()));
        }
        self.check_steps(steps)?;
        let sa: Vec<f64> = steps.iter().map(|&i| self.schedule.sqrt_alpha_bar(i)).collect();
        let sn: Vec<f64> = steps.iter().map(|&i| self.schedule.sqrt_one_minus_alpha_bar(i)).collect();
        let sa = per_sample(&sa, x0)?;
        let sn = per_sample(&sn, x0)?;
        Ok((x0.broadcast_mul(&sa)? + eps.broadcast_mul(&sn)?)?)
    }

    /// The training loss on a batch: one random step and one `eps` per sample (drawn from `seed`),
    /// then [`Diffusion::loss_at`].
    ///
    /// `x0` is the clean target `[B, C_x, H, W]`, `cond` an optional condition `[B, C_c, H, W]`.
    pub fn loss<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        x0: &Tensor,
        cond: Option<&Tensor>,
        loss: Loss,
        seed: u64,
    ) -> Result<Tensor> {
        let (b, cx, h, w) = dims4("target x0", x0)?;
        let cc = check_condition(cond, b, h, w)?;
        let mut rng = pbdl_core::seed::rng(seed);
        let r = self.schedule.len();
        let steps: Vec<usize> = (0..b).map(|_| rng.random_range(0..r)).collect();
        let noisy_c = if self.conditioning == Conditioning::Noisy { cc } else { 0 };
        let eps = Self::noise(&[b, noisy_c + cx, h, w], x0.dtype(), x0.device(), rng.random())?;
        self.loss_at(model, x0, cond, &steps, &eps, loss)
    }

    /// The training loss at given steps and noise (deterministic; [`Diffusion::loss`] draws them).
    ///
    /// `eps` has the shape of the diffused tensor: `[B, C_c + C_x, H, W]` for noisy conditioning
    /// with a condition, `[B, C_x, H, W]` otherwise.
    pub fn loss_at<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        x0: &Tensor,
        cond: Option<&Tensor>,
        steps: &[usize],
        eps: &Tensor,
        loss: Loss,
    ) -> Result<Tensor> {
        let (b, _, h, w) = dims4("target x0", x0)?;
        check_condition(cond, b, h, w)?;
        let input = match (cond, self.conditioning) {
            (Some(c), Conditioning::Noisy) => {
                self.q_sample(&Tensor::cat(&[&c.to_dtype(x0.dtype())?, x0], 1)?, steps, eps)?
            }
            (Some(c), Conditioning::Clean) => {
                Tensor::cat(&[&c.to_dtype(x0.dtype())?, &self.q_sample(x0, steps, eps)?], 1)?
            }
            (None, _) => self.q_sample(x0, steps, eps)?,
        };
        let pred = predict_checked(model, &input, steps, eps.dim(1)?)?;
        loss.compute(&pred, eps)
    }

    /// Evenly spaced DDIM steps: `k` indices from `0` to `R - 1` inclusive (`[R - 1]` for `k = 1`).
    pub fn ddim_steps(&self, k: usize) -> Result<Vec<usize>> {
        let r = self.schedule.len();
        if k == 0 || k > r {
            return Err(Error::InvalidConfig {
                name: "DDIM steps",
                value: k.to_string(),
                hint: "use between 1 and the schedule length R sampling steps",
            });
        }
        if k == 1 {
            return Ok(vec![r - 1]);
        }
        Ok((0..k).map(|j| ((j * (r - 1)) as f64 / (k - 1) as f64).round() as usize).collect())
    }

    fn check_steps(&self, steps: &[usize]) -> Result<()> {
        let r = self.schedule.len();
        if let Some(&s) = steps.iter().find(|&&s| s >= r) {
            return Err(Error::InvalidConfig {
                name: "diffusion step",
                value: s.to_string(),
                hint: "steps are 0-based indices below the schedule length R",
            });
        }
        Ok(())
    }
}

/// `[B, 1, 1, 1]` coefficients, one per sample, in `like`'s dtype and device.
fn per_sample(v: &[f64], like: &Tensor) -> Result<Tensor> {
    let shape: Vec<usize> = std::iter::once(v.len()).chain(std::iter::repeat_n(1, like.rank() - 1)).collect();
    Ok(Tensor::from_vec(v.to_vec(), shape, like.device())?.to_dtype(like.dtype())?)
}

/// `(B, C, H, W)` of a rank-4 tensor, or a typed error naming `what`.
fn dims4(what: &str, x: &Tensor) -> Result<(usize, usize, usize, usize)> {
    match *x.dims() {
        [b, c, h, w] => Ok((b, c, h, w)),
        _ => Err(Error::shape(format!("{what} (layout [B, C, H, W])"), "rank 4", x.dims())),
    }
}

/// Checks that a condition has the target's batch and spatial size; returns its channel count.
fn check_condition(cond: Option<&Tensor>, b: usize, h: usize, w: usize) -> Result<usize> {
    let Some(c) = cond else { return Ok(0) };
    let (cb, cc, ch, cw) = dims4("condition", c)?;
    if (cb, ch, cw) != (b, h, w) {
        return Err(Error::shape(
            "condition batch and spatial size (must match the target)",
            format!("[{b}, C_c, {h}, {w}]"),
            c.dims(),
        ));
    }
    Ok(cc)
}

/// Runs the model on `input` at `steps` and checks its input channels and output shape.
fn predict_checked<M: NoisePredictor + ?Sized>(
    model: &M,
    input: &Tensor,
    steps: &[usize],
    out_channels: usize,
) -> Result<Tensor> {
    let (b, c, h, w) = dims4("model input", input)?;
    if let Some(expected) = model.input_channels() {
        if expected != c {
            return Err(Error::shape(
                "model input channels (condition + target channels vs what the model expects)",
                expected,
                c,
            ));
        }
    }
    let t = Diffusion::step_tensor(steps, input.device())?;
    let out = model.predict(input, &t)?;
    if out.dims() != [b, out_channels, h, w] {
        return Err(Error::shape("model output (predicted noise)", [b, out_channels, h, w], out.dims()));
    }
    Ok(out)
}
