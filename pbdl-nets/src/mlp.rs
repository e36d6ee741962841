//! A multilayer perceptron `[batch, in] -> [batch, out]`: [`Linear`] layers with an activation
//! between them (and optionally after the last).

use crate::layers::Linear;
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::Activation;
use serde::{Deserialize, Serialize};

/// Configuration of an [`Mlp`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MlpConfig {
    /// Widths `[in, hidden.., out]`: `widths.len() - 1` layers; at least two entries.
    pub widths: Vec<usize>,
    /// Activation after every hidden layer.
    pub activation: Activation,
    /// Activation after the last layer ([`Activation::Identity`] for a plain regression head).
    pub output_activation: Activation,
}

impl MlpConfig {
    /// Layers of the given widths with `activation` between them and none after the last.
    pub fn new(widths: Vec<usize>, activation: Activation) -> Self {
        Self { widths, activation, output_activation: Activation::Identity }
    }

    /// `in -> hidden x depth -> out`: `depth` hidden layers of width `hidden`.
    pub fn uniform(input: usize, hidden: usize, depth: usize, output: usize, activation: Activation) -> Self {
        let mut widths = vec![input];
        widths.extend(std::iter::repeat_n(hidden, depth));
        widths.push(output);
        Self::new(widths, activation)
    }

    fn validate(&self) -> Result<()> {
        if self.widths.len() < 2 || self.widths.contains(&0) {
            return Err(Error::InvalidConfig {
                name: "MlpConfig::widths",
                value: format!("{:?}", self.widths),
                hint: "give at least the input and output widths, all positive, e.g. [2, 64, 64, 1]",
            });
        }
        Ok(())
    }
}

/// A multilayer perceptron; layer `i` takes its variables from `layers.{i}` (`weight`
/// `[out, in]`, `bias` `[out]`, PyTorch's `nn.Linear` initialisation).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_core::nn::Activation;
/// use pbdl_nets::mlp::{Mlp, MlpConfig};
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let mlp = Mlp::new(MlpConfig::uniform(3, 32, 2, 1, Activation::Tanh), vb)?;
/// pbdl_nets::seeded_init(&varmap, 0)?;
/// let y = mlp.forward(&Tensor::zeros((5, 3), DType::F32, &Device::Cpu)?)?;
/// assert_eq!(y.dims(), &[5, 1]);
/// assert_eq!(pbdl_nets::count_parameters(&varmap), 3 * 32 + 32 + 32 * 32 + 32 + 32 + 1);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Mlp {
    config: MlpConfig,
    layers: Vec<Linear>,
}

impl Mlp {
    /// Builds the layers, taking (or creating) their variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for fewer than two widths or a zero width.
    pub fn new(config: MlpConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let layers = config
            .widths
            .windows(2)
            .enumerate()
            .map(|(i, w)| Linear::new(w[0], w[1], vb.pp(format!("layers.{i}"))))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { config, layers })
    }

    /// The configuration.
    pub fn config(&self) -> &MlpConfig {
        &self.config
    }

    /// The network on `x` `[batch, in]`; returns `[batch, out]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for an input that is not `[batch, in]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let input = self.config.widths[0];
        if x.rank() != 2 || x.dim(1)? != input {
            return Err(Error::shape("Mlp input", format!("[batch, {input}]"), x.dims()));
        }
        let last = self.layers.len() - 1;
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            let act = if i < last { self.config.activation } else { self.config.output_activation };
            h = act.apply(&h)?;
        }
        Ok(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    #[test]
    fn shapes_and_errors() {
        let vb = VarBuilder::zeros(DType::F32, &Device::Cpu);
        let mlp = Mlp::new(MlpConfig::new(vec![4, 7, 2], Activation::Relu), vb.clone()).unwrap();
        assert_eq!(mlp.forward(&Tensor::zeros((3, 4), DType::F32, &Device::Cpu).unwrap()).unwrap().dims(), &[3, 2]);
        let wrong = Tensor::zeros((3, 5), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(mlp.forward(&wrong), Err(Error::ShapeMismatch { .. })));
        assert!(matches!(Mlp::new(MlpConfig::new(vec![4], Activation::Relu), vb), Err(Error::InvalidConfig { .. })));
        let cfg = MlpConfig { output_activation: Activation::Sigmoid, ..MlpConfig::new(vec![4, 2], Activation::Relu) };
        let json = serde_json::to_string(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<MlpConfig>(&json).unwrap(), cfg);
    }
}
