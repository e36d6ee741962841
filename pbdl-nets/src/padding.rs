//! What a convolution sees beyond the border, and a 2D convolution layer that applies it.
//!
//! Global weather fields are periodic in longitude (x, the last axis) but not in latitude (y):
//! WeatherBench's `PeriodicConv2D` pads x circularly and y with zeros. [`Padding::PeriodicX`]
//! does the same through `pbdl_core::conv`'s per-axis padding modes, inside the convolution's
//! gather (no padded copy of the input, no extra nodes in the gradient graph).

use crate::layers::conv2d_layer;
use crate::{Error, Result};
use candle_core::{Module, Tensor};
use candle_nn::VarBuilder;
use pbdl_core::conv::{Conv2d, Conv2dParams, PaddingMode};
use pbdl_core::nn::Activation;
use serde::{Deserialize, Serialize};

/// How a [`PaddedConv2d`] extends its input beyond the border.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Padding {
    /// Zeros on every side (PyTorch's default). The default.
    #[default]
    Zeros,
    /// Periodic along y and x (PyTorch's `padding_mode="circular"`).
    Periodic,
    /// Periodic along x (longitude), zeros along y (latitude), as WeatherBench's
    /// `PeriodicConv2D` (a `pad` wider than the field wraps around it more than once).
    PeriodicX,
}

/// A 2D convolution `[batch, in, y, x] -> [batch, out, y', x']` with a square kernel, a bias,
/// `pad` cells of [`Padding`] on each side and PyTorch's initialisation. Variables: `weight`
/// `[out, in, k, k]` and `bias` `[out]` under the given `VarBuilder`.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use candle_nn::{VarBuilder, VarMap};
/// use pbdl_nets::{PaddedConv2d, Padding};
///
/// let varmap = VarMap::new();
/// let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
/// let conv = PaddedConv2d::same(2, 5, 3, Padding::PeriodicX, vb.pp("conv"))?;
/// let x = Tensor::zeros((4, 2, 8, 16), DType::F32, &Device::Cpu)?;
/// assert_eq!(conv.forward(&x)?.dims(), &[4, 5, 8, 16]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct PaddedConv2d {
    conv: Conv2d,
    pad: usize,
    padding: Padding,
}

impl PaddedConv2d {
    /// A layer `c_in -> c_out` with a `kernel x kernel` kernel, stride `stride` and `pad` cells
    /// of `padding` on each side; the output size along an axis of size `n` is
    /// `(n + 2 pad - kernel) / stride + 1`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for zero channels, kernel or stride; a pbdl-core error if `vb`
    /// holds variables of other shapes.
    pub fn new(
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
        pad: usize,
        padding: Padding,
        vb: VarBuilder,
    ) -> Result<Self> {
        if c_in == 0 || c_out == 0 || kernel == 0 || stride == 0 {
            return Err(Error::InvalidConfig {
                name: "PaddedConv2d channels / kernel / stride",
                value: format!("{c_in} -> {c_out}, kernel {kernel}, stride {stride}"),
                hint: "use at least one channel each way, a kernel of at least 1 and a stride of at least 1",
            });
        }
        let base = Conv2dParams::default().stride(stride);
        let params = match padding {
            Padding::Zeros => base.padding(pad),
            Padding::Periodic => base.padding(pad).circular(),
            Padding::PeriodicX => {
                Conv2dParams { padding_mode: [PaddingMode::Zeros, PaddingMode::Circular], ..base.padding(pad) }
            }
        };
        Ok(Self { conv: conv2d_layer(vb, c_in, c_out, kernel, params, true)?, pad, padding })
    }

    /// A stride-1 layer that keeps the size: an odd `kernel` with `pad = kernel / 2`.
    ///
    /// # Errors
    /// As [`PaddedConv2d::new`]; [`Error::InvalidConfig`] for an even kernel.
    pub fn same(c_in: usize, c_out: usize, kernel: usize, padding: Padding, vb: VarBuilder) -> Result<Self> {
        if kernel % 2 == 0 {
            return Err(Error::InvalidConfig {
                name: "kernel",
                value: kernel.to_string(),
                hint: "a size-preserving convolution needs an odd kernel (1, 3, 5, ..)",
            });
        }
        Self::new(c_in, c_out, kernel, 1, kernel / 2, padding, vb)
    }

    /// The padding mode.
    pub fn padding(&self) -> Padding {
        self.padding
    }

    /// The underlying convolution (its weight, bias and parameters).
    pub fn conv(&self) -> &Conv2d {
        &self.conv
    }

    /// The convolution of `x` `[batch, in, y, x]`.
    ///
    /// # Errors
    /// [`Error::ShapeMismatch`] for a wrong rank, or an empty x axis with periodic padding;
    /// pbdl-core's errors for wrong channels or a too small input.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.check_input(x)?;
        Ok(self.conv.forward(x)?)
    }

    /// `act(self.forward(x))`, with the bias and a ReLU or LeakyReLU fused into the
    /// convolution (see `pbdl_core::conv::conv_act`).
    ///
    /// # Errors
    /// As [`PaddedConv2d::forward`].
    pub fn forward_act(&self, x: &Tensor, act: Activation) -> Result<Tensor> {
        self.check_input(x)?;
        Ok(self.conv.forward_act(x, act)?)
    }

    fn check_input(&self, x: &Tensor) -> Result<()> {
        if x.rank() != 4 {
            return Err(Error::shape("PaddedConv2d input", "[batch, channel, y, x]", x.dims()));
        }
        if matches!(self.padding, Padding::Periodic | Padding::PeriodicX) && self.pad > 0 && x.dim(3)? == 0 {
            return Err(Error::shape(
                "PaddedConv2d input (periodic padding needs at least one column)",
                "[batch, channel, y, >= 1]",
                x.dims(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    fn layer(padding: Padding, seed: u64) -> PaddedConv2d {
        let varmap = VarMap::new();
        let conv = PaddedConv2d::same(2, 3, 3, padding, VarBuilder::from_varmap(&varmap, DType::F64, &Device::Cpu));
        crate::seeded_init(&varmap, seed).unwrap();
        conv.unwrap()
    }

    fn to_vec(t: &Tensor) -> Vec<f64> {
        t.flatten_all().unwrap().to_vec1().unwrap()
    }

    /// Periodic in x: shifting the input by one column along x shifts the output the same way;
    /// along y the border is zero-padded, so the first row sees zeros above.
    #[test]
    fn periodic_x_commutes_with_shifts_in_x_and_pads_y_with_zeros() {
        let conv = layer(Padding::PeriodicX, 1);
        let x = pbdl_core::seed::randn((1, 2, 5, 6), 0.0, 1.0, DType::F64, &Device::Cpu, 2).unwrap();
        let roll = |t: &Tensor| Tensor::cat(&[&t.narrow(3, 5, 1).unwrap(), &t.narrow(3, 0, 5).unwrap()], 3).unwrap();
        let a = to_vec(&conv.forward(&roll(&x)).unwrap());
        let b = to_vec(&roll(&conv.forward(&x).unwrap()));
        assert!(a.iter().zip(&b).all(|(u, v)| (u - v).abs() < 1e-12));
        // Along y the border is zero-padded: the fully periodic layer with the same weights
        // (same seed) differs in the first and last rows only.
        let (py, full) = (conv.forward(&x).unwrap(), layer(Padding::Periodic, 1).forward(&x).unwrap());
        let rows = |t: &Tensor, r0, n| to_vec(&t.narrow(2, r0, n).unwrap());
        assert!(rows(&py, 1, 3).iter().zip(rows(&full, 1, 3)).all(|(u, v)| (u - v).abs() < 1e-12));
        assert_ne!(rows(&py, 0, 1), rows(&full, 0, 1));
        assert_ne!(rows(&py, 4, 1), rows(&full, 4, 1));
    }

    #[test]
    fn sizes_and_errors() {
        for padding in [Padding::Zeros, Padding::Periodic, Padding::PeriodicX] {
            let y = layer(padding, 3).forward(&Tensor::zeros((2, 2, 4, 7), DType::F64, &Device::Cpu).unwrap());
            assert_eq!(y.unwrap().dims(), &[2, 3, 4, 7]);
        }
        let narrow = Tensor::zeros((1, 2, 4, 0), DType::F64, &Device::Cpu).unwrap();
        assert!(matches!(layer(Padding::PeriodicX, 4).forward(&narrow), Err(Error::ShapeMismatch { .. })));
        let vb = VarBuilder::zeros(DType::F32, &Device::Cpu);
        assert!(matches!(PaddedConv2d::same(2, 3, 4, Padding::Zeros, vb.clone()), Err(Error::InvalidConfig { .. })));
        assert!(matches!(PaddedConv2d::new(2, 3, 3, 0, 1, Padding::Zeros, vb), Err(Error::InvalidConfig { .. })));
    }
}
