//! Procedural "peak" images, our stand-in for the 110 peak PNGs of the racecar repository.
//!
//! Each `size x size` image holds one (class 0) or two (class 1) Gaussian peaks
//! `255 exp(-|p - c|^2 / (2 w^2))`, centres `c` uniform in `[size/7, 6 size/7]^2` (away from
//! the border), widths `w` uniform in `[1.5, 3.5]` pixels; overlapping peaks add, clipped at 255.
//! Pixel values are in `[0, 255]` like the PNGs the official code reads (no rescaling).

use crate::error::{Error, Result};
use candle_core::{DType, Device, Tensor};
use rand::Rng;

/// Images `[2 n_per_class, size * size]` (class 0 first) and labels `[2 n_per_class]` (`u32`).
///
/// # Errors
/// [`Error::ShapeMismatch`] for `size < 7` (no room for the peaks away from the border) or
/// `n_per_class == 0`.
pub fn peak_images(n_per_class: usize, size: usize, dtype: DType, seed: u64) -> Result<(Tensor, Tensor)> {
    if size < 7 || n_per_class == 0 {
        return Err(Error::shape(
            "peak images (size, images per class)",
            "size >= 7 and at least one image per class",
            format!("({size}, {n_per_class})"),
        ));
    }
    let mut rng = pbdl_core::seed::rng(seed);
    let (lo, hi) = (size as f64 / 7.0, 6.0 * size as f64 / 7.0);
    let mut pixels = Vec::with_capacity(2 * n_per_class * size * size);
    let mut labels = Vec::with_capacity(2 * n_per_class);
    for class in 0..2u32 {
        for _ in 0..n_per_class {
            let peaks: Vec<(f64, f64, f64)> = (0..=class)
                .map(|_| (rng.random_range(lo..hi), rng.random_range(lo..hi), rng.random_range(1.5..3.5)))
                .collect();
            for y in 0..size {
                for x in 0..size {
                    let v: f64 = peaks
                        .iter()
                        .map(|&(cy, cx, w)| {
                            let r2 = (y as f64 - cy).powi(2) + (x as f64 - cx).powi(2);
                            255.0 * (-r2 / (2.0 * w * w)).exp()
                        })
                        .sum();
                    pixels.push(v.min(255.0));
                }
            }
            labels.push(class);
        }
    }
    let x = Tensor::from_vec(pixels, (2 * n_per_class, size * size), &Device::Cpu)?.to_dtype(dtype)?;
    Ok((x, Tensor::new(labels, &Device::Cpu)?))
}
