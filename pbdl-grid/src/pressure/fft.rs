//! Periodic Poisson solve by a real 2D FFT: rows with a real-to-complex transform, columns with a
//! complex one, divide by the eigenvalues of the five-point Laplacian, transform back.

use crate::pad::parallel_cells;
use crate::scratch::{take, Pod};
use crate::Grid;
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, FftNum, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// A planned periodic Poisson solve in float type `F`.
pub(crate) struct FftPoisson<F: FftNum> {
    nx: usize,
    ny: usize,
    nh: usize,
    r2c: Arc<dyn RealToComplex<F>>,
    c2r: Arc<dyn ComplexToReal<F>>,
    fwd: Arc<dyn Fft<F>>,
    inv: Arc<dyn Fft<F>>,
    /// `1 / (lambda(kx, ky) nx ny)`, laid out `[kx][ky]`; 0 for the constant mode.
    inv_eig: Vec<F>,
}

impl<F: FftNum> FftPoisson<F>
where
    Complex<F>: Pod,
{
    pub(crate) fn new(grid: &Grid) -> Self {
        let (nx, ny) = (grid.nx, grid.ny);
        let nh = nx / 2 + 1;
        let mut rp = RealFftPlanner::<F>::new();
        let mut cp = FftPlanner::<F>::new();
        let (dx, dy) = (grid.dx(), grid.dy());
        let norm = (nx * ny) as f64;
        let mut inv_eig = vec![F::zero(); nh * ny];
        for kx in 0..nh {
            for ky in 0..ny {
                let lx = (2.0 * (2.0 * std::f64::consts::PI * kx as f64 / nx as f64).cos() - 2.0) / (dx * dx);
                let ly = (2.0 * (2.0 * std::f64::consts::PI * ky as f64 / ny as f64).cos() - 2.0) / (dy * dy);
                let lam = lx + ly;
                let v = if kx == 0 && ky == 0 { 0.0 } else { 1.0 / (lam * norm) };
                inv_eig[kx * ny + ky] = F::from_f64(v).expect("float");
            }
        }
        Self {
            nx,
            ny,
            nh,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            fwd: cp.plan_fft_forward(ny),
            inv: cp.plan_fft_inverse(ny),
            inv_eig,
        }
    }

    /// `out = L^+ rhs` (both `ny x nx`).
    pub(crate) fn solve(&self, rhs: &[F], out: &mut [F]) {
        let (nx, ny, nh) = (self.nx, self.ny, self.nh);
        let par = parallel_cells(nx * ny);
        let zero = Complex::new(F::zero(), F::zero());
        let mut spec = take::<Complex<F>>(ny * nh);
        let mut spec_t = take::<Complex<F>>(ny * nh);
        // Rows: real -> half spectrum.
        let rows = |(src, dst): (&[F], &mut [Complex<F>]), (tmp, scr): &mut (Vec<F>, Vec<Complex<F>>)| {
            tmp.copy_from_slice(src);
            self.r2c.process_with_scratch(tmp, dst, scr).expect("fft sizes match");
        };
        let init_r = || (vec![F::zero(); nx], self.r2c.make_scratch_vec());
        if par {
            rhs.par_chunks(nx).zip(spec.par_chunks_mut(nh)).for_each_init(init_r, |s, x| rows(x, s));
        } else {
            let mut s = init_r();
            rhs.chunks(nx).zip(spec.chunks_mut(nh)).for_each(|x| rows(x, &mut s));
        }
        transpose(&spec, ny, nh, &mut spec_t, par);
        // Columns: forward, divide, inverse.
        let cols = |(k, col): (usize, &mut [Complex<F>]), scr: &mut Vec<Complex<F>>| {
            self.fwd.process_with_scratch(col, scr);
            for (c, &e) in col.iter_mut().zip(&self.inv_eig[k * ny..(k + 1) * ny]) {
                *c = *c * e;
            }
            self.inv.process_with_scratch(col, scr);
        };
        let scr_len = self.fwd.get_inplace_scratch_len().max(self.inv.get_inplace_scratch_len());
        let init_c = || vec![zero; scr_len];
        if par {
            spec_t.par_chunks_mut(ny).enumerate().for_each_init(init_c, |s, x| cols(x, s));
        } else {
            // All columns in one call each way: rustfft's batched path is faster than per-column calls.
            let mut s = init_c();
            self.fwd.process_with_scratch(&mut spec_t, &mut s);
            for (c, &e) in spec_t.iter_mut().zip(&self.inv_eig[..]) {
                *c = *c * e;
            }
            self.inv.process_with_scratch(&mut spec_t, &mut s);
        }
        transpose(&spec_t, nh, ny, &mut spec, par);
        // Rows back: half spectrum -> real. Round-off can leave imaginary parts on the real bins.
        let back = |(src, dst): (&mut [Complex<F>], &mut [F]), scr: &mut Vec<Complex<F>>| {
            src[0].im = F::zero();
            if nx % 2 == 0 {
                src[nh - 1].im = F::zero();
            }
            self.c2r.process_with_scratch(src, dst, scr).expect("fft sizes match");
        };
        let init_b = || self.c2r.make_scratch_vec();
        if par {
            spec.par_chunks_mut(nh).zip(out.par_chunks_mut(nx)).for_each_init(init_b, |s, x| back(x, s));
        } else {
            let mut s = init_b();
            spec.chunks_mut(nh).zip(out.chunks_mut(nx)).for_each(|x| back(x, &mut s));
        }
    }
}

/// `dst[c][r] = src[r][c]` for a `rows x cols` matrix, in `TILE x TILE` blocks so that both
/// the reads and the writes stay within a few cache lines (a plain column loop strides through
/// `dst` and was ~9% of a 128^2 Navier-Stokes step).
fn transpose<T: Copy + Send + Sync>(src: &[T], rows: usize, cols: usize, dst: &mut [T], par: bool) {
    const TILE: usize = 16;
    // One band = TILE destination rows (source columns), all source rows.
    let band = |(b, d): (usize, &mut [T])| {
        let c0 = b * TILE;
        let nc = d.len() / rows;
        for r0 in (0..rows).step_by(TILE) {
            let r1 = (r0 + TILE).min(rows);
            for c in 0..nc {
                let drow = &mut d[c * rows..(c + 1) * rows];
                for r in r0..r1 {
                    drow[r] = src[r * cols + c0 + c];
                }
            }
        }
    };
    if par {
        dst.par_chunks_mut(TILE * rows).enumerate().for_each(band);
    } else {
        dst.chunks_mut(TILE * rows).enumerate().for_each(band);
    }
}
