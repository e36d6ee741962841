//! A convolutional GAN discriminator: per-sample logits and the feature maps of every level
//! (for feature-matching or perceptual losses, as tempoGAN and TecoGAN use), with the binary
//! cross-entropy of logits for the adversarial losses.
//!
//! With widths `[c_1, .., c_L]`, level `i` is a `kernel x kernel` stride-2 conv
//! (`c_{i-1} -> c_i`, `c_0` = input channels, padding `(kernel - 1) / 2`, which halves even
//! sizes for kernels 3 to 5), an optional GroupNorm (not on the first level, as in DCGAN) and
//! the activation (LeakyReLU 0.2 by default). The head is one [`Linear`] to a logit, on the
//! flattened last feature map when the input size is fixed (`input_size`, tempoGAN's dense
//! head), or on its spatial mean otherwise (any size that is a multiple of `2^L`).

use crate::layers::Linear;
use crate::padding::{PaddedConv2d, Padding};
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use pbdl_core::nn::activation::softplus;
use pbdl_core::nn::{Activation, GroupNorm, GroupNormConfig};
use serde::{Deserialize, Serialize};

/// Configuration of a [`Discriminator`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiscriminatorConfig {
    /// Channels of the input (e.g. a frame, or frames stacked on the channel axis).
    pub in_channels: usize,
    /// Widths `[c_1, .., c_L]` of the `L` stride-2 levels.
    pub widths: Vec<usize>,
    /// Kernel size of the convs (4 as in DCGAN; 3 to 5 halve even sizes exactly).
    pub kernel: usize,
    /// Activation after each level.
    pub activation: Activation,
    /// GroupNorm groups on levels 2.. (dividing their widths), or `None` for no norm.
    pub norm_groups: Option<usize>,
    /// Border handling of the convs.
    pub padding: Padding,
    /// `Some([height, width])`: a fixed input size and a dense head on the flattened features;
    /// `None`: any size, a head on the spatial mean.
    pub input_size: Option<[usize; 2]>,
}

impl DiscriminatorConfig {
    /// `in_channels`, the given widths, kernel 4, LeakyReLU 0.2, no norm, zero padding and a
    /// head on the spatial mean.
    pub fn new(in_channels: usize, widths: Vec<usize>) -> Self {
        Self {
            in_channels,
            widths,
            kernel: 4,
            activation: Activation::LeakyRelu { negative_slope: 0.2 },
            norm_groups: None,
            padding: Padding::Zeros,
            input_size: None,
        }
    }

    /// The factor by which height and width must be divisible (`2^L`).
    pub fn size_multiple(&self) -> usize {
        1 << self.widths.len()
    }

    fn validate(&self) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.widths.is_empty() || self.widths.contains(&0) || self.in_channels == 0 {
            return bad(
                "DiscriminatorConfig channels",
                format!("{} -> {:?}", self.in_channels, self.widths),
                "use at least one input channel and one positive width",
            );
        }
        if !(3..=5).contains(&self.kernel) {
            return bad("kernel", self.kernel.to_string(), "use a kernel of 3, 4 or 5 (stride 2 halves the size)");
        }
        if let Some(g) = self.norm_groups {
            if g == 0 || self.widths[1..].iter().any(|c| c % g != 0) {
                return bad("norm_groups", g.to_string(), "use a group count that divides the widths after the first");
            }
        }
        if let Some([h, w]) = self.input_size {
            let m = self.size_multiple();
            if h == 0 || w == 0 || h % m != 0 || w % m != 0 {
                return bad("input_size", format!("{h} x {w}"), "use positive multiples of 2^levels");
            }
        }
        Ok(())
    }
}

/// A discriminator's answer for a batch.
#[derive(Clone, Debug)]
pub struct DiscriminatorOutput {
    /// One logit per sample, `[batch]` (positive: judged real).
    pub logits: Tensor,
    /// The feature map after each level, `[batch, c_i, y / 2^i, x / 2^i]`.
    pub features: Vec<Tensor>,
}

/// One level: strided conv, optional norm, activation.
#[derive(Clone, Debug)]
struct Level {
    conv: PaddedConv2d,
    norm: Option<GroupNorm>,
}

/// The conv discriminator (see the module docs). Variables: `levels.{i}.conv.*`,
/// `levels.{i}.norm.*`, `head.*`.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::discriminator::{bce_with_logits, Discriminator, DiscriminatorConfig};
///
/// let varmap = VarMap::new();
/// let d = Discriminator::new(
///     DiscriminatorConfig::new(2, vec![8, 16, 32]),
///     VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu),
/// )?;
/// pbdl_nets::seeded_init(&varmap, 0)?;
/// let out = d.forward(&Tensor::zeros((5, 2, 32, 32), DType::F32, &Device::Cpu)?)?;
/// assert_eq!(out.logits.dims(), &[5]);
/// assert_eq!(out.features[2].dims(), &[5, 32, 4, 4]);
/// let loss_real = bce_with_logits(&out.logits, 1.0)?; // the discriminator's loss on real data
/// assert!(loss_real.to_scalar::<f32>()? > 0.0);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Discriminator {
    config: DiscriminatorConfig,
    levels: Vec<Level>,
    head: Linear,
}

impl Discriminator {
    /// Builds the discriminator, taking (or creating) its variables in `vb`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for no or zero widths, a kernel outside 3..=5, groups that do
    /// not divide the widths, or an input size that is not a multiple of `2^L`.
    pub fn new(config: DiscriminatorConfig, vb: VarBuilder) -> Result<Self> {
        config.validate()?;
        let pad = (config.kernel - 1) / 2;
        let mut levels = Vec::with_capacity(config.widths.len());
        let mut c_prev = config.in_channels;
        for (i, &c) in config.widths.iter().enumerate() {
            let vb = vb.pp(format!("levels.{i}"));
            let conv = PaddedConv2d::new(c_prev, c, config.kernel, 2, pad, config.padding, vb.pp("conv"))?;
            let norm = match config.norm_groups {
                Some(g) if i > 0 => Some(GroupNorm::new(g, c, GroupNormConfig::default(), vb.pp("norm"))?),
                _ => None,
            };
            levels.push(Level { conv, norm });
            c_prev = c;
        }
        let head_in = match config.input_size {
            Some([h, w]) => c_prev * (h / config.size_multiple()) * (w / config.size_multiple()),
            None => c_prev,
        };
        let head = Linear::new(head_in, 1, vb.pp("head"))?;
        Ok(Self { config, levels, head })
    }

    /// The configuration.
    pub fn config(&self) -> &DiscriminatorConfig {
        &self.config
    }

    /// Logits and features of `x` `[batch, in_channels, y, x]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong shape, a size that is not a multiple of `2^L`, or
    /// (with a dense head) a size other than `input_size`.
    pub fn forward(&self, x: &Tensor) -> Result<DiscriminatorOutput> {
        let cfg = &self.config;
        let (m, d) = (cfg.size_multiple(), x.dims());
        let size_ok = match cfg.input_size {
            Some([h, w]) => d.len() == 4 && d[2] == h && d[3] == w,
            None => d.len() == 4 && d[2] > 0 && d[3] > 0 && d[2] % m == 0 && d[3] % m == 0,
        };
        if !size_ok || d[1] != cfg.in_channels {
            let size = match cfg.input_size {
                Some([h, w]) => format!("{h}, {w}"),
                None => format!("y, x (multiples of {m})"),
            };
            return Err(Error::shape("Discriminator input", format!("[batch, {}, {size}]", cfg.in_channels), d));
        }
        let mut h = x.clone();
        let mut features = Vec::with_capacity(self.levels.len());
        for level in &self.levels {
            h = level.conv.forward(&h)?;
            if let Some(n) = &level.norm {
                h = n.apply(&h)?;
            }
            h = cfg.activation.apply(&h)?;
            features.push(h.clone());
        }
        let pooled = match cfg.input_size {
            Some(_) => h.flatten_from(1)?,
            None => h.flatten_from(2)?.mean(2)?,
        };
        let logits = self.head.forward(&pooled)?.squeeze(1)?;
        Ok(DiscriminatorOutput { logits, features })
    }
}

/// Mean binary cross-entropy of `logits` against the label `target` (1 real, 0 fake, or a
/// smoothed label in between): `mean(softplus(l) - target l)`, stable for large `|l|`.
///
/// The discriminator minimises `bce(D(real), 1) + bce(D(fake), 0)`; the non-saturating
/// generator loss is `bce(D(fake), 1)`.
///
/// # Errors
/// [`Error::InvalidConfig`] for a target outside `[0, 1]`.
pub fn bce_with_logits(logits: &Tensor, target: f64) -> Result<Tensor> {
    if !(0.0..=1.0).contains(&target) {
        return Err(Error::InvalidConfig {
            name: "bce_with_logits target",
            value: target.to_string(),
            hint: "use a label in [0, 1] (1 real, 0 fake)",
        });
    }
    Ok((softplus(logits)? - (logits * target)?)?.mean_all()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn shapes_heads_and_errors() {
        let dev = Device::Cpu;
        for (input_size, head_in) in [(None, 6), (Some([16, 8]), 6 * 4 * 2)] {
            let varmap = VarMap::new();
            let cfg = DiscriminatorConfig {
                input_size,
                norm_groups: Some(2),
                kernel: 3,
                padding: Padding::PeriodicX,
                ..DiscriminatorConfig::new(3, vec![4, 6])
            };
            let d = Discriminator::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &dev)).unwrap();
            let out = d.forward(&Tensor::zeros((2, 3, 16, 8), DType::F32, &dev).unwrap()).unwrap();
            assert_eq!(out.logits.dims(), &[2]);
            assert_eq!(
                out.features.iter().map(|f| f.dims().to_vec()).collect::<Vec<_>>(),
                [[2, 4, 8, 4], [2, 6, 4, 2]]
            );
            let data = varmap.data().lock().unwrap();
            assert_eq!(data["head.weight"].dims(), &[1, head_in]);
            assert!(!data.contains_key("levels.0.norm.weight") && data.contains_key("levels.1.norm.weight"));
            let other = Tensor::zeros((2, 3, 8, 8), DType::F32, &dev).unwrap();
            assert_eq!(d.forward(&other).is_ok(), input_size.is_none());
            let odd = Tensor::zeros((2, 3, 6, 8), DType::F32, &dev).unwrap();
            assert!(matches!(d.forward(&odd), Err(Error::ShapeMismatch { .. })));
        }
        let vb = VarBuilder::zeros(DType::F32, &dev);
        let bad = DiscriminatorConfig { kernel: 7, ..DiscriminatorConfig::new(3, vec![4]) };
        assert!(matches!(Discriminator::new(bad, vb.clone()), Err(Error::InvalidConfig { .. })));
        let bad = DiscriminatorConfig { input_size: Some([6, 8]), ..DiscriminatorConfig::new(3, vec![4, 4]) };
        assert!(matches!(Discriminator::new(bad, vb), Err(Error::InvalidConfig { .. })));
    }

    #[test]
    fn bce_matches_its_definition() {
        let l = Tensor::new(&[-30f64, -1.0, 0.0, 2.0, 40.0], &Device::Cpu).unwrap();
        for target in [0.0, 0.9, 1.0] {
            let got = bce_with_logits(&l, target).unwrap().to_scalar::<f64>().unwrap();
            let want = [-30f64, -1.0, 0.0, 2.0, 40.0]
                .iter()
                .map(|&x| {
                    // -t ln p - (1 - t) ln(1 - p) with p = sigmoid(x): ln p = -softplus(-x),
                    // ln(1 - p) = -softplus(x).
                    let sp = |v: f64| v.max(0.0) + (-v.abs()).exp().ln_1p();
                    target * sp(-x) + (1.0 - target) * sp(x)
                })
                .sum::<f64>()
                / 5.0;
            assert!((got - want).abs() < 1e-12, "{target}: {got} vs {want}");
        }
        assert!(matches!(bce_with_logits(&l, 1.5), Err(Error::InvalidConfig { .. })));
    }
}
