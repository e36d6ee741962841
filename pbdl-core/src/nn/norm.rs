//! Functional normalisations: composed from differentiable candle ops, except the fused
//! CPU group norm (`super::fused`).

use super::epilogue::Epilogue;
use super::Activation;
use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Half-precision statistics lose too much; normalise those in `f32` (as candle-nn does).
fn internal_dtype(dtype: DType) -> DType {
    match dtype {
        DType::F16 | DType::BF16 => DType::F32,
        d => d,
    }
}

pub(crate) fn check_eps(op: &'static str, eps: f64) -> Result<()> {
    if !(eps >= 0.0 && eps.is_finite()) {
        return Err(Error::invalid(op, "eps", format!("must be a finite number >= 0 (typically 1e-5), got {eps}")));
    }
    Ok(())
}

/// Checks that the trailing dims of `x` are `normalized_shape`; returns (outer, inner) sizes.
fn split_trailing(op: &'static str, x: &Tensor, normalized_shape: &[usize]) -> Result<(usize, usize)> {
    if normalized_shape.is_empty() {
        return Err(Error::invalid(
            op,
            "normalized_shape",
            "is empty; give the trailing dims to normalise over, e.g. &[channels]",
        ));
    }
    let dims = x.dims();
    let k = normalized_shape.len();
    if dims.len() < k || &dims[dims.len() - k..] != normalized_shape {
        return Err(Error::Shape {
            op,
            arg: "x",
            expected: format!("[.., {}] (trailing dims = normalized_shape)", join(normalized_shape)),
            got: dims.to_vec(),
        });
    }
    let inner: usize = normalized_shape.iter().product();
    let outer: usize = dims[..dims.len() - k].iter().product();
    Ok((outer, inner))
}

fn join(dims: &[usize]) -> String {
    dims.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")
}

/// Checks an optional affine parameter's shape and dtype.
fn check_param(
    op: &'static str,
    arg: &'static str,
    p: Option<&Tensor>,
    expected: &[usize],
    dtype: DType,
) -> Result<()> {
    let Some(p) = p else { return Ok(()) };
    if p.dims() != expected {
        return Err(Error::Shape { op, arg, expected: format!("{expected:?}"), got: p.dims().to_vec() });
    }
    if p.dtype() != dtype {
        return Err(Error::invalid(
            op,
            arg,
            format!("has dtype {:?} but x has {dtype:?}; convert one with `.to_dtype(..)`", p.dtype()),
        ));
    }
    Ok(())
}

/// `y * weight + bias`, where the parameters are already shaped to broadcast against `y`.
fn affine(y: Tensor, weight: Option<&Tensor>, bias: Option<&Tensor>) -> Result<Tensor> {
    let y = match weight {
        Some(w) => y.broadcast_mul(w)?,
        None => y,
    };
    Ok(match bias {
        Some(b) => y.broadcast_add(b)?,
        None => y,
    })
}

/// `(x - mean) / sqrt(var + eps)` over dim 1 of a 2-D (or 3-D: dim 2) view; two-pass variance.
fn standardise(x: &Tensor, dim: usize, eps: f64) -> Result<Tensor> {
    let mean = x.mean_keepdim(dim)?;
    let centred = x.broadcast_sub(&mean)?;
    let var = centred.sqr()?.mean_keepdim(dim)?;
    Ok(centred.broadcast_div(&(var + eps)?.sqrt()?)?)
}

/// Layer normalisation over the trailing dims `normalized_shape` of `x`, with optional
/// elementwise `weight` and `bias` of shape `normalized_shape`:
/// `y = (x - mean) / sqrt(var + eps) * weight + bias` (biased variance, as PyTorch's
/// `F.layer_norm`). Differentiable in `x`, `weight` and `bias`, unlike
/// `candle_nn::ops::layer_norm`.
///
/// ```
/// use candle_core::{Device, Tensor};
/// let x = Tensor::new(&[[1.0f64, 2.0, 3.0, 6.0]], &Device::Cpu)?;
/// let y = pbdl_core::nn::layer_norm(&x, &[4], None, None, 0.0)?;
/// // mean 3, variance (4 + 1 + 0 + 9) / 4 = 3.5
/// let s = 3.5f64.sqrt();
/// let expect = [-2.0 / s, -1.0 / s, 0.0, 3.0 / s];
/// for (a, b) in y.flatten_all()?.to_vec1::<f64>()?.iter().zip(expect) {
///     assert!((a - b).abs() < 1e-12);
/// }
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn layer_norm(
    x: &Tensor,
    normalized_shape: &[usize],
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
) -> Result<Tensor> {
    const OP: &str = "layer_norm";
    let (outer, inner) = split_trailing(OP, x, normalized_shape)?;
    check_eps(OP, eps)?;
    check_param(OP, "weight", weight, normalized_shape, x.dtype())?;
    check_param(OP, "bias", bias, normalized_shape, x.dtype())?;
    let flat = x.to_dtype(internal_dtype(x.dtype()))?.reshape((outer, inner))?;
    let y = standardise(&flat, 1, eps)?.reshape(x.shape())?.to_dtype(x.dtype())?;
    // Parameters of shape `normalized_shape` broadcast against the trailing dims.
    affine(y, weight, bias)
}

/// RMS normalisation over the trailing dims `normalized_shape` of `x`:
/// `y = x / sqrt(mean(x^2) + eps) * weight`, with an optional `weight` of shape
/// `normalized_shape`. Differentiable, unlike `candle_nn::ops::rms_norm`.
///
/// ```
/// use candle_core::{Device, Tensor};
/// let x = Tensor::new(&[3.0f64, -4.0], &Device::Cpu)?;
/// let y = pbdl_core::nn::rms_norm(&x, &[2], None, 0.0)?.to_vec1::<f64>()?;
/// let r = 12.5f64.sqrt(); // sqrt((9 + 16) / 2)
/// assert!((y[0] - 3.0 / r).abs() < 1e-12 && (y[1] + 4.0 / r).abs() < 1e-12);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn rms_norm(x: &Tensor, normalized_shape: &[usize], weight: Option<&Tensor>, eps: f64) -> Result<Tensor> {
    const OP: &str = "rms_norm";
    let (outer, inner) = split_trailing(OP, x, normalized_shape)?;
    check_eps(OP, eps)?;
    check_param(OP, "weight", weight, normalized_shape, x.dtype())?;
    let flat = x.to_dtype(internal_dtype(x.dtype()))?.reshape((outer, inner))?;
    let ms = flat.sqr()?.mean_keepdim(1)?;
    let y = flat.broadcast_div(&(ms + eps)?.sqrt()?)?.reshape(x.shape())?.to_dtype(x.dtype())?;
    affine(y, weight, None)
}

/// Group normalisation of `x` laid out `[batch, channel, ..]`: the channels are split into
/// `num_groups` contiguous groups and each (sample, group) is standardised over its channels
/// and all trailing (spatial) dims; then the optional per-channel `weight` and `bias` (shape
/// `[channel]`) are applied. `num_groups = 1` is a layer norm over `[channel, ..]`;
/// `num_groups = channel` is an instance norm.
///
/// On the CPU in `f32` and `f64` this is one fused custom op with a hand-written backward
/// (statistics accumulated in `f64`); other dtypes and devices use [`group_norm_composed`],
/// which gives the same values to round-off.
///
/// ```
/// use candle_core::{DType, Device};
/// let x = pbdl_core::seed::randn((2, 6, 5), 1.0, 3.0, DType::F64, &Device::Cpu, 1)?;
/// let y = pbdl_core::nn::group_norm(&x, 3, None, None, 1e-5)?;
/// // Each of the 2 x 3 groups of 2 channels x 5 points now has mean 0.
/// let means = y.reshape((2, 3, 10))?.mean(2)?.flatten_all()?.to_vec1::<f64>()?;
/// assert!(means.iter().all(|m| m.abs() < 1e-12));
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn group_norm(
    x: &Tensor,
    num_groups: usize,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
) -> Result<Tensor> {
    group_norm_act(x, num_groups, weight, bias, eps, Activation::Identity)
}

/// `act(group_norm(x, ..))`: with a ReLU or LeakyReLU (positive slope) the activation is applied
/// inside the fused group norm kernel (one op, one pass; its derivative is read off the output,
/// 0 at exactly 0 for ReLU as in PyTorch, see `conv_act`); other activations run after it.
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_core::nn::{group_norm, group_norm_act, Activation};
///
/// let x = Tensor::randn(0f32, 1.0, (2, 4, 5, 5), &Device::Cpu)?;
/// let act = Activation::LeakyRelu { negative_slope: 0.2 };
/// let fused = group_norm_act(&x, 2, None, None, 1e-5, act)?;
/// let unfused = act.apply(&group_norm(&x, 2, None, None, 1e-5)?)?;
/// assert_eq!(fused.flatten_all()?.to_vec1::<f32>()?, unfused.flatten_all()?.to_vec1::<f32>()?);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
///
/// # Errors
/// As [`group_norm`].
pub fn group_norm_act(
    x: &Tensor,
    num_groups: usize,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
    act: Activation,
) -> Result<Tensor> {
    check_group_norm(x, num_groups, weight, bias, eps)?;
    if super::fused::fusable(x) {
        if let Some(e) = Epilogue::of(act) {
            return Ok(super::fused::group_norm(x, num_groups, weight, bias, eps, e)?);
        }
        let y = super::fused::group_norm(x, num_groups, weight, bias, eps, Epilogue::Identity)?;
        return act.apply(&y);
    }
    act.apply(&group_norm_composed(x, num_groups, weight, bias, eps)?)
}

/// Checks the arguments of a group norm.
fn check_group_norm(
    x: &Tensor,
    num_groups: usize,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
) -> Result<()> {
    const OP: &str = "group_norm";
    let dims = x.dims();
    if dims.len() < 2 {
        return Err(Error::Shape {
            op: OP,
            arg: "x",
            expected: "rank >= 2 [batch, channel, ..]".into(),
            got: dims.to_vec(),
        });
    }
    let channels = dims[1];
    if num_groups == 0 || channels % num_groups != 0 {
        return Err(Error::invalid(
            OP,
            "num_groups",
            format!("{num_groups} does not divide the {channels} channels; use a divisor of {channels}"),
        ));
    }
    check_eps(OP, eps)?;
    check_param(OP, "weight", weight, &[channels], x.dtype())?;
    check_param(OP, "bias", bias, &[channels], x.dtype())
}

/// [`group_norm`] composed from differentiable candle ops (mean, centre, variance, divide,
/// affine: about 8 ops forward and 20 backward, each a pass over memory into a fresh buffer).
/// Any dtype (half precision is normalised in `f32`) and any device; it is the reference the
/// fused CPU kernel is tested against, and the path `PBDL_NN_COMPOSED=1` selects for A/B
/// timings.
pub fn group_norm_composed(
    x: &Tensor,
    num_groups: usize,
    weight: Option<&Tensor>,
    bias: Option<&Tensor>,
    eps: f64,
) -> Result<Tensor> {
    check_group_norm(x, num_groups, weight, bias, eps)?;
    let dims = x.dims();
    let (batch, channels) = (dims[0], dims[1]);
    let per_group = x.elem_count() / (batch * num_groups).max(1);
    let grouped = x.to_dtype(internal_dtype(x.dtype()))?.reshape((batch, num_groups, per_group))?;
    let y = standardise(&grouped, 2, eps)?.reshape(x.shape())?.to_dtype(x.dtype())?;
    // Per-channel parameters as [1, C, 1, ..] so they broadcast over batch and space.
    let mut param_shape = vec![1; dims.len()];
    param_shape[1] = channels;
    let weight = weight.map(|w| w.reshape(param_shape.as_slice())).transpose()?;
    let bias = bias.map(|b| b.reshape(param_shape.as_slice())).transpose()?;
    affine(y, weight.as_ref(), bias.as_ref())
}
