//! # pbdl-latent
//!
//! Latent-space physics (Wiewel, Becher & Thuerey, Eurographics 2019): a convolutional
//! autoencoder compresses the pressure field of a smoke solver to a short code, an LSTM predicts
//! the next code from the last few, and inside the solver loop the decoded prediction replaces
//! the pressure solve on all but every `i`-th step. The solver is pbdl-grid's `Fluid`
//! (`pbdl_grid::Fluid`), entered through its pressure split, never copied.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | buoyant smoke plumes (one scene per inflow position) with every step's pressure |
//! | [`autoencoder`] | the strided-conv autoencoder of a field to a flat code |
//! | [`data3d`] | 3D buoyant smoke plumes ([`pbdl_grid::grid3d::Smoke3d`], one scene per inflow position) with every step's pressure |
//! | [`autoencoder3d`] | the strided-conv3d autoencoder of a 3D field to a flat code, its training and held-out error |
//! | [`predictor`] | the encoder/decoder LSTM over a window of past codes |
//! | [`model`] | autoencoder + predictor + scales, saved and loaded as checkpoints |
//! | [`train`] | both training phases on pbdl-core's resumable training loop |
//! | [`hybrid`] | [`hybrid::HybridSmoke`]: the solver with predicted pressures, a `Stepper` |
//! | [`eval`] | reconstruction, one-step prediction and rollout scores against the solver |
//! | [`lss`] | latent space subdivision (Wiewel et al. 2020): split velocity/density/parameter code, rollout, swap and parameter scores |
//! | [`error`] | [`Error`], [`Result`] |
//!
//! ```no_run
//! use pbdl_latent::data::{generate, PlumeData};
//! use pbdl_latent::eval::{autoencoder_error, rollout};
//! use pbdl_latent::hybrid::Schedule;
//! use pbdl_latent::train::{train, LatentTrainConfig};
//!
//! let data = generate(&PlumeData::default())?;
//! let model = train(&data, &LatentTrainConfig::default(), None)?;
//! println!("held-out reconstruction error {:.3}", autoencoder_error(&model, &data.test)?);
//! let scene = data.config.scene(data.test[0].param);
//! let score = rollout(&model, &scene, Schedule { warmup: 50, interval: 2 }, 150)?;
//! println!("density error vs the solver {:.3}", score.density_error_max);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```
#![warn(missing_docs)]

pub mod autoencoder;
pub mod autoencoder3d;
pub mod data;
pub mod data3d;
pub mod error;
pub mod eval;
pub mod hybrid;
pub mod lss;
pub mod model;
pub mod predictor;
pub mod train;

pub use error::{Error, Result};
