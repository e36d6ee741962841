//! Resolution changes without learned weights: space-to-depth (2x2 pixels to channels) and
//! nearest-neighbour 2x upsampling.

use crate::{Error, Result};
use candle_core::Tensor;

/// Space-to-depth: `[b, c, 2h, 2w] -> [b, 4c, h, w]`, channel `4 c + 2 dy + dx`. This is PyTorch's
/// `pixel_unshuffle(x, 2)`, i.e. [`crate::shuffle::pixel_unshuffle`] with `r = 2` (tested there).
///
/// ```
/// use candle_core::{DType, Device, Tensor};
/// use pbdl_nets::resample::{space_to_depth, upsample_nearest2};
///
/// let x = Tensor::zeros((2, 3, 8, 4), DType::F32, &Device::Cpu)?;
/// assert_eq!(space_to_depth(&x)?.dims(), &[2, 12, 4, 2]);
/// assert_eq!(upsample_nearest2(&x)?.dims(), &[2, 3, 16, 8]);
/// # Ok::<(), pbdl_nets::Error>(())
/// ```
///
/// # Errors
/// [`Error::ShapeMismatch`] unless `x` is `[batch, channel, y, x]` with even `y` and `x`.
pub fn space_to_depth(x: &Tensor) -> Result<Tensor> {
    let d = x.dims();
    if d.len() != 4 || d[2] % 2 != 0 || d[3] % 2 != 0 {
        return Err(Error::shape("space_to_depth input (height and width must be even)", "[batch, c, 2h, 2w]", d));
    }
    let (b, c, h, w) = x.dims4()?;
    let y = x.reshape((b, c, h / 2, 2, w / 2, 2))?.permute([0, 1, 3, 5, 2, 4])?;
    Ok(y.contiguous()?.reshape((b, 4 * c, h / 2, w / 2))?)
}

/// Nearest-neighbour 2x upsampling `[b, c, h, w] -> [b, c, 2h, 2w]` (its gradient sums the
/// four copies).
///
/// # Errors
/// [`Error::ShapeMismatch`] unless `x` is `[batch, channel, y, x]`.
pub fn upsample_nearest2(x: &Tensor) -> Result<Tensor> {
    if x.rank() != 4 {
        return Err(Error::shape("upsample_nearest2 input", "[batch, c, h, w]", x.dims()));
    }
    let (b, c, h, w) = x.dims4()?;
    let y = x.reshape((b, c, h, 1, w, 1))?.broadcast_as((b, c, h, 2, w, 2))?;
    Ok(y.contiguous()?.reshape((b, c, 2 * h, 2 * w))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn space_to_depth_and_nearest_upsampling_follow_their_index_maps() {
        let x = Tensor::arange(0f32, 32.0, &Device::Cpu).unwrap().reshape((1, 2, 4, 4)).unwrap();
        let y = space_to_depth(&x).unwrap();
        assert_eq!(y.dims(), &[1, 8, 2, 2]);
        let x4: Vec<f32> = x.flatten_all().unwrap().to_vec1().unwrap();
        let y4: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
        // y[c*4 + 2 p1 + p2, i, j] = x[c, 2 i + p1, 2 j + p2]
        for c in 0..2 {
            for p1 in 0..2 {
                for p2 in 0..2 {
                    for i in 0..2 {
                        for j in 0..2 {
                            let yi = ((c * 4 + 2 * p1 + p2) * 2 + i) * 2 + j;
                            let xi = (c * 4 + 2 * i + p1) * 4 + 2 * j + p2;
                            assert_eq!(y4[yi], x4[xi]);
                        }
                    }
                }
            }
        }
        let u = upsample_nearest2(&y).unwrap();
        assert_eq!(u.dims(), &[1, 8, 4, 4]);
        let u4: Vec<f32> = u.flatten_all().unwrap().to_vec1().unwrap();
        for c in 0..8 {
            for i in 0..4 {
                for j in 0..4 {
                    assert_eq!(u4[(c * 4 + i) * 4 + j], y4[(c * 2 + i / 2) * 2 + j / 2]);
                }
            }
        }
    }
}
