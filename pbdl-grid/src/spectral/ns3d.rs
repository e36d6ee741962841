//! [`SpectralNavierStokes3d`]: 3D incompressible Navier-Stokes in a triply periodic box,
//! velocity (rotational) form, pseudo-spectral in space, low-storage IMEX Runge-Kutta in time.

use super::engine2d::{dealias_cutoff, SpectralFloat};
use super::engine3d::{Engine3d, EngineSpec3d};
use super::ns2d::SpectralConfig;
use crate::grid3d::Grid3d;
use crate::scratch::Pod;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_core::Real;
use realfft::num_complex::Complex;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// The state of the fast path: the three velocity spectra in the precision of the initial tensor.
#[derive(Clone, Debug)]
pub struct SpectralState3d {
    spectra: Spectra3,
    speed: [f64; 3],
}

#[derive(Clone, Debug)]
enum Spectra3 {
    F32([Vec<Complex<f32>>; 3]),
    F64([Vec<Complex<f64>>; 3]),
}

impl SpectralState3d {
    /// The precision of the state.
    pub fn dtype(&self) -> DType {
        match self.spectra {
            Spectra3::F32(_) => DType::F32,
            Spectra3::F64(_) => DType::F64,
        }
    }
}

/// Pseudo-spectral incompressible Navier-Stokes in a triply periodic box, rotational form:
///
/// ```text
/// du/dt = P(u x omega) + nu lap u,   omega = curl u,   P = I - k k^T / |k|^2 (Leray)
/// ```
///
/// The pressure (with `|u|^2 / 2`) is the part `P` removes. The cross product is evaluated on the
/// grid points (cell centres) and dealiased by the 2/3 rule on every axis; the viscosity is
/// implicit (Crank-Nicolson per stage of the [`super::ImexScheme`]). For a velocity whose modes
/// lie inside the 2/3 set, the explicit term is orthogonal to `u` and to `omega`: the truncated
/// system conserves energy and helicity when `nu = 0`.
///
/// Fast path on a [`SpectralState3d`]; differentiable path through
/// [`pbdl_core::stepper::Stepper::step`] on a velocity tensor `[batch, 3, nz, ny, nx]`.
///
/// ```
/// use pbdl_grid::grid3d::Grid3d;
/// use pbdl_grid::spectral::{SpectralConfig, SpectralNavierStokes3d};
/// let grid = Grid3d::cube(16, 2.0 * std::f64::consts::PI)?;
/// let ns = SpectralNavierStokes3d::new(grid, SpectralConfig { nu: 0.01, dt: 0.05, scheme: Default::default(), drag: 0.0 })?;
/// // ABC flow (A = B = C = 1), a Beltrami flow: u x omega is a gradient, so it only decays.
/// let abc = |d: f64| ns.sample_velocity(candle_core::DType::F64, move |x, y, z| {
///     [d * (z.sin() + y.cos()), d * (x.sin() + z.cos()), d * (y.sin() + x.cos())]
/// });
/// let mut s = ns.state_from_velocity(&abc(1.0)?)?;
/// ns.advance(&mut s, 20)?;
/// let err = (ns.velocity(&s)? - abc((-0.01f64).exp())?)?.abs()?.max_all()?.to_scalar::<f64>()?;
/// assert!(err < 1e-9);
/// # Ok::<(), pbdl_grid::Error>(())
/// ```
pub struct SpectralNavierStokes3d {
    grid: Grid3d,
    config: SpectralConfig,
    e32: OnceLock<Engine3d<f32>>,
    e64: OnceLock<Engine3d<f64>>,
}

impl std::fmt::Debug for SpectralNavierStokes3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpectralNavierStokes3d").field("grid", &self.grid).field("config", &self.config).finish()
    }
}

trait Engine3dOf: SpectralFloat
where
    Complex<Self>: Pod,
{
    fn engine_of(ns: &SpectralNavierStokes3d) -> &Engine3d<Self>;
}

impl Engine3dOf for f32 {
    fn engine_of(ns: &SpectralNavierStokes3d) -> &Engine3d<f32> {
        ns.e32.get_or_init(|| Engine3d::new(&ns.spec()))
    }
}

impl Engine3dOf for f64 {
    fn engine_of(ns: &SpectralNavierStokes3d) -> &Engine3d<f64> {
        ns.e64.get_or_init(|| Engine3d::new(&ns.spec()))
    }
}

macro_rules! dispatch3 {
    ($self:ident, $spectra:expr, |$e:ident, $u:ident| $body:expr) => {
        match $spectra {
            Spectra3::F32($u) => {
                let $e = <f32 as Engine3dOf>::engine_of($self);
                $body
            }
            Spectra3::F64($u) => {
                let $e = <f64 as Engine3dOf>::engine_of($self);
                $body
            }
        }
    };
}

impl SpectralNavierStokes3d {
    /// A stepper on `grid` (periodic on every axis). Errors on a negative or non-finite
    /// viscosity, a non-positive time step, or a drag (not supported in 3D).
    pub fn new(grid: Grid3d, config: SpectralConfig) -> Result<Self> {
        grid.validate()?;
        if !(config.nu >= 0.0 && config.nu.is_finite()) {
            return Err(Error::Invalid { field: "nu", reason: format!("must be finite and >= 0, got {}", config.nu) });
        }
        if !(config.dt > 0.0 && config.dt.is_finite()) {
            return Err(Error::Invalid {
                field: "dt",
                reason: format!("must be positive and finite, got {}", config.dt),
            });
        }
        if config.drag != 0.0 {
            return Err(Error::Invalid {
                field: "drag",
                reason: "the 3D spectral solver has no drag term; use 0".into(),
            });
        }
        Ok(Self { grid, config, e32: OnceLock::new(), e64: OnceLock::new() })
    }

    fn spec(&self) -> EngineSpec3d {
        let g = &self.grid;
        EngineSpec3d {
            n: [g.nx, g.ny, g.nz],
            l: [g.lx, g.ly, g.lz],
            nu: self.config.nu,
            dt: self.config.dt,
            scheme: self.config.scheme,
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The configuration.
    pub fn config(&self) -> &SpectralConfig {
        &self.config
    }

    /// The operators of one step, in order.
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = vec!["spectral.fft", "spectral.rotational_advection_dealiased_2/3", "spectral.leray_projection"];
        if self.config.nu > 0.0 {
            ops.push("spectral.viscosity_implicit");
        }
        ops.push(self.config.scheme.operator());
        ops
    }

    /// The largest stable time step for advection speeds `(sx, sy, sz)` (see
    /// [`super::SpectralNavierStokes::stable_time_step`]).
    pub fn stable_time_step(grid: &Grid3d, scheme: super::ImexScheme, speed: [f64; 3]) -> f64 {
        let n = [grid.nx, grid.ny, grid.nz];
        let l = [grid.lx, grid.ly, grid.lz];
        let rate: f64 = (0..3).map(|a| 2.0 * PI * dealias_cutoff(n[a]) as f64 / l[a] * speed[a].abs()).sum();
        if rate > 0.0 {
            scheme.imaginary_axis_limit() / rate
        } else {
            f64::INFINITY
        }
    }

    /// A velocity `[1, 3, nz, ny, nx]` sampled from `f(x, y, z)` at the cell centres.
    pub fn sample_velocity(&self, dtype: DType, f: impl Fn(f64, f64, f64) -> [f64; 3]) -> Result<Tensor> {
        let g = &self.grid;
        let [dx, dy, dz] = g.spacing();
        let n = g.cells();
        let mut data = vec![0.0; 3 * n];
        for k in 0..g.nz {
            for j in 0..g.ny {
                for i in 0..g.nx {
                    let v = f((i as f64 + 0.5) * dx, (j as f64 + 0.5) * dy, (k as f64 + 0.5) * dz);
                    let p = (k * g.ny + j) * g.nx + i;
                    for a in 0..3 {
                        data[a * n + p] = v[a];
                    }
                }
            }
        }
        Ok(Tensor::from_vec(data, (1, 3, g.nz, g.ny, g.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }

    /// The state of a cell-centred velocity `[3, nz, ny, nx]` or `[1, 3, nz, ny, nx]` (f32 or
    /// f64), projected to zero divergence (spectrally).
    pub fn state_from_velocity(&self, velocity: &Tensor) -> Result<SpectralState3d> {
        let g = self.grid;
        let t = if velocity.rank() == 4 { velocity.unsqueeze(0)? } else { velocity.clone() };
        if t.dims() != [1, 3, g.nz, g.ny, g.nx] {
            return Err(Error::Shape {
                op: "SpectralNavierStokes3d::state_from_velocity",
                arg: "velocity",
                expected: format!("[3, {}, {}, {}] on the cell centres", g.nz, g.ny, g.nx),
                got: velocity.dims().to_vec(),
            });
        }
        let max = t.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        if !max.is_finite() {
            return Err(Error::NonFinite { what: "initial velocity", value: max });
        }
        let spectra = match t.dtype() {
            DType::F32 => Spectra3::F32(self.spectra_of::<f32>(&t.flatten_all()?.to_vec1::<f32>()?)),
            DType::F64 => Spectra3::F64(self.spectra_of::<f64>(&t.flatten_all()?.to_vec1::<f64>()?)),
            other => {
                return Err(Error::Invalid {
                    field: "velocity",
                    reason: format!("dtype {other:?}: the spectral solver runs in f32 or f64"),
                })
            }
        };
        let mut s = SpectralState3d { spectra, speed: [0.0; 3] };
        s.speed = speeds(&self.velocity(&s)?)?;
        Ok(s)
    }

    fn spectra_of<F: Engine3dOf>(&self, uvw: &[F]) -> [Vec<Complex<F>>; 3]
    where
        Complex<F>: Pod,
    {
        let e = F::engine_of(self);
        let n = self.grid.cells();
        let z0 = Complex::new(F::zero(), F::zero());
        let mut u = [vec![z0; e.modes()], vec![z0; e.modes()], vec![z0; e.modes()]];
        for a in 0..3 {
            e.forward_into(&uvw[a * n..(a + 1) * n], &mut u[a]);
        }
        e.project(&mut u);
        u
    }

    /// `steps` time steps of the fast path. Errors (typed) when the velocity stops being finite.
    pub fn advance(&self, state: &mut SpectralState3d, steps: usize) -> Result<()> {
        for _ in 0..steps {
            let s = dispatch3!(self, &mut state.spectra, |e, u| {
                let s = e.step(u);
                [s[0].wide(), s[1].wide(), s[2].wide()]
            });
            state.speed = s;
            if !s.iter().all(|v| v.is_finite()) {
                return Err(Error::NonFinite { what: "velocity", value: s[0].max(s[1]).max(s[2]) });
            }
        }
        Ok(())
    }

    /// Checks the state: finite, and the time step stable for its speed.
    pub fn check(&self, state: &SpectralState3d) -> Result<()> {
        let s = speeds(&self.velocity(state)?)?;
        if !s.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite { what: "velocity", value: s[0].max(s[1]).max(s[2]) });
        }
        let stable = Self::stable_time_step(&self.grid, self.config.scheme, s);
        if self.config.dt > stable {
            let lim = self.config.scheme.imaginary_axis_limit();
            return Err(Error::Unstable {
                what: "advective rate dt (k . |u|)",
                value: self.config.dt * lim / stable,
                limit: lim,
                scheme: format!("{:?}", self.config.scheme),
                dt: self.config.dt,
                stable_dt: stable,
            });
        }
        Ok(())
    }

    fn physical<F: Engine3dOf>(&self, fields: &[Vec<Complex<F>>; 3]) -> Result<Tensor>
    where
        Complex<F>: Pod,
    {
        let e = F::engine_of(self);
        let g = self.grid;
        let n = g.cells();
        let mut out = vec![F::zero(); 3 * n];
        for (a, f) in fields.iter().enumerate() {
            e.inverse_into(f, &mut out[a * n..(a + 1) * n]);
        }
        Ok(Tensor::from_vec(out, (1, 3, g.nz, g.ny, g.nx), &Device::Cpu)?)
    }

    /// The velocity on the cell centres, `[1, 3, nz, ny, nx]` in the state's precision.
    pub fn velocity(&self, state: &SpectralState3d) -> Result<Tensor> {
        match &state.spectra {
            Spectra3::F32(u) => self.physical(u),
            Spectra3::F64(u) => self.physical(u),
        }
    }

    /// The vorticity on the cell centres, `[1, 3, nz, ny, nx]`.
    pub fn vorticity(&self, state: &SpectralState3d) -> Result<Tensor> {
        dispatch3!(self, &state.spectra, |e, u| self.physical(&e.curl(u)))
    }

    /// The explicit term `P(u x omega)` (dealiased) on the cell centres, `[1, 3, nz, ny, nx]`.
    pub fn explicit_terms(&self, state: &SpectralState3d) -> Result<Tensor> {
        dispatch3!(self, &state.spectra, |e, u| self.physical(&e.explicit_terms(u).0))
    }

    /// Kinetic energy per unit volume `1/2 <|u|^2>`, in f64.
    pub fn energy(&self, state: &SpectralState3d) -> Result<f64> {
        let v = self.velocity(state)?.to_dtype(DType::F64)?;
        Ok(0.5 * v.sqr()?.sum_all()?.to_scalar::<f64>()? / self.grid.cells() as f64)
    }

    /// Enstrophy per unit volume `1/2 <|omega|^2>`, in f64 (`dE/dt = -2 nu Z` unforced).
    pub fn enstrophy(&self, state: &SpectralState3d) -> Result<f64> {
        let w = self.vorticity(state)?.to_dtype(DType::F64)?;
        Ok(0.5 * w.sqr()?.sum_all()?.to_scalar::<f64>()? / self.grid.cells() as f64)
    }

    /// Largest spectral divergence `max |k . u_hat| / max |k| |u_hat|` (0 up to round-off).
    pub fn relative_divergence(&self, state: &SpectralState3d) -> f64 {
        fn go<F: Engine3dOf>(e: &Engine3d<F>, u: &[Vec<Complex<F>>; 3]) -> f64
        where
            Complex<F>: Pod,
        {
            let [_, ny, nz] = e.n;
            let (mut div, mut scale) = (0.0f64, 0.0f64);
            for i in 0..e.modes() {
                let (r, rest) = (i / (ny * nz), i % (ny * nz));
                let k = [e.kx[r], e.ky[rest / nz], e.kz[rest % nz]];
                let d = u[0][i] * k[0] + u[1][i] * k[1] + u[2][i] * k[2];
                div = div.max(d.norm().wide());
                let kk = (k[0] * k[0] + k[1] * k[1] + k[2] * k[2]).sqrt().wide();
                for a in 0..3 {
                    scale = scale.max(kk * u[a][i].norm().wide());
                }
            }
            if scale > 0.0 {
                div / scale
            } else {
                0.0
            }
        }
        dispatch3!(self, &state.spectra, |e, u| go(e, u))
    }
}

/// `max |u|, |v|, |w|` of a velocity `[B, 3, nz, ny, nx]`.
fn speeds(v: &Tensor) -> Result<[f64; 3]> {
    let m = |c: usize| -> Result<f64> {
        Ok(v.narrow(1, c, 1)?.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?)
    };
    Ok([m(0)?, m(1)?, m(2)?])
}
