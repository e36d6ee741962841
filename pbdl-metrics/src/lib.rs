//! # pbdl-metrics
//!
//! Distances between physical fields: the classic pointwise, structural, statistical and spectral
//! metrics, and the learned metrics LSiM (2D, Kohl et al., ICML 2020) and VolSiM (3D, Kohl et al.,
//! AAAI 2023) evaluated from their published weights.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`classic`] | [`classic::mse`], [`classic::mae`], [`classic::rmse`], [`classic::rel_l2`], [`classic::psnr`] per sample of a batch of 1D/2D/3D fields (differentiable) |
//! | [`classic::ssim`] | [`classic::ssim2d`], [`classic::ssim3d`]: Gaussian-window SSIM (Wang et al. 2004), differentiable |
//! | [`classic::correlation`] | Pearson (differentiable) and Spearman (average ranks for ties) correlation, per sample and of plain value lists |
//! | [`classic::spectrum`] | radially averaged energy spectrum (FFT, Parseval-normalised) and a log-spectral error |
//! | [`classic::temporal`] | temporal stability of a rollout, `mean |s_t - s_(t-1)| / dt` |
//! | [`lsim`] | [`Lsim`]: the published LSiM metric from `LSiM.safetensors`, default (224, nearest) and native-size paths, per-pair or official whole-batch normalisation, differentiable |
//! | [`volsim`] | [`Volsim`]: VolSiM (3D) from `VolSiM_MS_3scales.safetensors`, any number of scales, native size or the official cubic-spline resize to 64^3 ([`Volsim::with_resize`]), differentiable; 1-channel and constant volumes work |
//! | [`NormScope`] | per-pair (default) or official whole-call input normalisation, for both learned metrics |
//! | [`convert`] | the official legacy `.pth` checkpoints (our own pickle reader) to the safetensors layout of [`weights`]; `cargo xtask weights convert` |
//! | [`weights`] | reading the converted safetensors weight files with typed errors; where the default weights live |
//! | [`mod@pool`] | re-export of [`pbdl_core::nn::max_pool2d`] (overlapping windows with a backward; candle's has none for kernel != stride) |
//! | [`files`] | [`files::read_field`] (`.npy`/`.npz`/`.png`) and [`files::compare`]: any metric on two arrays from files, the library side of `cargo xtask metric` |
//! | [`temporal`] | video/sequence metrics: a dense optical flow ([`temporal::optical_flow`], coarse-to-fine Horn–Schunck with warping), TecoGAN's tOF, tLSiM (TecoGAN's tLP with LSiM in place of LPIPS), per-frame PSNR/SSIM/LSiM, [`temporal::TemporalScores`] |
//! | [`error`] | [`Error`], [`Result`] |
//! | [`train`] | training a metric from scratch: solver-generated sequences, LSiM/VolSiM losses and "fit2" ground truth, calibration, Spearman evaluation |
//!
//! Conventions: fields are candle tensors `[batch, channel, (z,) (y,) x]`, x fastest, `f32` or
//! `f64`; a metric returns one value per batch entry. Bad input (mismatched shapes, NaN/Inf,
//! empty tensors, unsupported dtypes, a weight file that does not fit) is a typed [`Error`].
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_metrics::classic::{mse, pearson, ssim2d, SsimConfig};
//!
//! let dev = Device::Cpu;
//! let a = Tensor::arange(0f64, 256.0, &dev)?.reshape((1, 1, 16, 16))?;
//! let b = ((&a * 2.0)? + 1.0)?; // a linear map of a
//! assert_eq!(mse(&a, &a)?.to_vec1::<f64>()?, [0.0]);
//! assert!((pearson(&a, &b)?.to_vec1::<f64>()?[0] - 1.0).abs() < 1e-12);
//! let s = ssim2d(&a, &a, &SsimConfig::default())?.to_vec1::<f64>()?[0];
//! assert!((s - 1.0).abs() < 1e-12);
//! # Ok::<(), pbdl_metrics::Error>(())
//! ```
#![warn(missing_docs)]

mod check;
pub mod classic;
pub mod convert;
pub mod error;
pub mod files;
mod learned;
pub mod lsim;
pub mod pool;
pub mod temporal;
pub mod train;
pub mod volsim;
pub mod weights;

pub use error::{Error, Result};
pub use learned::NormScope;
pub use lsim::{Lsim, LsimOptions, LsimSize};
pub use volsim::{Volsim, VolsimOptions};
