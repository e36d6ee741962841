//! Padding with a mode per axis: zeros, periodic, replicate or reflect, as `numpy.pad`.
//!
//! [`pad_per_axis`] pads the trailing axes of a tensor (the spatial axes of `[batch, channel, y,
//! x]` or `[batch, channel, z, y, x]`), each with its own `(before, after, mode)`, so a global
//! weather field can be periodic in longitude and replicated in latitude. The modes are exactly
//! `numpy.pad`'s, including pads wider than the axis:
//!
//! | [`PadMode`] | `numpy.pad` | PyTorch `F.pad` | `[1 2 3 4 5]` padded `(2, 3)` |
//! |---|---|---|---|
//! | `Zeros` | `'constant'` (0) | `'constant'` | `0 0 1 2 3 4 5 0 0 0` |
//! | `Periodic` | `'wrap'` | `'circular'` (needs pad <= n) | `4 5 1 2 3 4 5 1 2 3` |
//! | `Replicate` | `'edge'` | `'replicate'` | `1 1 1 2 3 4 5 5 5 5` |
//! | `Reflect` | `'reflect'` | `'reflect'` (needs pad < n) | `3 2 1 2 3 4 5 4 3 2` |
//!
//! `Reflect` mirrors about the edge element without repeating it; wider pads continue the
//! mirror image periodically (period `2 (n - 1)`, as numpy), and an axis of one element is
//! replicated (numpy's legacy behaviour). Zeros are a candle `cat`; the other modes are an
//! `index_select` along the axis, whose gradient sums the copies back onto their source.
//! [`crate::Padding`] (what [`crate::PaddedConv2d`] uses) covers the conv-layer cases; its
//! `PeriodicX` computes what `pad_per_axis(x, &[(0, 0, Zeros), (p, p, Periodic)])` followed by a conv with
//! zero padding `p` along y computes, without the padded copy.

use crate::{Error, Result};
use candle_core::Tensor;
use serde::{Deserialize, Serialize};

/// How one axis is extended beyond its ends (see the module docs for the numpy names).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PadMode {
    /// Zeros (numpy `'constant'` with 0). The default.
    #[default]
    Zeros,
    /// Periodic continuation (numpy `'wrap'`, PyTorch `'circular'`).
    Periodic,
    /// The edge value repeated (numpy `'edge'`, PyTorch `'replicate'`).
    Replicate,
    /// Mirror image about the edge element, which is not repeated (numpy `'reflect'`).
    Reflect,
}

impl PadMode {
    /// The source index, in `0..n`, of padded position `j` (`j < 0` before the axis, `j >= n`
    /// after it). Not for [`PadMode::Zeros`]; `n >= 1`.
    fn source(self, j: i64, n: i64) -> i64 {
        match self {
            PadMode::Zeros | PadMode::Periodic => j.rem_euclid(n),
            PadMode::Replicate => j.clamp(0, n - 1),
            PadMode::Reflect if n == 1 => 0,
            PadMode::Reflect => {
                let period = 2 * (n - 1);
                let m = j.rem_euclid(period);
                if m < n {
                    m
                } else {
                    period - m
                }
            }
        }
    }
}

/// Pads one axis `dim` of `x` by `before` and `after` elements in `mode`.
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_nets::pad::{pad_axis, PadMode};
///
/// let x = Tensor::new(&[1f32, 2., 3., 4., 5.], &Device::Cpu)?;
/// let y = pad_axis(&x, 0, 2, 3, PadMode::Reflect)?;
/// assert_eq!(y.to_vec1::<f32>()?, [3., 2., 1., 2., 3., 4., 5., 4., 3., 2.]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
///
/// # Errors
/// [`Error::ShapeMismatch`] for `dim` out of range, or for an empty axis with a non-zero pad
/// in a mode other than `Zeros` (there is nothing to copy).
pub fn pad_axis(x: &Tensor, dim: usize, before: usize, after: usize, mode: PadMode) -> Result<Tensor> {
    if dim >= x.rank() {
        return Err(Error::shape(format!("pad_axis input (axis {dim} to pad)"), format!("rank > {dim}"), x.dims()));
    }
    if before == 0 && after == 0 {
        return Ok(x.clone());
    }
    if mode == PadMode::Zeros {
        return Ok(x.pad_with_zeros(dim, before, after)?);
    }
    let n = x.dim(dim)?;
    if n == 0 {
        return Err(Error::shape(
            format!("pad_axis input ({mode:?} padding needs a non-empty axis {dim})"),
            format!("size >= 1 along axis {dim}"),
            x.dims(),
        ));
    }
    let (b, n) = (before as i64, n as i64);
    let idx: Vec<u32> = (-b..n + after as i64).map(|j| mode.source(j, n) as u32).collect();
    let idx = Tensor::from_vec(idx, before + n as usize + after, x.device())?;
    Ok(x.index_select(&idx, dim)?)
}

/// Pads the last `pads.len()` axes of `x`, `pads[k] = (before, after, mode)` for axis
/// `rank - pads.len() + k` (so for `[batch, channel, y, x]`, `pads = [y, x]`). Axes are padded
/// one after the other; corners therefore combine the modes as `numpy.pad` does.
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_nets::pad::{pad_per_axis, PadMode};
///
/// // [1, 1, 2, 3]: periodic in x (longitude), replicated in y (latitude).
/// let x = Tensor::new(&[[1f32, 2., 3.], [4., 5., 6.]], &Device::Cpu)?.reshape((1, 1, 2, 3))?;
/// let y = pad_per_axis(&x, &[(1, 1, PadMode::Replicate), (1, 1, PadMode::Periodic)])?;
/// assert_eq!(
///     y.squeeze(0)?.squeeze(0)?.to_vec2::<f32>()?,
///     [[3., 1., 2., 3., 1.], [3., 1., 2., 3., 1.], [6., 4., 5., 6., 4.], [6., 4., 5., 6., 4.]]
/// );
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
///
/// # Errors
/// [`Error::ShapeMismatch`] if `x` has fewer than `pads.len()` axes, or as [`pad_axis`].
pub fn pad_per_axis(x: &Tensor, pads: &[(usize, usize, PadMode)]) -> Result<Tensor> {
    if x.rank() < pads.len() {
        return Err(Error::shape(
            format!("pad_per_axis input ({} padded axes)", pads.len()),
            format!("rank >= {}", pads.len()),
            x.dims(),
        ));
    }
    let first = x.rank() - pads.len();
    let mut y = x.clone();
    for (k, &(before, after, mode)) in pads.iter().enumerate() {
        y = pad_axis(&y, first + k, before, after, mode)?;
    }
    Ok(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use pbdl_core::{check_grad, grad_check::GradCheckOptions, tolerance::GRAD_CHECK_F64};

    fn pad1(v: &[f64], before: usize, after: usize, mode: PadMode) -> Vec<f64> {
        let x = Tensor::new(v, &Device::Cpu).unwrap();
        pad_axis(&x, 0, before, after, mode).unwrap().to_vec1().unwrap()
    }

    /// numpy.pad's documented examples on `[1, 2, 3, 4, 5]` with `(2, 3)`, and hand-worked wide
    /// pads (numpy continues wrap / reflect periodically past the axis length).
    #[test]
    fn one_axis_matches_numpy_pad() {
        let a = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(pad1(&a, 2, 3, PadMode::Zeros), [0., 0., 1., 2., 3., 4., 5., 0., 0., 0.]);
        assert_eq!(pad1(&a, 2, 3, PadMode::Periodic), [4., 5., 1., 2., 3., 4., 5., 1., 2., 3.]);
        assert_eq!(pad1(&a, 2, 3, PadMode::Replicate), [1., 1., 1., 2., 3., 4., 5., 5., 5., 5.]);
        assert_eq!(pad1(&a, 2, 3, PadMode::Reflect), [3., 2., 1., 2., 3., 4., 5., 4., 3., 2.]);
        // np.pad([1, 2, 3], 5, 'reflect'): period 4 = 2 (n - 1).
        let b = [1.0, 2.0, 3.0];
        assert_eq!(pad1(&b, 5, 5, PadMode::Reflect), [2., 1., 2., 3., 2., 1., 2., 3., 2., 1., 2., 3., 2.]);
        // np.pad([1, 2, 3], (4, 5), 'wrap')
        assert_eq!(pad1(&b, 4, 5, PadMode::Periodic), [3., 1., 2., 3., 1., 2., 3., 1., 2., 3., 1., 2.]);
        // A single element: reflect replicates it (numpy's legacy rule); no pad, no change.
        assert_eq!(pad1(&[7.0], 2, 1, PadMode::Reflect), [7., 7., 7., 7.]);
        assert_eq!(pad1(&b, 0, 0, PadMode::Reflect), b);
        assert_eq!(pad1(&b, 0, 2, PadMode::Reflect), [1., 2., 3., 2., 1.]);
    }

    /// 2D, one mode per axis, corners included: `np.pad(a, ((1, 2), (2, 1)), mode)` per axis
    /// means padding y first and then x on the y-padded array.
    #[test]
    fn two_axes_with_different_modes_match_hand_computed_arrays() {
        let a = Tensor::new(&[[1f64, 2., 3.], [4., 5., 6.]], &Device::Cpu).unwrap().reshape((1, 1, 2, 3)).unwrap();
        let pad2 = |py: (usize, usize, PadMode), px: (usize, usize, PadMode)| -> Vec<Vec<f64>> {
            pad_per_axis(&a, &[py, px]).unwrap().squeeze(0).unwrap().squeeze(0).unwrap().to_vec2().unwrap()
        };
        // y zeros (1, 0), x reflect (2, 1)
        assert_eq!(
            pad2((1, 0, PadMode::Zeros), (2, 1, PadMode::Reflect)),
            [[0., 0., 0., 0., 0., 0.], [3., 2., 1., 2., 3., 2.], [6., 5., 4., 5., 6., 5.]]
        );
        // y reflect (1, 1) (2 rows: mirror gives the other row), x edge (1, 2)
        assert_eq!(
            pad2((1, 1, PadMode::Reflect), (1, 2, PadMode::Replicate)),
            [[4., 4., 5., 6., 6., 6.], [1., 1., 2., 3., 3., 3.], [4., 4., 5., 6., 6., 6.], [1., 1., 2., 3., 3., 3.]]
        );
        // y wrap (0, 3), x zeros (1, 1)
        assert_eq!(
            pad2((0, 3, PadMode::Periodic), (1, 1, PadMode::Zeros)),
            [
                [0., 1., 2., 3., 0.],
                [0., 4., 5., 6., 0.],
                [0., 1., 2., 3., 0.],
                [0., 4., 5., 6., 0.],
                [0., 1., 2., 3., 0.]
            ]
        );
    }

    #[test]
    fn three_spatial_axes_and_batch_axes_are_untouched() {
        let x = pbdl_core::seed::randn((2, 3, 2, 3, 4), 0.0, 1.0, DType::F32, &Device::Cpu, 1).unwrap();
        let pads = [(1, 0, PadMode::Replicate), (0, 2, PadMode::Reflect), (3, 3, PadMode::Periodic)];
        let y = pad_per_axis(&x, &pads).unwrap();
        assert_eq!(y.dims(), &[2, 3, 3, 5, 10]);
        // Each (batch, channel) item padded alone gives the same.
        let item = pad_per_axis(&x.get(1).unwrap().get(2).unwrap(), &pads).unwrap();
        let a: Vec<f32> = y.get(1).unwrap().get(2).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(a, item.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        // f32 and f64 pad identically (copies only).
        let y64 = pad_per_axis(&x.to_dtype(DType::F64).unwrap(), &pads).unwrap();
        let b: Vec<f64> = y64.flatten_all().unwrap().to_vec1().unwrap();
        let c: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
        assert!(b.iter().zip(&c).all(|(u, &v)| *u == v as f64));
    }

    #[test]
    fn errors_name_the_problem() {
        let x = Tensor::zeros((2, 0, 3), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(pad_axis(&x, 1, 1, 0, PadMode::Periodic), Err(Error::ShapeMismatch { .. })));
        assert_eq!(pad_axis(&x, 1, 1, 2, PadMode::Zeros).unwrap().dims(), &[2, 3, 3]);
        assert!(matches!(pad_axis(&x, 3, 1, 1, PadMode::Zeros), Err(Error::ShapeMismatch { .. })));
        let pads = [(1, 1, PadMode::Zeros); 4];
        assert!(matches!(pad_per_axis(&x, &pads), Err(Error::ShapeMismatch { .. })));
    }

    /// Wide pads make elements appear several times; the gradient must add all copies.
    #[test]
    fn gradients_match_finite_differences_for_every_mode() {
        let x = pbdl_core::seed::randn((1, 2, 3, 4), 0.0, 1.0, DType::F64, &Device::Cpu, 2).unwrap();
        let mut worst = 0.0f64;
        for mode in [PadMode::Zeros, PadMode::Periodic, PadMode::Replicate, PadMode::Reflect] {
            let f = |v: &[Tensor]| {
                pad_per_axis(&v[0], &[(4, 2, mode), (1, 6, PadMode::Reflect)]).map_err(candle_core::Error::wrap)
            };
            let rep = check_grad(f, std::slice::from_ref(&x), &GradCheckOptions::default()).unwrap();
            rep.ensure(GRAD_CHECK_F64).unwrap();
            worst = worst.max(rep.max_rel_error);
        }
        eprintln!("pad_per_axis FD rel error (worst over modes) {worst:e}");
    }
}
