//! Transposed convolution ("deconvolution"), the adjoint of a strided convolution.
//!
//! `conv_transpose(x, w)` equals the input gradient of `conv(·, w)` at output gradient `x`, so
//! it reuses that op: forward is the col2im kernel of [`super::backward`], and its gradients
//! (a forward convolution for the input, the weight-gradient op for the weight) are already
//! differentiable. Layouts follow PyTorch's `ConvTranspose{1,2,3}d`.

use super::backward::grad_input_tensor;
use super::epilogue::{bias_act_tensor, Epilogue};
use super::geometry::Geometry;
use super::params::ConvParams;
use crate::error::check_float;
use crate::nn::Activation;
use crate::{Error, Result};
use candle_core::Tensor;

/// `N`-dimensional transposed convolution (`N` = 1, 2 or 3), PyTorch's `conv_transpose{N}d`.
///
/// Shapes: `x` is `[batch, in_channels, spatial...]`, `weight` is
/// `[in_channels, out_channels / groups, kernel...]` (PyTorch's transposed layout), `bias` is
/// `[out_channels]`. Along an axis of input size `n` the output has size
/// `(n - 1) * stride - 2 * padding + dilation * (kernel - 1) + output_padding + 1`;
/// `output_padding` (per axis, smaller than the stride or the dilation) picks one of the
/// input sizes that a strided convolution maps to `n`. `params.padding_mode` must be
/// [`PaddingMode::Zeros`] (as in PyTorch). Gradients flow to `x`, `weight` and `bias`.
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use pbdl_core::conv::{conv_transpose2d, Conv2dParams};
///
/// let dev = Device::Cpu;
/// let x = Tensor::ones((1, 4, 8, 6), DType::F32, &dev)?;
/// let w = Tensor::ones((4, 2, 4, 4), DType::F32, &dev)?; // [in, out, ky, kx]
/// // The 2x upsampling of a U-Net decoder: kernel 4, stride 2, padding 1.
/// let y = conv_transpose2d(&x, &w, None, &Conv2dParams::default().stride(2).padding(1), [0, 0])?;
/// assert_eq!(y.dims(), &[1, 2, 16, 12]);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
///
/// # Errors
/// [`Error::Shape`] for wrong ranks, channel counts or bias length; [`Error::InvalidArgument`]
/// for circular padding, an output padding not smaller than the stride or dilation, padding
/// that leaves no output, or groups that do not divide the channels; [`Error::DType`] for
/// other or mixed dtypes.
pub fn conv_transpose<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
    output_padding: [usize; N],
) -> Result<Tensor> {
    conv_transpose_act(x, weight, bias, params, output_padding, Activation::Identity)
}

/// `act(conv_transpose(x, weight, bias))`, with the bias and a ReLU or LeakyReLU (positive
/// slope) applied by one op after the transposed convolution (one pass, one graph node, the
/// bias gradient as a per-channel sum); other activations are applied separately. Shapes,
/// errors and the gradient at 0 as [`conv_transpose`] and [`super::conv_act`].
pub fn conv_transpose_act<const N: usize>(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<N>,
    output_padding: [usize; N],
    act: Activation,
) -> Result<Tensor> {
    const OP: &str = "conv_transpose";
    if !params.is_zero_padded() {
        return Err(Error::invalid(OP, "params", "only zero padding is supported; use PaddingMode::Zeros"));
    }
    if x.rank() != N + 2 {
        return Err(Error::Shape {
            op: OP,
            arg: "input",
            expected: format!("rank {} [batch, in_channels, spatial...]", N + 2),
            got: x.dims().to_vec(),
        });
    }
    if weight.rank() != N + 2 {
        return Err(Error::Shape {
            op: OP,
            arg: "weight",
            expected: format!("rank {} [in_channels, out_channels / groups, kernel...]", N + 2),
            got: weight.dims().to_vec(),
        });
    }
    let (xd, wd) = (x.dims(), weight.dims());
    if wd[0] != xd[1] {
        return Err(Error::Shape {
            op: OP,
            arg: "weight",
            expected: format!("[{}, out_channels / groups, kernel...] (dim 0 = input channels)", xd[1]),
            got: wd.to_vec(),
        });
    }
    let groups = params.groups.max(1);
    let c_out = wd[1] * groups;
    // The output size, and the forward convolution whose input gradient this is.
    let mut out_dims = vec![xd[0], c_out];
    for a in 0..N {
        let (s, p, d, k, op) = (params.stride[a], params.padding[a], params.dilation[a], wd[2 + a], output_padding[a]);
        if s == 0 || d == 0 {
            return Err(Error::invalid(OP, "params", "stride and dilation must be at least 1"));
        }
        if op >= s && op >= d {
            return Err(Error::invalid(
                OP,
                "output_padding",
                format!("{output_padding:?} must be smaller than the stride or the dilation on each axis"),
            ));
        }
        let full = (xd[2 + a].max(1) - 1) * s + d * k.max(1).saturating_sub(1) + op + 1;
        if xd[2 + a] == 0 || full <= 2 * p {
            return Err(Error::invalid(
                OP,
                "padding",
                format!("padding {p} on spatial axis {a} leaves no output (input {xd:?}, weight {wd:?}); use less"),
            ));
        }
        out_dims.push(full - 2 * p);
    }
    let geo = Geometry::new(OP, &out_dims, wd, params)?;
    if geo.y_shape() != xd {
        return Err(Error::Shape {
            op: OP,
            arg: "input",
            expected: format!("{:?} (the convolution output of the computed size)", geo.y_shape()),
            got: xd.to_vec(),
        });
    }
    if !x.device().is_cpu() || !weight.device().is_cpu() || bias.is_some_and(|b| !b.device().is_cpu()) {
        return Err(Error::invalid(OP, "input", "runs on the CPU; move the tensors with `.to_device(&Device::Cpu)`"));
    }
    check_float(OP, "input", x)?;
    check_float(OP, "weight", weight)?;
    if weight.dtype() != x.dtype() {
        return Err(Error::DType { op: OP, arg: "weight", expected: "the dtype of `input`", got: weight.dtype() });
    }
    let y = grad_input_tensor(&geo, x, weight)?;
    let fused = Epilogue::of(act).filter(|_| crate::nn::fusion_enabled());
    let Some(b) = bias else {
        // Without a bias the activation still goes through the epilogue (zero bias), so the
        // derivative at 0 follows one rule whether or not the layer has a bias.
        return match fused {
            Some(e) if e != Epilogue::Identity => {
                Ok(bias_act_tensor(&y, &Tensor::zeros(c_out, y.dtype(), y.device())?, e)?)
            }
            _ => act.apply(&y),
        };
    };
    if b.dims() != [c_out] {
        return Err(Error::Shape {
            op: OP,
            arg: "bias",
            expected: format!("[{c_out}] (one entry per output channel)"),
            got: b.dims().to_vec(),
        });
    }
    if b.dtype() != x.dtype() {
        return Err(Error::DType { op: OP, arg: "bias", expected: "the dtype of `input`", got: b.dtype() });
    }
    match fused {
        Some(e) => Ok(bias_act_tensor(&y, b, e)?),
        None => {
            let mut shape = vec![1; N + 2];
            shape[1] = c_out;
            act.apply(&y.broadcast_add(&b.reshape(shape)?)?)
        }
    }
}

/// 2D transposed convolution: `x` `[batch, in, y, x]`, `weight` `[in, out / groups, ky, kx]`.
/// See [`conv_transpose`].
pub fn conv_transpose2d(
    x: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    params: &ConvParams<2>,
    output_padding: [usize; 2],
) -> Result<Tensor> {
    conv_transpose(x, weight, bias, params, output_padding)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv::{conv2d, Conv2dParams};
    use crate::{check_grad, seed, GradCheckOptions};
    use candle_core::{DType, Device};

    fn randn(shape: &[usize], dtype: DType, s: u64) -> Tensor {
        seed::randn(shape, 0.0, 1.0, dtype, &Device::Cpu, s).unwrap()
    }

    fn max_abs(t: &Tensor) -> f64 {
        t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_dtype(DType::F64).unwrap().to_scalar().unwrap()
    }

    #[test]
    fn matches_candle_conv_transpose2d_forward() {
        // (input, weight, stride, padding, output_padding, dilation): the U-Net upsampling
        // (k4 s2 p1), an odd kernel with output padding, and a dilated one.
        let cases = [
            ([2, 3, 5, 4], [3, 4, 4, 4], 2, 1, 0, 1),
            ([1, 2, 4, 6], [2, 3, 3, 3], 2, 1, 1, 1),
            ([2, 2, 3, 3], [2, 2, 3, 3], 1, 2, 0, 2),
        ];
        for (i, (xs, ws, s, p, op, d)) in cases.into_iter().enumerate() {
            let x = randn(&xs, DType::F32, 10 + i as u64);
            let w = randn(&ws, DType::F32, 20 + i as u64);
            let params = Conv2dParams::default().stride(s).padding(p).dilation(d);
            let ours = conv_transpose2d(&x, &w, None, &params, [op, op]).unwrap();
            let theirs = x.conv_transpose2d(&w, p, op, s, d).unwrap();
            assert_eq!(ours.dims(), theirs.dims(), "case {i}");
            let err = max_abs(&(&ours - &theirs).unwrap()) / max_abs(&theirs);
            println!("conv_transpose2d vs candle, case {i}: max rel diff {err:.2e}");
            assert!(err < 1e-5, "case {i}: relative difference {err:.2e}");
        }
    }

    #[test]
    fn is_the_adjoint_of_conv2d_with_groups() {
        // <conv_transpose(y, w), x> = <y, conv(x, w)> for every x, y (f64, grouped).
        let params = Conv2dParams::default().stride(2).padding(1).groups(2);
        let x = randn(&[2, 4, 8, 6], DType::F64, 1);
        let w = randn(&[6, 2, 4, 4], DType::F64, 2);
        let y = conv2d(&x, &w, None, &params).unwrap();
        let r = randn(y.dims(), DType::F64, 3);
        let t = conv_transpose2d(&r, &w, None, &params, [0, 0]).unwrap();
        assert_eq!(t.dims(), x.dims());
        let lhs = (t * &x).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
        let rhs = (r * y).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap();
        assert!((lhs - rhs).abs() < 1e-10 * rhs.abs().max(1.0), "{lhs} vs {rhs}");
    }

    #[test]
    fn gradients_match_finite_differences() {
        let params = Conv2dParams::default().stride(2).padding(1);
        let inputs =
            [randn(&[2, 3, 4, 3], DType::F64, 4), randn(&[3, 2, 4, 4], DType::F64, 5), randn(&[2], DType::F64, 6)];
        let report = check_grad(
            |t| Ok(conv_transpose2d(&t[0], &t[1], Some(&t[2]), &params, [0, 0])?),
            &inputs,
            &GradCheckOptions::default(),
        )
        .unwrap();
        println!("conv_transpose2d FD: max rel error {:.2e}", report.max_rel_error);
        assert!(report.max_rel_error < 1e-6, "{report:?}");
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let x = randn(&[1, 3, 4, 4], DType::F32, 7);
        let p = Conv2dParams::default().stride(2).padding(1);
        let wrong_in = randn(&[2, 2, 4, 4], DType::F32, 8);
        assert!(matches!(conv_transpose2d(&x, &wrong_in, None, &p, [0, 0]), Err(Error::Shape { arg: "weight", .. })));
        let w = randn(&[3, 2, 4, 4], DType::F32, 9);
        assert!(matches!(
            conv_transpose2d(&x, &w, None, &p, [2, 0]),
            Err(Error::InvalidArgument { arg: "output_padding", .. })
        ));
        assert!(matches!(
            conv_transpose2d(&x, &w, None, &p.circular(), [0, 0]),
            Err(Error::InvalidArgument { arg: "params", .. })
        ));
        let b = randn(&[3], DType::F32, 10);
        assert!(matches!(conv_transpose2d(&x, &w, Some(&b), &p, [0, 0]), Err(Error::Shape { arg: "bias", .. })));
    }
}
