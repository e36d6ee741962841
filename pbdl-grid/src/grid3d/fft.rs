//! Periodic 3D Poisson solve by FFT: real-to-complex along x, complex along y and z, divide by
//! the eigenvalues of the seven-point Laplacian `D G`, transform back.
//!
//! Dividing by the *discrete* operator's eigenvalues (not `-|k|^2`) makes `D G p = b - mean(b)`
//! hold to round-off, so a projected velocity is discretely divergence-free to round-off.

use super::Grid3d;
use crate::pad::parallel_cells;
use crate::scratch::{take, Pod};
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, FftNum, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// A planned periodic 3D Poisson solve in float type `F`.
pub(crate) struct FftPoisson3d<F: FftNum> {
    n: [usize; 3],
    nh: usize,
    r2c: Arc<dyn RealToComplex<F>>,
    c2r: Arc<dyn ComplexToReal<F>>,
    /// Forward and inverse complex transforms along y and along z.
    fy: Arc<dyn Fft<F>>,
    iy: Arc<dyn Fft<F>>,
    fz: Arc<dyn Fft<F>>,
    iz: Arc<dyn Fft<F>>,
    /// `1 / (lambda(kx, ky, kz) nx ny nz)`, laid out `[kx][ky][kz]`; 0 for the constant mode.
    inv_eig: Vec<F>,
}

/// Eigenvalue of the periodic second difference along one axis for wavenumber index `k`.
fn eig1(k: usize, n: usize, h: f64) -> f64 {
    (2.0 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos() - 2.0) / (h * h)
}

impl<F: FftNum> FftPoisson3d<F>
where
    Complex<F>: Pod,
{
    pub(crate) fn new(grid: &Grid3d) -> Self {
        let (nx, ny, nz) = (grid.nx, grid.ny, grid.nz);
        let nh = nx / 2 + 1;
        let [dx, dy, dz] = grid.spacing();
        let norm = (nx * ny * nz) as f64;
        let mut inv_eig = vec![F::zero(); nh * ny * nz];
        for kx in 0..nh {
            for ky in 0..ny {
                for kz in 0..nz {
                    let lam = eig1(kx, nx, dx) + eig1(ky, ny, dy) + eig1(kz, nz, dz);
                    let v = if kx == 0 && ky == 0 && kz == 0 { 0.0 } else { 1.0 / (lam * norm) };
                    inv_eig[(kx * ny + ky) * nz + kz] = F::from_f64(v).expect("float");
                }
            }
        }
        let mut rp = RealFftPlanner::<F>::new();
        let mut cp = FftPlanner::<F>::new();
        Self {
            n: [nx, ny, nz],
            nh,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            fy: cp.plan_fft_forward(ny),
            iy: cp.plan_fft_inverse(ny),
            fz: cp.plan_fft_forward(nz),
            iz: cp.plan_fft_inverse(nz),
            inv_eig,
        }
    }

    /// `out = L^+ rhs` (both `nz x ny x nx`); the mean of `rhs` is dropped.
    pub(crate) fn solve(&self, rhs: &[F], out: &mut [F]) {
        let ([nx, ny, nz], nh) = (self.n, self.nh);
        let par = parallel_cells(nx * ny * nz);
        let plane = ny * nh;
        let zero = Complex::new(F::zero(), F::zero());
        let mut a = take::<Complex<F>>(nz * plane);
        let mut b = take::<Complex<F>>(nz * plane);
        // x: real rows -> half spectra, a = [z][y][kx].
        let init_r = || (vec![F::zero(); nx], self.r2c.make_scratch_vec());
        let rows = |(src, dst): (&[F], &mut [Complex<F>]), (tmp, scr): &mut (Vec<F>, Vec<Complex<F>>)| {
            tmp.copy_from_slice(src);
            self.r2c.process_with_scratch(tmp, dst, scr).expect("fft sizes match");
        };
        if par {
            rhs.par_chunks(nx).zip(a.par_chunks_mut(nh)).for_each_init(init_r, |s, x| rows(x, s));
        } else {
            let mut s = init_r();
            rhs.chunks(nx).zip(a.chunks_mut(nh)).for_each(|x| rows(x, &mut s));
        }
        // y: per plane, b = [z][kx][y], forward along y.
        let ys = self.fy.get_inplace_scratch_len().max(self.iy.get_inplace_scratch_len());
        let fwd_y = |(src, dst): (&[Complex<F>], &mut [Complex<F>]), scr: &mut Vec<Complex<F>>| {
            transpose(src, ny, nh, dst);
            self.fy.process_with_scratch(dst, scr);
        };
        for_planes(&a, &mut b, plane, par, || vec![zero; ys], fwd_y);
        // z: a = [kx][y][z] (rows of the whole volume transposed), forward, divide, inverse.
        transpose_par(&b, nz, plane, &mut a, par);
        let zs = self.fz.get_inplace_scratch_len().max(self.iz.get_inplace_scratch_len());
        let cols = |(m, col): (usize, &mut [Complex<F>]), scr: &mut Vec<Complex<F>>| {
            self.fz.process_with_scratch(col, scr);
            for (c, &e) in col.iter_mut().zip(&self.inv_eig[m * nz..(m + 1) * nz]) {
                *c = *c * e;
            }
            self.iz.process_with_scratch(col, scr);
        };
        if par {
            a.par_chunks_mut(nz).enumerate().for_each_init(|| vec![zero; zs], |s, x| cols(x, s));
        } else {
            let mut s = vec![zero; zs];
            a.chunks_mut(nz).enumerate().for_each(|x| cols(x, &mut s));
        }
        transpose_par(&a, plane, nz, &mut b, par);
        // y back: inverse along y, a = [z][y][kx].
        // `src` is read-only here: transform a copy (per-thread buffer), then transpose.
        let inv_y = |(src, dst): (&[Complex<F>], &mut [Complex<F>]),
                     (col, scr): &mut (Vec<Complex<F>>, Vec<Complex<F>>)| {
            col.copy_from_slice(src);
            self.iy.process_with_scratch(col, scr);
            transpose(col, nh, ny, dst);
        };
        for_planes(&b, &mut a, plane, par, || (vec![zero; plane], vec![zero; ys]), inv_y);
        // x back. Round-off can leave imaginary parts on the real bins.
        let back = |(src, dst): (&mut [Complex<F>], &mut [F]), scr: &mut Vec<Complex<F>>| {
            src[0].im = F::zero();
            if nx % 2 == 0 {
                src[nh - 1].im = F::zero();
            }
            self.c2r.process_with_scratch(src, dst, scr).expect("fft sizes match");
        };
        if par {
            a.par_chunks_mut(nh)
                .zip(out.par_chunks_mut(nx))
                .for_each_init(|| self.c2r.make_scratch_vec(), |s, x| back(x, s));
        } else {
            let mut s = self.c2r.make_scratch_vec();
            a.chunks_mut(nh).zip(out.chunks_mut(nx)).for_each(|x| back(x, &mut s));
        }
    }
}

/// Runs `f((src_plane, dst_plane), scratch)` over the `plane`-sized chunks of `src` and `dst`.
fn for_planes<T: Send + Sync, S, I, G>(src: &[T], dst: &mut [T], plane: usize, par: bool, init: I, f: G)
where
    I: Fn() -> S + Send + Sync,
    G: Fn((&[T], &mut [T]), &mut S) + Send + Sync,
{
    if par {
        src.par_chunks(plane).zip(dst.par_chunks_mut(plane)).for_each_init(init, |s, x| f(x, s));
    } else {
        let mut s = init();
        src.chunks(plane).zip(dst.chunks_mut(plane)).for_each(|x| f(x, &mut s));
    }
}

/// `dst[c][r] = src[r][c]` for a `rows x cols` matrix.
fn transpose<T: Copy>(src: &[T], rows: usize, cols: usize, dst: &mut [T]) {
    for (c, d) in dst.chunks_mut(rows).enumerate() {
        for r in 0..rows {
            d[r] = src[r * cols + c];
        }
    }
}

/// [`transpose`], parallel over the destination rows for large volumes.
fn transpose_par<T: Copy + Send + Sync>(src: &[T], rows: usize, cols: usize, dst: &mut [T], par: bool) {
    let f = |(c, d): (usize, &mut [T])| {
        for r in 0..rows {
            d[r] = src[r * cols + c];
        }
    };
    if par {
        dst.par_chunks_mut(rows).enumerate().for_each(f);
    } else {
        dst.chunks_mut(rows).enumerate().for_each(f);
    }
}
