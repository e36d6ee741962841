//! Convolution layers for building networks: weights from a `VarBuilder`, `candle_nn::Module`.

use super::params::ConvParams;
use crate::nn::Activation;
use crate::{Error, Result};
use candle_core::Tensor;
use candle_nn::{Init, Module, VarBuilder};
use serde::{Deserialize, Serialize};

/// Configuration of a [`Conv`] layer; [`ConvLayerConfig::init`] creates it.
///
/// ```
/// use candle_core::{DType, Device, Module, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_core::conv::{Conv2dParams, ConvLayerConfig};
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let layer = ConvLayerConfig::new(4, 8, [3, 3])
///     .with_params(Conv2dParams::default().padding(1).circular())
///     .init(vb.pp("conv1"))?;
/// let y = layer.forward(&Tensor::ones((1, 4, 10, 10), DType::F32, &Device::Cpu)?)?;
/// assert_eq!(y.dims(), &[1, 8, 10, 10]);
/// assert!(varmap.data().lock().unwrap().contains_key("conv1.weight"));
/// # Ok::<(), pbdl_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(bound(
    serialize = "[usize; N]: Serialize, [super::PaddingMode; N]: Serialize",
    deserialize = "[usize; N]: Deserialize<'de>, [super::PaddingMode; N]: Deserialize<'de>"
))]
pub struct ConvLayerConfig<const N: usize> {
    /// Channels of the input.
    pub in_channels: usize,
    /// Channels of the output.
    pub out_channels: usize,
    /// Kernel size per spatial axis.
    pub kernel_size: [usize; N],
    /// Whether the layer adds a learned bias per output channel. Default `true`.
    pub bias: bool,
    /// Stride, padding, dilation, groups, padding mode. Default [`ConvParams::default`].
    pub params: ConvParams<N>,
}

impl<const N: usize> ConvLayerConfig<N> {
    /// A layer from `in_channels` to `out_channels` with the given kernel size, a bias and
    /// default parameters.
    pub fn new(in_channels: usize, out_channels: usize, kernel_size: [usize; N]) -> Self {
        Self { in_channels, out_channels, kernel_size, bias: true, params: ConvParams::default() }
    }

    /// Sets stride, padding, dilation, groups and padding mode.
    pub fn with_params(mut self, params: ConvParams<N>) -> Self {
        self.params = params;
        self
    }

    /// Drops the bias.
    pub fn without_bias(mut self) -> Self {
        self.bias = false;
        self
    }

    /// Creates the layer, taking `weight` (and `bias`) from `vb`. New variables are initialised
    /// like PyTorch's: uniform in `±1/sqrt(fan_in)` with `fan_in = in_channels / groups *
    /// prod(kernel_size)` (Kaiming-uniform with `a = sqrt(5)`).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for zero channels or kernel sizes, or groups that do not
    /// divide the channels; a candle error if `vb` holds a tensor of another shape.
    pub fn init(&self, vb: VarBuilder) -> Result<Conv<N>> {
        const OP: &str = "ConvLayerConfig::init";
        if !(1..=3).contains(&N) {
            return Err(Error::invalid(OP, "kernel_size", format!("{N} spatial axes given; use 1, 2 or 3")));
        }
        if self.in_channels == 0 || self.out_channels == 0 || self.kernel_size.contains(&0) {
            return Err(Error::invalid(
                OP,
                "config",
                format!(
                    "channels and kernel sizes must be at least 1, got in {} out {} kernel {:?}",
                    self.in_channels, self.out_channels, self.kernel_size
                ),
            ));
        }
        let g = self.params.groups;
        if g == 0 || self.in_channels % g != 0 || self.out_channels % g != 0 {
            return Err(Error::invalid(
                OP,
                "groups",
                format!(
                    "groups = {g} must be at least 1 and divide in_channels ({}) and out_channels ({})",
                    self.in_channels, self.out_channels
                ),
            ));
        }
        let fan_in = self.in_channels / g * self.kernel_size.iter().product::<usize>();
        let bound = 1.0 / (fan_in as f64).sqrt();
        let init = Init::Uniform { lo: -bound, up: bound };
        let mut shape = vec![self.out_channels, self.in_channels / g];
        shape.extend_from_slice(&self.kernel_size);
        let weight = vb.get_with_hints(shape, "weight", init)?;
        let bias = if self.bias { Some(vb.get_with_hints(self.out_channels, "bias", init)?) } else { None };
        Conv::new(weight, bias, self.params)
    }
}

/// An `N`-dimensional convolution layer `y = conv(x, weight) + bias` (see [`super::conv`]).
#[derive(Clone, Debug)]
pub struct Conv<const N: usize> {
    weight: Tensor,
    bias: Option<Tensor>,
    params: ConvParams<N>,
}

/// A 1D convolution layer; build it with [`ConvLayerConfig::init`].
pub type Conv1d = Conv<1>;
/// A 2D convolution layer; build it with [`ConvLayerConfig::init`].
pub type Conv2d = Conv<2>;
/// A 3D convolution layer; build it with [`ConvLayerConfig::init`].
pub type Conv3d = Conv<3>;

impl<const N: usize> Conv<N> {
    /// A layer from existing tensors: `weight` `[out, in / groups, kernel...]`, `bias` `[out]`.
    ///
    /// # Errors
    /// [`Error::Shape`] if `weight` does not have rank `N + 2` or `bias` does not match its
    /// first dimension.
    pub fn new(weight: Tensor, bias: Option<Tensor>, params: ConvParams<N>) -> Result<Self> {
        const OP: &str = "Conv::new";
        if weight.rank() != N + 2 {
            return Err(Error::Shape {
                op: OP,
                arg: "weight",
                expected: format!("rank {} [out_channels, in_channels / groups, kernel...]", N + 2),
                got: weight.dims().to_vec(),
            });
        }
        if let Some(b) = &bias {
            if b.dims() != [weight.dim(0)?] {
                return Err(Error::Shape {
                    op: OP,
                    arg: "bias",
                    expected: format!("[{}] (weight dim 0)", weight.dim(0)?),
                    got: b.dims().to_vec(),
                });
            }
        }
        Ok(Self { weight, bias, params })
    }

    /// The weight, `[out_channels, in_channels / groups, kernel...]`.
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    /// The bias, `[out_channels]`, if the layer has one.
    pub fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    /// Stride, padding, dilation, groups and padding mode.
    pub fn params(&self) -> &ConvParams<N> {
        &self.params
    }

    /// `act(conv(x) + bias)`, fused into one op where [`super::conv_act`] can.
    ///
    /// # Errors
    /// As [`super::conv`].
    pub fn forward_act(&self, x: &Tensor, act: Activation) -> Result<Tensor> {
        super::conv_act(x, &self.weight, self.bias.as_ref(), &self.params, act)
    }
}

impl<const N: usize> Module for Conv<N> {
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        Ok(super::conv(x, &self.weight, self.bias.as_ref(), &self.params)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::Conv3dParams;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn init_follows_pytorch_bounds_and_names() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu);
        let cfg = ConvLayerConfig::new(6, 4, [3, 3, 3]).with_params(Conv3dParams::default().groups(2));
        let layer = cfg.init(vb.pp("c")).unwrap();
        assert_eq!(layer.weight().dims(), &[4, 3, 3, 3, 3]);
        let bound = 1.0 / (3.0f64 * 27.0).sqrt();
        let w = layer.weight().flatten_all().unwrap().to_vec1::<f64>().unwrap();
        assert!(w.iter().all(|v| v.abs() <= bound));
        assert!(w.iter().any(|v| v.abs() > 0.5 * bound), "weights look all tiny");
        let data = varmap.data().lock().unwrap();
        let mut names: Vec<_> = data.keys().cloned().collect();
        names.sort();
        assert_eq!(names, ["c.bias", "c.weight"]);
    }

    #[test]
    fn bad_configs_are_typed_errors() {
        let vb = VarBuilder::zeros(DType::F32, &Device::Cpu);
        let bad_groups = ConvLayerConfig::new(6, 4, [3]).with_params(crate::conv::Conv1dParams::default().groups(4));
        assert!(matches!(bad_groups.init(vb.clone()), Err(Error::InvalidArgument { arg: "groups", .. })));
        assert!(matches!(ConvLayerConfig::new(0, 4, [3]).init(vb), Err(Error::InvalidArgument { .. })));
    }
}
