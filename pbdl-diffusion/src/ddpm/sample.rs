//! The ancestral DDPM and the DDIM samplers (equations in the parent module's docs).

use super::{check_condition, dims4, predict_checked, Conditioning, Diffusion, NoisePredictor};
use crate::{Error, Result};
use candle_core::Tensor;

/// A condition prepared for one sampler call.
struct Prepared {
    c: Tensor,
    /// The fixed condition noise of noisy conditioning (one draw per call).
    c_noise: Option<Tensor>,
}

/// The stream of the condition noise; step noise uses the step index as stream.
const C_NOISE_STREAM: u64 = u64::MAX;

/// Standard normal noise of the shape, dtype and device of `like`, drawn from `stream` of `seed`.
fn noise_like(like: &Tensor, seed: u64, stream: u64) -> Result<Tensor> {
    Diffusion::noise(like.dims(), like.dtype(), like.device(), pbdl_core::noise::stream_seed(seed, stream))
}

impl Diffusion {
    fn prepare(&self, cond: Option<&Tensor>, x: &Tensor, seed: u64) -> Result<Option<Prepared>> {
        let (b, _, h, w) = dims4("start noise x", x)?;
        check_condition(cond, b, h, w)?;
        let Some(c) = cond else { return Ok(None) };
        let c = c.to_dtype(x.dtype())?;
        let c_noise = match self.conditioning {
            Conditioning::Noisy => Some(noise_like(&c, seed, C_NOISE_STREAM)?),
            Conditioning::Clean => None,
        };
        Ok(Some(Prepared { c, c_noise }))
    }

    /// Predicts the noise of the target channels of `x` at step `i`, detached: a sampler never
    /// backpropagates, and keeping the graph would hold every step's activations (candle keeps
    /// the op graph of anything computed from a `Var`).
    fn eps_target<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        cond: Option<&Prepared>,
        x: &Tensor,
        i: usize,
    ) -> Result<Tensor> {
        let b = x.dim(0)?;
        let steps = vec![i; b];
        let cx = x.dim(1)?;
        let eps = match cond {
            None => predict_checked(model, x, &steps, cx)?,
            Some(Prepared { c, c_noise: None }) => predict_checked(model, &Tensor::cat(&[c, x], 1)?, &steps, cx)?,
            Some(Prepared { c, c_noise: Some(n) }) => {
                // ACDM: the condition is diffused to step i with the call's fixed noise, the model
                // predicts eps on all channels, and only the target part is used.
                let s = &self.schedule;
                let c_i = ((c * s.sqrt_alpha_bar(i))? + (n * s.sqrt_one_minus_alpha_bar(i))?)?;
                let cc = c.dim(1)?;
                let eps = predict_checked(model, &Tensor::cat(&[&c_i, x], 1)?, &steps, cc + cx)?;
                eps.narrow(1, cc, cx)?
            }
        };
        Ok(eps.detach())
    }

    /// Ancestral DDPM sampling over all `R` steps.
    ///
    /// `x_start` is the state at the last step `R - 1`, usually [`Diffusion::noise`] of the target
    /// shape `[B, C_x, H, W]`; `cond` is `[B, C_c, H, W]` or `None`. The step noise (and, for
    /// noisy conditioning, the one condition noise) are drawn from `seed`.
    pub fn sample_ddpm<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        cond: Option<&Tensor>,
        x_start: &Tensor,
        seed: u64,
    ) -> Result<Tensor> {
        let prepared = self.prepare(cond, x_start, seed)?;
        let s = &self.schedule;
        let mut x = x_start.clone();
        for i in (0..s.len()).rev() {
            x = self.ddpm_step(model, prepared.as_ref(), &x, i, seed)?;
        }
        check_finite(&x)?;
        Ok(x)
    }

    /// One ancestral step from `x_i` to `x_{i-1}` (for `i = 0`: the noise-free posterior mean,
    /// the sample). Use [`Diffusion::sample_ddpm`] for a full sample; this is for benchmarks and
    /// custom loops (the condition noise of noisy conditioning is drawn from `seed`).
    pub fn sample_ddpm_step<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        cond: Option<&Tensor>,
        x: &Tensor,
        i: usize,
        seed: u64,
    ) -> Result<Tensor> {
        self.check_steps(&[i])?;
        let prepared = self.prepare(cond, x, seed)?;
        self.ddpm_step(model, prepared.as_ref(), x, i, seed)
    }

    fn ddpm_step<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        cond: Option<&Prepared>,
        x: &Tensor,
        i: usize,
        seed: u64,
    ) -> Result<Tensor> {
        let s = &self.schedule;
        let eps = self.eps_target(model, cond, x, i)?;
        let mu = ((x - (eps * (s.beta(i) / s.sqrt_one_minus_alpha_bar(i)))?)? / s.alpha(i).sqrt())?;
        if i == 0 {
            return Ok(mu);
        }
        let xi = noise_like(x, seed, i as u64)?;
        Ok((mu + (xi * s.posterior_variance(i).sqrt())?)?)
    }

    /// DDIM sampling on the increasing step sub-sequence `steps` (e.g. [`Diffusion::ddim_steps`]).
    ///
    /// `x_start` is the state at the last listed step. `eta = 0` is deterministic (the same
    /// `x_start` and condition always give the same sample, `seed` only matters for the
    /// condition noise of noisy conditioning); `eta = 1` on all steps is ancestral DDPM.
    pub fn sample_ddim<M: NoisePredictor + ?Sized>(
        &self,
        model: &M,
        cond: Option<&Tensor>,
        x_start: &Tensor,
        steps: &[usize],
        eta: f64,
        seed: u64,
    ) -> Result<Tensor> {
        if steps.is_empty() || steps.windows(2).any(|w| w[0] >= w[1]) {
            return Err(Error::InvalidConfig {
                name: "DDIM steps",
                value: format!("{steps:?}"),
                hint: "give a non-empty, strictly increasing list of step indices, e.g. Diffusion::ddim_steps(k)",
            });
        }
        self.check_steps(steps)?;
        if !(eta.is_finite() && eta >= 0.0) {
            return Err(Error::InvalidConfig {
                name: "DDIM eta",
                value: eta.to_string(),
                hint: "use eta >= 0 (0: deterministic DDIM, 1: DDPM-like noise)",
            });
        }
        let prepared = self.prepare(cond, x_start, seed)?;
        let s = &self.schedule;
        let mut x = x_start.clone();
        for j in (0..steps.len()).rev() {
            let i = steps[j];
            let ab = s.alpha_bar(i);
            let ab_prev = if j > 0 { s.alpha_bar(steps[j - 1]) } else { 1.0 };
            let eps = self.eps_target(model, prepared.as_ref(), &x, i)?;
            let x0_hat = ((&x - (&eps * (1.0 - ab).sqrt())?)? / ab.sqrt())?;
            let sigma = eta * ((1.0 - ab_prev) / (1.0 - ab) * (1.0 - ab / ab_prev)).sqrt();
            let dir = (1.0 - ab_prev - sigma * sigma).max(0.0).sqrt();
            x = ((x0_hat * ab_prev.sqrt())? + (eps * dir)?)?;
            if sigma > 0.0 {
                let xi = noise_like(&x, seed, i as u64)?;
                x = (x + (xi * sigma)?)?;
            }
        }
        check_finite(&x)?;
        Ok(x)
    }
}

fn check_finite(x: &Tensor) -> Result<()> {
    let s = x.abs()?.sum_all()?.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
    if !s.is_finite() {
        return Err(Error::NonFinite { what: "diffusion sample".into(), step: 0 });
    }
    Ok(())
}
