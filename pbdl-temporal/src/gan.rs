//! The adversarial parts of tempoGAN: the spatial discriminator's conditioned input, the
//! temporal discriminator's advected triplets, the losses of both players and the balance
//! of discriminator updates.
//!
//! * Spatial discriminator `D_s`: the nearest-upsampled low-resolution density next to a
//!   high-resolution frame (2 channels): "is this a plausible detailed version of that input?"
//! * Temporal discriminator `D_t`: frames `t-1`, `t`, `t+1`, the outer two advected to time `t`
//!   with the known (upsampled low-resolution) velocity by semi-Lagrangian steps (3 channels):
//!   "do these frames move consistently with the flow?" Real triplets are aligned up to the
//!   advection's error; flickering details are not.
//! * Losses: sigmoid cross entropy for both players; the generator also gets L1 to the truth
//!   and a feature-space term on `D_s`'s levels (`sum_l mean |phi_l(real) - phi_l(fake)|`,
//!   weight `lambda_f`; tempoGAN's 2D example uses a small negative weight).
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use pbdl_temporal::gan::temporal_input;
//!
//! let hr = Tensor::rand(0f32, 1.0, (3, 1, 16, 16), &Device::Cpu)?; // frames t-1, t, t+1
//! let v = Tensor::zeros((3, 2, 4, 4), DType::F32, &Device::Cpu)?; // no motion
//! let x = temporal_input(&hr, &v, 4)?;
//! assert_eq!(x.dims(), [1, 3, 16, 16]);
//! // Without motion the advected frames are the frames themselves.
//! assert_eq!(x.flatten_all()?.to_vec1::<f32>()?, hr.flatten_all()?.to_vec1::<f32>()?);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

use crate::warp::{advect, upsample_motion};
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_nets::resample::upsample_nearest2;
use serde::{Deserialize, Serialize};

/// The `D_s` input `[B, 2, F y, F x]`: nearest-upsampled `lr` `[B, 1, y, x]` and `hr`.
pub fn spatial_input(lr: &Tensor, hr: &Tensor, factor: usize) -> Result<Tensor> {
    let mut up = lr.clone();
    let mut f = 1;
    while f < factor {
        up = upsample_nearest2(&up)?;
        f *= 2;
    }
    if up.dims() != hr.dims() {
        return Err(Error::input("hr", format!("{:?} does not match the upsampled input {:?}", hr.dims(), up.dims())));
    }
    Ok(Tensor::cat(&[&up, hr], 1)?)
}

/// The `D_t` input `[B, 3, Y, X]` from `hr` `[3 B, 1, Y, X]` (triplets `t-1, t, t+1` one after
/// the other) and the low-resolution velocity `lr_velocity` `[3 B, 2, y, x]` (cells per frame)
/// of the same frames: frame `t-1` advected one frame forward with its velocity, frame `t`,
/// frame `t+1` advected one frame back with its velocity.
pub fn temporal_input(hr: &Tensor, lr_velocity: &Tensor, factor: usize) -> Result<Tensor> {
    let d = hr.dims();
    if d.len() != 4 || d[0] % 3 != 0 || d[0] == 0 || d[1] != 1 {
        return Err(Error::input("hr", format!("{d:?}: expected [3 B, 1, Y, X] (triplets of frames)")));
    }
    let b = d[0] / 3;
    let v = upsample_motion(lr_velocity, factor)?;
    if v.dims()[0] != d[0] || v.dims()[2..] != d[2..] {
        return Err(Error::input(
            "velocity",
            format!("{:?} does not fit frames {d:?} at factor {factor}", lr_velocity.dims()),
        ));
    }
    let frames = hr.reshape((b, 3, d[2], d[3]))?;
    let vel = v.reshape((b, 3, 2, d[2], d[3]))?;
    let pick = |k: usize| -> Result<(Tensor, Tensor)> {
        Ok((frames.narrow(1, k, 1)?.contiguous()?, vel.narrow(1, k, 1)?.squeeze(1)?.contiguous()?))
    };
    let (prev, v_prev) = pick(0)?;
    let (mid, _) = pick(1)?;
    let (next, v_next) = pick(2)?;
    let fwd = advect(&prev, &v_prev, 1.0)?;
    let bwd = advect(&next, &v_next, -1.0)?;
    Ok(Tensor::cat(&[&fwd, &mid, &bwd], 1)?)
}

/// Weights of the generator's loss terms (tempoGAN's 2D settings by default, with the
/// adversarial weight explicit).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LossWeights {
    /// L1 to the high-resolution truth. Default 5 (tempoGAN).
    pub l1: f64,
    /// The spatial adversarial term. Default 1.
    pub spatial: f64,
    /// The temporal adversarial term (used only by the temporal GAN). Default 1 (tempoGAN).
    pub temporal: f64,
    /// The feature-space term on `D_s`'s levels. Default -1e-5 (tempoGAN's 2D example).
    pub feature: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self { l1: 5.0, spatial: 1.0, temporal: 1.0, feature: -1e-5 }
    }
}

impl LossWeights {
    /// Checks that every weight is finite and the content and adversarial ones are >= 0.
    pub fn validate(&self) -> Result<()> {
        let ok = [self.l1, self.spatial, self.temporal].iter().all(|w| *w >= 0.0 && w.is_finite())
            && self.feature.is_finite();
        if !ok {
            return Err(Error::config("loss", format!("{self:?}: use finite weights, l1 / spatial / temporal >= 0")));
        }
        Ok(())
    }
}

/// `sum_l mean |real_l - fake_l|` over matching feature maps.
pub fn feature_loss(real: &[Tensor], fake: &[Tensor]) -> Result<Tensor> {
    if real.len() != fake.len() || real.is_empty() {
        return Err(Error::input("features", format!("{} real vs {} fake levels", real.len(), fake.len())));
    }
    let mut total = (real[0].broadcast_sub(&fake[0])?).abs()?.mean_all()?;
    for (r, f) in real.iter().zip(fake).skip(1) {
        total = (total + (r - f)?.abs()?.mean_all()?)?;
    }
    Ok(total)
}

/// TecoGAN's discriminator balance: a moving average (decay 0.99) of
/// `mean log D(real) + L_adv` (the generator's adversarial loss); the discriminator trains only
/// while it is below the threshold (0.4), i.e. while the generator is not already losing badly.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Balance {
    /// The moving average (starts at 0).
    pub average: f64,
    /// Decay of the average. Default 0.99.
    pub decay: f64,
    /// Train the discriminator while `average < threshold`. Default 0.4.
    pub threshold: f64,
}

impl Default for Balance {
    fn default() -> Self {
        Self { average: 0.0, decay: 0.99, threshold: 0.4 }
    }
}

impl Balance {
    /// Whether the discriminator should update now.
    pub fn train_discriminator(&self) -> bool {
        self.average < self.threshold
    }

    /// Folds in one update's `mean log D(real)` and generator adversarial loss.
    pub fn observe(&mut self, mean_log_d_real: f64, generator_adversarial: f64) {
        if (mean_log_d_real + generator_adversarial).is_finite() {
            self.average = self.decay * self.average + (1.0 - self.decay) * (mean_log_d_real + generator_adversarial);
        }
    }
}
