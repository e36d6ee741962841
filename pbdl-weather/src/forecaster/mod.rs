//! The Rasp & Thuerey (2021) forecaster: a ResNet on lat-lon fields at several past times
//! plus constants, optionally with a continuous lead time, trained with a latitude-weighted MSE.
//!
//! | module | what it gives you |
//! |---|---|
//! | [`cnn`] | [`WeatherCnn`], WeatherBench's baseline CNN (periodic convs, ELU) |
//! | [`data`] | [`Dataset`] `[time, variable, lat, lon]` + constants, [`Normalizer`], [`SampleSpec`] (history, fixed or continuous lead, targets) |
//! | [`model`] | [`WeatherResNet`] and [`ResNetConfig`] (full size with the paper's parameter count, CPU size) |
//! | [`train`](mod@train) | latitude-weighted MSE, Adam, reduce-on-plateau, early stopping, checkpoints and resume; [`train::predict`] |

pub mod cnn;
pub mod data;
pub mod model;
pub mod train;

pub use cnn::{CnnConfig, WeatherCnn};
pub use data::{Dataset, Lead, Normalizer, SampleSpec};
pub use model::{ResNetConfig, WeatherResNet};
pub use train::{predict, train, TrainConfig, TrainState};

/// A network that maps a normalised input batch `[B, in, lat, lon]` to the normalised targets.
pub trait Forecaster {
    /// Input channels it expects.
    fn in_channels(&self) -> usize;
    /// The forecast; `train` selects training behaviour (batch statistics, dropout from `seed`).
    fn forward(&self, x: &candle_core::Tensor, train: bool, seed: u64) -> crate::Result<candle_core::Tensor>;
    /// Its configuration as JSON (stored with checkpoints).
    fn describe(&self) -> serde_json::Value;
}

impl Forecaster for WeatherResNet {
    fn in_channels(&self) -> usize {
        self.config().in_channels
    }

    fn forward(&self, x: &candle_core::Tensor, train: bool, seed: u64) -> crate::Result<candle_core::Tensor> {
        WeatherResNet::forward(self, x, train, seed)
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "resnet": self.config() })
    }
}
