//! Test cases 2 and 6 of Williamson, Drake, Hack, Jakob and Swarztrauber (1992), "A standard
//! test set for numerical approximations to the shallow water equations in spherical geometry",
//! J. Comput. Phys. 102, 211-224, and their normalised height error norms.
//!
//! * Test 2: steady-state nonlinear zonal geostrophic flow, rotated by `alpha` (for
//!   `alpha != 0` the flow crosses the poles). The exact solution is the initial state.
//! * Test 6: Rossby-Haurwitz wave of wavenumber `R = 4`. For the non-divergent barotropic
//!   vorticity equation it is an exact solution moving eastward without change of shape at
//!   `nu = (R (3 + R) omega - 2 Omega) / ((1 + R)(2 + R))` rad/s (Haurwitz 1940); for the shallow
//!   water equations it is not an exact solution, the pattern is only approximately steady and
//!   moves at nearly that speed, so [`test6_height`] is a reference, not the truth. Williamson
//!   et al. measure test 6 against a high-resolution run instead; [`truncate_spectral`] and
//!   [`synthesis_truncated`] evaluate such a run's field exactly at a coarser run's grid points.

use super::gauss::GaussianGrid;
use super::legendre::SpectralLayout;
use super::model::Planet;
use super::transform::SpectralTransform;
use super::Complex;
use crate::error::{Error, Result};

/// Test 2: `gh_0` (m^2/s^2).
pub const TEST2_GH0: f64 = 2.94e4;
/// Test 6: `omega = K` (1/s).
pub const TEST6_OMEGA: f64 = 7.848e-6;
/// Test 6: wavenumber `R`.
pub const TEST6_R: i32 = 4;
/// Test 6: `h_0` (m).
pub const TEST6_H0: f64 = 8000.0;

/// An initial state on a Gaussian grid: winds (m/s) and layer geopotential `g h` (m^2/s^2).
#[derive(Clone, Debug, PartialEq)]
pub struct InitialState {
    /// Zonal wind `[lat][lon]`.
    pub u: Vec<f64>,
    /// Meridional wind `[lat][lon]`.
    pub v: Vec<f64>,
    /// Geopotential `g h` `[lat][lon]`.
    pub phi: Vec<f64>,
}

/// Test 2's `u_0 = 2 pi a / 12 days` (m/s).
pub fn test2_u0(planet: &Planet) -> f64 {
    2.0 * std::f64::consts::PI * planet.radius / (12.0 * 86400.0)
}

/// Test 2 (steady zonal geostrophic flow) with rotation angle `alpha` (radians).
pub fn test2_initial(grid: &GaussianGrid, planet: &Planet, alpha: f64) -> InitialState {
    let u0 = test2_u0(planet);
    let (sa, ca) = alpha.sin_cos();
    let lon = grid.lon_rad();
    let n = grid.len();
    let (mut u, mut v, mut phi) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for (j, &mu) in grid.mu.iter().enumerate() {
        let c = (1.0 - mu * mu).sqrt();
        for (i, &l) in lon.iter().enumerate() {
            let p = j * lon.len() + i;
            u[p] = u0 * (c * ca + l.cos() * mu * sa);
            v[p] = -u0 * l.sin() * sa;
            let s = -l.cos() * c * sa + mu * ca;
            phi[p] = TEST2_GH0 - (planet.radius * planet.omega * u0 + 0.5 * u0 * u0) * s * s;
        }
    }
    InitialState { u, v, phi }
}

/// Test 6 (Rossby-Haurwitz wave 4) initial state.
pub fn test6_initial(grid: &GaussianGrid, planet: &Planet) -> InitialState {
    let (w, k, r) = (TEST6_OMEGA, TEST6_OMEGA, TEST6_R);
    let rf = r as f64;
    let a = planet.radius;
    let lon = grid.lon_rad();
    let n = grid.len();
    let (mut u, mut v) = (vec![0.0; n], vec![0.0; n]);
    for (j, &mu) in grid.mu.iter().enumerate() {
        let c = (1.0 - mu * mu).sqrt();
        for (i, &l) in lon.iter().enumerate() {
            let p = j * lon.len() + i;
            u[p] = a * w * c + a * k * c.powi(r - 1) * (rf * mu * mu - c * c) * (rf * l).cos();
            v[p] = -a * k * rf * c.powi(r - 1) * mu * (rf * l).sin();
        }
    }
    let phi = test6_height(grid, planet, 0.0).iter().map(|h| h * planet.gravity).collect();
    InitialState { u, v, phi }
}

/// Test 6's height field (m) rotated eastward by `shift` radians: the initial pattern moved
/// rigidly, the reference for the wave at time `t` with `shift = nu t`.
pub fn test6_height(grid: &GaussianGrid, planet: &Planet, shift: f64) -> Vec<f64> {
    let (w, k, r) = (TEST6_OMEGA, TEST6_OMEGA, TEST6_R);
    let rf = r as f64;
    let (a, om, g) = (planet.radius, planet.omega, planet.gravity);
    let lon = grid.lon_rad();
    let mut h = vec![0.0; grid.len()];
    for (j, &mu) in grid.mu.iter().enumerate() {
        let c2 = 1.0 - mu * mu;
        let c = c2.sqrt();
        let c2r = c.powi(2 * r);
        let aa = 0.5 * w * (2.0 * om + w) * c2
            + 0.25 * k * k * c2r * ((rf + 1.0) * c2 + (2.0 * rf * rf - rf - 2.0) - 2.0 * rf * rf / c2);
        let bb = 2.0 * (om + w) * k / ((rf + 1.0) * (rf + 2.0))
            * c.powi(r)
            * ((rf * rf + 2.0 * rf + 2.0) - (rf + 1.0) * (rf + 1.0) * c2);
        let cc = 0.25 * k * k * c2r * ((rf + 1.0) * c2 - (rf + 2.0));
        for (i, &l) in lon.iter().enumerate() {
            let lr = l - shift;
            let gh = g * TEST6_H0 + a * a * (aa + bb * (rf * lr).cos() + cc * (2.0 * rf * lr).cos());
            h[j * lon.len() + i] = gh / g;
        }
    }
    h
}

/// The Haurwitz (1940) phase speed (rad/s, eastward) of test 6's wave in the non-divergent
/// barotropic vorticity equation: `(R (3 + R) omega - 2 Omega) / ((1 + R)(2 + R))`.
pub fn rossby_haurwitz_phase_speed(planet: &Planet) -> f64 {
    let r = TEST6_R as f64;
    (r * (3.0 + r) * TEST6_OMEGA - 2.0 * planet.omega) / ((1.0 + r) * (2.0 + r))
}

/// Williamson et al.'s normalised errors of `h` against `h_ref`: `l1 = I|h - h_ref| / I|h_ref|`,
/// `l2 = sqrt(I (h - h_ref)^2 / I h_ref^2)`, `l_inf = max|h - h_ref| / max|h_ref|`, with `I` the
/// global integral (Gaussian quadrature).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorNorms {
    /// Normalised l1 error.
    pub l1: f64,
    /// Normalised l2 error.
    pub l2: f64,
    /// Normalised maximum error.
    pub linf: f64,
}

/// The normalised error norms ([`ErrorNorms`]) of a grid field against a reference.
pub fn error_norms(grid: &GaussianGrid, h: &[f64], h_ref: &[f64]) -> Result<ErrorNorms> {
    grid.check_len(h, "h")?;
    grid.check_len(h_ref, "h_ref")?;
    let nl = grid.n_lon();
    let (mut e1, mut r1, mut e2, mut r2, mut emax, mut rmax) = (0.0, 0.0, 0.0, 0.0, 0.0_f64, 0.0_f64);
    for p in 0..grid.len() {
        let w = grid.weights[p / nl];
        let (d, r) = ((h[p] - h_ref[p]).abs(), h_ref[p].abs());
        e1 += w * d;
        r1 += w * r;
        e2 += w * d * d;
        r2 += w * r * r;
        emax = emax.max(d);
        rmax = rmax.max(r);
    }
    if r1 == 0.0 || !e1.is_finite() {
        return Err(Error::InvalidArgument("reference field is zero or fields are not finite".into()));
    }
    Ok(ErrorNorms { l1: e1 / r1, l2: (e2 / r2).sqrt(), linf: emax / rmax })
}

/// Truncates spectral coefficients of `T_from` (the [`SpectralLayout`] order: by `m`, then `n`)
/// to `T_to`, `to <= from`: keeps the `X_n^m` with `n <= to` (hence `m <= to`), drops the rest.
/// The normalisation of `P_n^m` does not depend on the truncation, so the kept coefficients are
/// those of the same harmonics.
pub fn truncate_spectral(spec: &[Complex], from: usize, to: usize) -> Result<Vec<Complex>> {
    if to > from {
        return Err(Error::InvalidArgument(format!("cannot truncate T{from} to the larger T{to}")));
    }
    let (lf, lt) = (SpectralLayout::new(from), SpectralLayout::new(to));
    if spec.len() != lf.len() {
        return Err(Error::InvalidArgument(format!("{} spectral coefficients; T{from} has {}", spec.len(), lf.len())));
    }
    Ok(lt.modes().map(|(m, n)| spec[lf.index(m, n)]).collect())
}

/// Evaluates a `T_from` spectral field (`from >= target.truncation()`) truncated to the target
/// transform's `T_M` at the target's Gaussian grid points (`[lat][lon]`). This is spectral
/// interpolation of a high-resolution reference onto a coarse grid: exact for the truncated
/// field, with no grid interpolation error, and the natural reference for a `T_M` run.
pub fn synthesis_truncated(spec: &[Complex], from: usize, target: &SpectralTransform) -> Result<Vec<f64>> {
    target.synthesis(&truncate_spectral(spec, from, target.truncation())?)
}

/// Phase (radians, in `(-pi, pi]`) of zonal wavenumber `k` of one latitude row on equally
/// spaced longitudes from 0: `arg sum_i f_i exp(-i k lambda_i)`. A pattern `cos(k (lambda - s))`
/// has phase `-k s`.
pub fn zonal_phase(row: &[f64], k: usize) -> f64 {
    let n = row.len() as f64;
    let mut s = Complex::ZERO;
    for (i, f) in row.iter().enumerate() {
        let a = -2.0 * std::f64::consts::PI * (k * i) as f64 / n;
        s += Complex::new(a.cos(), a.sin()) * *f;
    }
    s.arg()
}
