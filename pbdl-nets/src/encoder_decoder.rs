//! A convolutional encoder to a latent map and a decoder back: the autoencoder of latent-space
//! methods (e.g. an LSTM that steps the latent state in time).
//!
//! With widths `[c_1, .., c_L]`:
//!
//! * [`ConvEncoder`]: level `i` is a 4x4 stride-2 conv (`c_{i-1} -> c_i`, `c_0` = input
//!   channels), an optional GroupNorm and the activation, halving height and width; then a 3x3
//!   conv `c_L -> latent_channels` without activation. `[B, C, H, W] -> [B, latent, H / 2^L,
//!   W / 2^L]`.
//! * [`ConvDecoder`]: a 3x3 conv `latent -> c_L` with norm and activation; level `i = L..1`
//!   doubles height and width (`c_i -> c_{i-1}`, `c_0` = `c_1`), with norm and activation; a
//!   3x3 conv `c_1 -> out_channels` without activation.
//!
//! The decoder doubles with a 4x4 stride-2 transposed conv ([`Upsampling::Transposed`]) or a
//! nearest 2x upsampling and a 3x3 conv ([`Upsampling::Nearest`]). Every conv pads as the
//! config's [`Padding`] says, except the transposed conv, which always pads with zeros
//! (`pbdl_core::conv::conv_transpose2d` has no periodic mode): use `Nearest` for periodic
//! domains. `H` and `W` must be multiples of `2^L`.

use crate::layers::ConvTranspose2d;
use crate::padding::{PaddedConv2d, Padding};
use crate::resample::upsample_nearest2;
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::{Activation, GroupNorm, GroupNormConfig};
use serde::{Deserialize, Serialize};

/// How the decoder doubles the resolution.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Upsampling {
    /// A 4x4 stride-2 transposed convolution (zero-padded border). The default.
    #[default]
    Transposed,
    /// Nearest-neighbour 2x upsampling followed by a 3x3 convolution.
    Nearest,
}

/// Configuration of a [`ConvEncoder`] / [`ConvDecoder`] pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncoderDecoderConfig {
    /// Channels of the encoder input.
    pub in_channels: usize,
    /// Channels of the decoder output (usually `in_channels`).
    pub out_channels: usize,
    /// Widths `[c_1, .., c_L]` of the `L` resolution levels.
    pub widths: Vec<usize>,
    /// Channels of the latent map.
    pub latent_channels: usize,
    /// Activation after each norm.
    pub activation: Activation,
    /// GroupNorm groups (dividing every width), or `None` for no norm.
    pub norm_groups: Option<usize>,
    /// How the decoder doubles the resolution.
    pub upsampling: Upsampling,
    /// Border handling of the convs.
    pub padding: Padding,
}

impl EncoderDecoderConfig {
    /// `channels` in and out, the given widths and latent channels, GELU, no norm, transposed
    /// convs, zero padding.
    pub fn new(channels: usize, widths: Vec<usize>, latent_channels: usize) -> Self {
        Self {
            in_channels: channels,
            out_channels: channels,
            widths,
            latent_channels,
            activation: Activation::Gelu,
            norm_groups: None,
            upsampling: Upsampling::Transposed,
            padding: Padding::Zeros,
        }
    }

    /// The factor by which height and width must be divisible (`2^L`).
    pub fn size_multiple(&self) -> usize {
        1 << self.widths.len()
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.widths.is_empty() || self.widths.contains(&0) {
            return bad("widths", format!("{:?}", self.widths), "use at least one positive width, e.g. [16, 32]");
        }
        if self.in_channels == 0 || self.out_channels == 0 || self.latent_channels == 0 {
            return bad(
                "channels",
                format!("{} -> latent {} -> {}", self.in_channels, self.latent_channels, self.out_channels),
                "use at least one channel in, in the latent and out",
            );
        }
        if let Some(g) = self.norm_groups {
            if g == 0 || self.widths.iter().any(|c| c % g != 0) {
                return bad("norm_groups", g.to_string(), "use a group count that divides every width");
            }
        }
        Ok(())
    }

    fn check_input(&self, what: &str, x: &Tensor, channels: usize, multiple: usize) -> Result<()> {
        let d = x.dims();
        if d.len() != 4 || d[1] != channels || d[2] == 0 || d[3] == 0 || d[2] % multiple != 0 || d[3] % multiple != 0 {
            return Err(Error::shape(
                format!("{what} (height and width must be positive multiples of {multiple})"),
                format!("[batch, {channels}, y, x]"),
                d,
            ));
        }
        Ok(())
    }
}

/// Norm and activation after a conv.
#[derive(Clone, Debug)]
struct NormAct {
    norm: Option<GroupNorm>,
    activation: Activation,
}

impl NormAct {
    fn new(cfg: &EncoderDecoderConfig, channels: usize, vb: VarBuilder) -> Result<Self> {
        let norm = cfg.norm_groups.map(|g| GroupNorm::new(g, channels, GroupNormConfig::default(), vb)).transpose()?;
        Ok(Self { norm, activation: cfg.activation })
    }

    fn forward(&self, h: &Tensor) -> Result<Tensor> {
        Ok(match &self.norm {
            Some(n) => n.apply_act(h, self.activation)?,
            None => self.activation.apply(h)?,
        })
    }
}

/// The strided conv encoder (see the module docs). Variables: `downs.{i}.conv.*`,
/// `downs.{i}.norm.*`, `to_latent.*`.
#[derive(Clone, Debug)]
pub struct ConvEncoder {
    config: EncoderDecoderConfig,
    downs: Vec<(PaddedConv2d, NormAct)>,
    to_latent: PaddedConv2d,
}

impl ConvEncoder {
    /// Builds the encoder, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for no or zero widths, zero channels or groups that do not
    /// divide the widths.
    pub fn new(config: EncoderDecoderConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let mut downs = Vec::with_capacity(config.widths.len());
        let mut c_prev = config.in_channels;
        for (i, &c) in config.widths.iter().enumerate() {
            let vb = vb.pp(format!("downs.{i}"));
            let conv = PaddedConv2d::new(c_prev, c, 4, 2, 1, config.padding, vb.pp("conv"))?;
            downs.push((conv, NormAct::new(&config, c, vb.pp("norm"))?));
            c_prev = c;
        }
        let to_latent = PaddedConv2d::same(c_prev, config.latent_channels, 3, config.padding, vb.pp("to_latent"))?;
        Ok(Self { config, downs, to_latent })
    }

    /// The latent map of `x` `[batch, in_channels, y, x]`: `[batch, latent_channels, y / 2^L,
    /// x / 2^L]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong shape, or a size that is not a multiple of `2^L`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let cfg = &self.config;
        cfg.check_input("ConvEncoder input", x, cfg.in_channels, cfg.size_multiple())?;
        let mut h = x.clone();
        for (conv, norm_act) in &self.downs {
            h = norm_act.forward(&conv.forward(&h)?)?;
        }
        self.to_latent.forward(&h)
    }
}

/// One decoder level's doubling layer.
#[derive(Clone, Debug)]
enum Up {
    Transposed(ConvTranspose2d),
    Nearest(PaddedConv2d),
}

/// The decoder back from the latent map (see the module docs). Variables: `from_latent.*`,
/// `from_latent_norm.*`, `ups.{j}.conv.*`, `ups.{j}.norm.*` (`j = 0` is the coarsest level),
/// `output.*`.
#[derive(Clone, Debug)]
pub struct ConvDecoder {
    config: EncoderDecoderConfig,
    from_latent: (PaddedConv2d, NormAct),
    ups: Vec<(Up, NormAct)>,
    output: PaddedConv2d,
}

impl ConvDecoder {
    /// Builds the decoder, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// As [`ConvEncoder::new`].
    pub fn new(config: EncoderDecoderConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let w = &config.widths;
        let top = w[w.len() - 1];
        let from_latent = (
            PaddedConv2d::same(config.latent_channels, top, 3, config.padding, vb.pp("from_latent"))?,
            NormAct::new(&config, top, vb.pp("from_latent_norm"))?,
        );
        let mut ups = Vec::with_capacity(w.len());
        for (j, i) in (0..w.len()).rev().enumerate() {
            let (c_in, c_out) = (w[i], w[i.saturating_sub(1)]);
            let vb = vb.pp(format!("ups.{j}"));
            let up = match config.upsampling {
                Upsampling::Transposed => Up::Transposed(ConvTranspose2d::new(vb.pp("conv"), c_in, c_out, 4, 2, 1)?),
                Upsampling::Nearest => Up::Nearest(PaddedConv2d::same(c_in, c_out, 3, config.padding, vb.pp("conv"))?),
            };
            ups.push((up, NormAct::new(&config, c_out, vb.pp("norm"))?));
        }
        let output = PaddedConv2d::same(w[0], config.out_channels, 3, config.padding, vb.pp("output"))?;
        Ok(Self { config, from_latent, ups, output })
    }

    /// The decoded field of a latent map `z` `[batch, latent_channels, y, x]`: `[batch,
    /// out_channels, y 2^L, x 2^L]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong shape.
    pub fn forward(&self, z: &Tensor) -> Result<Tensor> {
        let cfg = &self.config;
        cfg.check_input("ConvDecoder latent", z, cfg.latent_channels, 1)?;
        let mut h = self.from_latent.1.forward(&self.from_latent.0.forward(z)?)?;
        for (up, norm_act) in &self.ups {
            h = match up {
                Up::Transposed(conv) => conv.forward(&h)?,
                Up::Nearest(conv) => conv.forward(&upsample_nearest2(&h)?)?,
            };
            h = norm_act.forward(&h)?;
        }
        self.output.forward(&h)
    }
}

/// An encoder and a decoder built from one config (variables `encoder.*`, `decoder.*`).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::encoder_decoder::{Autoencoder, EncoderDecoderConfig};
///
/// let varmap = VarMap::new();
/// let cfg = EncoderDecoderConfig::new(2, vec![8, 16], 4);
/// let ae = Autoencoder::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?;
/// pbdl_nets::seeded_init(&varmap, 0)?;
/// let x = Tensor::zeros((3, 2, 32, 16), DType::F32, &Device::Cpu)?;
/// let z = ae.encoder().forward(&x)?;
/// assert_eq!(z.dims(), &[3, 4, 8, 4]);
/// assert_eq!(ae.decoder().forward(&z)?.dims(), &[3, 2, 32, 16]);
/// assert_eq!(ae.forward(&x)?.dims(), &[3, 2, 32, 16]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Autoencoder {
    encoder: ConvEncoder,
    decoder: ConvDecoder,
}

impl Autoencoder {
    /// Builds both halves, taking (or creating) their variables in `vb`.
    ///
    /// # Errors
    /// As [`ConvEncoder::new`].
    pub fn new(config: EncoderDecoderConfig, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            encoder: ConvEncoder::new(config.clone(), vb.pp("encoder"))?,
            decoder: ConvDecoder::new(config, vb.pp("decoder"))?,
        })
    }

    /// The encoder.
    pub fn encoder(&self) -> &ConvEncoder {
        &self.encoder
    }

    /// The decoder.
    pub fn decoder(&self) -> &ConvDecoder {
        &self.decoder
    }

    /// The reconstruction `decoder(encoder(x))`.
    ///
    /// # Errors
    /// As [`ConvEncoder::forward`].
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.decoder.forward(&self.encoder.forward(x)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn shapes_variables_and_errors() {
        for (upsampling, padding) in
            [(Upsampling::Transposed, Padding::Zeros), (Upsampling::Nearest, Padding::PeriodicX)]
        {
            let varmap = VarMap::new();
            let cfg = EncoderDecoderConfig {
                upsampling,
                padding,
                norm_groups: Some(2),
                out_channels: 1,
                ..EncoderDecoderConfig::new(3, vec![4, 6, 8], 5)
            };
            let ae = Autoencoder::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu)).unwrap();
            let x = Tensor::zeros((2, 3, 16, 24), DType::F32, &Device::Cpu).unwrap();
            assert_eq!(ae.encoder().forward(&x).unwrap().dims(), &[2, 5, 2, 3]);
            assert_eq!(ae.forward(&x).unwrap().dims(), &[2, 1, 16, 24]);
            let data = varmap.data().lock().unwrap();
            assert_eq!(data["encoder.downs.0.conv.weight"].dims(), &[4, 3, 4, 4]);
            assert_eq!(data["encoder.to_latent.weight"].dims(), &[5, 8, 3, 3]);
            let up0 = if upsampling == Upsampling::Transposed { [8, 6, 4, 4] } else { [6, 8, 3, 3] };
            assert_eq!(data["decoder.ups.0.conv.weight"].dims(), &up0);
            assert_eq!(data["decoder.ups.2.norm.weight"].dims(), &[4]);
            assert_eq!(data["decoder.output.weight"].dims(), &[1, 4, 3, 3]);
            let odd = Tensor::zeros((2, 3, 12, 24), DType::F32, &Device::Cpu).unwrap();
            assert!(matches!(ae.forward(&odd), Err(Error::ShapeMismatch { .. })));
        }
        let vb = VarBuilder::zeros(DType::F32, &Device::Cpu);
        let bad = EncoderDecoderConfig::new(3, vec![], 5);
        assert!(matches!(ConvEncoder::new(bad, vb.clone()), Err(Error::InvalidConfig { .. })));
        let bad = EncoderDecoderConfig { norm_groups: Some(3), ..EncoderDecoderConfig::new(3, vec![4], 5) };
        assert!(matches!(ConvDecoder::new(bad, vb), Err(Error::InvalidConfig { .. })));
    }
}
