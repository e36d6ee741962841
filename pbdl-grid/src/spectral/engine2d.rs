//! The fast path of the 2D pseudo-spectral solver: planned real FFTs over plain buffers, the
//! vorticity spectrum kept in a transposed layout `[kx][ky]` so that every complex transform runs
//! over a contiguous row, and the nonlinear term evaluated in three fused passes per stage:
//!
//! 1. per `kx` row: the four spectra `u`, `v`, `d omega/dx`, `d omega/dy` from `omega` (stream
//!    function `psi = omega / |k|^2`), inverse-transformed along `y`; rows of zeros (modes the
//!    state does not hold) are skipped;
//! 2. per `y` row: the four half-complex rows to real (`x`), the advection
//!    `-(u + U) omega_x - (v + V) omega_y`, and its real-to-complex transform along `x`;
//! 3. per retained `kx` row: the forward transform along `y`, the 2/3 filter, and the IMEX stage
//!    update of `omega` and `h` fused into the same loop.
//!
//! The 2/3 rule (Orszag 1971) keeps `|k| <= (n - 1) / 3` along each axis, which removes the
//! aliasing of quadratic products exactly; the filter acts on the advection term only, as in
//! JAX-CFD, so a state holding higher modes keeps them (they decay by viscosity).

use super::imex::ImexScheme;
use crate::pad::parallel_cells;
use crate::scratch::{take, Pod};
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, FftNum, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// Float types of the fast path.
pub(crate) trait SpectralFloat: FftNum + pbdl_core::Real {}
impl SpectralFloat for f32 {}
impl SpectralFloat for f64 {}

/// What the engine is built from (all in f64).
#[derive(Clone, Debug)]
pub(crate) struct EngineSpec {
    pub nx: usize,
    pub ny: usize,
    pub lx: f64,
    pub ly: f64,
    pub nu: f64,
    pub drag: f64,
    pub dt: f64,
    pub scheme: ImexScheme,
}

/// One IMEX stage with its per-mode factors: `h <- N + beta h`, `w <- p w + q h`.
struct Stage<F> {
    beta: F,
    p: Vec<F>,
    q: Vec<F>,
}

/// Signed wavenumber index of FFT bin `k` of `n`.
pub(crate) fn signed(k: usize, n: usize) -> i64 {
    if k <= n / 2 {
        k as i64
    } else {
        k as i64 - n as i64
    }
}

/// The largest retained `|k|` of the 2/3 rule on an axis of `n` points.
pub(crate) fn dealias_cutoff(n: usize) -> i64 {
    ((n as i64) - 1) / 3
}

/// Angular wavenumber of bin `k` of `n` on a length `l` for first derivatives: zero at the
/// Nyquist bin of an even `n` (its derivative is not a real signal).
pub(crate) fn derivative_wavenumber(k: usize, n: usize, l: f64) -> f64 {
    if n % 2 == 0 && k == n / 2 {
        0.0
    } else {
        2.0 * std::f64::consts::PI * signed(k, n) as f64 / l
    }
}

/// The planned 2D solver in float type `F`.
pub(crate) struct Engine2d<F: FftNum> {
    pub nx: usize,
    pub ny: usize,
    pub nh: usize,
    r2c: Arc<dyn RealToComplex<F>>,
    c2r: Arc<dyn ComplexToReal<F>>,
    /// Complex inverse transform along `x` (two real rows at once in pass 2).
    inv_x: Arc<dyn Fft<F>>,
    fwd: Arc<dyn Fft<F>>,
    inv: Arc<dyn Fft<F>>,
    /// Derivative wavenumbers (angular, zero at Nyquist), unscaled.
    pub kx: Vec<f64>,
    pub ky: Vec<f64>,
    /// The same divided by `nx ny` (the scale of the unnormalised inverse folded in).
    kx_scaled: Vec<F>,
    ky_scaled: Vec<F>,
    /// `1 / |k|^2` per mode `[kx][ky]` (0 for the mean).
    inv_k2: Vec<F>,
    /// Rows `kx < keep_x` hold retained modes.
    keep_x: usize,
    /// 1 for a retained `ky`, 0 otherwise.
    keep_y: Vec<F>,
    stages: Vec<Stage<F>>,
    /// Spectrum of a constant vorticity forcing (`[kx][ky]`), added to the explicit terms.
    forcing: Option<Vec<Complex<F>>>,
    parallel: bool,
    /// Row length of the pass-1 buffer: `ny` rounded up to odd. Pass 2 reads it with a stride
    /// of `4 ld`; a power-of-two stride put every read of a row into one L1 cache set.
    ld: usize,
}

impl<F: SpectralFloat> Engine2d<F>
where
    Complex<F>: Pod,
{
    pub(crate) fn new(spec: &EngineSpec) -> Self {
        let (nx, ny) = (spec.nx, spec.ny);
        let nh = nx / 2 + 1;
        let mut rp = RealFftPlanner::<F>::new();
        let mut cp = FftPlanner::<F>::new();
        let kx: Vec<f64> = (0..nh).map(|k| derivative_wavenumber(k, nx, spec.lx)).collect();
        let ky: Vec<f64> = (0..ny).map(|k| derivative_wavenumber(k, ny, spec.ly)).collect();
        let norm = 1.0 / (nx * ny) as f64;
        let f = |v: f64| F::c(v);
        // |k|^2 with the full Nyquist wavenumbers (the Laplacian of a Nyquist mode is real).
        let two_pi = 2.0 * std::f64::consts::PI;
        let mut k2 = vec![0.0; nh * ny];
        for r in 0..nh {
            let ax = two_pi * signed(r, nx) as f64 / spec.lx;
            for j in 0..ny {
                let ay = two_pi * signed(j, ny) as f64 / spec.ly;
                k2[r * ny + j] = ax * ax + ay * ay;
            }
        }
        let inv_k2 = k2.iter().map(|&v| f(if v > 0.0 { 1.0 / v } else { 0.0 })).collect();
        let (cx, cy) = (dealias_cutoff(nx), dealias_cutoff(ny));
        let keep_y = (0..ny).map(|j| f(if signed(j, ny).abs() <= cy { 1.0 } else { 0.0 })).collect();
        let c = spec.scheme.coefficients();
        let stages = (0..c.betas.len())
            .map(|k| {
                let mu = 0.5 * spec.dt * (c.alphas[k + 1] - c.alphas[k]);
                let lin = |m: usize| -spec.nu * k2[m] - spec.drag;
                Stage {
                    beta: f(c.betas[k]),
                    p: (0..nh * ny).map(|m| f((1.0 + mu * lin(m)) / (1.0 - mu * lin(m)))).collect(),
                    q: (0..nh * ny).map(|m| f(c.gammas[k] * spec.dt / (1.0 - mu * lin(m)))).collect(),
                }
            })
            .collect();
        Self {
            nx,
            ny,
            nh,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            inv_x: cp.plan_fft_inverse(nx),
            fwd: cp.plan_fft_forward(ny),
            inv: cp.plan_fft_inverse(ny),
            kx_scaled: kx.iter().map(|&v| f(v * norm)).collect(),
            ky_scaled: ky.iter().map(|&v| f(v * norm)).collect(),
            kx,
            ky,
            inv_k2,
            keep_x: (cx + 1).min(nh as i64) as usize,
            keep_y,
            stages,
            forcing: None,
            // One pass reads or writes five fields (four inverse transforms and the product), so
            // the work of one op is five fields' worth of elements.
            parallel: parallel_cells(5 * nx * ny),
            ld: ny | 1,
        }
    }

    /// Sets a constant vorticity forcing given on the grid points (`[ny][nx]`, row-major).
    pub(crate) fn set_forcing(&mut self, forcing: &[F]) {
        self.forcing = Some(self.forward(forcing));
    }

    fn zero() -> Complex<F> {
        Complex::new(F::zero(), F::zero())
    }

    /// Unnormalised forward 2D transform of a real `[ny][nx]` field into the `[kx][ky]` layout.
    pub(crate) fn forward(&self, real: &[F]) -> Vec<Complex<F>> {
        let (nx, ny, nh) = (self.nx, self.ny, self.nh);
        let mut out = vec![Self::zero(); nh * ny];
        let mut row = vec![F::zero(); nx];
        let mut spec = vec![Self::zero(); nh];
        let mut scratch = self.r2c.make_scratch_vec();
        for j in 0..ny {
            row.copy_from_slice(&real[j * nx..(j + 1) * nx]);
            self.r2c.process_with_scratch(&mut row, &mut spec, &mut scratch).expect("r2c sizes are planned");
            for r in 0..nh {
                out[r * ny + j] = spec[r];
            }
        }
        let mut cs = vec![Self::zero(); self.fwd.get_inplace_scratch_len()];
        self.fwd.process_with_scratch(&mut out, &mut cs);
        out
    }

    /// Normalised inverse of [`Engine2d::forward`] (numpy's `irfft2` semantics: the imaginary
    /// parts of the DC and Nyquist columns are dropped after the transform along `y`).
    pub(crate) fn inverse(&self, spec: &[Complex<F>]) -> Vec<F> {
        let (nx, ny, nh) = (self.nx, self.ny, self.nh);
        let mut cols = spec.to_vec();
        let mut cs = vec![Self::zero(); self.inv.get_inplace_scratch_len()];
        self.inv.process_with_scratch(&mut cols, &mut cs);
        let mut out = vec![F::zero(); nx * ny];
        let mut row = vec![Self::zero(); nh];
        let mut scratch = self.c2r.make_scratch_vec();
        let norm = F::c(1.0 / (nx * ny) as f64);
        for j in 0..ny {
            for r in 0..nh {
                row[r] = cols[r * ny + j] * norm;
            }
            clear_real_edges(&mut row, nx);
            self.c2r
                .process_with_scratch(&mut row, &mut out[j * nx..(j + 1) * nx], &mut scratch)
                .expect("c2r sizes are planned");
        }
        out
    }

    /// `i k_x z` and `i k_y z` multipliers applied to a spectrum (unscaled): `(d/dx, d/dy)`.
    pub(crate) fn derivatives(&self, z: &[Complex<F>]) -> (Vec<Complex<F>>, Vec<Complex<F>>) {
        let ny = self.ny;
        let mut dx = vec![Self::zero(); z.len()];
        let mut dy = vec![Self::zero(); z.len()];
        for r in 0..self.nh {
            let ax = F::c(self.kx[r]);
            for j in 0..ny {
                let m = r * ny + j;
                let ay = F::c(self.ky[j]);
                dx[m] = Complex::new(-ax * z[m].im, ax * z[m].re);
                dy[m] = Complex::new(-ay * z[m].im, ay * z[m].re);
            }
        }
        (dx, dy)
    }

    /// The stream function `psi = omega / |k|^2` (`lap psi = -omega`, zero mean).
    pub(crate) fn stream_spectrum(&self, w: &[Complex<F>]) -> Vec<Complex<F>> {
        w.iter().zip(&self.inv_k2).map(|(z, &s)| *z * s).collect()
    }

    /// The velocity spectra `(u, v) = (dpsi/dy, -dpsi/dx)` of a vorticity spectrum.
    pub(crate) fn velocity_spectra(&self, w: &[Complex<F>]) -> (Vec<Complex<F>>, Vec<Complex<F>>) {
        let (px, py) = self.derivatives(&self.stream_spectrum(w));
        (py, px.into_iter().map(|z| -z).collect())
    }

    /// Multiplies a spectrum by `exp(i (k_x sx + k_y sy))`: the field shifted by `(-sx, -sy)`,
    /// i.e. sampled at `x + sx, y + sy` (derivative wavenumbers, so Nyquist modes stay put).
    pub(crate) fn shift(&self, z: &[Complex<F>], sx: f64, sy: f64) -> Vec<Complex<F>> {
        let ny = self.ny;
        let mut out = z.to_vec();
        for r in 0..self.nh {
            for j in 0..ny {
                let phase = self.kx[r] * sx + self.ky[j] * sy;
                out[r * ny + j] = z[r * ny + j] * Complex::new(F::c(phase.cos()), F::c(phase.sin()));
            }
        }
        out
    }

    /// One time step of the vorticity spectrum `w` (`[kx][ky]`, unnormalised) with the mean
    /// velocity `mean`; returns the largest `|u| + |v|`-type speed (`max(|u|, |v|)` per axis)
    /// seen in the first stage (for the stability check).
    pub(crate) fn step(&self, w: &mut [Complex<F>], mean: [F; 2]) -> [F; 2] {
        let (nh, ny) = (self.nh, self.ny);
        let mut t4 = take::<Complex<F>>(4 * nh * self.ld);
        let mut q = take::<Complex<F>>(ny * nh);
        let mut h = take::<Complex<F>>(nh * ny);
        h.fill(Self::zero());
        let mut speed = [F::zero(); 2];
        for (k, stage) in self.stages.iter().enumerate() {
            self.spectra_to_columns(w, &mut t4);
            let s = self.advection_rows(&t4, mean, &mut q, k == 0);
            if k == 0 {
                speed = s;
            }
            self.update_columns(&q, stage, w, &mut h);
        }
        speed
    }

    /// The dealiased advection term `-(u . grad) omega` of `w` (plus the forcing), spectrum
    /// `[kx][ky]`, unnormalised.
    pub(crate) fn explicit_terms(&self, w: &[Complex<F>], mean: [F; 2]) -> Vec<Complex<F>> {
        let (nh, ny) = (self.nh, self.ny);
        let mut t4 = take::<Complex<F>>(4 * nh * self.ld);
        let mut q = take::<Complex<F>>(ny * nh);
        self.spectra_to_columns(w, &mut t4);
        self.advection_rows(&t4, mean, &mut q, false);
        // A stage with beta = 0, p = 0, q = 1 writes N itself.
        let stage = Stage { beta: F::zero(), p: vec![F::zero(); nh * ny], q: vec![F::one(); nh * ny] };
        let mut out = vec![Self::zero(); nh * ny];
        let mut hbuf = vec![Self::zero(); nh * ny];
        self.update_columns(&q, &stage, &mut out, &mut hbuf);
        out
    }

    /// Pass 1: per `kx` row, `[u, v, omega_x, omega_y]` (scaled by `1/N`) transformed back along
    /// `y`, into `t4` laid out `[kx][4][y]` with rows of `ld` entries.
    fn spectra_to_columns(&self, w: &[Complex<F>], t4: &mut [Complex<F>]) {
        let ny = self.ny;
        let scratch_len = self.inv.get_inplace_scratch_len();
        let body = |r: usize, out: &mut [Complex<F>], scratch: &mut [Complex<F>]| {
            let wr = &w[r * ny..(r + 1) * ny];
            if wr.iter().all(|z| z.re == F::zero() && z.im == F::zero()) {
                out.fill(Self::zero());
                return;
            }
            let ax = self.kx_scaled[r];
            let inv_k2 = &self.inv_k2[r * ny..(r + 1) * ny];
            let ld = self.ld;
            let (u, rest) = out.split_at_mut(ld);
            let (v, rest) = rest.split_at_mut(ld);
            let (gx, gy) = rest.split_at_mut(ld);
            for j in 0..ny {
                let z = wr[j];
                let ay = self.ky_scaled[j];
                let (pr, pi) = (z.re * inv_k2[j], z.im * inv_k2[j]);
                // i a z = (-a im, a re); u = dpsi/dy, v = -dpsi/dx.
                u[j] = Complex::new(-ay * pi, ay * pr);
                v[j] = Complex::new(ax * pi, -ax * pr);
                gx[j] = Complex::new(-ax * z.im, ax * z.re);
                gy[j] = Complex::new(-ay * z.im, ay * z.re);
            }
            for f in [u, v, gx, gy] {
                self.inv.process_with_scratch(&mut f[..ny], scratch);
            }
        };
        if self.parallel {
            t4.par_chunks_mut(4 * self.ld)
                .enumerate()
                .for_each_init(|| take::<Complex<F>>(scratch_len), |s, (r, out)| body(r, out, s));
        } else {
            let mut s = take::<Complex<F>>(scratch_len);
            t4.chunks_mut(4 * self.ld).enumerate().for_each(|(r, out)| body(r, out, &mut s));
        }
    }

    /// Pass 2: per `y` row, the four fields to real, the advection, and its transform along `x`
    /// into `q` (`[y][kx]`, only `kx < keep_x` written). Returns the largest `|u|`, `|v|` when
    /// `track_speed` (zeros otherwise).
    fn advection_rows(&self, t4: &[Complex<F>], mean: [F; 2], q: &mut [Complex<F>], track_speed: bool) -> [F; 2] {
        let (nx, nh, keep_x, ld) = (self.nx, self.nh, self.keep_x, self.ld);
        let scratch_len = self.r2c.get_scratch_len().max(self.inv_x.get_inplace_scratch_len());
        let body = |y: usize, out: &mut [Complex<F>], buf: &mut RowBuffers<F>| -> [F; 2] {
            // Two real rows per complex inverse transform: with half spectra A and B, the full
            // spectrum Z = A + iB (extended by Hermitian symmetry) transforms to a + ib. One
            // vectorised complex FFT instead of two real ones (realfft's pre-pass is scalar).
            for pair in 0..2 {
                let (ka, kb) = (2 * pair, 2 * pair + 1);
                let col = |k: usize| t4[k * ld + y..].iter().step_by(4 * ld);
                for ((ha, hb), (a, b)) in buf.half.iter_mut().zip(buf.half_b.iter_mut()).zip(col(ka).zip(col(kb))) {
                    *ha = *a;
                    *hb = *b;
                }
                clear_real_edges(&mut buf.half, nx);
                clear_real_edges(&mut buf.half_b, nx);
                let z = &mut buf.full;
                for (zk, (a, b)) in z.iter_mut().zip(buf.half.iter().zip(&buf.half_b)) {
                    *zk = Complex::new(a.re - b.im, a.im + b.re);
                }
                for k in 1..=nx - nh {
                    // conj(A) + i conj(B) at -k.
                    let (a, b) = (buf.half[k], buf.half_b[k]);
                    z[nx - k] = Complex::new(a.re + b.im, b.re - a.im);
                }
                self.inv_x.process_with_scratch(z, &mut buf.scratch);
                let (ra, rb) = buf.real[ka * nx..(kb + 1) * nx].split_at_mut(nx);
                for ((x, y), zk) in ra.iter_mut().zip(rb.iter_mut()).zip(z.iter()) {
                    *x = zk.re;
                    *y = zk.im;
                }
            }
            let (u, rest) = buf.real.split_at_mut(nx);
            let (v, rest) = rest.split_at_mut(nx);
            let (gx, rest) = rest.split_at_mut(nx);
            let gy = &rest[..nx];
            for i in 0..nx {
                buf.product[i] = -((u[i] + mean[0]) * gx[i] + (v[i] + mean[1]) * gy[i]);
            }
            // The speeds only for the stability check (first stage): the NaN-aware maximum does
            // not vectorise and took half of this loop's time in every stage.
            let (mut su, mut sv) = (F::zero(), F::zero());
            if track_speed {
                for i in 0..nx {
                    su = su.fmax((u[i] + mean[0]).abs());
                    sv = sv.fmax((v[i] + mean[1]).abs());
                }
            }
            self.r2c
                .process_with_scratch(&mut buf.product, &mut buf.half, &mut buf.scratch)
                .expect("r2c sizes are planned");
            out[..keep_x].copy_from_slice(&buf.half[..keep_x]);
            [su, sv]
        };
        let max2 = |a: [F; 2], b: [F; 2]| [a[0].fmax(b[0]), a[1].fmax(b[1])];
        let init = || RowBuffers::new(nx, nh, scratch_len);
        if self.parallel {
            q.par_chunks_mut(nh)
                .enumerate()
                .map_init(init, |b, (y, out)| body(y, out, b))
                .reduce(|| [F::zero(); 2], max2)
        } else {
            let mut b = init();
            q.chunks_mut(nh).enumerate().map(|(y, out)| body(y, out, &mut b)).fold([F::zero(); 2], max2)
        }
    }

    /// Pass 3: per `kx` row, the forward transform along `y` of the advection, the 2/3 filter,
    /// the forcing, and the stage update `h <- N + beta h`, `w <- p w + q h`.
    fn update_columns(&self, q: &[Complex<F>], stage: &Stage<F>, w: &mut [Complex<F>], h: &mut [Complex<F>]) {
        let (ny, nh, keep_x) = (self.ny, self.nh, self.keep_x);
        let scratch_len = self.fwd.get_inplace_scratch_len();
        let body = |r: usize,
                    wr: &mut [Complex<F>],
                    hr: &mut [Complex<F>],
                    col: &mut Vec<Complex<F>>,
                    s: &mut [Complex<F>]| {
            let base = r * ny;
            if r < keep_x {
                for j in 0..ny {
                    col[j] = q[j * nh + r];
                }
                self.fwd.process_with_scratch(&mut col[..ny], s);
                for j in 0..ny {
                    col[j] *= self.keep_y[j];
                }
            } else {
                col[..ny].fill(Self::zero());
            }
            if let Some(f) = &self.forcing {
                for j in 0..ny {
                    col[j] += f[base + j];
                }
            }
            let (p, qq) = (&stage.p[base..base + ny], &stage.q[base..base + ny]);
            for j in 0..ny {
                let hn = col[j] + hr[j] * stage.beta;
                hr[j] = hn;
                wr[j] = wr[j] * p[j] + hn * qq[j];
            }
        };
        if self.parallel {
            w.par_chunks_mut(ny).zip(h.par_chunks_mut(ny)).enumerate().for_each_init(
                || (vec![Self::zero(); ny], take::<Complex<F>>(scratch_len)),
                |(col, s), (r, (wr, hr))| body(r, wr, hr, col, s),
            );
        } else {
            let mut col = vec![Self::zero(); ny];
            let mut s = take::<Complex<F>>(scratch_len);
            for (r, (wr, hr)) in w.chunks_mut(ny).zip(h.chunks_mut(ny)).enumerate() {
                body(r, wr, hr, &mut col, &mut s);
            }
        }
    }
}

/// Per-row buffers of pass 2.
struct RowBuffers<F: Copy + 'static> {
    half: Vec<Complex<F>>,
    half_b: Vec<Complex<F>>,
    full: Vec<Complex<F>>,
    real: Vec<F>,
    product: Vec<F>,
    scratch: Vec<Complex<F>>,
}

impl<F: SpectralFloat> RowBuffers<F> {
    fn new(nx: usize, nh: usize, scratch: usize) -> Self {
        let z = Complex::new(F::zero(), F::zero());
        Self {
            half: vec![z; nh],
            half_b: vec![z; nh],
            full: vec![z; nx],
            real: vec![F::zero(); 4 * nx],
            product: vec![F::zero(); nx],
            scratch: vec![z; scratch],
        }
    }
}

/// Drops the imaginary parts of the DC and (even `nx`) Nyquist entries of a half spectrum before
/// a complex-to-real transform, as numpy's `irfft` does.
fn clear_real_edges<F: SpectralFloat>(half: &mut [Complex<F>], nx: usize) {
    half[0].im = F::zero();
    if nx % 2 == 0 {
        let last = half.len() - 1;
        half[last].im = F::zero();
    }
}
