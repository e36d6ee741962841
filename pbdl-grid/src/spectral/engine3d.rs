//! The fast path of the 3D pseudo-spectral solver: planned real 3D FFTs over plain buffers and
//! the rotational-form step `du/dt = P(u x omega) + nu lap u` (the pressure absorbs
//! `|u|^2 / 2`, `P` is the Leray projection `I - k k^T / |k|^2`), dealiased by the 2/3 rule.
//!
//! Spectra are laid out `[kx][ky][kz]` (`kx` over the half spectrum `nx/2+1`): the transform
//! runs real-to-complex along `x`, then along `y` and `z` after a transpose each, so every
//! complex transform runs over a contiguous row.

use super::engine2d::{dealias_cutoff, derivative_wavenumber, signed, SpectralFloat};
use super::imex::ImexScheme;
use crate::pad::parallel_cells;
use crate::scratch::{take, uninit, Pod};
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// What the engine is built from.
#[derive(Clone, Debug)]
pub(crate) struct EngineSpec3d {
    pub n: [usize; 3],
    pub l: [f64; 3],
    pub nu: f64,
    pub dt: f64,
    pub scheme: ImexScheme,
}

struct Stage<F> {
    beta: F,
    p: Vec<F>,
    q: Vec<F>,
}

/// The planned 3D solver in float type `F`.
pub(crate) struct Engine3d<F: SpectralFloat> {
    pub n: [usize; 3],
    pub nh: usize,
    r2c: Arc<dyn RealToComplex<F>>,
    c2r: Arc<dyn ComplexToReal<F>>,
    fy: Arc<dyn Fft<F>>,
    iy: Arc<dyn Fft<F>>,
    fz: Arc<dyn Fft<F>>,
    iz: Arc<dyn Fft<F>>,
    /// Derivative wavenumbers per axis (zero at Nyquist).
    pub kx: Vec<F>,
    pub ky: Vec<F>,
    pub kz: Vec<F>,
    /// 1 for a retained mode (2/3 rule on every axis), per `[kx][ky][kz]`.
    keep: Vec<F>,
    stages: Vec<Stage<F>>,
    parallel: bool,
}

/// Runs a complex transform over every row of `buf` (rows of the plan's length).
fn fft_rows<F: SpectralFloat>(plan: &Arc<dyn Fft<F>>, buf: &mut [Complex<F>], parallel: bool)
where
    Complex<F>: Pod,
{
    let len = plan.len();
    let scratch = plan.get_inplace_scratch_len();
    if parallel {
        let rows = (buf.len() / len).div_ceil(rayon::current_num_threads().max(1) * 4).max(1);
        buf.par_chunks_mut(rows * len).for_each(|chunk| {
            let mut s = take::<Complex<F>>(scratch);
            plan.process_with_scratch(chunk, &mut s);
        });
    } else {
        let mut s = take::<Complex<F>>(scratch);
        plan.process_with_scratch(buf, &mut s);
    }
}

impl<F: SpectralFloat> Engine3d<F>
where
    Complex<F>: Pod,
{
    pub(crate) fn new(spec: &EngineSpec3d) -> Self {
        let [nx, ny, nz] = spec.n;
        let nh = nx / 2 + 1;
        let mut rp = RealFftPlanner::<F>::new();
        let mut cp = FftPlanner::<F>::new();
        let f = |v: f64| F::c(v);
        let kx: Vec<f64> = (0..nh).map(|k| derivative_wavenumber(k, nx, spec.l[0])).collect();
        let ky: Vec<f64> = (0..ny).map(|k| derivative_wavenumber(k, ny, spec.l[1])).collect();
        let kz: Vec<f64> = (0..nz).map(|k| derivative_wavenumber(k, nz, spec.l[2])).collect();
        let full = |k: usize, n: usize, l: f64| 2.0 * std::f64::consts::PI * signed(k, n) as f64 / l;
        let m = nh * ny * nz;
        let mut k2 = vec![0.0; m];
        let mut keep = vec![F::zero(); m];
        let c = [dealias_cutoff(nx), dealias_cutoff(ny), dealias_cutoff(nz)];
        for r in 0..nh {
            for j in 0..ny {
                for l in 0..nz {
                    let i = (r * ny + j) * nz + l;
                    let (a, b, g) = (full(r, nx, spec.l[0]), full(j, ny, spec.l[1]), full(l, nz, spec.l[2]));
                    k2[i] = a * a + b * b + g * g;
                    let kept = (r as i64) <= c[0] && signed(j, ny).abs() <= c[1] && signed(l, nz).abs() <= c[2];
                    keep[i] = f(if kept { 1.0 } else { 0.0 });
                }
            }
        }
        let co = spec.scheme.coefficients();
        let stages = (0..co.betas.len())
            .map(|k| {
                let mu = 0.5 * spec.dt * (co.alphas[k + 1] - co.alphas[k]);
                Stage {
                    beta: f(co.betas[k]),
                    p: k2.iter().map(|&v| f((1.0 - mu * spec.nu * v) / (1.0 + mu * spec.nu * v))).collect(),
                    q: k2.iter().map(|&v| f(co.gammas[k] * spec.dt / (1.0 + mu * spec.nu * v))).collect(),
                }
            })
            .collect();
        Self {
            n: spec.n,
            nh,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            fy: cp.plan_fft_forward(ny),
            iy: cp.plan_fft_inverse(ny),
            fz: cp.plan_fft_forward(nz),
            iz: cp.plan_fft_inverse(nz),
            kx: kx.into_iter().map(f).collect(),
            ky: ky.into_iter().map(f).collect(),
            kz: kz.into_iter().map(f).collect(),
            keep,
            stages,
            parallel: parallel_cells(nx * ny * nz),
        }
    }

    /// Modes of one spectrum.
    pub(crate) fn modes(&self) -> usize {
        self.nh * self.n[1] * self.n[2]
    }

    /// Unnormalised forward transform of a real `[nz][ny][nx]` field into `out` (`[kx][ky][kz]`).
    pub(crate) fn forward_into(&self, real: &[F], out: &mut [Complex<F>]) {
        let [nx, ny, nz] = self.n;
        let nh = self.nh;
        let z0 = Complex::new(F::zero(), F::zero());
        let mut a = take::<Complex<F>>(nz * ny * nh);
        let scratch = self.r2c.get_scratch_len();
        let rows = |(src, dst): (&[F], &mut [Complex<F>]), s: &mut Vec<F>, sc: &mut Vec<Complex<F>>| {
            s.copy_from_slice(src);
            self.r2c.process_with_scratch(s, dst, sc).expect("r2c sizes are planned");
        };
        if self.parallel {
            real.par_chunks(nx)
                .zip(a.par_chunks_mut(nh))
                .for_each_init(|| (vec![F::zero(); nx], vec![z0; scratch]), |(s, sc), x| rows(x, s, sc));
        } else {
            let (mut s, mut sc) = (vec![F::zero(); nx], vec![z0; scratch]);
            real.chunks(nx).zip(a.chunks_mut(nh)).for_each(|x| rows(x, &mut s, &mut sc));
        }
        // a[z][y][r] -> b[r][z][y], transform along y.
        let mut b = take::<Complex<F>>(nh * nz * ny);
        self.transpose(&a, &mut b, |r, z, y| (z * ny + y) * nh + r, [nh, nz, ny]);
        fft_rows(&self.fy, &mut b, self.parallel);
        // b[r][z][y] -> out[r][y][z], transform along z.
        self.transpose(&b, out, |r, y, z| (r * nz + z) * ny + y, [nh, ny, nz]);
        fft_rows(&self.fz, out, self.parallel);
    }

    /// Normalised inverse of [`Engine3d::forward_into`] (numpy's `irfftn` semantics).
    pub(crate) fn inverse_into(&self, spec: &[Complex<F>], out: &mut [F]) {
        let [nx, ny, nz] = self.n;
        let nh = self.nh;
        let z0 = Complex::new(F::zero(), F::zero());
        let mut c = take::<Complex<F>>(spec.len());
        c.copy_from_slice(spec);
        fft_rows(&self.iz, &mut c, self.parallel);
        let mut b = take::<Complex<F>>(spec.len());
        self.transpose(&c, &mut b, |r, z, y| (r * ny + y) * nz + z, [nh, nz, ny]);
        fft_rows(&self.iy, &mut b, self.parallel);
        let mut a = take::<Complex<F>>(spec.len());
        self.transpose(&b, &mut a, |z, y, r| (r * nz + z) * ny + y, [nz, ny, nh]);
        let norm = F::c(1.0 / (nx * ny * nz) as f64);
        let scratch = self.c2r.get_scratch_len();
        let rows = |(src, dst): (&mut [Complex<F>], &mut [F]), sc: &mut Vec<Complex<F>>| {
            src[0].im = F::zero();
            if nx % 2 == 0 {
                src[nh - 1].im = F::zero();
            }
            self.c2r.process_with_scratch(src, dst, sc).expect("c2r sizes are planned");
            dst.iter_mut().for_each(|v| *v *= norm);
        };
        if self.parallel {
            a.par_chunks_mut(nh).zip(out.par_chunks_mut(nx)).for_each_init(|| vec![z0; scratch], |sc, x| rows(x, sc));
        } else {
            let mut sc = vec![z0; scratch];
            a.chunks_mut(nh).zip(out.chunks_mut(nx)).for_each(|x| rows(x, &mut sc));
        }
    }

    /// `dst[i][j][k] = src[index(i, j, k)]` over `dims = [ni, nj, nk]`.
    fn transpose(
        &self,
        src: &[Complex<F>],
        dst: &mut [Complex<F>],
        index: impl Fn(usize, usize, usize) -> usize + Sync,
        dims: [usize; 3],
    ) {
        let [_, nj, nk] = dims;
        let plane = |(i, d): (usize, &mut [Complex<F>])| {
            for j in 0..nj {
                for k in 0..nk {
                    d[j * nk + k] = src[index(i, j, k)];
                }
            }
        };
        if self.parallel {
            dst.par_chunks_mut(nj * nk).enumerate().for_each(plane);
        } else {
            dst.chunks_mut(nj * nk).enumerate().for_each(plane);
        }
    }

    /// The wavenumber vector of mode `i` (derivative wavenumbers).
    #[inline]
    fn k_of(&self, i: usize) -> [F; 3] {
        let [_, ny, nz] = self.n;
        let (r, rest) = (i / (ny * nz), i % (ny * nz));
        [self.kx[r], self.ky[rest / nz], self.kz[rest % nz]]
    }

    /// Leray projection of three spectra in place: `c <- c - k (k . c) / |k|^2`.
    pub(crate) fn project(&self, c: &mut [Vec<Complex<F>>; 3]) {
        for i in 0..self.modes() {
            let k = self.k_of(i);
            let kk = k[0] * k[0] + k[1] * k[1] + k[2] * k[2];
            if kk > F::zero() {
                let d = (c[0][i] * k[0] + c[1][i] * k[1] + c[2][i] * k[2]) / kk;
                for a in 0..3 {
                    c[a][i] -= d * k[a];
                }
            }
        }
    }

    /// `i k x u` of three velocity spectra: the vorticity spectra.
    pub(crate) fn curl(&self, u: &[Vec<Complex<F>>; 3]) -> [Vec<Complex<F>>; 3] {
        let m = self.modes();
        let z0 = Complex::new(F::zero(), F::zero());
        let mut w = [vec![z0; m], vec![z0; m], vec![z0; m]];
        let i_times = |z: Complex<F>| Complex::new(-z.im, z.re);
        for i in 0..m {
            let k = self.k_of(i);
            w[0][i] = i_times(u[2][i] * k[1] - u[1][i] * k[2]);
            w[1][i] = i_times(u[0][i] * k[2] - u[2][i] * k[0]);
            w[2][i] = i_times(u[1][i] * k[0] - u[0][i] * k[1]);
        }
        w
    }

    /// The explicit terms `P(u x omega)`, dealiased, of velocity spectra `u`; returns them and
    /// `max |u|, |v|, |w|`.
    pub(crate) fn explicit_terms(&self, u: &[Vec<Complex<F>>; 3]) -> ([Vec<Complex<F>>; 3], [F; 3]) {
        let cells = self.n[0] * self.n[1] * self.n[2];
        let w = self.curl(u);
        // Six physical fields (u, omega) and three products, from the per-thread scratch pool:
        // fresh buffers every stage cost page faults at 64^3 and up.
        let mut phys = uninit::<F>(6 * cells);
        for a in 0..3 {
            self.inverse_into(&u[a], &mut phys[a * cells..(a + 1) * cells]);
            self.inverse_into(&w[a], &mut phys[(3 + a) * cells..(4 + a) * cells]);
        }
        let field = |k: usize| &phys[k * cells..(k + 1) * cells];
        let (pu, pv, pw, ox, oy, oz) = (field(0), field(1), field(2), field(3), field(4), field(5));
        let mut speed = [F::zero(); 3];
        let mut cross = uninit::<F>(3 * cells);
        let (cx, rest) = cross.split_at_mut(cells);
        let (cy, cz) = rest.split_at_mut(cells);
        for p in 0..cells {
            let (uu, vv, ww) = (pu[p], pv[p], pw[p]);
            speed[0] = speed[0].fmax(uu.abs());
            speed[1] = speed[1].fmax(vv.abs());
            speed[2] = speed[2].fmax(ww.abs());
            cx[p] = vv * oz[p] - ww * oy[p];
            cy[p] = ww * ox[p] - uu * oz[p];
            cz[p] = uu * oy[p] - vv * ox[p];
        }
        let z0 = Complex::new(F::zero(), F::zero());
        let m = self.modes();
        let mut n = [vec![z0; m], vec![z0; m], vec![z0; m]];
        for a in 0..3 {
            self.forward_into(&cross[a * cells..(a + 1) * cells], &mut n[a]);
            n[a].iter_mut().zip(&self.keep).for_each(|(z, &k)| *z *= k);
        }
        self.project(&mut n);
        (n, speed)
    }

    /// One time step of the velocity spectra; returns the speeds at its start.
    pub(crate) fn step(&self, u: &mut [Vec<Complex<F>>; 3]) -> [F; 3] {
        let z0 = Complex::new(F::zero(), F::zero());
        let m = self.modes();
        let mut h = [vec![z0; m], vec![z0; m], vec![z0; m]];
        let mut speed = [F::zero(); 3];
        for (k, st) in self.stages.iter().enumerate() {
            let (n, s) = self.explicit_terms(u);
            if k == 0 {
                speed = s;
            }
            for a in 0..3 {
                for i in 0..m {
                    let hn = n[a][i] + h[a][i] * st.beta;
                    h[a][i] = hn;
                    u[a][i] = u[a][i] * st.p[i] + hn * st.q[i];
                }
            }
        }
        speed
    }
}
