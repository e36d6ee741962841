//! Structural similarity (SSIM, Wang et al. 2004) with a Gaussian window, in 1D, 2D and 3D.
//!
//! Per channel, with Gaussian-weighted local means `mu`, variances `s^2` and covariance `s_ab`
//! (population weighting: `s^2 = G * a^2 - mu^2`, as in the authors' MATLAB code):
//!
//! ```text
//! ssim_map = (2 mu_a mu_b + C1)(2 s_ab + C2) / ((mu_a^2 + mu_b^2 + C1)(s_a^2 + s_b^2 + C2)),
//! C1 = (k1 R)^2,  C2 = (k2 R)^2,
//! ```
//!
//! evaluated where the window fits inside the field ("valid" positions, no padding); the SSIM of
//! a sample is the mean of the map over channels and positions. The window is separable: a 1D
//! Gaussian of `window` taps and standard deviation `sigma`, normalised to sum 1, along every
//! spatial axis. Defaults are the paper's: 11 taps, sigma 1.5, k1 = 0.01, k2 = 0.03.
//! SSIM is symmetric, at most 1, and 1 for identical inputs.

use crate::classic::pointwise::per_sample_mean;
use crate::{check, Error, Result};
use candle_core::{DType, Tensor};
use pbdl_core::conv::{conv, ConvParams};

/// Parameters of [`ssim2d`] / [`ssim3d`] / [`ssim_nd`]; `Default` is the paper's setting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimConfig {
    /// Taps of the Gaussian window along each axis; odd, at most every spatial size. Default 11.
    pub window: usize,
    /// Standard deviation of the window in cells. Default 1.5.
    pub sigma: f64,
    /// Luminance constant factor. Default 0.01.
    pub k1: f64,
    /// Contrast constant factor. Default 0.03.
    pub k2: f64,
    /// The data range `R` (255 for 8-bit images). `None` (default) takes each sample's joint
    /// peak-to-peak range of both inputs (a constant, not differentiated), or 1 where that is 0.
    pub data_range: Option<f64>,
}

impl Default for SsimConfig {
    fn default() -> Self {
        Self { window: 11, sigma: 1.5, k1: 0.01, k2: 0.03, data_range: None }
    }
}

/// SSIM of 2D fields `[batch, channel, y, x]`; `[batch]`. Differentiable. See the module docs.
///
/// Errors: as [`ssim_nd`].
pub fn ssim2d(a: &Tensor, b: &Tensor, cfg: &SsimConfig) -> Result<Tensor> {
    spatial_rank("ssim2d", a, b, 2)?;
    ssim_nd(a, b, cfg)
}

/// SSIM of 3D fields `[batch, channel, z, y, x]`; `[batch]`. Differentiable. See the module docs.
///
/// Errors: as [`ssim_nd`].
pub fn ssim3d(a: &Tensor, b: &Tensor, cfg: &SsimConfig) -> Result<Tensor> {
    spatial_rank("ssim3d", a, b, 3)?;
    ssim_nd(a, b, cfg)
}

fn spatial_rank(op: &'static str, a: &Tensor, b: &Tensor, n: usize) -> Result<()> {
    for (arg, t) in [("a", a), ("b", b)] {
        if t.rank() != n + 2 {
            let layout = if n == 2 { "[batch, channel, y, x]" } else { "[batch, channel, z, y, x]" };
            return Err(Error::Shape { op, arg, expected: layout.into(), got: t.dims().to_vec() });
        }
    }
    Ok(())
}

/// SSIM of fields with 1, 2 or 3 spatial axes; `[batch]`. Differentiable in `a` and `b`.
///
/// Errors: shapes that differ or have no spatial axis, non-float, empty or non-finite inputs;
/// an even or zero `window`, a `window` larger than a spatial size (pass a smaller one), a
/// non-positive `sigma` or `data_range`.
pub fn ssim_nd(a: &Tensor, b: &Tensor, cfg: &SsimConfig) -> Result<Tensor> {
    const OP: &str = "ssim";
    check::field_pair(OP, a, b, 1..=3)?;
    let dims = a.dims().to_vec();
    let n = dims.len() - 2;
    if cfg.window == 0 || cfg.window % 2 == 0 {
        return Err(Error::invalid(OP, "window", format!("must be odd and positive, got {}", cfg.window)));
    }
    if let Some(&s) = dims[2..].iter().find(|&&s| s < cfg.window) {
        return Err(Error::invalid(
            OP,
            "window",
            format!("{} taps do not fit a spatial size of {s} (shape {dims:?}); use an odd window <= {s}", cfg.window),
        ));
    }
    if !(cfg.sigma > 0.0 && cfg.sigma.is_finite()) {
        return Err(Error::invalid(OP, "sigma", format!("must be positive, got {}", cfg.sigma)));
    }
    let (batch, channels) = (dims[0], dims[1]);
    let ranges: Vec<f64> = match cfg.data_range {
        Some(r) if r > 0.0 && r.is_finite() => vec![r; batch],
        Some(r) => return Err(Error::invalid(OP, "data_range", format!("must be positive and finite, got {r}"))),
        None => {
            let both = Tensor::cat(&[a.flatten_from(1)?, b.flatten_from(1)?], 1)?.to_dtype(DType::F64)?;
            let hi = both.max(1)?.to_vec1::<f64>()?;
            let lo = both.min(1)?.to_vec1::<f64>()?;
            hi.iter().zip(&lo).map(|(h, l)| if h > l { h - l } else { 1.0 }).collect()
        }
    };
    let dtype = a.dtype();
    let dev = a.device();
    // Per (sample, channel) constants, shaped to broadcast over [batch * channel, 1, spatial...].
    let mut cshape = vec![batch * channels, 1];
    cshape.extend(std::iter::repeat_n(1, n));
    let consts = |k: f64| -> Result<Tensor> {
        let v: Vec<f64> = ranges.iter().flat_map(|r| std::iter::repeat_n((k * r) * (k * r), channels)).collect();
        Ok(Tensor::from_vec(v, cshape.clone(), dev)?.to_dtype(dtype)?)
    };
    let (c1, c2) = (consts(cfg.k1)?, consts(cfg.k2)?);

    let mut flat_shape = vec![batch * channels, 1];
    flat_shape.extend_from_slice(&dims[2..]);
    let a = a.reshape(flat_shape.clone())?;
    let b = b.reshape(flat_shape)?;
    let stack = Tensor::cat(&[&a, &b, &a.sqr()?, &b.sqr()?, &(&a * &b)?], 0)?;
    let filtered = gaussian_filter(&stack, n, cfg.window, cfg.sigma)?;
    let m = batch * channels;
    let part = |i: usize| filtered.narrow(0, i * m, m);
    let (mu_a, mu_b, aa, bb, ab) = (part(0)?, part(1)?, part(2)?, part(3)?, part(4)?);
    let mu_ab = (&mu_a * &mu_b)?;
    let mu_a2 = mu_a.sqr()?;
    let mu_b2 = mu_b.sqr()?;
    let var_a = (aa - &mu_a2)?;
    let var_b = (bb - &mu_b2)?;
    let cov = (ab - &mu_ab)?;
    let num = ((mu_ab * 2.0)?.broadcast_add(&c1)? * (cov * 2.0)?.broadcast_add(&c2)?)?;
    let den = ((mu_a2 + mu_b2)?.broadcast_add(&c1)? * (var_a + var_b)?.broadcast_add(&c2)?)?;
    let map = (num / den)?;
    // [batch * channel, 1, valid...] -> [batch, channel * valid].
    per_sample_mean(&map.reshape((batch, ()))?)
}

/// Separable Gaussian filter ("valid" positions) of `x` `[m, 1, spatial...]` with `n` spatial axes.
fn gaussian_filter(x: &Tensor, n: usize, window: usize, sigma: f64) -> Result<Tensor> {
    let c = (window / 2) as f64;
    let g: Vec<f64> = (0..window).map(|i| (-((i as f64 - c).powi(2)) / (2.0 * sigma * sigma)).exp()).collect();
    let s: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / s).collect();
    let mut y = x.clone();
    for axis in 0..n {
        let mut kshape = vec![1usize, 1];
        kshape.extend((0..n).map(|d| if d == axis { window } else { 1 }));
        let k = Tensor::from_vec(g.clone(), kshape, x.device())?.to_dtype(x.dtype())?;
        y = match n {
            1 => conv(&y, &k, None, &ConvParams::<1>::default())?,
            2 => conv(&y, &k, None, &ConvParams::<2>::default())?,
            _ => conv(&y, &k, None, &ConvParams::<3>::default())?,
        };
    }
    Ok(y)
}
