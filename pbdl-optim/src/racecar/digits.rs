//! Procedurally drawn digits: our stand-in for MNIST, which cannot be downloaded here and whose
//! files we do not commit. These are *not* MNIST images; they only share its format.
//!
//! Each digit `0..=9` is a stroke skeleton (polylines, circular arcs and quadratic Bezier curves
//! in a unit box, y down) drawn anti-aliased onto a `28 x 28` image with values in `[0, 1]`:
//! a pixel's value is `clamp(w/2 + 1/2 - d, 0, 1)`, `d` the distance of its centre to the
//! skeleton and `w` the stroke width in pixels (a linear ramp one pixel wide at the stroke's
//! edge). As in MNIST, the digit fits a `20 x 20` box centred in the image: the skeleton is
//! slanted, rotated and stretched, then scaled so that its ink (skeleton plus half the stroke
//! width) has its longer side equal to [`DigitStyle::size`] pixels (at most 20), and placed in
//! the box at [`DigitStyle::shift`] (a fraction of the room left). No pixel outside the box
//! `[4, 24) x [4, 24)` gets ink. [`DigitJitter`] draws these style parameters at random from a
//! seed: same seed, same images.

use crate::error::{Error, Result};
use candle_core::{Device, Tensor};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Image side in pixels (MNIST's 28).
pub const SIDE: usize = 28;
/// Side of the box the digit is drawn in (MNIST's 20).
pub const BOX: usize = 20;
/// First pixel row/column of the box (`(SIDE - BOX) / 2`).
pub const BOX_START: usize = (SIDE - BOX) / 2;

/// How one digit is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DigitStyle {
    /// Horizontal shear: the top of the digit moves right by `slant` times its height
    /// (before scaling). Default `0`.
    pub slant: f64,
    /// Rotation in radians (positive: clockwise on screen). Default `0`.
    pub rotation: f64,
    /// Horizontal stretch factor before fitting (`> 0`). Default `1`.
    pub stretch: f64,
    /// Stroke width in pixels, in `(0, 6]`. Default `2.2`.
    pub thickness: f64,
    /// Longer side of the ink in pixels, in `(thickness, 20]`. Default `20`.
    pub size: f64,
    /// Placement in the box, `[x, y]`, each in `[0, 1]`: `0` left/top, `1` right/bottom.
    /// Default `[0.5, 0.5]` (centred).
    pub shift: [f64; 2],
}

impl Default for DigitStyle {
    fn default() -> Self {
        Self { slant: 0.0, rotation: 0.0, stretch: 1.0, thickness: 2.2, size: BOX as f64, shift: [0.5, 0.5] }
    }
}

impl DigitStyle {
    /// Checks every field's range.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] naming the first field out of range.
    pub fn validate(&self) -> Result<()> {
        let bad = |name, value, hint| Err(Error::InvalidConfig { name, value, hint });
        if !self.slant.is_finite() {
            return bad("digit slant", self.slant, "use a finite shear, e.g. in [-0.3, 0.3]");
        }
        if !self.rotation.is_finite() {
            return bad("digit rotation", self.rotation, "use a finite angle in radians");
        }
        if !(self.stretch > 0.0 && self.stretch.is_finite()) {
            return bad("digit stretch", self.stretch, "use a finite factor > 0, e.g. in [0.8, 1.2]");
        }
        if !(self.thickness > 0.0 && self.thickness <= 6.0) {
            return bad("digit thickness", self.thickness, "use a stroke width in (0, 6] pixels");
        }
        if !(self.size > self.thickness && self.size <= BOX as f64) {
            return bad("digit size", self.size, "use a size above the stroke width and at most 20 pixels");
        }
        for s in self.shift {
            if !(0.0..=1.0).contains(&s) {
                return bad("digit shift", s, "use fractions in [0, 1] of the room left in the 20x20 box");
            }
        }
        Ok(())
    }
}

/// Ranges `(lo, hi)` that [`DigitJitter::sample`] draws each [`DigitStyle`] field from,
/// uniformly (`lo == hi` fixes a field).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DigitJitter {
    /// Shear. Default `(-0.3, 0.3)`.
    pub slant: (f64, f64),
    /// Rotation in radians. Default `(-0.15, 0.15)` (about 8.6 degrees).
    pub rotation: (f64, f64),
    /// Horizontal stretch. Default `(0.8, 1.2)`.
    pub stretch: (f64, f64),
    /// Stroke width in pixels. Default `(1.6, 3.0)`.
    pub thickness: (f64, f64),
    /// Longer ink side in pixels. Default `(17, 20)`.
    pub size: (f64, f64),
    /// Placement fraction, both axes. Default `(0.25, 0.75)`.
    pub shift: (f64, f64),
}

impl Default for DigitJitter {
    fn default() -> Self {
        Self {
            slant: (-0.3, 0.3),
            rotation: (-0.15, 0.15),
            stretch: (0.8, 1.2),
            thickness: (1.6, 3.0),
            size: (17.0, 20.0),
            shift: (0.25, 0.75),
        }
    }
}

impl DigitJitter {
    /// No jitter: every sample is [`DigitStyle::default`].
    pub fn none() -> Self {
        let d = DigitStyle::default();
        Self {
            slant: (d.slant, d.slant),
            rotation: (d.rotation, d.rotation),
            stretch: (d.stretch, d.stretch),
            thickness: (d.thickness, d.thickness),
            size: (d.size, d.size),
            shift: (d.shift[0], d.shift[0]),
        }
    }

    /// One style drawn from the ranges (the fields in declaration order, then shift x, y).
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a range with `lo > hi` or a non-finite end, or when the
    /// drawn style is invalid (see [`DigitStyle::validate`]).
    pub fn sample<R: Rng>(&self, rng: &mut R) -> Result<DigitStyle> {
        let mut draw = |(lo, hi): (f64, f64), name: &'static str| -> Result<f64> {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(Error::InvalidConfig { name, value: hi - lo, hint: "give a finite range with lo <= hi" });
            }
            Ok(if lo == hi { lo } else { rng.random_range(lo..hi) })
        };
        let style = DigitStyle {
            slant: draw(self.slant, "slant range")?,
            rotation: draw(self.rotation, "rotation range")?,
            stretch: draw(self.stretch, "stretch range")?,
            thickness: draw(self.thickness, "thickness range")?,
            size: draw(self.size, "size range")?,
            shift: [draw(self.shift, "shift range")?, draw(self.shift, "shift range")?],
        };
        style.validate()?;
        Ok(style)
    }
}

type Stroke = Vec<[f64; 2]>;

/// A circular arc around `c` with radius `r` from angle `a0` to `a1` (degrees; 0 = right,
/// 90 = down, as on screen), sampled every 5 degrees or finer.
fn arc(c: [f64; 2], r: [f64; 2], a0: f64, a1: f64) -> Stroke {
    let n = ((a1 - a0).abs() / 5.0).ceil().max(1.0) as usize;
    (0..=n)
        .map(|i| {
            let a = (a0 + (a1 - a0) * i as f64 / n as f64).to_radians();
            [c[0] + r[0] * a.cos(), c[1] + r[1] * a.sin()]
        })
        .collect()
}

/// A quadratic Bezier curve from `p0` to `p2` with control point `p1`, 16 segments.
fn bezier(p0: [f64; 2], p1: [f64; 2], p2: [f64; 2]) -> Stroke {
    (0..=16)
        .map(|i| {
            let t = i as f64 / 16.0;
            let (a, b, c) = ((1.0 - t) * (1.0 - t), 2.0 * t * (1.0 - t), t * t);
            [a * p0[0] + b * p1[0] + c * p2[0], a * p0[1] + b * p1[1] + c * p2[1]]
        })
        .collect()
}

/// The stroke skeleton of `digit` in a unit box (x right, y down, height 1): a list of
/// polylines.
///
/// # Errors
/// [`Error::InvalidConfig`] for `digit > 9`.
pub fn skeleton(digit: u8) -> Result<Vec<Vec<[f64; 2]>>> {
    Ok(match digit {
        0 => vec![arc([0.5, 0.5], [0.3, 0.48], 0.0, 360.0)],
        1 => vec![vec![[0.3, 0.2], [0.56, 0.0], [0.5, 1.0]]],
        2 => {
            let mut s = arc([0.5, 0.28], [0.28, 0.26], 190.0, 380.0);
            s.extend(bezier([0.75, 0.37], [0.55, 0.65], [0.18, 1.0]).into_iter().skip(1));
            s.push([0.86, 1.0]);
            vec![s]
        }
        3 => {
            let mut s = arc([0.5, 0.26], [0.27, 0.24], 200.0, 450.0);
            s.extend(arc([0.5, 0.73], [0.3, 0.27], 270.0, 520.0).into_iter().skip(1));
            vec![s]
        }
        4 => vec![vec![[0.66, 1.0], [0.66, 0.0], [0.12, 0.68], [0.9, 0.68]]],
        5 => {
            let mut s = vec![[0.82, 0.0], [0.28, 0.0], [0.22, 0.46]];
            s.extend(arc([0.48, 0.7], [0.32, 0.3], 235.0, 500.0).into_iter().skip(1));
            vec![s]
        }
        6 => vec![bezier([0.74, 0.03], [0.2, 0.15], [0.2, 0.7]), arc([0.5, 0.7], [0.3, 0.3], 0.0, 360.0)],
        7 => vec![vec![[0.12, 0.0], [0.88, 0.0], [0.42, 1.0]], vec![[0.35, 0.5], [0.75, 0.5]]],
        8 => vec![arc([0.5, 0.25], [0.24, 0.23], 0.0, 360.0), arc([0.5, 0.73], [0.29, 0.26], 0.0, 360.0)],
        9 => vec![arc([0.5, 0.3], [0.29, 0.28], 0.0, 360.0), bezier([0.79, 0.3], [0.78, 0.7], [0.62, 1.0])],
        _ => {
            return Err(Error::InvalidConfig { name: "digit", value: digit as f64, hint: "use a digit in 0..=9" });
        }
    })
}

/// Distance of point `p` to the segment `a`-`b`.
fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 { (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
    let (ex, ey) = (p[0] - a[0] - t * dx, p[1] - a[1] - t * dy);
    (ex * ex + ey * ey).sqrt()
}

/// Draws `digit` with `style`: `SIDE * SIDE` values in `[0, 1]`, row-major `[y, x]` (row 0 at
/// the top), ink only inside the `20 x 20` box.
///
/// # Errors
/// [`Error::InvalidConfig`] for `digit > 9` or a style out of range ([`DigitStyle::validate`]).
pub fn render_digit(digit: u8, style: &DigitStyle) -> Result<Vec<f64>> {
    style.validate()?;
    let strokes = skeleton(digit)?;
    // Slant (about the vertical middle), stretch, rotate (about the box centre).
    let (sin, cos) = style.rotation.sin_cos();
    let strokes: Vec<Stroke> = strokes
        .iter()
        .map(|s| {
            s.iter()
                .map(|&[x, y]| {
                    let x = 0.5 + (x - 0.5 + style.slant * (0.5 - y)) * style.stretch;
                    let (u, v) = (x - 0.5, y - 0.5);
                    [u * cos - v * sin, u * sin + v * cos]
                })
                .collect()
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in strokes.iter().flatten() {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let half = 0.5 * style.thickness;
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let scale = (style.size - style.thickness) / extent;
    // Top-left corner of the ink box (skeleton box grown by half the stroke width), in pixels.
    let mut origin = [0.0; 2];
    for k in 0..2 {
        let ink = scale * (hi[k] - lo[k]) + style.thickness;
        origin[k] = BOX_START as f64 + style.shift[k] * (BOX as f64 - ink);
    }
    let segments: Vec<([f64; 2], [f64; 2])> = strokes
        .iter()
        .flat_map(|s| {
            let place =
                |p: [f64; 2]| [origin[0] + half + scale * (p[0] - lo[0]), origin[1] + half + scale * (p[1] - lo[1])];
            s.windows(2).map(move |w| (place(w[0]), place(w[1])))
        })
        .collect();
    let mut img = vec![0.0; SIDE * SIDE];
    for y in 0..SIDE {
        for x in 0..SIDE {
            let p = [x as f64 + 0.5, y as f64 + 0.5];
            let d = segments.iter().map(|&(a, b)| segment_distance(p, a, b)).fold(f64::INFINITY, f64::min);
            img[y * SIDE + x] = (half + 0.5 - d).clamp(0.0, 1.0);
        }
    }
    Ok(img)
}

/// One image per entry of `digits`, each with a style drawn from `jitter` (one random stream
/// from `seed`, in order): `[digits.len(), SIDE * SIDE]` `f64` values in `[0, 1]`.
///
/// # Errors
/// [`Error::ShapeMismatch`] for an empty `digits`; [`Error::InvalidConfig`] for a digit above
/// 9 or a bad jitter range.
pub fn digit_images(digits: &[u8], jitter: &DigitJitter, seed: u64) -> Result<Tensor> {
    if digits.is_empty() {
        return Err(Error::shape("digits to draw", "at least one", 0));
    }
    let mut rng = pbdl_core::seed::rng(seed);
    let mut pixels = Vec::with_capacity(digits.len() * SIDE * SIDE);
    for &d in digits {
        let style = jitter.sample(&mut rng)?;
        pixels.extend(render_digit(d, &style)?);
    }
    Ok(Tensor::from_vec(pixels, (digits.len(), SIDE * SIDE), &Device::Cpu)?)
}
