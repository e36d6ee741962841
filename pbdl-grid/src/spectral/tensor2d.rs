//! The differentiable path of [`SpectralNavierStokes`]: the same step as the fast path, written
//! with candle ops and [`pbdl_core::fft`] (whose backward passes are the FFT's adjoints), so a
//! loss on a rollout backpropagates to the initial velocity and to anything upstream.
//! Complex spectra are `[..., ny, nx/2+1, 2]` (`(re, im)` last), as [`pbdl_core::fft::rfft2`]
//! returns them.

use super::engine2d::{dealias_cutoff, derivative_wavenumber, signed};
use super::ns2d::SpectralNavierStokes;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, D};
use pbdl_core::fft::{irfft2, rfft2};
use pbdl_core::stepper::{Differentiability, Stepper};
use std::f64::consts::PI;

/// Per-mode tables `[ny, nh, 1]` in the state's dtype.
struct Tables {
    kx: Tensor,
    ky: Tensor,
    inv_k2: Tensor,
    keep: Tensor,
    /// `(beta, p, q)` per stage: `h <- N + beta h`, `w <- p w + q h`.
    stages: Vec<(f64, Tensor, Tensor)>,
    /// Spectrum of the vorticity forcing `[ny, nh, 2]`.
    forcing: Option<Tensor>,
}

/// `i k z` for a real multiplier `k` broadcast against `z` (`[..., 2]`).
pub(super) fn mul_i(z: &Tensor, k: &Tensor) -> candle_core::Result<Tensor> {
    let re = z.narrow(D::Minus1, 0, 1)?;
    let im = z.narrow(D::Minus1, 1, 1)?;
    Tensor::cat(&[&im.broadcast_mul(k)?.neg()?, &re.broadcast_mul(k)?], D::Minus1)
}

impl SpectralNavierStokes {
    fn tables(&self, dtype: DType) -> Result<Tables> {
        let (g, cfg) = (self.grid(), self.config());
        let (nx, ny) = (g.nx, g.ny);
        let nh = nx / 2 + 1;
        let dev = &Device::Cpu;
        let table = |f: &dyn Fn(usize, usize) -> f64| -> Result<Tensor> {
            let mut v = Vec::with_capacity(ny * nh);
            for j in 0..ny {
                for r in 0..nh {
                    v.push(f(j, r));
                }
            }
            Ok(Tensor::from_vec(v, (ny, nh, 1), dev)?.to_dtype(dtype)?)
        };
        let k2 = |j: usize, r: usize| {
            let ax = 2.0 * PI * signed(r, nx) as f64 / g.lx;
            let ay = 2.0 * PI * signed(j, ny) as f64 / g.ly;
            ax * ax + ay * ay
        };
        let (cx, cy) = (dealias_cutoff(nx), dealias_cutoff(ny));
        let c = cfg.scheme.coefficients();
        let mut stages = Vec::new();
        for k in 0..c.betas.len() {
            let mu = 0.5 * cfg.dt * (c.alphas[k + 1] - c.alphas[k]);
            let lin = |j: usize, r: usize| -cfg.nu * k2(j, r) - cfg.drag;
            stages.push((
                c.betas[k],
                table(&|j, r| (1.0 + mu * lin(j, r)) / (1.0 - mu * lin(j, r)))?,
                table(&|j, r| c.gammas[k] * cfg.dt / (1.0 - mu * lin(j, r)))?,
            ));
        }
        let forcing = match self.forcing() {
            None => None,
            Some(f) => {
                let kk = 2.0 * PI * f.wavenumber as f64 / g.ly;
                let col: Vec<f64> = (0..ny)
                    .flat_map(|j| {
                        let y = (j as f64 + 0.5) * g.dy();
                        std::iter::repeat_n(-f.amplitude * kk * (kk * y).cos(), nx)
                    })
                    .collect();
                Some(rfft2(&Tensor::from_vec(col, (ny, nx), dev)?.to_dtype(dtype)?)?)
            }
        };
        Ok(Tables {
            kx: table(&|_, r| derivative_wavenumber(r, nx, g.lx))?,
            ky: table(&|j, _| derivative_wavenumber(j, ny, g.ly))?,
            inv_k2: table(&|j, r| if j == 0 && r == 0 { 0.0 } else { 1.0 / k2(j, r) })?,
            keep: table(&|j, r| {
                if signed(j, ny).abs() <= cy && (r as i64) <= cx {
                    1.0
                } else {
                    0.0
                }
            })?,
            stages,
            forcing,
        })
    }

    /// The explicit terms of a vorticity spectrum `w` `[B, ny, nh, 2]` with mean velocity
    /// `(mu, mv)` (each `[B, 1, 1]`).
    fn explicit_tensor(&self, t: &Tables, w: &Tensor, mu: &Tensor, mv: &Tensor) -> Result<Tensor> {
        let nx = self.grid().nx;
        let psi = w.broadcast_mul(&t.inv_k2)?;
        let u = irfft2(&mul_i(&psi, &t.ky)?, nx)?.broadcast_add(mu)?;
        let v = irfft2(&mul_i(&psi, &t.kx)?.neg()?, nx)?.broadcast_add(mv)?;
        let gx = irfft2(&mul_i(w, &t.kx)?, nx)?;
        let gy = irfft2(&mul_i(w, &t.ky)?, nx)?;
        let adv = ((u * gx)? + (v * gy)?)?.neg()?;
        let n = rfft2(&adv)?.broadcast_mul(&t.keep)?;
        Ok(match &t.forcing {
            Some(f) => n.broadcast_add(f)?,
            None => n,
        })
    }

    /// One step of a velocity `[B, 2, ny, nx]` on the cell centres with candle ops (see
    /// [`Stepper::step`]).
    pub fn step_tensor(&self, velocity: &Tensor) -> Result<Tensor> {
        let g = *self.grid();
        let (b, c, ny, nx) = velocity.dims4().map_err(|_| shape_error(velocity, &g))?;
        if (c, ny, nx) != (2, g.ny, g.nx) {
            return Err(shape_error(velocity, &g));
        }
        let dtype = velocity.dtype();
        if !matches!(dtype, DType::F32 | DType::F64) {
            return Err(Error::Invalid { field: "velocity", reason: format!("dtype {dtype:?}: use f32 or f64") });
        }
        let t = self.tables(dtype)?;
        let n = (nx * ny) as f64;
        let uh = rfft2(&velocity.narrow(1, 0, 1)?.squeeze(1)?)?;
        let vh = rfft2(&velocity.narrow(1, 1, 1)?.squeeze(1)?)?;
        // The mean velocity is the DC entry over N; it only decays by the drag.
        let mean = |z: &Tensor| -> Result<Tensor> {
            Ok(z.narrow(1, 0, 1)?.narrow(2, 0, 1)?.narrow(3, 0, 1)?.reshape((b, 1, 1))?.affine(1.0 / n, 0.0)?)
        };
        let (mu, mv) = (mean(&uh)?, mean(&vh)?);
        let mut w = (mul_i(&vh, &t.kx)? - mul_i(&uh, &t.ky)?)?;
        let mut h = w.zeros_like()?;
        for (beta, p, q) in &t.stages {
            let nl = self.explicit_tensor(&t, &w, &mu, &mv)?;
            h = (nl + h.affine(*beta, 0.0)?)?;
            w = (w.broadcast_mul(p)? + h.broadcast_mul(q)?)?;
        }
        let decay = (-self.config().drag * self.config().dt).exp();
        let psi = w.broadcast_mul(&t.inv_k2)?;
        let u = irfft2(&mul_i(&psi, &t.ky)?, nx)?.broadcast_add(&mu.affine(decay, 0.0)?)?;
        let v = irfft2(&mul_i(&psi, &t.kx)?.neg()?, nx)?.broadcast_add(&mv.affine(decay, 0.0)?)?;
        Ok(Tensor::stack(&[u, v], 1)?)
    }
}

fn shape_error(v: &Tensor, g: &crate::Grid) -> Error {
    Error::Shape {
        op: "SpectralNavierStokes::step",
        arg: "velocity",
        expected: format!("[batch, 2, {}, {}] on the cell centres", g.ny, g.nx),
        got: v.dims().to_vec(),
    }
}

/// The differentiable path: `State` is the cell-centred velocity `[batch, 2, ny, nx]`. For long
/// runs without gradients use the fast path ([`SpectralNavierStokes::advance`]), several times
/// faster.
impl Stepper for SpectralNavierStokes {
    type State = Tensor;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config().dt
    }

    fn operators(&self) -> Vec<&'static str> {
        SpectralNavierStokes::operators(self)
    }

    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }

    fn step(&self, state: &Tensor) -> Result<Tensor> {
        self.step_tensor(state)
    }
}
