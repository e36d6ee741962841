//! Particle pictures: 2D particles splatted into a pixel field (background NaN) for
//! [`pbdl_core::viz`]'s PNG and GIF writers.

/// A raster of particle values: `h * w` row-major `[y, x]`, y up, NaN where no particle is.
#[derive(Clone, Debug, PartialEq)]
pub struct Raster {
    /// Pixel values.
    pub data: Vec<f64>,
    /// Rows.
    pub h: usize,
    /// Columns.
    pub w: usize,
}

/// Paints each particle as a disc of `radius_px` pixels with its value into a raster of the box
/// `[lo, hi]` at `px_per_unit` pixels per length unit; later particles paint over earlier ones.
pub fn scatter(
    positions: &[[f64; 2]],
    values: &[f64],
    lo: [f64; 2],
    hi: [f64; 2],
    px_per_unit: f64,
    radius_px: f64,
) -> Raster {
    let w = (((hi[0] - lo[0]) * px_per_unit).ceil() as usize).clamp(1, 4096);
    let h = (((hi[1] - lo[1]) * px_per_unit).ceil() as usize).clamp(1, 4096);
    let mut data = vec![f64::NAN; w * h];
    let r = radius_px.max(0.5);
    let ri = r.ceil() as i64;
    for (p, &v) in positions.iter().zip(values) {
        let cx = (p[0] - lo[0]) * px_per_unit;
        let cy = (p[1] - lo[1]) * px_per_unit;
        if !(cx.is_finite() && cy.is_finite()) {
            continue;
        }
        let (ix, iy) = (cx.floor() as i64, cy.floor() as i64);
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                let (x, y) = (ix + dx, iy + dy);
                if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                    continue;
                }
                let (fx, fy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                if fx * fx + fy * fy <= r * r {
                    data[y as usize * w + x as usize] = v;
                }
            }
        }
    }
    Raster { data, h, w }
}
