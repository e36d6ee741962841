//! The WeatherBench baseline CNN (Rasp et al. 2020, notebook 3): a stack of periodic
//! convolutions with ELU between them and none after the last, no normalisation. The
//! published configuration is filters 64, 64, 64, 64, 2 with kernel 5 on z500 and t850 at one
//! time ([`CnnConfig::weatherbench`], 313,858 parameters), one network per lead time, trained
//! with Adam at 1e-4 on the MSE.

use crate::error::{Error, Result};
use crate::forecaster::model::{core_err, nets_err};
use crate::forecaster::Forecaster;
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::Activation;
use pbdl_nets::{PaddedConv2d, Padding};
use serde::{Deserialize, Serialize};

/// Layers of the CNN.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CnnConfig {
    /// Input channels.
    pub in_channels: usize,
    /// Output channels of each layer; the last is the number of predicted variables.
    pub filters: Vec<usize>,
    /// Odd kernel size of every layer.
    pub kernel: usize,
}

impl CnnConfig {
    /// WeatherBench's CNN: 2 inputs (z500, t850), filters 64, 64, 64, 64, 2, kernel 5.
    pub fn weatherbench() -> Self {
        Self { in_channels: 2, filters: vec![64, 64, 64, 64, 2], kernel: 5 }
    }
}

/// The WeatherBench CNN `[B, in, lat, lon] -> [B, filters.last(), lat, lon]`.
#[derive(Clone, Debug)]
pub struct WeatherCnn {
    config: CnnConfig,
    layers: Vec<PaddedConv2d>,
}

impl WeatherCnn {
    /// Builds the layers under `vb` (`conv<i>.*`).
    pub fn new(config: CnnConfig, vb: VarBuilder) -> Result<Self> {
        if config.filters.is_empty() || config.filters.contains(&0) || config.in_channels == 0 || config.kernel % 2 == 0
        {
            return Err(Error::InvalidArgument(format!(
                "CNN needs channels > 0, at least one layer and an odd kernel: {config:?}"
            )));
        }
        let mut c_in = config.in_channels;
        let mut layers = Vec::new();
        for (i, &c_out) in config.filters.iter().enumerate() {
            layers.push(
                PaddedConv2d::same(c_in, c_out, config.kernel, Padding::PeriodicX, vb.pp(format!("conv{i}")))
                    .map_err(nets_err)?,
            );
            c_in = c_out;
        }
        Ok(Self { config, layers })
    }

    /// The configuration.
    pub fn config(&self) -> &CnnConfig {
        &self.config
    }
}

impl Forecaster for WeatherCnn {
    fn in_channels(&self) -> usize {
        self.config.in_channels
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "cnn": self.config })
    }

    fn forward(&self, x: &Tensor, _train: bool, _seed: u64) -> Result<Tensor> {
        let last = self.layers.len() - 1;
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = if i < last {
                Activation::Elu { alpha: 1.0 }.apply(&layer.forward(&h).map_err(nets_err)?).map_err(core_err)?
            } else {
                layer.forward(&h).map_err(nets_err)?
            };
        }
        Ok(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn weatherbench_cnn_has_its_parameter_count_and_keeps_the_grid() {
        let varmap = VarMap::new();
        let net =
            WeatherCnn::new(CnnConfig::weatherbench(), VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))
                .unwrap();
        // 2*64*25+64 + 3*(64*64*25+64) + 64*2*25+2
        assert_eq!(pbdl_nets::count_parameters(&varmap), 313_858);
        let x = Tensor::zeros((1, 2, 32, 64), DType::F32, &Device::Cpu).unwrap();
        assert_eq!(net.forward(&x, false, 0).unwrap().dims(), &[1, 2, 32, 64]);
    }
}
