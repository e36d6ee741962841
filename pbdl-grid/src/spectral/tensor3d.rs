//! The differentiable path of [`SpectralNavierStokes3d`]: the fast path's step in candle ops and
//! [`pbdl_core::fft`] (`rfft3` / `irfft3` with their adjoints). Spectra are
//! `[batch, nz, ny, nx/2+1, 2]`.

use super::engine2d::{dealias_cutoff, derivative_wavenumber, signed};
use super::ns3d::SpectralNavierStokes3d;
use super::tensor2d::mul_i;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_core::fft::{irfft3, rfft3};
use pbdl_core::stepper::{Differentiability, Stepper};
use std::f64::consts::PI;

struct Tables3 {
    /// Derivative wavenumbers along x, y, z, each broadcast as `[nz, ny, nh, 1]`.
    k: [Tensor; 3],
    /// `1 / |k|^2` of the derivative wavenumbers (0 where they vanish): the projection.
    inv_kk: Tensor,
    keep: Tensor,
    stages: Vec<(f64, Tensor, Tensor)>,
}

impl SpectralNavierStokes3d {
    fn tables3(&self, dtype: DType) -> Result<Tables3> {
        let (g, cfg) = (*self.grid(), *self.config());
        let (nx, ny, nz) = (g.nx, g.ny, g.nz);
        let nh = nx / 2 + 1;
        let table = |f: &dyn Fn(usize, usize, usize) -> f64| -> Result<Tensor> {
            let mut v = Vec::with_capacity(nz * ny * nh);
            for l in 0..nz {
                for j in 0..ny {
                    for r in 0..nh {
                        v.push(f(l, j, r));
                    }
                }
            }
            Ok(Tensor::from_vec(v, (nz, ny, nh, 1), &Device::Cpu)?.to_dtype(dtype)?)
        };
        let full = |k: usize, n: usize, l: f64| 2.0 * PI * signed(k, n) as f64 / l;
        let k2 = |l: usize, j: usize, r: usize| {
            full(r, nx, g.lx).powi(2) + full(j, ny, g.ly).powi(2) + full(l, nz, g.lz).powi(2)
        };
        let dk = |l: usize, j: usize, r: usize| {
            [derivative_wavenumber(r, nx, g.lx), derivative_wavenumber(j, ny, g.ly), derivative_wavenumber(l, nz, g.lz)]
        };
        let c = [dealias_cutoff(nx), dealias_cutoff(ny), dealias_cutoff(nz)];
        let co = cfg.scheme.coefficients();
        let mut stages = Vec::new();
        for k in 0..co.betas.len() {
            let mu = 0.5 * cfg.dt * (co.alphas[k + 1] - co.alphas[k]);
            let nu = cfg.nu;
            stages.push((
                co.betas[k],
                table(&|l, j, r| (1.0 - mu * nu * k2(l, j, r)) / (1.0 + mu * nu * k2(l, j, r)))?,
                table(&|l, j, r| co.gammas[k] * cfg.dt / (1.0 + mu * nu * k2(l, j, r)))?,
            ));
        }
        Ok(Tables3 {
            k: [
                table(&|l, j, r| dk(l, j, r)[0])?,
                table(&|l, j, r| dk(l, j, r)[1])?,
                table(&|l, j, r| dk(l, j, r)[2])?,
            ],
            inv_kk: table(&|l, j, r| {
                let k = dk(l, j, r);
                let kk = k[0] * k[0] + k[1] * k[1] + k[2] * k[2];
                if kk > 0.0 {
                    1.0 / kk
                } else {
                    0.0
                }
            })?,
            keep: table(&|l, j, r| {
                let kept = (r as i64) <= c[0] && signed(j, ny).abs() <= c[1] && signed(l, nz).abs() <= c[2];
                if kept {
                    1.0
                } else {
                    0.0
                }
            })?,
            stages,
        })
    }

    fn project_tensor(t: &Tables3, c: [Tensor; 3]) -> Result<[Tensor; 3]> {
        let d = (c[0].broadcast_mul(&t.k[0])? + c[1].broadcast_mul(&t.k[1])?)?;
        let d = (d + c[2].broadcast_mul(&t.k[2])?)?.broadcast_mul(&t.inv_kk)?;
        let out = |a: usize| -> Result<Tensor> { Ok((&c[a] - d.broadcast_mul(&t.k[a])?)?) };
        Ok([out(0)?, out(1)?, out(2)?])
    }

    fn explicit_tensor(&self, t: &Tables3, u: &[Tensor; 3]) -> Result<[Tensor; 3]> {
        let nx = self.grid().nx;
        let k = &t.k;
        let w = [
            (mul_i(&u[2], &k[1])? - mul_i(&u[1], &k[2])?)?,
            (mul_i(&u[0], &k[2])? - mul_i(&u[2], &k[0])?)?,
            (mul_i(&u[1], &k[0])? - mul_i(&u[0], &k[1])?)?,
        ];
        let p: Vec<Tensor> = u.iter().chain(w.iter()).map(|z| irfft3(z, nx)).collect::<pbdl_core::Result<_>>()?;
        let cross = [
            ((&p[1] * &p[5])? - (&p[2] * &p[4])?)?,
            ((&p[2] * &p[3])? - (&p[0] * &p[5])?)?,
            ((&p[0] * &p[4])? - (&p[1] * &p[3])?)?,
        ];
        let f = |a: usize| -> Result<Tensor> { Ok(rfft3(&cross[a])?.broadcast_mul(&t.keep)?) };
        Self::project_tensor(t, [f(0)?, f(1)?, f(2)?])
    }

    /// One step of a velocity `[B, 3, nz, ny, nx]` on the cell centres with candle ops (see
    /// [`Stepper::step`]); the velocity is projected first, as the fast path does when it
    /// builds its state.
    pub fn step_tensor(&self, velocity: &Tensor) -> Result<Tensor> {
        let g = *self.grid();
        let dims = velocity.dims();
        if dims.len() != 5 || dims[1..] != [3, g.nz, g.ny, g.nx] {
            return Err(Error::Shape {
                op: "SpectralNavierStokes3d::step",
                arg: "velocity",
                expected: format!("[batch, 3, {}, {}, {}] on the cell centres", g.nz, g.ny, g.nx),
                got: dims.to_vec(),
            });
        }
        let dtype = velocity.dtype();
        if !matches!(dtype, DType::F32 | DType::F64) {
            return Err(Error::Invalid { field: "velocity", reason: format!("dtype {dtype:?}: use f32 or f64") });
        }
        let t = self.tables3(dtype)?;
        let comp = |a: usize| -> Result<Tensor> { Ok(rfft3(&velocity.narrow(1, a, 1)?.squeeze(1)?)?) };
        let mut u = Self::project_tensor(&t, [comp(0)?, comp(1)?, comp(2)?])?;
        let mut h: Option<[Tensor; 3]> = None;
        for (beta, p, q) in &t.stages {
            let n = self.explicit_tensor(&t, &u)?;
            let hn: [Tensor; 3] = match &h {
                None => n,
                Some(h) => [
                    (&n[0] + h[0].affine(*beta, 0.0)?)?,
                    (&n[1] + h[1].affine(*beta, 0.0)?)?,
                    (&n[2] + h[2].affine(*beta, 0.0)?)?,
                ],
            };
            let upd = |a: usize| -> Result<Tensor> { Ok((u[a].broadcast_mul(p)? + hn[a].broadcast_mul(q)?)?) };
            u = [upd(0)?, upd(1)?, upd(2)?];
            h = Some(hn);
        }
        let nx = g.nx;
        let out: Vec<Tensor> = u.iter().map(|z| irfft3(z, nx)).collect::<pbdl_core::Result<_>>()?;
        Ok(Tensor::stack(&out, 1)?)
    }
}

/// The differentiable path: `State` is the cell-centred velocity `[batch, 3, nz, ny, nx]`.
impl Stepper for SpectralNavierStokes3d {
    type State = Tensor;
    type Error = Error;

    fn dt(&self) -> f64 {
        self.config().dt
    }

    fn operators(&self) -> Vec<&'static str> {
        SpectralNavierStokes3d::operators(self)
    }

    fn differentiability(&self) -> Differentiability {
        Differentiability::Full
    }

    fn step(&self, state: &Tensor) -> Result<Tensor> {
        self.step_tensor(state)
    }
}
