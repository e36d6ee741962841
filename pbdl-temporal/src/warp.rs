//! Moving frames in time with a known or estimated motion: the semi-Lagrangian advection of
//! tempoGAN's temporal discriminator and the backward warp of TecoGAN.
//!
//! Conventions: a motion field `[B, 2, y, x]` holds the displacement per frame in cells of the
//! field it moves (x component first, y up as the rows); [`advect`] moves a frame `k` frames
//! forward along it (`k = -1` moves it one frame back). Borders are clamped (border replicate).
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use pbdl_temporal::warp::advect;
//!
//! // A uniform motion of one cell per frame in +x moves a frame one cell to the right.
//! let f = Tensor::arange(0f32, 8.0, &Device::Cpu)?.reshape((1, 1, 1, 8))?;
//! let v = Tensor::cat(&[Tensor::ones((1, 1, 1, 8), candle_core::DType::F32, &Device::Cpu)?,
//!                       Tensor::zeros((1, 1, 1, 8), candle_core::DType::F32, &Device::Cpu)?], 1)?;
//! let moved = advect(&f, &v, 1.0)?;
//! assert_eq!(moved.flatten_all()?.to_vec1::<f32>()?[3], 2.0);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::sample::{resize2d, warp, Boundary, Resize};

/// Semi-Lagrangian advection of `field` `[B, C, y, x]` by `k` frames of the motion `velocity`
/// `[B, 2, y, x]` (cells per frame): `out(x) = field(x - k v(x))`, bilinear, borders clamped.
/// Differentiable with respect to both inputs.
pub fn advect(field: &Tensor, velocity: &Tensor, k: f64) -> Result<Tensor> {
    check_motion("velocity", field, velocity)?;
    Ok(warp(field, &(velocity * -k)?, Boundary::Clamp)?)
}

/// TecoGAN's backward warp: `out(x) = field(x - flow(x))` with `flow` `[B, 2, y, x]` in cells
/// (the motion from the previous frame to the current one); the same as [`advect`] with `k = 1`.
pub fn backward_warp(field: &Tensor, flow: &Tensor) -> Result<Tensor> {
    advect(field, flow, 1.0)
}

/// A low-resolution motion `[B, 2, n, m]` (low-resolution cells per frame) as a motion of the
/// `factor`-times finer grid: bilinearly upsampled (half-pixel centres, edges replicated) and
/// multiplied by `factor`.
pub fn upsample_motion(motion: &Tensor, factor: usize) -> Result<Tensor> {
    let d = motion.dims();
    if d.len() != 4 || d[1] != 2 || factor == 0 {
        return Err(Error::input("velocity", format!("{d:?}: expected [B, 2, y, x] (and a factor >= 1)")));
    }
    let up = resize2d(motion, (d[2] * factor, d[3] * factor), Resize::Bilinear { align_corners: false })?;
    Ok((up * factor as f64)?)
}

fn check_motion(name: &str, field: &Tensor, motion: &Tensor) -> Result<()> {
    let (f, m) = (field.dims(), motion.dims());
    if f.len() != 4 || m.len() != 4 || m[1] != 2 || m[0] != f[0] || m[2] != f[2] || m[3] != f[3] {
        return Err(Error::input(
            name,
            format!(
                "{m:?}: expected [{}, 2, {}, {}] to move a field of shape {f:?}",
                f.first().unwrap_or(&0),
                f.get(2).unwrap_or(&0),
                f.get(3).unwrap_or(&0)
            ),
        ));
    }
    Ok(())
}
