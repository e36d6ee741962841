//! Input checks shared by the metrics: shapes, dtypes, emptiness, finiteness.

use crate::{Error, Result};
use candle_core::{DType, Tensor};

/// Checks that `t` is `f32` or `f64`.
pub(crate) fn float(op: &'static str, arg: &'static str, t: &Tensor) -> Result<()> {
    match t.dtype() {
        DType::F32 | DType::F64 => Ok(()),
        got => Err(Error::DType { op, arg, expected: "f32 or f64 (convert with `.to_dtype(..)`)", got }),
    }
}

/// Checks that `t` has at least one element.
pub(crate) fn non_empty(op: &'static str, arg: &'static str, t: &Tensor) -> Result<()> {
    if t.elem_count() == 0 {
        return Err(Error::Empty { op, arg, shape: t.dims().to_vec() });
    }
    Ok(())
}

/// Checks that every value of `t` is finite; names the first bad one.
pub(crate) fn finite(op: &'static str, arg: &'static str, t: &Tensor) -> Result<()> {
    let flat = t.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    if let Some((index, &value)) = flat.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Error::NonFinite { op, arg, index, value });
    }
    Ok(())
}

/// Checks a pair of batched fields `[batch, channel, spatial...]` with `spatial` axes in
/// `ranks` (e.g. `1..=3`): same shape, float, non-empty, finite.
pub(crate) fn field_pair(
    op: &'static str,
    a: &Tensor,
    b: &Tensor,
    spatial: std::ops::RangeInclusive<usize>,
) -> Result<()> {
    for (arg, t) in [("a", a), ("b", b)] {
        let r = t.rank();
        if r < 2 || !spatial.contains(&(r - 2)) {
            return Err(Error::Shape {
                op,
                arg,
                expected: format!(
                    "[batch, channel, spatial...] with {} to {} spatial axes",
                    spatial.start(),
                    spatial.end()
                ),
                got: t.dims().to_vec(),
            });
        }
        float(op, arg, t)?;
        non_empty(op, arg, t)?;
    }
    if a.dims() != b.dims() {
        return Err(Error::ShapeMismatch { op, a: a.dims().to_vec(), b: b.dims().to_vec() });
    }
    finite(op, "a", a)?;
    finite(op, "b", b)?;
    Ok(())
}
