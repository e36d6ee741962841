//! Orthonormal associated Legendre functions `P_n^m(mu)` (`int_{-1}^{1} (P_n^m)^2 dmu = 1`, no
//! Condon-Shortley phase) and `H_n^m = (1 - mu^2) dP_n^m/dmu`, tabulated at given latitudes for
//! triangular truncation `T_M`.
//!
//! Recurrences (stable upward in `n` for fixed `m`):
//! `P_0^0 = 1/sqrt(2)`, `P_m^m = sqrt((2m+1)/(2m)) sqrt(1-mu^2) P_{m-1}^{m-1}`,
//! `P_{m+1}^m = sqrt(2m+3) mu P_m^m`, `eps_n^m P_n^m = mu P_{n-1}^m - eps_{n-1}^m P_{n-2}^m`
//! with `eps_n^m = sqrt((n^2 - m^2) / (4 n^2 - 1))`; and
//! `H_n^m = -n eps_{n+1}^m P_{n+1}^m + (n+1) eps_n^m P_{n-1}^m`.

use crate::error::{Error, Result};

/// Spectral index layout of triangular truncation `T_M`: `(m, n)` with `0 <= m <= n <= M`,
/// ordered by `m`, then `n`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpectralLayout {
    m_trunc: usize,
    offsets: Vec<usize>,
    len: usize,
}

impl SpectralLayout {
    /// The layout of `T_M`.
    pub fn new(m_trunc: usize) -> Self {
        let mut offsets = Vec::with_capacity(m_trunc + 1);
        let mut k = 0;
        for m in 0..=m_trunc {
            offsets.push(k);
            k += m_trunc + 1 - m;
        }
        Self { m_trunc, offsets, len: k }
    }

    /// The truncation `M`.
    pub fn truncation(&self) -> usize {
        self.m_trunc
    }

    /// Number of coefficients `(M + 1)(M + 2) / 2`.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Index of `(m, n)`; requires `m <= n <= M`.
    #[inline]
    pub fn index(&self, m: usize, n: usize) -> usize {
        self.offsets[m] + n - m
    }

    /// Iterator over `(m, n)` in storage order.
    pub fn modes(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..=self.m_trunc).flat_map(move |m| (m..=self.m_trunc).map(move |n| (m, n)))
    }
}

/// `P_n^m` and `H_n^m` at a set of latitudes, `[lat][spectral index]`.
#[derive(Clone, Debug)]
pub struct LegendreTable {
    layout: SpectralLayout,
    n_lat: usize,
    p: Vec<f64>,
    h: Vec<f64>,
}

impl LegendreTable {
    /// Tabulates for truncation `m_trunc` at `mu = sin(lat)` (each in `(-1, 1)`).
    pub fn new(m_trunc: usize, mu: &[f64]) -> Result<Self> {
        if let Some(bad) = mu.iter().find(|x| !x.is_finite() || x.abs() >= 1.0) {
            return Err(Error::InvalidArgument(format!("mu = {bad} is not strictly inside (-1, 1)")));
        }
        let layout = SpectralLayout::new(m_trunc);
        let ns = layout.len();
        let mut p = vec![0.0; mu.len() * ns];
        let mut h = vec![0.0; mu.len() * ns];
        let eps = |n: usize, m: usize| -> f64 {
            let (n, m) = (n as f64, m as f64);
            ((n * n - m * m) / (4.0 * n * n - 1.0)).sqrt()
        };
        // One column n = m..=M+1 for a fixed m (M+1 is needed for H_M).
        let mut col = vec![0.0; m_trunc + 2];
        for (j, &x) in mu.iter().enumerate() {
            let s = (1.0 - x * x).sqrt();
            let mut pmm = std::f64::consts::FRAC_1_SQRT_2;
            for m in 0..=m_trunc {
                if m > 0 {
                    pmm *= ((2 * m + 1) as f64 / (2 * m) as f64).sqrt() * s;
                }
                // col[i] = P_{m+i}^m
                col[0] = pmm;
                col[1] = (2.0 * m as f64 + 3.0).sqrt() * x * pmm;
                for i in 2..col.len() - m {
                    let n = m + i;
                    col[i] = (x * col[i - 1] - eps(n - 1, m) * col[i - 2]) / eps(n, m);
                }
                for n in m..=m_trunc {
                    let k = j * ns + layout.index(m, n);
                    let i = n - m;
                    p[k] = col[i];
                    let lower = if n > m { (n as f64 + 1.0) * eps(n, m) * col[i - 1] } else { 0.0 };
                    h[k] = -(n as f64) * eps(n + 1, m) * col[i + 1] + lower;
                }
            }
        }
        Ok(Self { layout, n_lat: mu.len(), p, h })
    }

    /// The spectral layout.
    pub fn layout(&self) -> &SpectralLayout {
        &self.layout
    }

    /// Number of latitudes.
    pub fn n_lat(&self) -> usize {
        self.n_lat
    }

    /// `P_n^m` at latitude `j` for all `(m, n)` in layout order.
    #[inline]
    pub fn p_row(&self, j: usize) -> &[f64] {
        let ns = self.layout.len();
        &self.p[j * ns..(j + 1) * ns]
    }

    /// `H_n^m = (1 - mu^2) dP_n^m / dmu` at latitude `j`, layout order.
    #[inline]
    pub fn h_row(&self, j: usize) -> &[f64] {
        let ns = self.layout.len();
        &self.h[j * ns..(j + 1) * ns]
    }
}

#[cfg(test)]
mod tests {
    use super::super::gauss::gaussian_latitudes;
    use super::*;

    #[test]
    fn orthonormal_under_gauss_quadrature() {
        let m_trunc = 42;
        let (mu, w) = gaussian_latitudes(64).unwrap();
        let t = LegendreTable::new(m_trunc, &mu).unwrap();
        let lay = t.layout().clone();
        let mut worst: f64 = 0.0;
        for m in 0..=m_trunc {
            for n1 in m..=m_trunc {
                for n2 in m..=m_trunc {
                    let (k1, k2) = (lay.index(m, n1), lay.index(m, n2));
                    let s: f64 = (0..mu.len()).map(|j| w[j] * t.p_row(j)[k1] * t.p_row(j)[k2]).sum();
                    worst = worst.max((s - if n1 == n2 { 1.0 } else { 0.0 }).abs());
                }
            }
        }
        assert!(worst < 1e-12, "worst deviation from orthonormality {worst}");
    }

    #[test]
    fn derivative_matches_finite_differences() {
        let m_trunc = 21;
        let x0 = [0.3_f64, -0.71, 0.95];
        let d = 1e-6;
        let xs: Vec<f64> = x0.iter().flat_map(|&x| [x - d, x, x + d]).collect();
        let t = LegendreTable::new(m_trunc, &xs).unwrap();
        for (i, &x) in x0.iter().enumerate() {
            for k in 0..t.layout().len() {
                let fd = (t.p_row(3 * i + 2)[k] - t.p_row(3 * i)[k]) / (2.0 * d) * (1.0 - x * x);
                let h = t.h_row(3 * i + 1)[k];
                assert!((fd - h).abs() < 1e-6 * (1.0 + h.abs()), "k {k} x {x}: {fd} vs {h}");
            }
        }
    }
}
