//! Pointwise error metrics: MSE, MAE, RMSE, relative L2, PSNR.

use crate::{check, Error, Result};
use candle_core::{DType, Tensor};

/// Mean over every axis but the batch axis: `[batch, ...] -> [batch]`.
pub(crate) fn per_sample_mean(t: &Tensor) -> Result<Tensor> {
    Ok(t.flatten_from(1)?.mean(1)?)
}

/// Sum over every axis but the batch axis: `[batch, ...] -> [batch]`.
pub(crate) fn per_sample_sum(t: &Tensor) -> Result<Tensor> {
    Ok(t.flatten_from(1)?.sum(1)?)
}

/// Mean squared error per sample: `mean (a - b)^2` over channels and space; `[batch]`.
///
/// Differentiable in `a` and `b`. Errors: shapes that differ or are not
/// `[batch, channel, spatial...]` with 1 to 3 spatial axes, dtypes other than `f32`/`f64`,
/// empty or non-finite inputs.
pub fn mse(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    check::field_pair("mse", a, b, 1..=3)?;
    per_sample_mean(&(a - b)?.sqr()?)
}

/// Mean absolute error per sample: `mean |a - b|`; `[batch]`. Checks as [`mse`].
pub fn mae(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    check::field_pair("mae", a, b, 1..=3)?;
    per_sample_mean(&(a - b)?.abs()?)
}

/// Root mean squared error per sample: `sqrt(mse)`; `[batch]`. Checks as [`mse`]. (Its gradient
/// is infinite where `a == b`, as for any square root at zero.)
pub fn rmse(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    check::field_pair("rmse", a, b, 1..=3)?;
    Ok(per_sample_mean(&(a - b)?.sqr()?)?.sqrt()?)
}

/// Relative L2 error per sample: `||pred - target||_2 / ||target||_2`; `[batch]`.
///
/// `target` is the reference. A sample whose target is zero everywhere has no relative error:
/// [`Error::Invalid`] (use [`rmse`] there).
pub fn rel_l2(pred: &Tensor, target: &Tensor) -> Result<Tensor> {
    check::field_pair("rel_l2", pred, target, 1..=3)?;
    let norm = per_sample_sum(&target.sqr()?)?;
    let norms = norm.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    if let Some(i) = norms.iter().position(|&n| n == 0.0) {
        return Err(Error::invalid(
            "rel_l2",
            "target",
            format!("sample {i} of the target is zero everywhere, so the relative error is undefined; use rmse"),
        ));
    }
    Ok((per_sample_sum(&(pred - target)?.sqr()?)? / norm)?.sqrt()?)
}

/// Peak signal-to-noise ratio in decibels per sample: `10 log10(R^2 / mse(pred, target))`; `[batch]`.
///
/// `data_range` is `R`, the range the values can span (255 for 8-bit images, 1 for fields in
/// [0, 1]); `None` takes each sample's peak-to-peak range of `target` (as a constant, not
/// differentiated). Identical inputs give `+inf` (the usual convention). Errors: a
/// non-positive or non-finite `data_range`, or `None` with a constant target; otherwise as [`mse`].
pub fn psnr(pred: &Tensor, target: &Tensor, data_range: Option<f64>) -> Result<Tensor> {
    check::field_pair("psnr", pred, target, 1..=3)?;
    let batch = target.dim(0)?;
    let ranges: Vec<f64> = match data_range {
        Some(r) if r > 0.0 && r.is_finite() => vec![r; batch],
        Some(r) => return Err(Error::invalid("psnr", "data_range", format!("must be positive and finite, got {r}"))),
        None => {
            let flat = target.flatten_from(1)?.to_dtype(DType::F64)?;
            let hi = flat.max(1)?.to_vec1::<f64>()?;
            let lo = flat.min(1)?.to_vec1::<f64>()?;
            let r: Vec<f64> = hi.iter().zip(&lo).map(|(h, l)| h - l).collect();
            if let Some(i) = r.iter().position(|&r| r == 0.0) {
                return Err(Error::invalid(
                    "psnr",
                    "data_range",
                    format!("sample {i} of the target is constant, so its range is 0; pass Some(range)"),
                ));
            }
            r
        }
    };
    let r2 = Tensor::from_vec(ranges.iter().map(|r| r * r).collect::<Vec<_>>(), batch, target.device())?
        .to_dtype(target.dtype())?;
    let m = per_sample_mean(&(pred - target)?.sqr()?)?;
    Ok(((r2 / m)?.log()? * (10.0 / std::f64::consts::LN_10))?)
}
