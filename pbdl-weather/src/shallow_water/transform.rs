//! Spectral transforms on a Gaussian grid with triangular truncation `T_M`: scalar analysis and
//! synthesis, winds from streamfunction and velocity potential, and the divergence and curl of
//! `(A, B) / cos^2(phi)` fluxes (the vorticity-divergence form of Hack and Jakob 1992).
//!
//! With `mu = sin(phi)`, `U = u cos(phi)`, `V = v cos(phi)` and radius `a`:
//! * `U = (1/a) [d chi/d lambda - (1 - mu^2) d psi/d mu]`, `V = (1/a) [d psi/d lambda + (1 - mu^2) d chi/d mu]`;
//! * `div(A, B) = 1/(a (1 - mu^2)) dA/d lambda + (1/a) dB/d mu` (so `delta = div(U, V)`);
//! * `curl(A, B) = div(B, -A)` (so `zeta = curl(U, V)`).
//!
//! Analysis of `div` integrates `dB/dmu` by parts, which uses that `B` vanishes at the poles
//! (true for `B = V q`).

use super::fft::Fft;
use super::gauss::GaussianGrid;
use super::legendre::{LegendreTable, SpectralLayout};
use super::Complex;
use crate::error::{Error, Result};

/// Scratch buffers for the transforms (one per thread of use; the model keeps its own).
#[derive(Clone, Debug)]
pub struct TransformScratch {
    pub(crate) fa: Vec<Complex>,
    pub(crate) fb: Vec<Complex>,
    pub(crate) buf: Vec<Complex>,
}

/// The transforms for one truncation and Gaussian grid; everything is precomputed.
#[derive(Clone, Debug)]
pub struct SpectralTransform {
    grid: GaussianGrid,
    legendre: LegendreTable,
    fft: Fft,
    radius: f64,
    /// `w_j / (a (1 - mu_j^2))` for the flux analysis.
    wdiv: Vec<f64>,
    /// `n(n+1)` per spectral index.
    nn1: Vec<f64>,
    /// `m` per spectral index, as f64.
    mf: Vec<f64>,
}

impl SpectralTransform {
    /// Transforms for `T_{m_trunc}` on `n_lat` Gaussian latitudes and `2 n_lat` longitudes, on a
    /// sphere of `radius` metres. Needs `n_lat > m_trunc`; quadratic products are alias-free for
    /// `n_lat >= (3 m_trunc + 1) / 2` (T21 on 32, T42 on 64, T63 on 96, T85 on 128).
    pub fn new(m_trunc: usize, n_lat: usize, radius: f64) -> Result<Self> {
        if m_trunc == 0 || n_lat <= m_trunc {
            return Err(Error::InvalidArgument(format!(
                "truncation T{m_trunc} on {n_lat} latitudes: need 1 <= M < n_lat (T21 on 32, T42 on 64)"
            )));
        }
        if !(radius.is_finite() && radius > 0.0) {
            return Err(Error::InvalidArgument(format!("radius {radius} must be positive and finite")));
        }
        let grid = GaussianGrid::new(n_lat)?;
        let legendre = LegendreTable::new(m_trunc, &grid.mu)?;
        let fft = Fft::new(grid.n_lon());
        let wdiv = grid.mu.iter().zip(&grid.weights).map(|(m, w)| w / (radius * (1.0 - m * m))).collect();
        let lay = legendre.layout();
        let nn1 = lay.modes().map(|(_, n)| (n * (n + 1)) as f64).collect();
        let mf = lay.modes().map(|(m, _)| m as f64).collect();
        Ok(Self { grid, legendre, fft, radius, wdiv, nn1, mf })
    }

    /// The Gaussian grid.
    pub fn grid(&self) -> &GaussianGrid {
        &self.grid
    }

    /// The spectral layout.
    pub fn layout(&self) -> &SpectralLayout {
        self.legendre.layout()
    }

    /// The truncation `M`.
    pub fn truncation(&self) -> usize {
        self.layout().truncation()
    }

    /// Number of spectral coefficients.
    pub fn n_spec(&self) -> usize {
        self.layout().len()
    }

    /// The sphere's radius (m).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The precomputed Legendre table.
    pub fn legendre(&self) -> &LegendreTable {
        &self.legendre
    }

    /// `n(n+1)` per spectral index (the Laplacian is `-n(n+1)/a^2`).
    pub fn n_n1(&self) -> &[f64] {
        &self.nn1
    }

    /// Eigenvalue of the Laplacian on spherical harmonics of degree `n`: `-n(n+1)/a^2`.
    pub fn laplacian_eigenvalue(&self, n: usize) -> f64 {
        -((n * (n + 1)) as f64) / (self.radius * self.radius)
    }

    /// Scratch buffers sized for this transform.
    pub fn scratch(&self) -> TransformScratch {
        let nf = self.grid.n_lat() * (self.truncation() + 1);
        TransformScratch {
            fa: vec![Complex::ZERO; nf],
            fb: vec![Complex::ZERO; nf],
            buf: vec![Complex::ZERO; self.grid.n_lon()],
        }
    }

    /// An all-zero spectral array.
    pub fn zeros(&self) -> Vec<Complex> {
        vec![Complex::ZERO; self.n_spec()]
    }

    // ---- Fourier (longitude) stage: coefficients stored [lat][m], m = 0..=M ----

    pub(crate) fn fourier_analysis(&self, grid: &[f64], four: &mut [Complex], buf: &mut [Complex]) {
        let (nl, mp) = (self.grid.n_lon(), self.truncation() + 1);
        for j in 0..self.grid.n_lat() {
            self.fft.analyse_row(&grid[j * nl..(j + 1) * nl], &mut four[j * mp..(j + 1) * mp], buf);
        }
    }

    pub(crate) fn fourier_synthesis(&self, four: &[Complex], grid: &mut [f64], buf: &mut [Complex]) {
        let (nl, mp) = (self.grid.n_lon(), self.truncation() + 1);
        for j in 0..self.grid.n_lat() {
            self.fft.synthesise_row(&four[j * mp..(j + 1) * mp], &mut grid[j * nl..(j + 1) * nl], buf);
        }
    }

    // ---- Legendre (latitude) stage ----

    /// `spec = sum_j w_j P F_m(j)`.
    pub(crate) fn legendre_analysis(&self, four: &[Complex], spec: &mut [Complex]) {
        let lay = self.layout();
        let mt = lay.truncation();
        spec.fill(Complex::ZERO);
        for j in 0..self.grid.n_lat() {
            let w = self.grid.weights[j];
            let p = self.legendre.p_row(j);
            let f = &four[j * (mt + 1)..(j + 1) * (mt + 1)];
            for m in 0..=mt {
                let fm = f[m] * w;
                let k0 = lay.index(m, m);
                for k in k0..k0 + mt + 1 - m {
                    spec[k] += fm * p[k];
                }
            }
        }
        self.clean_m0(spec);
    }

    /// `div = div(A, B)` and `curl = curl(A, B)` from the Fourier coefficients of `A` and `B`
    /// (either output may be skipped).
    pub(crate) fn legendre_div_curl(
        &self,
        fa: &[Complex],
        fb: &[Complex],
        mut div: Option<&mut [Complex]>,
        mut curl: Option<&mut [Complex]>,
    ) {
        let lay = self.layout();
        let mt = lay.truncation();
        if let Some(d) = div.as_deref_mut() {
            d.fill(Complex::ZERO);
        }
        if let Some(c) = curl.as_deref_mut() {
            c.fill(Complex::ZERO);
        }
        for j in 0..self.grid.n_lat() {
            let w = self.wdiv[j];
            let p = self.legendre.p_row(j);
            let h = self.legendre.h_row(j);
            let r = j * (mt + 1)..(j + 1) * (mt + 1);
            let (fa, fb) = (&fa[r.clone()], &fb[r]);
            for m in 0..=mt {
                let a = fa[m] * w;
                let b = fb[m] * w;
                let (ima, imb) = (a.times_im(m as f64), b.times_im(m as f64));
                let k0 = lay.index(m, m);
                let ks = k0..k0 + mt + 1 - m;
                if let Some(d) = div.as_deref_mut() {
                    // div(A, B): i m A P - B H
                    for k in ks.clone() {
                        d[k] += ima * p[k] - b * h[k];
                    }
                }
                if let Some(c) = curl.as_deref_mut() {
                    // curl(A, B) = div(B, -A): i m B P + A H
                    for k in ks {
                        c[k] += imb * p[k] + a * h[k];
                    }
                }
            }
        }
        if let Some(d) = div {
            self.clean_m0(d);
        }
        if let Some(c) = curl {
            self.clean_m0(c);
        }
    }

    /// `F_m(j) = sum_n X_n^m P_n^m(mu_j)`.
    pub(crate) fn legendre_synthesis(&self, spec: &[Complex], four: &mut [Complex]) {
        let lay = self.layout();
        let mt = lay.truncation();
        for j in 0..self.grid.n_lat() {
            let p = self.legendre.p_row(j);
            let f = &mut four[j * (mt + 1)..(j + 1) * (mt + 1)];
            for m in 0..=mt {
                let k0 = lay.index(m, m);
                let mut s = Complex::ZERO;
                for k in k0..k0 + mt + 1 - m {
                    s += spec[k] * p[k];
                }
                f[m] = s;
            }
        }
    }

    /// Fourier coefficients of `U` and `V` from streamfunction `psi` and velocity potential `chi`.
    pub(crate) fn legendre_wind_synthesis(
        &self,
        psi: &[Complex],
        chi: &[Complex],
        fu: &mut [Complex],
        fv: &mut [Complex],
    ) {
        let lay = self.layout();
        let mt = lay.truncation();
        let ia = 1.0 / self.radius;
        for j in 0..self.grid.n_lat() {
            let p = self.legendre.p_row(j);
            let h = self.legendre.h_row(j);
            for m in 0..=mt {
                let k0 = lay.index(m, m);
                let (mut sp, mut sc, mut hp, mut hc) = (Complex::ZERO, Complex::ZERO, Complex::ZERO, Complex::ZERO);
                for k in k0..k0 + mt + 1 - m {
                    sp += psi[k] * p[k];
                    sc += chi[k] * p[k];
                    hp += psi[k] * h[k];
                    hc += chi[k] * h[k];
                }
                let mf = m as f64;
                fu[j * (mt + 1) + m] = (sc.times_im(mf) - hp) * ia;
                fv[j * (mt + 1) + m] = (sp.times_im(mf) + hc) * ia;
            }
        }
    }

    /// Fourier coefficients of `dq/dlambda` and `(1 - mu^2) dq/dmu`.
    pub(crate) fn legendre_gradient_synthesis(&self, q: &[Complex], fx: &mut [Complex], fy: &mut [Complex]) {
        let lay = self.layout();
        let mt = lay.truncation();
        for j in 0..self.grid.n_lat() {
            let p = self.legendre.p_row(j);
            let h = self.legendre.h_row(j);
            for m in 0..=mt {
                let k0 = lay.index(m, m);
                let (mut sp, mut sh) = (Complex::ZERO, Complex::ZERO);
                for k in k0..k0 + mt + 1 - m {
                    sp += q[k] * p[k];
                    sh += q[k] * h[k];
                }
                fx[j * (mt + 1) + m] = sp.times_im(m as f64);
                fy[j * (mt + 1) + m] = sh;
            }
        }
    }

    /// Zonal (m = 0) coefficients of real fields are real; drop round-off imaginary parts.
    fn clean_m0(&self, spec: &mut [Complex]) {
        for c in spec[..=self.truncation()].iter_mut() {
            c.im = 0.0;
        }
    }

    // ---- public, checked, allocating API ----

    fn check_grid(&self, f: &[f64], what: &str) -> Result<()> {
        self.grid.check_len(f, what)?;
        if f.iter().any(|x| !x.is_finite()) {
            return Err(Error::InvalidArgument(format!("{what} holds non-finite values")));
        }
        Ok(())
    }

    fn check_spec(&self, s: &[Complex], what: &str) -> Result<()> {
        if s.len() != self.n_spec() {
            return Err(Error::InvalidArgument(format!(
                "{what} has {} coefficients; T{} has {}",
                s.len(),
                self.truncation(),
                self.n_spec()
            )));
        }
        Ok(())
    }

    /// Grid -> spectral (the projection onto `T_M`; exact for band-limited fields).
    pub fn analysis(&self, grid: &[f64]) -> Result<Vec<Complex>> {
        self.check_grid(grid, "grid field")?;
        let mut s = self.scratch();
        let mut out = self.zeros();
        self.fourier_analysis(grid, &mut s.fa, &mut s.buf);
        self.legendre_analysis(&s.fa, &mut out);
        Ok(out)
    }

    /// Spectral -> grid.
    pub fn synthesis(&self, spec: &[Complex]) -> Result<Vec<f64>> {
        self.check_spec(spec, "spectral field")?;
        let mut s = self.scratch();
        let mut out = vec![0.0; self.grid.len()];
        self.legendre_synthesis(spec, &mut s.fa);
        self.fourier_synthesis(&s.fa, &mut out, &mut s.buf);
        Ok(out)
    }

    /// `(U, V) = (u cos(phi), v cos(phi))` on the grid from streamfunction and velocity potential.
    pub fn winds_from_psi_chi(&self, psi: &[Complex], chi: &[Complex]) -> Result<(Vec<f64>, Vec<f64>)> {
        self.check_spec(psi, "streamfunction")?;
        self.check_spec(chi, "velocity potential")?;
        let mut s = self.scratch();
        let mut u = vec![0.0; self.grid.len()];
        let mut v = vec![0.0; self.grid.len()];
        self.legendre_wind_synthesis(psi, chi, &mut s.fa, &mut s.fb);
        self.fourier_synthesis(&s.fa, &mut u, &mut s.buf);
        self.fourier_synthesis(&s.fb, &mut v, &mut s.buf);
        Ok((u, v))
    }

    /// `(U, V)` on the grid from vorticity and divergence (via `psi = chi = 0` at `n = 0`).
    pub fn winds_from_vort_div(&self, zeta: &[Complex], delta: &[Complex]) -> Result<(Vec<f64>, Vec<f64>)> {
        let psi = self.inverse_laplacian(zeta)?;
        let chi = self.inverse_laplacian(delta)?;
        self.winds_from_psi_chi(&psi, &chi)
    }

    /// Spectral `(div(A, B), curl(A, B))` of grid fluxes `(A, B)` (divided by `cos^2(phi)` as in
    /// the module doc); with `(A, B) = (U, V)` these are divergence and vorticity.
    pub fn div_curl(&self, a: &[f64], b: &[f64]) -> Result<(Vec<Complex>, Vec<Complex>)> {
        self.check_grid(a, "A")?;
        self.check_grid(b, "B")?;
        let mut s = self.scratch();
        self.fourier_analysis(a, &mut s.fa, &mut s.buf);
        self.fourier_analysis(b, &mut s.fb, &mut s.buf);
        let mut div = self.zeros();
        let mut curl = self.zeros();
        self.legendre_div_curl(&s.fa, &s.fb, Some(&mut div), Some(&mut curl));
        Ok((div, curl))
    }

    /// Spectral Laplacian.
    pub fn laplacian(&self, spec: &[Complex]) -> Result<Vec<Complex>> {
        self.check_spec(spec, "spectral field")?;
        let ia2 = 1.0 / (self.radius * self.radius);
        Ok(spec.iter().zip(&self.nn1).map(|(c, l)| *c * (-l * ia2)).collect())
    }

    /// Inverse Laplacian with the `n = 0` (global mean) coefficient set to zero.
    pub fn inverse_laplacian(&self, spec: &[Complex]) -> Result<Vec<Complex>> {
        self.check_spec(spec, "spectral field")?;
        let a2 = self.radius * self.radius;
        Ok(spec.iter().zip(&self.nn1).map(|(c, l)| if *l == 0.0 { Complex::ZERO } else { *c * (-a2 / l) }).collect())
    }

    /// `m` per spectral index (for callers that build spectral operators).
    pub fn m_values(&self) -> &[f64] {
        &self.mf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reproducible band-limited field: random-ish coefficients for all (m, n) <= M.
    fn spectrum(t: &SpectralTransform) -> Vec<Complex> {
        let mut s = t.zeros();
        for (k, (m, n)) in t.layout().modes().collect::<Vec<_>>().into_iter().enumerate() {
            let x = ((k as u64 * 2654435761) % 1000) as f64 / 1000.0 - 0.5;
            let y = ((k as u64 * 40503 + 17) % 997) as f64 / 997.0 - 0.5;
            s[k] = Complex::new(x, if m == 0 { 0.0 } else { y }) * (1.0 / (1.0 + n as f64));
        }
        s
    }

    fn max_diff(a: &[Complex], b: &[Complex]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (*x - *y).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn round_trip_of_band_limited_fields_is_exact() {
        for (m, nl) in [(21, 32), (42, 64), (30, 48)] {
            let t = SpectralTransform::new(m, nl, 6.37122e6).unwrap();
            let s = spectrum(&t);
            let g = t.synthesis(&s).unwrap();
            let back = t.analysis(&g).unwrap();
            let e = max_diff(&s, &back);
            assert!(e < 1e-12, "T{m}: round trip error {e}");
        }
    }

    #[test]
    fn laplacian_eigenvalues() {
        let a = 6.37122e6;
        let t = SpectralTransform::new(21, 32, a).unwrap();
        assert_eq!(t.laplacian_eigenvalue(3), -12.0 / (a * a));
        // Y_3^2 through the grid: div(grad) computed by the vector transforms reproduces -n(n+1)/a^2.
        let mut s = t.zeros();
        s[t.layout().index(2, 3)] = Complex::new(1.0, 0.5);
        let (u, v) = t.winds_from_psi_chi(&t.zeros(), &s).unwrap();
        let (div, curl) = t.div_curl(&u, &v).unwrap();
        let lap = t.laplacian(&s).unwrap();
        assert!(max_diff(&div, &lap) < 1e-12 * lap.iter().map(|c| c.abs()).fold(0.0, f64::max));
        assert!(curl.iter().all(|c| c.abs() < 1e-25));
        // And for a full random spectrum, vorticity -> winds -> vorticity is exact.
        let z = spectrum(&t);
        let d = spectrum(&t).iter().map(|c| *c * 0.3).collect::<Vec<_>>();
        let zs: Vec<Complex> = z.iter().map(|c| *c * 1e-5).collect();
        let ds: Vec<Complex> = d.iter().map(|c| *c * 1e-5).collect();
        let (u, v) = t.winds_from_vort_div(&zs, &ds).unwrap();
        let (d2, z2) = t.div_curl(&u, &v).unwrap();
        // n = 0 carries no wind; compare the rest.
        let n0 = t.layout().index(0, 0);
        let mut zs0 = zs.clone();
        zs0[n0] = Complex::ZERO;
        let mut ds0 = ds.clone();
        ds0[n0] = Complex::ZERO;
        assert!(max_diff(&z2, &zs0) < 1e-12 * 1e-5, "{}", max_diff(&z2, &zs0));
        assert!(max_diff(&d2, &ds0) < 1e-12 * 1e-5, "{}", max_diff(&d2, &ds0));
    }

    #[test]
    fn solid_body_rotation_winds_from_streamfunction() {
        let a = 6.37122e6;
        let u0 = 40.0;
        let alpha = 0.7_f64;
        let t = SpectralTransform::new(21, 32, a).unwrap();
        let g = t.grid().clone();
        let lon = g.lon_rad();
        // psi = -a u0 (sin(phi) cos(alpha) - cos(lambda) cos(phi) sin(alpha))
        let psi_g: Vec<f64> = (0..g.len())
            .map(|p| {
                let (mu, l) = (g.mu[p / g.n_lon()], lon[p % g.n_lon()]);
                -a * u0 * (mu * alpha.cos() - l.cos() * (1.0 - mu * mu).sqrt() * alpha.sin())
            })
            .collect();
        let psi = t.analysis(&psi_g).unwrap();
        let (uu, vv) = t.winds_from_psi_chi(&psi, &t.zeros()).unwrap();
        let mut worst: f64 = 0.0;
        for p in 0..g.len() {
            let (mu, l) = (g.mu[p / g.n_lon()], lon[p % g.n_lon()]);
            let c = (1.0 - mu * mu).sqrt();
            let u = u0 * (c * alpha.cos() + l.cos() * mu * alpha.sin());
            let v = -u0 * l.sin() * alpha.sin();
            worst = worst.max((uu[p] / c - u).abs()).max((vv[p] / c - v).abs());
        }
        assert!(worst < 1e-10 * u0, "solid-body wind error {worst} m/s");
        assert!(SpectralTransform::new(32, 32, a).is_err());
        assert!(t.analysis(&psi_g[1..]).is_err());
    }
}
