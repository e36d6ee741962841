//! The regular latitude-longitude grid of WeatherBench and its latitude weights.
//!
//! WeatherBench v1 grids have `n` latitudes at cell centres, ascending and without poles,
//! `lat_i = -90 + d/2 + i d`, and `2n` longitudes `0, d, ..., 360 - d` (d = 180 / n).

use crate::error::{Error, Result};

/// A regular lat-lon grid: latitudes ascending in degrees, longitudes in degrees.
#[derive(Clone, Debug, PartialEq)]
pub struct LatLonGrid {
    /// Latitudes (degrees), ascending, strictly inside (-90, 90).
    pub lat: Vec<f64>,
    /// Longitudes (degrees).
    pub lon: Vec<f64>,
}

impl LatLonGrid {
    /// The WeatherBench grid with `n_lat` latitudes and `2 n_lat` longitudes (32 for 5.625 deg).
    pub fn weatherbench(n_lat: usize) -> Self {
        let d = 180.0 / n_lat as f64;
        let lat = (0..n_lat).map(|i| -90.0 + d / 2.0 + i as f64 * d).collect();
        let lon = (0..2 * n_lat).map(|j| j as f64 * d).collect();
        Self { lat, lon }
    }

    /// A grid from given coordinates; latitudes must be ascending and within [-90, 90].
    pub fn new(lat: Vec<f64>, lon: Vec<f64>) -> Result<Self> {
        check_latitudes(&lat)?;
        Ok(Self { lat, lon })
    }

    /// Number of latitudes.
    pub fn n_lat(&self) -> usize {
        self.lat.len()
    }

    /// Number of longitudes.
    pub fn n_lon(&self) -> usize {
        self.lon.len()
    }
}

/// Checks that latitudes are finite, within [-90, 90] and strictly ascending.
pub fn check_latitudes(lat: &[f64]) -> Result<()> {
    if lat.is_empty() {
        return Err(Error::InvalidArgument("no latitudes".into()));
    }
    if let Some(bad) = lat.iter().find(|l| !l.is_finite() || l.abs() > 90.0) {
        return Err(Error::InvalidArgument(format!("latitude {bad} is outside [-90, 90] (latitudes are degrees)")));
    }
    if lat.windows(2).any(|w| w[1] <= w[0]) {
        return Err(Error::InvalidArgument(
            "latitudes must be strictly ascending as in WeatherBench (flip the field and its latitudes, e.g. xarray's sortby('lat'))".into(),
        ));
    }
    Ok(())
}

/// WeatherBench v1 weights `cos(lat) / mean(cos(lat))` (mean 1), as `score.py` computes them.
pub fn lat_weights(lat: &[f64]) -> Vec<f64> {
    let cos: Vec<f64> = lat.iter().map(|l| l.to_radians().cos()).collect();
    let mean = cos.iter().sum::<f64>() / cos.len() as f64;
    cos.iter().map(|c| c / mean).collect()
}

/// WeatherBench 2 area weights: `sin(upper edge) - sin(lower edge)` of each latitude cell,
/// normalised to mean 1. Cell edges lie halfway between latitudes and at the poles beyond the
/// outermost ones. On an equally spaced grid without poles these equal [`lat_weights`] to
/// rounding.
pub fn area_weights(lat: &[f64]) -> Vec<f64> {
    let n = lat.len();
    let edge = |k: usize| -> f64 {
        // Edge k lies below latitude k; edge n is the top.
        if k == 0 {
            -90.0
        } else if k == n {
            90.0
        } else {
            0.5 * (lat[k - 1] + lat[k])
        }
    };
    let w: Vec<f64> = (0..n).map(|i| edge(i + 1).to_radians().sin() - edge(i).to_radians().sin()).collect();
    let mean = w.iter().sum::<f64>() / n as f64;
    w.iter().map(|x| x / mean).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weatherbench_grid_matches_the_published_coordinates() {
        let g = LatLonGrid::weatherbench(32);
        assert_eq!(g.n_lon(), 64);
        assert_eq!(g.lat[0], -87.1875);
        assert_eq!(g.lat[31], 87.1875);
        assert_eq!(g.lon[63], 354.375);
    }

    #[test]
    fn weights_have_mean_one_and_area_weights_equal_cosine_on_weatherbench_grids() {
        let g = LatLonGrid::weatherbench(32);
        let w = lat_weights(&g.lat);
        let a = area_weights(&g.lat);
        assert!((w.iter().sum::<f64>() / 32.0 - 1.0).abs() < 1e-14);
        // sin(l + d/2) - sin(l - d/2) = 2 sin(d/2) cos(l): proportional to cos on equal spacing.
        for (x, y) in w.iter().zip(&a) {
            assert!((x - y).abs() < 1e-12, "{x} vs {y}");
        }
    }

    #[test]
    fn descending_latitudes_are_refused() {
        assert!(check_latitudes(&[10.0, 0.0]).is_err());
        assert!(check_latitudes(&[0.0, 95.0]).is_err());
    }
}
