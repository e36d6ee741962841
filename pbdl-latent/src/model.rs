//! A trained latent-space model: the pressure autoencoder, the LSTM predictor and the two
//! scales they were trained with, saved and loaded as two checkpoints (safetensors + JSON
//! sidecar, written atomically).

use crate::autoencoder::{AutoencoderConfig, LatentAutoencoder};
use crate::predictor::{LatentPredictor, PredictorConfig};
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarMap;
use pbdl_core::io::{load_varmap, read_checkpoint_info, save_varmap, CheckpointMeta};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The scales that map solver values to network values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scales {
    /// The autoencoder sees `pressure / pressure`: the 99.9th percentile of `|p|` over the
    /// training frames (as the paper normalises).
    pub pressure: f32,
    /// The predictor sees `code / code`: the standard deviation of the training codes (the
    /// paper divides by a fixed 3.5).
    pub code: f32,
}

/// The autoencoder's sidecar config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct AeSidecar {
    autoencoder: AutoencoderConfig,
    pressure_scale: f32,
}

/// The predictor's sidecar config.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct PredictorSidecar {
    predictor: PredictorConfig,
    code_scale: f32,
}

/// Autoencoder + predictor + scales (see the module docs).
#[derive(Clone)]
pub struct LatentModel {
    /// The pressure autoencoder.
    pub autoencoder: LatentAutoencoder,
    /// Its variables.
    pub autoencoder_vars: VarMap,
    /// The LSTM over codes.
    pub predictor: LatentPredictor,
    /// Its variables.
    pub predictor_vars: VarMap,
    /// The normalisations.
    pub scales: Scales,
}

impl std::fmt::Debug for LatentModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LatentModel")
            .field("autoencoder", &self.autoencoder)
            .field("predictor", &self.predictor)
            .field("scales", &self.scales)
            .finish_non_exhaustive()
    }
}

impl LatentModel {
    /// [`AutoencoderConfig::for_resolution`]`(n, 8)` and the default predictor with untrained
    /// weights and unit scales: the architecture at its cost, for timings (the time does not
    /// depend on the weights' values).
    pub fn untrained(n: usize) -> Result<Self> {
        let autoencoder_vars = VarMap::new();
        let autoencoder = LatentAutoencoder::new(AutoencoderConfig::for_resolution(n, 8), &autoencoder_vars, 0)?;
        let predictor_vars = VarMap::new();
        let predictor = LatentPredictor::new(
            PredictorConfig { code_size: autoencoder.code_size(), ..PredictorConfig::default() },
            &predictor_vars,
            0,
        )?;
        let scales = Scales { pressure: 1.0, code: 1.0 };
        Ok(Self { autoencoder, autoencoder_vars, predictor, predictor_vars, scales })
    }

    /// The normalised code `[B, code]` of pressures `[B, 1, n, n]` in solver units.
    pub fn encode_pressure(&self, p: &Tensor) -> Result<Tensor> {
        let z = self.autoencoder.encode(&(p / self.scales.pressure as f64)?)?;
        Ok((z / self.scales.code as f64)?)
    }

    /// Pressures `[B, 1, n, n]` in solver units from normalised codes `[B, code]`.
    pub fn decode_pressure(&self, z: &Tensor) -> Result<Tensor> {
        let p = self.autoencoder.decode(&(z * self.scales.code as f64)?)?;
        Ok((p * self.scales.pressure as f64)?)
    }

    /// The next normalised code from the last `window` normalised codes `[B, window, code]`.
    pub fn predict(&self, history: &Tensor) -> Result<Tensor> {
        self.predictor.forward(history)
    }

    /// Writes `autoencoder.safetensors` and `predictor.safetensors` (each with its JSON
    /// sidecar) into `dir`, atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir)
            .map_err(|e| Error::config("model dir", format!("{}: {e}; use a writable directory", dir.display())))?;
        let ae = AeSidecar { autoencoder: self.autoencoder.config().clone(), pressure_scale: self.scales.pressure };
        let meta = |config| CheckpointMeta { step: 0, seed: None, config };
        save_varmap(dir.join("autoencoder.safetensors"), &self.autoencoder_vars, &meta(to_value(&ae)?))?;
        let pr = PredictorSidecar { predictor: self.predictor.config().clone(), code_scale: self.scales.code };
        save_varmap(dir.join("predictor.safetensors"), &self.predictor_vars, &meta(to_value(&pr)?))?;
        Ok(())
    }

    /// Reads a model written by [`LatentModel::save`]. A missing or corrupt file, or a sidecar
    /// that does not describe the stored tensors, is a typed error naming the file.
    pub fn load(dir: &Path) -> Result<Self> {
        let ae_path = dir.join("autoencoder.safetensors");
        let ae: AeSidecar = from_value(&ae_path, read_checkpoint_info(&ae_path)?.config)?;
        let autoencoder_vars = VarMap::new();
        let autoencoder = LatentAutoencoder::new(ae.autoencoder, &autoencoder_vars, 0)?;
        load_varmap(&ae_path, &autoencoder_vars)?;
        let pr_path = dir.join("predictor.safetensors");
        let pr: PredictorSidecar = from_value(&pr_path, read_checkpoint_info(&pr_path)?.config)?;
        let predictor_vars = VarMap::new();
        let predictor = LatentPredictor::new(pr.predictor, &predictor_vars, 0)?;
        load_varmap(&pr_path, &predictor_vars)?;
        if predictor.config().code_size != autoencoder.code_size() {
            return Err(Error::config(
                "model",
                format!(
                    "{}: the predictor reads codes of {} entries, the autoencoder writes {}; save both from one training",
                    dir.display(),
                    predictor.config().code_size,
                    autoencoder.code_size()
                ),
            ));
        }
        let scales = Scales { pressure: ae.pressure_scale, code: pr.code_scale };
        Ok(Self { autoencoder, autoencoder_vars, predictor, predictor_vars, scales })
    }
}

fn to_value<T: Serialize>(t: &T) -> Result<serde_json::Value> {
    serde_json::to_value(t).map_err(|e| Error::config("model", format!("does not serialise: {e}")))
}

fn from_value<T: serde::de::DeserializeOwned>(path: &Path, v: serde_json::Value) -> Result<T> {
    serde_json::from_value(v).map_err(|e| {
        Error::config(
            "model",
            format!("{}: the sidecar is not a pbdl-latent model ({e}); retrain or pick the right file", path.display()),
        )
    })
}
