//! The spatio-temporal discriminator's input.

use super::motion::MotionNet;
use crate::warp::{backward_warp, upsample_motion};
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_nets::discriminator::DiscriminatorConfig;

/// Channels of [`triplet_input`] for single-channel frames: 3 frames, 3 warped, 3 upsampled.
pub const TRIPLET_CHANNELS: usize = 9;

/// The fraction of the height and width that the warped triplet keeps (a centred window);
/// the border around it is zeroed, as TecoGAN does where warping reads across the edge.
pub const CROP_FRACTION: f64 = 0.75;

/// The stop-gradient flows `[B, 4, N, N']` that warp the outer frames of a low-resolution
/// triplet `lr_triplet` `[B, 3, n, m]` (frames `t-1, t, t+1` on the channel axis) onto its
/// middle frame, upsampled by `factor`: channels 0..2 warp frame `t-1` onto `t` (F of
/// `(t-1, t)`), channels 2..4 warp frame `t+1` onto `t` (F of `(t+1, t)`).
pub fn triplet_flows(motion: &MotionNet, lr_triplet: &Tensor, factor: usize) -> Result<Tensor> {
    let d = lr_triplet.dims();
    if d.len() != 4 || d[1] != 3 {
        return Err(Error::input("lr triplet", format!("{d:?}: expected [batch, 3 (t-1, t, t+1), y, x]")));
    }
    let frame = |i| lr_triplet.narrow(1, i, 1);
    let (a, mid, c) = (frame(0)?, frame(1)?, frame(2)?);
    let back = upsample_motion(&motion.flow(&a, &mid)?, factor)?;
    let fwd = upsample_motion(&motion.flow(&c, &mid)?, factor)?;
    Ok(Tensor::cat(&[back, fwd], 1)?.detach())
}

/// D_s,t's input `[B, 9, N, N']`: channels 0..3 the high-resolution triplet `hr_triplet`
/// `[B, 3, N, N']` (frames `t-1, t, t+1`); 3..6 the triplet warped onto frame `t` with `flows`
/// `[B, 4, N, N']` (see [`triplet_flows`]; detached here, so no gradient reaches the motion
/// estimate) — frame `t-1` by channels 0..2, frame `t` unchanged, frame `t+1` by channels 2..4
/// — with everything outside the centred [`CROP_FRACTION`] window set to zero; 6..9 the
/// bilinear upsample (half-pixel centres) of the low-resolution triplet `lr_triplet`
/// `[B, 3, n, m]`. Differentiable with respect to `hr_triplet`.
pub fn triplet_input(hr_triplet: &Tensor, lr_triplet: &Tensor, flows: &Tensor) -> Result<Tensor> {
    let (h, l, fl) = (hr_triplet.dims(), lr_triplet.dims(), flows.dims());
    if h.len() != 4 || h[1] != 3 {
        return Err(Error::input("hr triplet", format!("{h:?}: expected [batch, 3 (t-1, t, t+1), y, x]")));
    }
    if l.len() != 4 || l[0] != h[0] || l[1] != 3 {
        return Err(Error::input("lr triplet", format!("{l:?}: expected [{}, 3, y, x]", h[0])));
    }
    if fl != [h[0], 4, h[2], h[3]] {
        return Err(Error::input("triplet flows", format!("{fl:?}: expected [{}, 4, {}, {}]", h[0], h[2], h[3])));
    }
    let flows = flows.detach();
    let frame = |i| hr_triplet.narrow(1, i, 1);
    let warped = Tensor::cat(
        &[
            backward_warp(&frame(0)?, &flows.narrow(1, 0, 2)?)?,
            frame(1)?,
            backward_warp(&frame(2)?, &flows.narrow(1, 2, 2)?)?,
        ],
        1,
    )?;
    let mask = centre_mask(h[2], h[3], hr_triplet)?;
    let warped = warped.broadcast_mul(&mask)?;
    let up = resize2d(lr_triplet, (h[2], h[3]), Resize::Bilinear { align_corners: false })?;
    Ok(Tensor::cat(&[hr_triplet, &warped, &up], 1)?)
}

/// `[1, 1, y, x]`: 1 inside the centred `CROP_FRACTION` window, 0 outside.
fn centre_mask(y: usize, x: usize, like: &Tensor) -> Result<Tensor> {
    let window = |n: usize| {
        let keep = ((n as f64) * CROP_FRACTION).round() as usize;
        let lo = (n - keep) / 2;
        lo..lo + keep
    };
    let (ry, rx) = (window(y), window(x));
    let v: Vec<f32> =
        (0..y * x).map(|i| if ry.contains(&(i / x)) && rx.contains(&(i % x)) { 1.0 } else { 0.0 }).collect();
    Ok(Tensor::from_vec(v, (1, 1, y, x), like.device())?.to_dtype(like.dtype())?)
}

/// A [`DiscriminatorConfig`] for D_s,t on [`triplet_input`]s: [`TRIPLET_CHANNELS`] input
/// channels and the given stride-2 widths (TecoGAN: 64, 64, 128, 256), kernel 4, leaky ReLU
/// 0.2, a head on the spatial mean (pbdl-nets' defaults; TecoGAN has batch norm and a
/// per-pixel head).
pub fn spatio_temporal_discriminator(widths: Vec<usize>) -> DiscriminatorConfig {
    DiscriminatorConfig::new(TRIPLET_CHANNELS, widths)
}
