//! Classic field metrics for batched 1D, 2D and 3D fields.
//!
//! Every function takes fields laid out `[batch, channel, (z,) (y,) x]` (1 to 3 spatial axes),
//! `f32` or `f64`, and returns one value per batch entry. Those that return a [`Tensor`] are
//! candle expressions and differentiable (use them as losses); the rank-based and FFT-based ones
//! return plain numbers.
//!
//! | function | definition per sample (means over channels and space) |
//! |---|---|
//! | [`mse`] | `mean (a - b)^2` |
//! | [`mae`] | `mean |a - b|` |
//! | [`rmse`] | `sqrt(mse)` |
//! | [`rel_l2`] | `||a - b||_2 / ||b||_2` (`b` is the reference) |
//! | [`psnr`] | `10 log10(R^2 / mse)` with data range `R` |
//! | [`ssim2d`], [`ssim3d`] | mean SSIM over a Gaussian window (11, sigma 1.5), see [`ssim`] |
//! | [`pearson`], [`spearman`] | correlation of all values of the sample, see [`correlation`] |
//! | [`energy_spectrum`], [`spectral_error`] | radially averaged `0.5 |u_hat|^2` and a log-spectral distance, see [`spectrum`] |
//! | [`temporal_change`], [`temporal_stability`] | `mean |s_t - s_(t-1)| / dt`, see [`temporal`] |

pub mod correlation;
mod pointwise;
pub mod spectrum;
pub mod ssim;
pub mod temporal;

pub use correlation::{pearson, pearson_values, spearman, spearman_values};
pub use pointwise::{mae, mse, psnr, rel_l2, rmse};
pub use spectrum::{energy_spectrum, spectral_error, Spectrum};
pub use ssim::{ssim2d, ssim3d, ssim_nd, SsimConfig};
pub use temporal::{temporal_change, temporal_stability};

#[cfg(doc)]
use candle_core::Tensor;
