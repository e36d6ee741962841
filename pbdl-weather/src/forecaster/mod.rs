//! The Rasp & Thuerey (2021) forecaster: a ResNet on lat-lon fields at several past times
//! plus constants, optionally with a continuous lead time, trained with a latitude-weighted MSE.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`model`] | [`WeatherResNet`] and [`ResNetConfig`] (full size with the paper's parameter count, CPU size) |

pub mod model;

pub use model::{ResNetConfig, WeatherResNet};
