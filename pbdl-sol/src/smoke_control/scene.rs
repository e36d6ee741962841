//! Seeded shape-transition scenes: a smooth density blob of one shape at one place, the target
//! a blob of another shape (or size, or orientation) elsewhere, both of equal mass.
//!
//! On a `n x n` box of unit cells, with `s = n / 32`:
//! - shape kinds circle, square, equilateral triangle, ellipse (axis ratio `U(0.5, 0.8)`),
//!   each rotated by a uniform angle, area `U(50, 110) s^2` cells;
//! - centres uniform in `[n/4, 3n/4]^2`, the target at least `n/8` from the start;
//! - rasterised with 4x4 sub-samples per cell (anti-aliased edges), then scaled to the mass
//!   `80 s^2` (so the density is about 1 inside).
//!
//! Scene `k` of set `seed` depends only on `(seed, k)`: train and held-out sets are different
//! seeds.

use super::config::SmokeControlConfig;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// A shape kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShapeKind {
    /// A disc.
    Circle,
    /// A square.
    Square,
    /// An equilateral triangle.
    Triangle,
    /// An ellipse.
    Ellipse,
}

/// One shape: kind, centre (cells), area (cells), rotation, and the ellipse's axis ratio.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Shape {
    /// Kind.
    pub kind: ShapeKind,
    /// Centre `[x, y]` in cells.
    pub centre: [f64; 2],
    /// Area in cells.
    pub area: f64,
    /// Rotation in radians.
    pub angle: f64,
    /// Minor / major axis ratio (ellipses only).
    pub ratio: f64,
}

impl Shape {
    /// Whether the point `(x, y)` lies inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (dx, dy) = (x - self.centre[0], y - self.centre[1]);
        let (c, s) = (self.angle.cos(), self.angle.sin());
        let (px, py) = (c * dx + s * dy, -s * dx + c * dy);
        match self.kind {
            ShapeKind::Circle => px * px + py * py <= self.area / std::f64::consts::PI,
            ShapeKind::Square => {
                let h = self.area.sqrt() / 2.0;
                px.abs() <= h && py.abs() <= h
            }
            ShapeKind::Triangle => {
                // Circumradius R of an equilateral triangle of this area; three half-planes.
                let side = (4.0 * self.area / 3f64.sqrt()).sqrt();
                let r_in = side / (2.0 * 3f64.sqrt());
                (0..3).all(|k| {
                    let a = std::f64::consts::FRAC_PI_2 + k as f64 * 2.0 * std::f64::consts::PI / 3.0;
                    px * a.cos() + py * a.sin() <= r_in
                })
            }
            ShapeKind::Ellipse => {
                let a = (self.area / (std::f64::consts::PI * self.ratio)).sqrt();
                let b = a * self.ratio;
                (px / a).powi(2) + (py / b).powi(2) <= 1.0
            }
        }
    }

    /// The anti-aliased coverage of each cell of an `n x n` grid (row-major `[y, x]`), 4x4
    /// sub-samples per cell.
    pub fn rasterise(&self, n: usize) -> Vec<f64> {
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let mut hits = 0;
                for sj in 0..4 {
                    for si in 0..4 {
                        let x = i as f64 + (si as f64 + 0.5) / 4.0;
                        let y = j as f64 + (sj as f64 + 0.5) / 4.0;
                        hits += usize::from(self.contains(x, y));
                    }
                }
                out[j * n + i] = hits as f64 / 16.0;
            }
        }
        out
    }
}

/// A batch of scenes. Densities `[batch, 1, n, n]`.
#[derive(Clone, Debug)]
pub struct SmokeScenes {
    /// Initial densities (the velocity starts at rest).
    pub initial: Tensor,
    /// Target densities.
    pub target: Tensor,
    /// `(start, target)` shape of each scene.
    pub shapes: Vec<(Shape, Shape)>,
}

impl SmokeScenes {
    /// Number of scenes.
    pub fn len(&self) -> usize {
        self.initial.dims()[0]
    }

    /// Whether there are no scenes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The scenes at `idx` (in that order).
    pub fn select(&self, idx: &[usize]) -> Result<Self> {
        let n = self.len();
        if let Some(&bad) = idx.iter().find(|&&i| i >= n) {
            return Err(Error::invalid("SmokeScenes::select", "idx", format!("index {bad} out of {n} scenes")));
        }
        let ids = Tensor::new(idx.iter().map(|&i| i as u32).collect::<Vec<_>>(), self.initial.device())?;
        Ok(Self {
            initial: self.initial.index_select(&ids, 0)?,
            target: self.target.index_select(&ids, 0)?,
            shapes: idx.iter().map(|&i| self.shapes[i]).collect(),
        })
    }
}

/// The generator of scene `k` of the set `seed` (a splitmix-style mix of both).
fn scene_rng(seed: u64, k: u64) -> rand::rngs::StdRng {
    let mut z = seed ^ k.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    rand::rngs::StdRng::seed_from_u64(z ^ (z >> 31))
}

fn random_shape(r: &mut rand::rngs::StdRng, n: usize, centre: [f64; 2]) -> Shape {
    let s2 = (n as f64 / 32.0).powi(2);
    let kind = [ShapeKind::Circle, ShapeKind::Square, ShapeKind::Triangle, ShapeKind::Ellipse][r.random_range(0..4)];
    Shape {
        kind,
        centre,
        area: r.random_range(50.0..110.0) * s2,
        angle: r.random_range(0.0..std::f64::consts::PI),
        ratio: r.random_range(0.5..0.8),
    }
}

/// The `(start, target)` shapes of scene `k` of set `seed` on an `n x n` box.
pub fn shape_pair(n: usize, seed: u64, k: u64) -> (Shape, Shape) {
    let mut r = scene_rng(seed, k);
    let (lo, hi) = (n as f64 / 4.0, 3.0 * n as f64 / 4.0);
    let a = [r.random_range(lo..hi), r.random_range(lo..hi)];
    let b = loop {
        let b = [r.random_range(lo..hi), r.random_range(lo..hi)];
        if ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt() >= n as f64 / 8.0 {
            break b;
        }
    };
    (random_shape(&mut r, n, a), random_shape(&mut r, n, b))
}

/// The mass every scene's densities are scaled to on an `n x n` box: `80 (n / 32)^2`.
pub fn scene_mass(n: usize) -> f64 {
    80.0 * (n as f64 / 32.0).powi(2)
}

fn density(shape: &Shape, n: usize) -> Vec<f64> {
    let mut d = shape.rasterise(n);
    let m: f64 = d.iter().sum();
    let scale = scene_mass(n) / m.max(1e-12);
    d.iter_mut().for_each(|v| *v *= scale);
    d
}

/// Scenes `range` of set `seed` in `dtype` on `device`.
///
/// # Errors
/// [`Error::InvalidConfig`] for a bad config or an empty range.
pub fn generate(
    cfg: &SmokeControlConfig,
    seed: u64,
    range: std::ops::Range<usize>,
    dtype: DType,
    device: &Device,
) -> Result<SmokeScenes> {
    cfg.validate()?;
    if range.is_empty() {
        return Err(Error::invalid("smoke_control::scene::generate", "range", "is empty; ask for at least one scene"));
    }
    let n = cfg.cells;
    let count = range.len();
    let (mut a, mut b, mut shapes) = (Vec::with_capacity(count * n * n), Vec::with_capacity(count * n * n), vec![]);
    for k in range {
        let (s, t) = shape_pair(n, seed, k as u64);
        a.extend(density(&s, n));
        b.extend(density(&t, n));
        shapes.push((s, t));
    }
    let shape = (count, 1, n, n);
    Ok(SmokeScenes {
        initial: Tensor::from_vec(a, shape, device)?.to_dtype(dtype)?,
        target: Tensor::from_vec(b, shape, device)?.to_dtype(dtype)?,
        shapes,
    })
}
