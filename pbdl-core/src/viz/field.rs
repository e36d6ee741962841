//! Scalar and vector fields to images.
//!
//! **Orientation.** A field `[H, W]` is indexed `[y, x]` with x fastest, as everywhere in pbdl.
//! Physical fields have y pointing up, so by default ([`Origin::Lower`]) row `y = 0` is drawn at
//! the *bottom* of the image, like matplotlib's `imshow(origin="lower")`. Use [`Origin::Upper`]
//! for image-like data whose row 0 is the top.
//!
//! **Size.** Each cell becomes a `k x k` block of pixels (nearest neighbour, no smoothing, so
//! cells stay visible). By default `k` is chosen so that the longer side is at least 256 pixels
//! (at most 16x); [`FieldStyle::upscale`] fixes it.
//!
//! ```
//! use pbdl_core::viz::{field_to_png, FieldStyle};
//! # fn main() -> pbdl_core::Result<()> {
//! let dir = tempfile::tempdir().unwrap();
//! let (h, w) = (32, 48);
//! // A bump in the lower left: y = 0 is the bottom row of the picture.
//! let data: Vec<f32> = (0..h * w)
//!     .map(|i| {
//!         let (y, x) = ((i / w) as f32, (i % w) as f32);
//!         (-((x - 10.0).powi(2) + (y - 8.0).powi(2)) / 40.0).exp()
//!     })
//!     .collect();
//! field_to_png(dir.path().join("bump.png"), &data, h, w, &FieldStyle::default())?;
//! let img = image::open(dir.path().join("bump.png")).unwrap();
//! assert_eq!((img.width(), img.height()), (48 * 6, 32 * 6));
//! # Ok(())
//! # }
//! ```

use super::colormap::{normalize, ColorRange, Colormap};
use super::{tensor_values, write_png};
use crate::error::{Error, Result};
use candle_core::Tensor;
use image::{Rgb, RgbImage};
use std::path::Path;

/// Where row 0 of a field is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Origin {
    /// Row 0 (y = 0) at the bottom: physical fields with y up. The default.
    #[default]
    Lower,
    /// Row 0 at the top: images and matrices.
    Upper,
}

/// How a scalar field is drawn.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldStyle {
    /// The colormap. Default: [`Colormap::Viridis`].
    pub colormap: Colormap,
    /// The data range mapped onto the colormap. Default: [`ColorRange::Auto`].
    pub range: ColorRange,
    /// Pixels per cell (integer, nearest neighbour); `None` (default): [`auto_upscale`].
    pub upscale: Option<u32>,
    /// Where row 0 goes. Default: [`Origin::Lower`] (y up).
    pub origin: Origin,
    /// Colour of NaN values. Default: [`NAN_COLOR`](super::NAN_COLOR) (magenta), so that a
    /// blown-up simulation is obvious; renders that use NaN for "empty" (particle scatter
    /// plots) set a background colour here.
    pub nan_color: [u8; 3],
}

impl Default for FieldStyle {
    fn default() -> Self {
        FieldStyle {
            colormap: Colormap::default(),
            range: ColorRange::default(),
            upscale: None,
            origin: Origin::default(),
            nan_color: super::NAN_COLOR,
        }
    }
}

impl FieldStyle {
    /// A style for signed data: [`Colormap::BlueWhiteRed`] with a range symmetric about 0.
    pub fn diverging() -> Self {
        FieldStyle { colormap: Colormap::BlueWhiteRed, ..Default::default() }
    }
}

/// The default upscale factor: the smallest integer that makes the longer side at least 256
/// pixels, clamped to `1..=16`.
pub fn auto_upscale(h: usize, w: usize) -> u32 {
    let m = h.max(w).max(1);
    256usize.div_ceil(m).clamp(1, 16) as u32
}

/// Renders a scalar field `data` (`h * w` values, row-major `[y, x]`) to an RGB image.
///
/// Errors: [`Error::Shape`] if `data.len() != h * w` or a side is 0,
/// [`Error::InvalidArgument`] for a bad range or upscale factor.
pub fn field_to_rgb<T: Copy + Into<f64>>(data: &[T], h: usize, w: usize, style: &FieldStyle) -> Result<RgbImage> {
    check_len("field_to_rgb", "data", data.len(), h, w)?;
    let (lo, hi) = style.range.resolve(data.iter().copied(), style.colormap)?;
    let k = upscale_factor("field_to_rgb", style, h, w)?;
    Ok(render(|i| data[i].into(), h, w, k, style, lo, hi, None))
}

/// Renders a scalar field to a PNG file (written atomically); see [`field_to_rgb`].
pub fn field_to_png<T: Copy + Into<f64>>(
    path: impl AsRef<Path>,
    data: &[T],
    h: usize,
    w: usize,
    style: &FieldStyle,
) -> Result<()> {
    write_png(path, &field_to_rgb(data, h, w, style)?)
}

/// [`field_to_rgb`] for a tensor `[H, W]` (leading size-1 axes, e.g. `[1, 1, H, W]`, are
/// accepted) of any dtype.
pub fn tensor_field_to_rgb(field: &Tensor, style: &FieldStyle) -> Result<RgbImage> {
    let dims = strip_leading_ones(field.dims(), 2);
    if dims.len() != 2 {
        return Err(Error::Shape {
            op: "tensor_field_to_rgb",
            arg: "field",
            expected: "[H, W] (leading size-1 axes allowed); pick a channel with .narrow(..)".into(),
            got: field.dims().to_vec(),
        });
    }
    field_to_rgb(&tensor_values(field)?, dims[0], dims[1], style)
}

/// [`field_to_png`] for a tensor; see [`tensor_field_to_rgb`].
pub fn tensor_field_to_png(path: impl AsRef<Path>, field: &Tensor, style: &FieldStyle) -> Result<()> {
    write_png(path, &tensor_field_to_rgb(field, style)?)
}

/// Arrows drawn over a vector field's magnitude.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrowStyle {
    /// Cells between arrows; `None` (default): about 12 arrows along the longer side.
    pub spacing: Option<usize>,
    /// Arrow colour. Default: white.
    pub color: [u8; 3],
    /// A one-pixel halo around each arrow, so that arrows read on light and dark colours alike.
    /// Default: black.
    pub outline: Option<[u8; 3]>,
    /// Length of the longest arrow, in units of `spacing`. Default: 0.9 (arrows do not touch).
    pub length: f64,
}

impl Default for ArrowStyle {
    fn default() -> Self {
        ArrowStyle { spacing: None, color: [255, 255, 255], outline: Some([0, 0, 0]), length: 0.9 }
    }
}

/// How a vector field is drawn: its magnitude as a scalar field, optionally with arrows.
#[derive(Clone, Debug, PartialEq)]
pub struct VectorStyle {
    /// Style of the magnitude image. Default: [`FieldStyle::default`].
    pub magnitude: FieldStyle,
    /// Arrows on top; `None` for the magnitude alone. Default: [`ArrowStyle::default`].
    pub arrows: Option<ArrowStyle>,
}

impl Default for VectorStyle {
    fn default() -> Self {
        VectorStyle { magnitude: FieldStyle::default(), arrows: Some(ArrowStyle::default()) }
    }
}

/// Renders a 2D vector field with components `u` (x) and `v` (y), each `h * w` values
/// row-major `[y, x]`: the magnitude `sqrt(u^2 + v^2)` in colour, with arrows pointing along
/// `(u, v)` (with [`Origin::Lower`], positive `v` points up in the picture).
///
/// With arrows and no fixed [`FieldStyle::upscale`], cells get twice the [`auto_upscale`]
/// (at most 16) pixels, so that arrows are large enough to read.
pub fn vector_field_to_rgb<T: Copy + Into<f64>>(
    u: &[T],
    v: &[T],
    h: usize,
    w: usize,
    style: &VectorStyle,
) -> Result<RgbImage> {
    check_len("vector_field_to_rgb", "u", u.len(), h, w)?;
    check_len("vector_field_to_rgb", "v", v.len(), h, w)?;
    let (u, v): (Vec<f64>, Vec<f64>) = (u.iter().map(|&a| a.into()).collect(), v.iter().map(|&a| a.into()).collect());
    let mag: Vec<f64> = u.iter().zip(&v).map(|(a, b)| a.hypot(*b)).collect();
    let mut magnitude = style.magnitude.clone();
    if style.arrows.is_some() && magnitude.upscale.is_none() {
        // Arrows need room: twice the usual auto size.
        magnitude.upscale = Some((2 * auto_upscale(h, w)).min(16));
    }
    let mut img = field_to_rgb(&mag, h, w, &magnitude)?;
    if let Some(arrows) = &style.arrows {
        let k = upscale_factor("vector_field_to_rgb", &magnitude, h, w)? as f64;
        draw_arrows(&mut img, &u, &v, &mag, h, w, k, magnitude.origin, arrows)?;
    }
    Ok(img)
}

/// Renders a vector field to a PNG file (written atomically); see [`vector_field_to_rgb`].
pub fn vector_field_to_png<T: Copy + Into<f64>>(
    path: impl AsRef<Path>,
    u: &[T],
    v: &[T],
    h: usize,
    w: usize,
    style: &VectorStyle,
) -> Result<()> {
    write_png(path, &vector_field_to_rgb(u, v, h, w, style)?)
}

/// [`vector_field_to_rgb`] for a tensor `[2, H, W]` (channel 0 = x component, channel 1 = y
/// component; leading size-1 axes such as a batch of one are accepted).
pub fn tensor_vector_field_to_rgb(field: &Tensor, style: &VectorStyle) -> Result<RgbImage> {
    let dims = strip_leading_ones(field.dims(), 3);
    if dims.len() != 3 || dims[0] != 2 {
        return Err(Error::Shape {
            op: "tensor_vector_field_to_rgb",
            arg: "field",
            expected: "[2, H, W] (components x, y; leading size-1 axes allowed)".into(),
            got: field.dims().to_vec(),
        });
    }
    let values = tensor_values(field)?;
    let n = dims[1] * dims[2];
    vector_field_to_rgb(&values[..n], &values[n..], dims[1], dims[2], style)
}

/// [`vector_field_to_png`] for a tensor; see [`tensor_vector_field_to_rgb`].
pub fn tensor_vector_field_to_png(path: impl AsRef<Path>, field: &Tensor, style: &VectorStyle) -> Result<()> {
    write_png(path, &tensor_vector_field_to_rgb(field, style)?)
}

/// Drops leading size-1 axes while the rank exceeds `rank`.
pub(crate) fn strip_leading_ones(dims: &[usize], rank: usize) -> &[usize] {
    let mut d = dims;
    while d.len() > rank && d[0] == 1 {
        d = &d[1..];
    }
    d
}

pub(crate) fn check_len(op: &'static str, arg: &'static str, len: usize, h: usize, w: usize) -> Result<()> {
    if h == 0 || w == 0 || len != h * w {
        return Err(Error::Shape {
            op,
            arg,
            expected: format!("h * w = {h} * {w} values, h and w > 0"),
            got: vec![len],
        });
    }
    Ok(())
}

pub(crate) fn upscale_factor(op: &'static str, style: &FieldStyle, h: usize, w: usize) -> Result<u32> {
    let k = style.upscale.unwrap_or_else(|| auto_upscale(h, w));
    // Image sides are u32; 1 << 15 keeps them, and the buffer, sane.
    if k == 0 || (h.max(w) as u64) * k as u64 > 1 << 15 {
        return Err(Error::invalid(
            op,
            "upscale",
            format!("{k} x {h} x {w} cells: use 1..=16 and images up to 32768 pixels"),
        ));
    }
    Ok(k)
}

/// Colours `h x w` values into an image with `k x k` pixels per cell. With `levels`, colours
/// are snapped to that many steps (GIF frames need at most 256 colours).
pub(crate) fn render(
    value: impl Fn(usize) -> f64,
    h: usize,
    w: usize,
    k: u32,
    style: &FieldStyle,
    lo: f64,
    hi: f64,
    levels: Option<u32>,
) -> RgbImage {
    let (colormap, origin) = (style.colormap, style.origin);
    let k = k as usize;
    let mut img = RgbImage::new((w * k) as u32, (h * k) as u32);
    for row in 0..h {
        let y = match origin {
            Origin::Lower => h - 1 - row,
            Origin::Upper => row,
        };
        for x in 0..w {
            let v = value(y * w + x);
            let mut t = normalize(v, lo, hi);
            if let Some(n) = levels {
                let n = (n.max(2) - 1) as f64;
                t = (t.clamp(0.0, 1.0) * n).round() / n;
            }
            let c = Rgb(if v.is_nan() { style.nan_color } else { colormap.rgb(t) });
            for py in row * k..(row + 1) * k {
                for px in x * k..(x + 1) * k {
                    img.put_pixel(px as u32, py as u32, c);
                }
            }
        }
    }
    img
}

fn draw_arrows(
    img: &mut RgbImage,
    u: &[f64],
    v: &[f64],
    mag: &[f64],
    h: usize,
    w: usize,
    k: f64,
    origin: Origin,
    style: &ArrowStyle,
) -> Result<()> {
    let spacing = style.spacing.unwrap_or_else(|| (h.max(w) / 12).max(1));
    if spacing == 0 || !(style.length.is_finite() && style.length > 0.0) {
        return Err(Error::invalid("vector_field_to_rgb", "arrows", "spacing and length must be > 0"));
    }
    let max = mag.iter().copied().filter(|m| m.is_finite()).fold(0.0, f64::max);
    if max == 0.0 {
        return Ok(());
    }
    let scale = style.length * spacing as f64 * k / max;
    // Arrows sit at the centres of every `spacing`-th cell, starting half a spacing in.
    for y in (spacing / 2..h).step_by(spacing) {
        for x in (spacing / 2..w).step_by(spacing) {
            let i = y * w + x;
            if !mag[i].is_finite() || mag[i] * scale < 1.0 {
                continue;
            }
            let row = match origin {
                Origin::Lower => h - 1 - y,
                Origin::Upper => y,
            };
            let (cx, cy) = ((x as f64 + 0.5) * k, (row as f64 + 0.5) * k);
            // Image rows grow downwards: with y up, +v must move the tip up.
            let dy = if origin == Origin::Lower { -v[i] } else { v[i] };
            let (ax, ay) = (u[i] * scale, dy * scale);
            // Centred on the cell, so that arrows of neighbouring cells do not overlap.
            let tail = (cx - ax / 2.0, cy - ay / 2.0);
            let tip = (cx + ax / 2.0, cy + ay / 2.0);
            let len = (ax * ax + ay * ay).sqrt();
            let head = (0.35 * len).clamp(2.0, 2.0 + 0.5 * k * spacing as f64);
            let (dx, dy) = (ax / len, ay / len);
            let (c, s) = (25f64.to_radians().cos(), 25f64.to_radians().sin());
            let barbs = [
                (tip.0 - head * (dx * c - dy * s), tip.1 - head * (dy * c + dx * s)),
                (tip.0 - head * (dx * c + dy * s), tip.1 - head * (dy * c - dx * s)),
            ];
            let segments = [(tail, tip), (tip, barbs[0]), (tip, barbs[1])];
            if let Some(outline) = style.outline {
                for (a, b) in segments {
                    draw_line(img, a, b, outline, 1);
                }
            }
            for (a, b) in segments {
                draw_line(img, a, b, style.color, 0);
            }
        }
    }
    Ok(())
}

/// A line of square brush radius `r` (0: one pixel), clipped to the image.
fn draw_line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), color: [u8; 3], r: i64) {
    let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().max(1.0) as usize;
    let (wd, ht) = (img.width() as i64, img.height() as i64);
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        let (x, y) = ((a.0 + (b.0 - a.0) * t).floor() as i64, (a.1 + (b.1 - a.1) * t).floor() as i64);
        for py in y - r..=y + r {
            for px in x - r..=x + r {
                if (0..wd).contains(&px) && (0..ht).contains(&py) {
                    img.put_pixel(px as u32, py as u32, Rgb(color));
                }
            }
        }
    }
}
