//! The Rasp & Thuerey (2021) forecaster: a ResNet on lat-lon fields at several past times
//! plus constants, optionally with a continuous lead time, trained with a latitude-weighted MSE.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`data`] | [`Dataset`] `[time, variable, lat, lon]` + constants, [`Normalizer`], [`SampleSpec`] (history, fixed or continuous lead, targets) |
//! | [`model`] | [`WeatherResNet`] and [`ResNetConfig`] (full size with the paper's parameter count, CPU size) |
//! | [`train`] | latitude-weighted MSE, Adam, reduce-on-plateau, early stopping, checkpoints and resume; [`train::predict`] |

pub mod data;
pub mod model;
pub mod train;

pub use data::{Dataset, Lead, Normalizer, SampleSpec};
pub use model::{ResNetConfig, WeatherResNet};
pub use train::{predict, train, TrainConfig, TrainState};
