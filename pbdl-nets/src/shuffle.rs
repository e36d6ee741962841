//! Pixel shuffle (sub-pixel convolution upsampling) and its inverse, with PyTorch's channel order.
//!
//! [`pixel_shuffle`] moves `r x r` channel groups into space, `[.., c r^2, h, w] -> [.., c, h r,
//! w r]`, as `torch.nn.PixelShuffle(r)`: output `(c, h r + i, w r + j)` is input
//! `(c r^2 + i r + j, h, w)`. [`pixel_unshuffle`] is its exact inverse, as
//! `torch.nn.PixelUnshuffle(r)`. Both are a reshape and a permutation, so candle differentiates
//! them (the gradient of one is the other applied to the cotangent). Like PyTorch they accept any
//! number of leading (batch) axes in front of the last three `[channel, y, x]`.
//!
//! [`crate::resample::space_to_depth`] is `pixel_unshuffle(x, 2)`: its channel `4 c + 2 dy + dx`
//! is PyTorch's order for `r = 2` (checked element by element in this module's tests).

use crate::{Error, Result};
use candle_core::Tensor;

/// The leading axes, flattened into one (1 when there are none), and `(channel, y, x)`.
fn split_dims(what: &str, x: &Tensor) -> Result<(Vec<usize>, usize, [usize; 3])> {
    let d = x.dims();
    if d.len() < 3 {
        return Err(Error::shape(format!("{what} input"), "[.., channel, y, x] (rank 3 or more)", d));
    }
    let lead = d[..d.len() - 3].to_vec();
    let b = lead.iter().product();
    Ok((lead, b, [d[d.len() - 3], d[d.len() - 2], d[d.len() - 1]]))
}

fn check_factor(r: usize) -> Result<()> {
    if r == 0 {
        return Err(Error::InvalidConfig {
            name: "pixel shuffle factor r",
            value: "0".into(),
            hint: "use an upscale / downscale factor of at least 1",
        });
    }
    Ok(())
}

fn with_lead(lead: &[usize], tail: [usize; 3]) -> Vec<usize> {
    lead.iter().copied().chain(tail).collect()
}

/// Pixel shuffle by `r`: `[.., c r^2, h, w] -> [.., c, h r, w r]`, output `(c, h r + i, w r + j)`
/// = input `(c r^2 + i r + j, h, w)` (PyTorch's `F.pixel_shuffle`). `r = 1` is the identity.
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_nets::shuffle::{pixel_shuffle, pixel_unshuffle};
///
/// // One channel group of 4 = 2 x 2 becomes one 2 x 2 block.
/// let x = Tensor::arange(0f32, 4.0, &Device::Cpu)?.reshape((1, 4, 1, 1))?;
/// let y = pixel_shuffle(&x, 2)?;
/// assert_eq!(y.dims(), &[1, 1, 2, 2]);
/// assert_eq!(y.flatten_all()?.to_vec1::<f32>()?, [0.0, 1.0, 2.0, 3.0]);
/// assert_eq!(pixel_unshuffle(&y, 2)?.flatten_all()?.to_vec1::<f32>()?, [0.0, 1.0, 2.0, 3.0]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
///
/// # Errors
/// [`Error::InvalidConfig`] for `r = 0`; [`Error::ShapeMismatch`] for a rank below 3 or a
/// channel count that is not a multiple of `r^2`.
pub fn pixel_shuffle(x: &Tensor, r: usize) -> Result<Tensor> {
    check_factor(r)?;
    let (lead, b, [cr2, h, w]) = split_dims("pixel_shuffle", x)?;
    if cr2 % (r * r) != 0 {
        return Err(Error::shape(
            format!("pixel_shuffle input (channels must be a multiple of r^2 = {})", r * r),
            format!("[.., c * {}, h, w]", r * r),
            x.dims(),
        ));
    }
    let c = cr2 / (r * r);
    let y = x.reshape((b, c, r, r, h, w))?.permute([0, 1, 4, 2, 5, 3])?;
    Ok(y.contiguous()?.reshape(with_lead(&lead, [c, h * r, w * r]))?)
}

/// Pixel unshuffle by `r`, the inverse of [`pixel_shuffle`]: `[.., c, h r, w r] -> [.., c r^2,
/// h, w]`, output `(c r^2 + i r + j, h, w)` = input `(c, h r + i, w r + j)` (PyTorch's
/// `F.pixel_unshuffle`). For `r = 2` it equals [`crate::resample::space_to_depth`].
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use pbdl_nets::shuffle::pixel_unshuffle;
///
/// let x = Tensor::zeros((2, 3, 9, 6), DType::F32, &Device::Cpu)?;
/// assert_eq!(pixel_unshuffle(&x, 3)?.dims(), &[2, 27, 3, 2]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
///
/// # Errors
/// [`Error::InvalidConfig`] for `r = 0`; [`Error::ShapeMismatch`] for a rank below 3 or a
/// height or width that is not a multiple of `r`.
pub fn pixel_unshuffle(x: &Tensor, r: usize) -> Result<Tensor> {
    check_factor(r)?;
    let (lead, b, [c, hr, wr]) = split_dims("pixel_unshuffle", x)?;
    if hr % r != 0 || wr % r != 0 {
        return Err(Error::shape(
            format!("pixel_unshuffle input (height and width must be multiples of r = {r})"),
            format!("[.., c, h * {r}, w * {r}]"),
            x.dims(),
        ));
    }
    let (h, w) = (hr / r, wr / r);
    let y = x.reshape((b, c, h, r, w, r))?.permute([0, 1, 3, 5, 2, 4])?;
    Ok(y.contiguous()?.reshape(with_lead(&lead, [c * r * r, h, w]))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resample::space_to_depth;
    use candle_core::{DType, Device};
    use pbdl_core::{check_grad, grad_check::GradCheckOptions, tolerance::GRAD_CHECK_F64};

    fn to_vec(t: &Tensor) -> Vec<f64> {
        t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap()
    }

    /// Each input element holds its own flat index, so the output names where every value came
    /// from; the index map is PyTorch's `(c, h r + i, w r + j) <- (c r^2 + i r + j, h, w)`.
    #[test]
    fn shuffle_follows_pytorchs_index_map_and_unshuffle_inverts_it() {
        let (b, c, r, h, w) = (2, 3, 3, 2, 4);
        let n = b * c * r * r * h * w;
        let x = Tensor::arange(0u32, n as u32, &Device::Cpu).unwrap().to_dtype(DType::F64).unwrap();
        let x = x.reshape((b, c * r * r, h, w)).unwrap();
        let y = pixel_shuffle(&x, r).unwrap();
        assert_eq!(y.dims(), &[b, c, h * r, w * r]);
        let yv = to_vec(&y);
        for bi in 0..b {
            for ci in 0..c {
                for hi in 0..h {
                    for i in 0..r {
                        for wi in 0..w {
                            for j in 0..r {
                                let out = ((bi * c + ci) * h * r + hi * r + i) * w * r + wi * r + j;
                                let inp = ((bi * c * r * r + ci * r * r + i * r + j) * h + hi) * w + wi;
                                assert_eq!(yv[out], inp as f64, "b {bi} c {ci} h {hi} i {i} w {wi} j {j}");
                            }
                        }
                    }
                }
            }
        }
        assert_eq!(to_vec(&pixel_unshuffle(&y, r).unwrap()), to_vec(&x));
        // And the other way round, on a non-square map.
        let z = pbdl_core::seed::randn((2, 2, 6, 9), 0.0, 1.0, DType::F32, &Device::Cpu, 4).unwrap();
        assert_eq!(to_vec(&pixel_shuffle(&pixel_unshuffle(&z, 3).unwrap(), 3).unwrap()), to_vec(&z));
    }

    #[test]
    fn space_to_depth_is_pixel_unshuffle_by_two() {
        let x = pbdl_core::seed::randn((2, 3, 6, 4), 0.0, 1.0, DType::F32, &Device::Cpu, 1).unwrap();
        assert_eq!(to_vec(&space_to_depth(&x).unwrap()), to_vec(&pixel_unshuffle(&x, 2).unwrap()));
    }

    #[test]
    fn leading_axes_and_identity_and_errors() {
        let x = pbdl_core::seed::randn((2, 3, 8, 2, 2), 0.0, 1.0, DType::F64, &Device::Cpu, 2).unwrap();
        let y = pixel_shuffle(&x, 2).unwrap();
        assert_eq!(y.dims(), &[2, 3, 2, 4, 4]);
        // Leading axes are batch axes: the same as shuffling each [c, h, w] item alone.
        let item = pixel_shuffle(&x.get(1).unwrap().get(2).unwrap(), 2).unwrap();
        assert_eq!(to_vec(&y.get(1).unwrap().get(2).unwrap()), to_vec(&item));
        assert_eq!(to_vec(&pixel_shuffle(&x, 1).unwrap()), to_vec(&x));
        let bad = Tensor::zeros((1, 6, 2, 2), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(pixel_shuffle(&bad, 2), Err(Error::ShapeMismatch { .. })));
        assert!(matches!(pixel_shuffle(&bad, 0), Err(Error::InvalidConfig { .. })));
        assert!(matches!(pixel_unshuffle(&bad, 3), Err(Error::ShapeMismatch { .. })));
        let flat = Tensor::zeros((4, 4), DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(pixel_unshuffle(&flat, 2), Err(Error::ShapeMismatch { .. })));
    }

    #[test]
    fn gradients_match_finite_differences() {
        let x = pbdl_core::seed::randn((2, 8, 3, 2), 0.0, 1.0, DType::F64, &Device::Cpu, 5).unwrap();
        let opts = GradCheckOptions::default();
        let f = |v: &[Tensor]| pixel_shuffle(&v[0], 2).map_err(candle_core::Error::wrap);
        let rep = check_grad(f, &[x], &opts).unwrap();
        rep.ensure(GRAD_CHECK_F64).unwrap();
        let z = pbdl_core::seed::randn((1, 2, 6, 3), 0.0, 1.0, DType::F64, &Device::Cpu, 6).unwrap();
        let g = |v: &[Tensor]| pixel_unshuffle(&v[0], 3).map_err(candle_core::Error::wrap);
        let rep2 = check_grad(g, &[z], &opts).unwrap();
        rep2.ensure(GRAD_CHECK_F64).unwrap();
        eprintln!("pixel_shuffle FD rel error {:e}, pixel_unshuffle {:e}", rep.max_rel_error, rep2.max_rel_error);
    }
}
