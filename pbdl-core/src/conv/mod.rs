//! Fast differentiable convolution in 1D, 2D and 3D, with zero or periodic padding.
//!
//! Layouts follow PyTorch: inputs `[batch, channel, (z,) y, x]`, weights
//! `[out_channels, in_channels / groups, (kz,) ky, kx]`, an optional bias `[out_channels]`.
//! The output size along an axis of input size `n`, kernel size `k`, padding `p`, dilation `d`
//! and stride `s` is `(n + 2p - d(k - 1) - 1) / s + 1` (rounded down).
//!
//! Every convolution runs as a 3D one (1D and 2D get singleton axes): the input is gathered
//! tile by tile into an im2col matrix and multiplied with the weight by the `gemm` crate, in
//! parallel over images and channel groups. Depthwise convolutions (one input and one output
//! channel per group, as in ConvNeXt blocks) skip im2col: direct kernels slide the kernel over a
//! padded copy of each channel. The gradients with respect to the input (a
//! transposed convolution, via col2im) and the weight are ops of their own and differentiable
//! again, so second derivatives are available wherever candle keeps the gradient graph (it
//! detaches gradients of intermediate nodes unless `CANDLE_GRAD_DO_NOT_DETACH=1`).
//!
//! Compared with candle 0.11's `conv1d`/`conv2d` this adds conv3d, circular padding, per-axis
//! stride/padding/dilation, a several times faster backward pass, and correct gradients where
//! candle's are not: its conv1d gradients are wrong for batch > 1, and its strided conv2d
//! backward fails when the two axes need different output paddings (e.g. 9x8 input, stride 2).
//!
//! ```
//! use candle_core::{DType, Device, Tensor, Var};
//! use pbdl_core::conv::{conv2d, Conv2dParams};
//!
//! let dev = Device::Cpu;
//! let x = Var::randn(0f32, 1.0, (2, 3, 16, 16), &dev)?; // [batch, channel, y, x]
//! let w = Var::randn(0f32, 0.1, (8, 3, 3, 3), &dev)?; // [out, in, ky, kx]
//! let b = Tensor::zeros(8, DType::F32, &dev)?;
//! // Periodic boundaries, output size equal to the input size.
//! let p = Conv2dParams::default().padding(1).circular();
//! let y = conv2d(&x, &w, Some(&b), &p)?;
//! assert_eq!(y.dims(), &[2, 8, 16, 16]);
//! let grads = y.sqr()?.sum_all()?.backward()?;
//! assert_eq!(grads.get(&w).unwrap().dims(), &[8, 3, 3, 3]);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

mod backward;
mod depthwise;
mod epilogue;
mod forward;
mod geometry;
mod im2col;
mod implicit;
mod layer;
mod params;
mod transpose;

pub use layer::{Conv, Conv1d, Conv2d, Conv3d, ConvLayerConfig};
pub use params::{Conv1dParams, Conv2dParams, Conv3dParams, ConvParams, PaddingMode};
pub use transpose::{conv_transpose, conv_transpose2d, conv_transpose_act};

use crate::error::check_float;
use crate::nn::Activation;
use crate::{Error, Result};
use candle_core::Tensor;
use epilogue::Epilogue;
use geometry::Geometry;

/// `N`-dimensional convolution (`N` = 1, 2 or 3) of `x` with `weight`, plus `bias` per output
/// channel; [`conv1d`], [`conv2d`] and [`conv3d`] are this with a fixed `N`.
///
/// Shapes: `x` is `[batch, in_channels, spatial...]` (`N` spatial axes), `weight` is
/// `[out_channels, in_channels / groups, kernel...]`, `bias` is `[out_channels]`. All three must
/// be `f32` or `f64` of one dtype, on the CPU. Gradients flow to all three.
///
/// # Errors
/// [`Error::Shape`] for wrong ranks, channel counts or bias length; [`Error::InvalidArgument`]
/// for a zero stride or dilation, groups that do not divide the channels, or a kernel larger
/// than the padded input; [`Error::DType`] for other or mixed dtypes.
pub fn conv<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
) -> Result<Tensor> {
    conv_with(x, weight, bias, params, None, Activation::Identity)
}

/// `act(conv(x, weight) + bias)`, with the bias and a [`Activation::Relu`] or
/// [`Activation::LeakyRelu`] (positive slope) fused into the convolution: one op in the
/// gradient graph instead of three, and no separate pass for the bias gradient. Other
/// activations are applied after the convolution. Shapes and errors as [`conv`].
///
/// The gradient at a pre-activation of exactly 0 is the mean of both slopes for LeakyReLU (as
/// [`crate::nn::activation::leaky_relu`]) and 0 for ReLU (PyTorch's rule; the unfused
/// [`crate::nn::activation::relu`] uses 1). Inside [`crate::nn::with_composed`] nothing is fused.
///
/// ```
/// use candle_core::{DType, Device, Tensor, Var};
/// use pbdl_core::conv::{conv2d, conv_act, Conv2dParams};
/// use pbdl_core::nn::Activation;
///
/// let dev = Device::Cpu;
/// let x = Tensor::randn(0f32, 1.0, (2, 4, 8, 8), &dev)?;
/// let w = Var::randn(0f32, 0.2, (6, 4, 3, 3), &dev)?;
/// let b = Var::randn(0f32, 0.1, 6, &dev)?;
/// let p = Conv2dParams::default().padding(1);
/// let act = Activation::LeakyRelu { negative_slope: 0.3 };
/// let fused = conv_act(&x, &w, Some(&b), &p, act)?;
/// let unfused = act.apply(&conv2d(&x, &w, Some(&b), &p)?)?;
/// assert_eq!(fused.flatten_all()?.to_vec1::<f32>()?, unfused.flatten_all()?.to_vec1::<f32>()?);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn conv_act<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
    act: Activation,
) -> Result<Tensor> {
    conv_with(x, weight, bias, params, None, act)
}

/// [`conv`] forced onto the im2col + matrix-product path even where a direct kernel exists
/// (depthwise convolutions), for its gradients too; for tests and benchmarks that compare the
/// two paths.
#[doc(hidden)]
pub fn conv_im2col<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
) -> Result<Tensor> {
    conv_with(x, weight, bias, params, Some(false), Activation::Identity)
}

/// Whether the opt-in implicit-GEMM path for stride-1 single-group convolutions is switched
/// on in this process (`PBDL_CONV_IMPLICIT=1`, read once); for tests that must know which
/// path ran.
#[doc(hidden)]
pub fn implicit_path_enabled() -> bool {
    implicit::enabled()
}

/// Whether [`conv`] runs the direct depthwise kernels for an input of shape `x`, a weight of
/// shape `w` and `params` (the shapes must be valid), rather than im2col.
#[doc(hidden)]
pub fn uses_direct_kernel<const N: usize>(x: &[usize], w: &[usize], params: &ConvParams<N>) -> Result<bool> {
    Ok(depthwise::handles(&Geometry::new("conv::uses_direct_kernel", x, w, params)?))
}

/// [`conv_act`], with `direct` overriding whether direct kernels may be used.
fn conv_with<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
    direct: Option<bool>,
    activation: Activation,
) -> Result<Tensor> {
    const OP: &str = "conv";
    let mut geo = Geometry::new(OP, x.dims(), weight.dims(), params)?;
    if let Some(d) = direct {
        geo.direct = d;
    }
    if !x.device().is_cpu() || !weight.device().is_cpu() || bias.is_some_and(|b| !b.device().is_cpu()) {
        return Err(Error::invalid(
            OP,
            "input",
            "the convolution runs on the CPU; move the tensors with `.to_device(&Device::Cpu)`",
        ));
    }
    check_float(OP, "input", x)?;
    check_float(OP, "weight", weight)?;
    if weight.dtype() != x.dtype() {
        return Err(Error::DType {
            op: OP,
            arg: "weight",
            expected: "the dtype of `input` (convert one with `.to_dtype(..)`)",
            got: weight.dtype(),
        });
    }
    if let Some(b) = bias {
        if b.dims() != [geo.c_out] {
            return Err(Error::Shape {
                op: OP,
                arg: "bias",
                expected: format!("[{}] (one entry per output channel, weight dim 0)", geo.c_out),
                got: b.dims().to_vec(),
            });
        }
        if b.dtype() != x.dtype() {
            return Err(Error::DType {
                op: OP,
                arg: "bias",
                expected: "the dtype of `input` (convert one with `.to_dtype(..)`)",
                got: b.dtype(),
            });
        }
    }
    let fused = if crate::nn::fusion_enabled() { Epilogue::of(activation) } else { None };
    // A direct depthwise kernel adds its bias itself; with a fusable activation the epilogue
    // adds it instead, so the activation's derivative follows the same rule as elsewhere.
    if let (Some(b), true, None | Some(Epilogue::Identity)) = (bias, depthwise::handles(&geo), fused) {
        let y = depthwise::conv_bias_tensor(&geo, x, weight, b)?;
        return activation.apply(&y);
    }
    match (fused, bias) {
        (Some(Epilogue::Identity), None) => Ok(forward::conv_tensor(&geo, x, weight)?),
        (Some(e), _) => Ok(epilogue::conv_bias_act_tensor(&geo, x, weight, bias, e)?),
        (None, _) => {
            let mut y = forward::conv_tensor(&geo, x, weight)?;
            if let Some(b) = bias {
                let mut shape = vec![1; N + 2];
                shape[1] = geo.c_out;
                y = y.broadcast_add(&b.reshape(shape)?)?;
            }
            activation.apply(&y)
        }
    }
}

/// 1D convolution: `x` `[batch, in_channels, x]`, `weight` `[out_channels, in_channels / groups, kx]`.
/// See [`conv`] for shapes and errors.
pub fn conv1d(x: &Tensor, weight: &Tensor, bias: Option<&Tensor>, params: &Conv1dParams) -> Result<Tensor> {
    conv(x, weight, bias, params)
}

/// 2D convolution: `x` `[batch, in_channels, y, x]`, `weight`
/// `[out_channels, in_channels / groups, ky, kx]`. See [`conv`] for shapes and errors.
pub fn conv2d(x: &Tensor, weight: &Tensor, bias: Option<&Tensor>, params: &Conv2dParams) -> Result<Tensor> {
    conv(x, weight, bias, params)
}

/// 3D convolution: `x` `[batch, in_channels, z, y, x]`, `weight`
/// `[out_channels, in_channels / groups, kz, ky, kx]`. See [`conv`] for shapes and errors.
pub fn conv3d(x: &Tensor, weight: &Tensor, bias: Option<&Tensor>, params: &Conv3dParams) -> Result<Tensor> {
    conv(x, weight, bias, params)
}

/// Output spatial size of an `N`-dimensional convolution of an input with spatial size `input`
/// and a kernel of size `kernel`, or the error [`conv`] would return.
pub fn output_size<const N: usize>(
    input: [usize; N],
    kernel: [usize; N],
    params: &ConvParams<N>,
) -> Result<[usize; N]> {
    let mut x = vec![1, params.groups.max(1)];
    x.extend_from_slice(&input);
    let mut w = vec![params.groups.max(1), 1];
    w.extend_from_slice(&kernel);
    let geo = Geometry::new("conv::output_size", &x, &w, params)?;
    let mut out = [0; N];
    out.copy_from_slice(&geo.output[3 - N..]);
    Ok(out)
}
