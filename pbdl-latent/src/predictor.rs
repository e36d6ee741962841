//! The LSTM that predicts the next latent code from a window of past codes.
//!
//! As in latent-space physics (Wiewel et al. 2019): an encoder LSTM reads the `window` previous
//! codes in reversed order (newest first) and keeps its last hidden state; a decoder LSTM takes
//! that state as its input for the one output step; a dense layer (the paper's 1x1 Conv1D) maps
//! the decoder's output to the code. The paper uses 256 and 512 units and a window of 6.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::VarMap;
//! use pbdl_latent::predictor::{LatentPredictor, PredictorConfig};
//!
//! let cfg = PredictorConfig { code_size: 10, window: 3, encoder_units: 8, decoder_units: 12, residual: false };
//! let varmap = VarMap::new();
//! let lstm = LatentPredictor::new(cfg, &varmap, 0)?;
//! let history = Tensor::zeros((2, 3, 10), DType::F32, &Device::Cpu)?; // [batch, window, code]
//! assert_eq!(lstm.forward(&history)?.dims(), [2, 10]);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_nets::recurrent::{Lstm, LstmConfig};
use pbdl_nets::Linear;
use serde::{Deserialize, Serialize};

/// Layout of a [`LatentPredictor`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictorConfig {
    /// Entries of a code (the autoencoder's `code_size`). Default 128.
    pub code_size: usize,
    /// Past codes the prediction reads (>= 1). Default 6 (the paper's).
    pub window: usize,
    /// Units of the encoder LSTM. Default 256 (the paper's).
    pub encoder_units: usize,
    /// Units of the decoder LSTM. Default 512 (the paper's).
    pub decoder_units: usize,
    /// Predict the change from the newest code instead of the code itself (not the paper's
    /// choice, which is `false`, the default): the network then starts from persistence.
    pub residual: bool,
}

impl Default for PredictorConfig {
    fn default() -> Self {
        Self { code_size: 128, window: 6, encoder_units: 256, decoder_units: 512, residual: false }
    }
}

/// Encoder LSTM, decoder LSTM and the dense output (see the module docs).
#[derive(Clone, Debug)]
pub struct LatentPredictor {
    encoder: Lstm,
    decoder: Lstm,
    output: Linear,
    config: PredictorConfig,
}

impl LatentPredictor {
    /// Builds the network with its variables in `varmap` (f32), initialised from `seed`.
    pub fn new(config: PredictorConfig, varmap: &VarMap, seed: u64) -> Result<Self> {
        if config.window == 0 || config.code_size == 0 || config.encoder_units == 0 || config.decoder_units == 0 {
            return Err(Error::config("PredictorConfig", format!("{config:?}: every size must be positive")));
        }
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let encoder = Lstm::new(LstmConfig::new(config.code_size, config.encoder_units), vb.pp("encoder"))?;
        let decoder = Lstm::new(LstmConfig::new(config.encoder_units, config.decoder_units), vb.pp("decoder"))?;
        let output = Linear::new(config.decoder_units, config.code_size, vb.pp("output"))?;
        pbdl_nets::seeded_init(varmap, seed)?;
        Ok(Self { encoder, decoder, output, config })
    }

    /// The layout.
    pub fn config(&self) -> &PredictorConfig {
        &self.config
    }

    /// Past codes `[B, window, code]`, oldest first -> the next code `[B, code]`.
    pub fn forward(&self, history: &Tensor) -> Result<Tensor> {
        let c = &self.config;
        let d = history.dims();
        if d.len() != 3 || d[1] != c.window || d[2] != c.code_size {
            return Err(Error::Shape {
                what: "latent history",
                expected: format!("[batch, {}, {}] (oldest first)", c.window, c.code_size),
                got: d.to_vec(),
            });
        }
        let reversed: Vec<Tensor> =
            (0..c.window).rev().map(|t| history.narrow(1, t, 1)).collect::<candle_core::Result<_>>()?;
        let enc = self.encoder.forward(&Tensor::cat(&reversed, 1)?, None)?;
        let summary = enc.states[0].h.unsqueeze(1)?; // [B, 1, encoder_units]
        let dec = self.decoder.forward(&summary, None)?;
        let out = self.output.forward(&dec.output.squeeze(1)?)?;
        Ok(if c.residual { (out + history.narrow(1, c.window - 1, 1)?.squeeze(1)?)? } else { out })
    }
}
