//! Rollouts (sequences of scalar fields) to animated GIFs.
//!
//! All frames share one colour range (with [`ColorRange::Auto`](super::ColorRange::Auto):
//! the range of the whole rollout), so colours mean the same value in every frame. Frames are
//! drawn like [`field_to_rgb`](super::field_to_rgb) (y up by default) with the colormap snapped
//! to 255 levels, which GIF's 256-colour palettes hold exactly (the 256th is for NaN).
//!
//! ```
//! use pbdl_core::viz::{rollout_to_gif, GifStyle};
//! # fn main() -> pbdl_core::Result<()> {
//! let dir = tempfile::tempdir().unwrap();
//! let (h, w) = (16, 16);
//! // A wave travelling right, 10 frames.
//! let frames: Vec<Vec<f32>> = (0..10)
//!     .map(|t| (0..h * w).map(|i| ((i % w) as f32 * 0.4 - t as f32 * 0.3).sin()).collect())
//!     .collect();
//! let style = GifStyle { frame_delay_ms: 50, ..GifStyle::diverging() };
//! rollout_to_gif(dir.path().join("wave.gif"), &frames, h, w, &style)?;
//! # Ok(())
//! # }
//! ```

use super::field::{check_len, render, upscale_factor, FieldStyle};
use super::tensor_values;
use crate::error::{Error, Result};
use crate::io::write_atomic;
use candle_core::Tensor;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbaImage};
use std::path::Path;

/// How a rollout is animated.
#[derive(Clone, Debug, PartialEq)]
pub struct GifStyle {
    /// How each frame is drawn; its range is applied to all frames together.
    pub field: FieldStyle,
    /// Time each frame is shown, in milliseconds (GIF stores hundredths of a second; many
    /// viewers show delays under 20 ms slower). Default: 100.
    pub frame_delay_ms: u32,
    /// Loop forever (default) or play once.
    pub repeat: bool,
}

impl Default for GifStyle {
    fn default() -> Self {
        GifStyle { field: FieldStyle::default(), frame_delay_ms: 100, repeat: true }
    }
}

impl GifStyle {
    /// [`FieldStyle::diverging`] frames, otherwise the defaults.
    pub fn diverging() -> Self {
        GifStyle { field: FieldStyle::diverging(), ..Default::default() }
    }
}

/// Writes `frames` (each `h * w` values, row-major `[y, x]`) as an animated GIF, atomically.
///
/// Errors: [`Error::InvalidArgument`] for no frames or a bad range or delay,
/// [`Error::Shape`] for a frame of the wrong length.
pub fn rollout_to_gif<T, S>(path: impl AsRef<Path>, frames: &[S], h: usize, w: usize, style: &GifStyle) -> Result<()>
where
    T: Copy + Into<f64>,
    S: AsRef<[T]>,
{
    const OP: &str = "rollout_to_gif";
    if frames.is_empty() {
        return Err(Error::invalid(OP, "frames", "no frames to animate"));
    }
    for f in frames {
        check_len(OP, "frames", f.as_ref().len(), h, w)?;
    }
    if style.frame_delay_ms == 0 || style.frame_delay_ms > 655_350 {
        return Err(Error::invalid(OP, "frame_delay_ms", format!("{} ms; use 10..=655350", style.frame_delay_ms)));
    }
    let field = &style.field;
    let all = frames.iter().flat_map(|f| f.as_ref().iter().copied());
    let (lo, hi) = field.range.resolve(all, field.colormap)?;
    let k = upscale_factor(OP, field, h, w)?;
    if (w * k as usize).max(h * k as usize) > u16::MAX as usize {
        return Err(Error::invalid(OP, "upscale", "GIF frames are at most 65535 pixels wide and high"));
    }
    let delay = Delay::from_numer_denom_ms(style.frame_delay_ms, 1);
    let images = frames.iter().map(|f| {
        let f = f.as_ref();
        let rgb = render(|i| f[i].into(), h, w, k, field, lo, hi, Some(255));
        let rgba = RgbaImage::from_fn(rgb.width(), rgb.height(), |x, y| {
            let [r, g, b] = rgb.get_pixel(x, y).0;
            image::Rgba([r, g, b, 255])
        });
        Frame::from_parts(rgba, 0, 0, delay)
    });
    write_atomic(path, |w| {
        // Speed 10 only matters above 256 colours, which our frames never have.
        let mut enc = GifEncoder::new_with_speed(w, 10);
        let repeat = if style.repeat { Repeat::Infinite } else { Repeat::Finite(0) };
        enc.set_repeat(repeat).map_err(std::io::Error::other)?;
        for frame in images {
            enc.encode_frame(frame).map_err(std::io::Error::other)?;
        }
        Ok(())
    })
}

/// [`rollout_to_gif`] for a tensor `[T, H, W]` or `[T, 1, H, W]` (a one-channel trajectory).
pub fn tensor_rollout_to_gif(path: impl AsRef<Path>, rollout: &Tensor, style: &GifStyle) -> Result<()> {
    let dims = rollout.dims();
    let (t, h, w) = match dims {
        [t, h, w] => (*t, *h, *w),
        [t, c, rest @ ..] if rest.len() == 2 && *c == 1 => (*t, rest[0], rest[1]),
        _ => {
            return Err(Error::Shape {
                op: "tensor_rollout_to_gif",
                arg: "rollout",
                expected: "[T, H, W] or [T, 1, H, W]; pick a channel with .narrow(1, c, 1)".into(),
                got: dims.to_vec(),
            })
        }
    };
    let values = tensor_values(rollout)?;
    // An empty frame size still yields `t` (empty) frames, so that the error is about the shape.
    let frames: Vec<&[f64]> = (0..t).map(|i| &values[i * h * w..(i + 1) * h * w]).collect();
    rollout_to_gif(path, &frames, h, w, style)
}
