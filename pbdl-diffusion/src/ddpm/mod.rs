//! The epsilon-prediction objective and the DDPM / DDIM samplers.
//!
//! TODO(core helper): training loss (MSE / Huber), ancestral DDPM, DDIM, conditioning.

use crate::Result;
use candle_core::Tensor;

/// A network that predicts the noise `eps` from a noisy input and the diffusion step.
///
/// `x` is `[B, C_in, H, W]` (the noisy target with any conditioning channels concatenated in
/// front), `t` is `[B]` (`f32`, the step index `0..R`). The output has the channels of the
/// part the model denoises (for ACDM's noisy conditioning that is all of `C_in`).
pub trait NoisePredictor {
    /// Predicts the noise.
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor>;
}
pub(crate) mod entries;
