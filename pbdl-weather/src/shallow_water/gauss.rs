//! Gaussian latitudes and quadrature weights, and interpolation to the WeatherBench latitudes.

use crate::error::{Error, Result};

/// A Gaussian grid: `n_lat` Gaussian latitudes (ascending) and `n_lon = 2 n_lat` equally spaced
/// longitudes starting at 0.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianGrid {
    /// `mu_j = sin(lat_j)`, ascending (south to north): the roots of `P_{n_lat}`.
    pub mu: Vec<f64>,
    /// Gauss-Legendre weights for `int_{-1}^{1} f dmu`; they sum to 2.
    pub weights: Vec<f64>,
    /// Latitudes in degrees, ascending.
    pub lat_deg: Vec<f64>,
    /// Longitudes in degrees, `0, d, ..., 360 - d`.
    pub lon_deg: Vec<f64>,
}

impl GaussianGrid {
    /// The grid with `n_lat` Gaussian latitudes and `2 n_lat` longitudes (32 for T21, 64 for T42).
    pub fn new(n_lat: usize) -> Result<Self> {
        let (mu, weights) = gaussian_latitudes(n_lat)?;
        let lat_deg = mu.iter().map(|m| m.asin().to_degrees()).collect();
        let n_lon = 2 * n_lat;
        let lon_deg = (0..n_lon).map(|k| k as f64 * 360.0 / n_lon as f64).collect();
        Ok(Self { mu, weights, lat_deg, lon_deg })
    }

    /// Number of latitudes.
    pub fn n_lat(&self) -> usize {
        self.mu.len()
    }

    /// Number of longitudes.
    pub fn n_lon(&self) -> usize {
        self.lon_deg.len()
    }

    /// Number of grid points `n_lat * n_lon`.
    pub fn len(&self) -> usize {
        self.n_lat() * self.n_lon()
    }

    /// Always false (a grid has at least one latitude); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.mu.is_empty()
    }

    /// Longitudes in radians.
    pub fn lon_rad(&self) -> Vec<f64> {
        self.lon_deg.iter().map(|l| l.to_radians()).collect()
    }

    /// The global mean of a grid field (Gaussian quadrature in latitude, mean in longitude).
    pub fn global_mean(&self, field: &[f64]) -> Result<f64> {
        self.check_len(field, "field")?;
        let n_lon = self.n_lon();
        let mut s = 0.0;
        for (j, w) in self.weights.iter().enumerate() {
            s += w * field[j * n_lon..(j + 1) * n_lon].iter().sum::<f64>();
        }
        Ok(s / (2.0 * n_lon as f64))
    }

    /// Index of the Gaussian latitude nearest to `lat_deg`.
    pub fn nearest_lat(&self, lat_deg: f64) -> usize {
        let mut best = 0;
        for (j, l) in self.lat_deg.iter().enumerate() {
            if (l - lat_deg).abs() < (self.lat_deg[best] - lat_deg).abs() {
                best = j;
            }
        }
        best
    }

    pub(crate) fn check_len(&self, field: &[f64], what: &str) -> Result<()> {
        if field.len() != self.len() {
            return Err(Error::InvalidArgument(format!(
                "{what} has {} values; the Gaussian grid has {} x {} = {} ([lat][lon], lat ascending)",
                field.len(),
                self.n_lat(),
                self.n_lon(),
                self.len()
            )));
        }
        Ok(())
    }
}

/// Gauss-Legendre nodes `mu_j` (ascending) and weights for `n` points: the roots of `P_n` by
/// Newton iteration from the usual cosine first guess.
pub fn gaussian_latitudes(n: usize) -> Result<(Vec<f64>, Vec<f64>)> {
    if n < 2 {
        return Err(Error::InvalidArgument(format!("a Gaussian grid needs at least 2 latitudes, got {n}")));
    }
    let mut mu = vec![0.0; n];
    let mut w = vec![0.0; n];
    let nf = n as f64;
    for k in 0..n.div_ceil(2) {
        // Guess for the (k+1)-th largest root (Abramowitz and Stegun 22.16.6).
        let mut x = (std::f64::consts::PI * (k as f64 + 0.75) / (nf + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, d) = legendre_and_derivative(n, x);
            dp = d;
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre_and_derivative(n, x);
        dp = if d.is_finite() { d } else { dp };
        let wk = 2.0 / ((1.0 - x * x) * dp * dp);
        // Roots are symmetric: fill both hemispheres so the grid is exactly symmetric.
        mu[n - 1 - k] = x;
        mu[k] = -x;
        w[n - 1 - k] = wk;
        w[k] = wk;
    }
    if n % 2 == 1 {
        mu[n / 2] = 0.0;
    }
    Ok((mu, w))
}

/// `P_n(x)` and `P_n'(x)` (unnormalised) by the three-term recurrence.
fn legendre_and_derivative(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let kf = k as f64;
        let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
        p0 = p1;
        p1 = p2;
    }
    let d = n as f64 * (x * p1 - p0) / (x * x - 1.0);
    (p1, d)
}

/// Interpolates a Gaussian-grid field `[lat][lon]` linearly in latitude to the WeatherBench
/// latitudes `lat_i = -90 + d/2 + i d` (`d = 180 / n_lat`, ascending) on the same longitudes.
///
/// WeatherBench's outermost latitudes lie poleward of the outermost Gaussian latitudes; there
/// the field is interpolated between the outermost row and a pole value, the zonal mean of that
/// row (right for scalars; for wind components the pole value is only a stand-in).
pub fn to_weatherbench(grid: &GaussianGrid, field: &[f64]) -> Result<Vec<f64>> {
    grid.check_len(field, "field")?;
    let (n_lat, n_lon) = (grid.n_lat(), grid.n_lon());
    let d = 180.0 / n_lat as f64;
    let row = |j: usize| &field[j * n_lon..(j + 1) * n_lon];
    let south = row(0).iter().sum::<f64>() / n_lon as f64;
    let north = row(n_lat - 1).iter().sum::<f64>() / n_lon as f64;
    let mut out = vec![0.0; n_lat * n_lon];
    for i in 0..n_lat {
        let lat = -90.0 + d / 2.0 + i as f64 * d;
        let dst = &mut out[i * n_lon..(i + 1) * n_lon];
        let first = grid.lat_deg[0];
        let last = grid.lat_deg[n_lat - 1];
        if lat <= first {
            let t = (lat + 90.0) / (first + 90.0);
            for (o, f) in dst.iter_mut().zip(row(0)) {
                *o = south + t * (f - south);
            }
        } else if lat >= last {
            let t = (90.0 - lat) / (90.0 - last);
            for (o, f) in dst.iter_mut().zip(row(n_lat - 1)) {
                *o = north + t * (f - north);
            }
        } else {
            // First Gaussian latitude above `lat`.
            let jh = grid.lat_deg.partition_point(|&l| l < lat);
            let (jl, jh) = (jh - 1, jh);
            let t = (lat - grid.lat_deg[jl]) / (grid.lat_deg[jh] - grid.lat_deg[jl]);
            for ((o, a), b) in dst.iter_mut().zip(row(jl)).zip(row(jh)) {
                *o = a + t * (b - a);
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_quadrature_is_exact_to_degree_2n_minus_1() {
        for n in [2usize, 5, 32, 64] {
            let (mu, w) = gaussian_latitudes(n).unwrap();
            assert!(mu.windows(2).all(|p| p[0] < p[1]));
            for deg in 0..2 * n {
                let q: f64 = mu.iter().zip(&w).map(|(x, w)| w * x.powi(deg as i32)).sum();
                let exact = if deg % 2 == 1 { 0.0 } else { 2.0 / (deg as f64 + 1.0) };
                assert!((q - exact).abs() < 1e-13, "n {n} deg {deg}: {q} vs {exact}");
            }
        }
    }

    #[test]
    fn weatherbench_interpolation_is_exact_for_linear_in_latitude() {
        let g = GaussianGrid::new(32).unwrap();
        let f: Vec<f64> = (0..g.len()).map(|p| 3.0 + 0.5 * g.lat_deg[p / g.n_lon()]).collect();
        let wb = to_weatherbench(&g, &f).unwrap();
        let d = 180.0 / 32.0;
        for i in 0..32 {
            let lat = -90.0 + d / 2.0 + i as f64 * d;
            // Inside the Gaussian range a linear profile is reproduced exactly.
            if lat.abs() < g.lat_deg[31] {
                assert!((wb[i * 64 + 5] - (3.0 + 0.5 * lat)).abs() < 1e-12);
            }
        }
        assert!(to_weatherbench(&g, &f[1..]).is_err());
    }
}
