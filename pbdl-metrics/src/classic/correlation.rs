//! Pearson and Spearman correlation: per sample of batched fields, and of plain value lists.
//!
//! Pearson's `r = sum (a - mean a)(b - mean b) / sqrt(sum (a - mean a)^2 sum (b - mean b)^2)`
//! over all values of a sample (channels and space). Spearman's rho is Pearson's r of the ranks,
//! with tied values sharing their average rank (as `scipy.stats.spearmanr`). Both are undefined
//! when one side is constant: that is an [`Error::Invalid`], never a NaN.

use crate::classic::pointwise::per_sample_sum;
use crate::{check, Error, Result};
use candle_core::{DType, Tensor};

/// Pearson correlation per sample of `[batch, channel, spatial...]` fields; `[batch]`.
///
/// Differentiable in `a` and `b`. A linear map `b = s a + c` gives `sign(s)`. Errors: those of
/// [`mse`](super::mse), and a sample that is constant in `a` or `b`.
pub fn pearson(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    check::field_pair("pearson", a, b, 1..=3)?;
    let a = a.flatten_from(1)?;
    let b = b.flatten_from(1)?;
    let da = a.broadcast_sub(&a.mean_keepdim(1)?)?;
    let db = b.broadcast_sub(&b.mean_keepdim(1)?)?;
    let saa = per_sample_sum(&da.sqr()?)?;
    let sbb = per_sample_sum(&db.sqr()?)?;
    for (arg, s) in [("a", &saa), ("b", &sbb)] {
        let v = s.to_dtype(DType::F64)?.to_vec1::<f64>()?;
        if let Some(i) = v.iter().position(|&v| v == 0.0) {
            return Err(constant("pearson", arg, i));
        }
    }
    Ok((per_sample_sum(&(da * db)?)? / (saa * sbb)?.sqrt()?)?)
}

/// Spearman rank correlation per sample of `[batch, channel, spatial...]` fields.
///
/// Ranks are not differentiable, so this returns plain numbers. Errors: as [`pearson`].
pub fn spearman(a: &Tensor, b: &Tensor) -> Result<Vec<f64>> {
    check::field_pair("spearman", a, b, 1..=3)?;
    let a = a.flatten_from(1)?.to_dtype(DType::F64)?.to_vec2::<f64>()?;
    let b = b.flatten_from(1)?.to_dtype(DType::F64)?.to_vec2::<f64>()?;
    a.iter()
        .zip(&b)
        .enumerate()
        .map(|(i, (a, b))| pearson_of(&ranks(a), &ranks(b)).map_err(|arg| constant("spearman", arg, i)))
        .collect()
}

/// Pearson correlation of two lists of values (e.g. distances against ground truth).
///
/// Errors: lists of different or zero length, non-finite values, a constant list.
pub fn pearson_values(a: &[f64], b: &[f64]) -> Result<f64> {
    values("pearson_values", a, b)?;
    pearson_of(a, b).map_err(|arg| constant("pearson_values", arg, 0))
}

/// Spearman rank correlation of two lists of values, ties sharing their average rank.
///
/// Errors: as [`pearson_values`].
pub fn spearman_values(a: &[f64], b: &[f64]) -> Result<f64> {
    values("spearman_values", a, b)?;
    pearson_of(&ranks(a), &ranks(b)).map_err(|arg| constant("spearman_values", arg, 0))
}

fn constant(op: &'static str, arg: &'static str, sample: usize) -> Error {
    Error::invalid(op, arg, format!("sample {sample} is constant, so the correlation is undefined"))
}

fn values(op: &'static str, a: &[f64], b: &[f64]) -> Result<()> {
    if a.len() != b.len() {
        return Err(Error::ShapeMismatch { op, a: vec![a.len()], b: vec![b.len()] });
    }
    for (arg, v) in [("a", a), ("b", b)] {
        if v.is_empty() {
            return Err(Error::Empty { op, arg, shape: vec![0] });
        }
        if let Some((index, &value)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
            return Err(Error::NonFinite { op, arg, index, value });
        }
    }
    Ok(())
}

/// Pearson's r in f64 with centred sums; `Err(arg)` names a constant side.
fn pearson_of(a: &[f64], b: &[f64]) -> std::result::Result<f64, &'static str> {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa == 0.0 {
        return Err("a");
    }
    if sbb == 0.0 {
        return Err("b");
    }
    Ok((sab / (saa * sbb).sqrt()).clamp(-1.0, 1.0))
}

/// 1-based ranks, ties sharing the average of their ranks.
pub(crate) fn ranks(v: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&i, &j| v[i].total_cmp(&v[j]));
    let mut r = vec![0.0; v.len()];
    let mut start = 0;
    while start < order.len() {
        let mut end = start + 1;
        while end < order.len() && v[order[end]] == v[order[start]] {
            end += 1;
        }
        // Ranks start+1 ..= end share their mean.
        let avg = (start + 1 + end) as f64 / 2.0;
        for &i in &order[start..end] {
            r[i] = avg;
        }
        start = end;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ties_share_their_average_rank() {
        assert_eq!(ranks(&[10.0, 20.0, 10.0, 30.0, 20.0]), [1.5, 3.5, 1.5, 5.0, 3.5]);
    }

    #[test]
    fn spearman_of_a_monotone_map_is_one() {
        let a: Vec<f64> = (0..20).map(|i| i as f64 * 0.3 - 2.0).collect();
        let b: Vec<f64> = a.iter().map(|x| x.powi(3) + 5.0).collect();
        assert_eq!(spearman_values(&a, &b).unwrap(), 1.0);
        let c: Vec<f64> = a.iter().map(|x| (-x).exp()).collect();
        assert_eq!(spearman_values(&a, &c).unwrap(), -1.0);
    }

    #[test]
    fn spearman_matches_scipy_with_ties() {
        // scipy.stats.spearmanr([1, 2, 2, 3, 5, 4], [2, 1, 4, 4, 6, 3]).statistic
        let r = spearman_values(&[1., 2., 2., 3., 5., 4.], &[2., 1., 4., 4., 6., 3.]).unwrap();
        assert!((r - 0.6617647058823529).abs() < 1e-12, "{r}");
    }

    #[test]
    fn constant_lists_are_an_error() {
        let e = pearson_values(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).unwrap_err();
        assert!(e.to_string().contains("constant"), "{e}");
    }
}
