//! [`SpectralNavierStokes`]: 2D incompressible Navier-Stokes in a periodic box, vorticity form,
//! pseudo-spectral in space, low-storage IMEX Runge-Kutta in time.

use super::engine2d::{dealias_cutoff, Engine2d, EngineSpec, SpectralFloat};
use super::imex::ImexScheme;
use crate::scratch::Pod;
use crate::{Boundaries, Error, Grid, MacField, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_core::Real;
use realfft::num_complex::Complex;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Parameters of a [`SpectralNavierStokes`] stepper.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpectralConfig {
    /// Kinematic viscosity (>= 0), treated implicitly (Crank-Nicolson per stage).
    pub nu: f64,
    /// Time step (> 0). Advection is explicit: see [`SpectralNavierStokes::stable_time_step`].
    pub dt: f64,
    /// The IMEX scheme. Default: [`ImexScheme::CnRk4`].
    #[serde(default = "default_scheme")]
    pub scheme: ImexScheme,
    /// Linear drag coefficient (>= 0): `-drag omega` on the vorticity (implicit, with the
    /// viscosity). Default 0.
    #[serde(default)]
    pub drag: f64,
}

fn default_scheme() -> ImexScheme {
    ImexScheme::CnRk4
}

/// A steady body force `f_x = amplitude sin(2 pi wavenumber y / ly)` (Kolmogorov flow).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KolmogorovForcing {
    /// Force amplitude.
    pub amplitude: f64,
    /// Periods along `y` (>= 1).
    pub wavenumber: u32,
}

/// The state of the fast path: the vorticity spectrum (precision of the initial tensor) and the
/// mean velocity, which the vorticity does not carry.
#[derive(Clone, Debug)]
pub struct SpectralState {
    spectrum: Spectrum,
    mean: [f64; 2],
    /// `max |u|, max |v|` at the start of the last step (or at creation).
    speed: [f64; 2],
}

#[derive(Clone, Debug)]
enum Spectrum {
    F32(Vec<Complex<f32>>),
    F64(Vec<Complex<f64>>),
}

impl SpectralState {
    /// The precision of the state.
    pub fn dtype(&self) -> DType {
        match self.spectrum {
            Spectrum::F32(_) => DType::F32,
            Spectrum::F64(_) => DType::F64,
        }
    }

    /// The mean velocity `(U, V)`.
    pub fn mean_velocity(&self) -> [f64; 2] {
        self.mean
    }
}

/// Pseudo-spectral incompressible Navier-Stokes on a doubly periodic box (vorticity form):
///
/// ```text
/// d omega/dt = -(u . grad) omega + nu lap omega - drag omega + curl f,   u = (U, V) + (dpsi/dy, -dpsi/dx),   lap psi = -omega
/// ```
///
/// Space: Fourier on the grid points (the cell centres of a [`Grid`]), the advection evaluated
/// in physical space and dealiased by the 2/3 rule; time: the low-storage IMEX scheme of
/// [`ImexScheme`] (viscosity and drag implicit, exact for the linear decay of each mode up to the
/// scheme's 2nd order). The same scheme as JAX-CFD's `spectral.equations.NavierStokes2D` with
/// `crank_nicolson_rk4`, plus the mean flow.
///
/// Two paths compute the same step:
/// * the fast path on a [`SpectralState`] ([`SpectralNavierStokes::state_from_velocity`],
///   [`SpectralNavierStokes::advance`]): planned real FFTs, three fused passes per stage, no
///   per-step allocation; `f32` or `f64`;
/// * the differentiable path, [`pbdl_core::stepper::Stepper::step`] on a velocity tensor
///   `[batch, 2, ny, nx]`: candle ops and [`pbdl_core::fft`] (whose backward is the FFT's
///   adjoint), so gradients reach the initial velocity and any network in the loop.
///
/// ```
/// use pbdl_grid::spectral::{SpectralConfig, SpectralNavierStokes};
/// use pbdl_grid::Grid;
/// let grid = Grid::square(32, 2.0 * std::f64::consts::PI)?;
/// let ns = SpectralNavierStokes::new(grid, SpectralConfig { nu: 0.01, dt: 0.05, scheme: Default::default(), drag: 0.0 })?;
/// // Taylor-Green: u = sin x cos y, v = -cos x sin y on the cell centres, f64.
/// let tg = |t: f64| ns.sample_velocity(candle_core::DType::F64, |x, y| {
///     let d = (-2.0 * 0.01 * t).exp();
///     [x.sin() * y.cos() * d, -x.cos() * y.sin() * d]
/// });
/// let mut state = ns.state_from_velocity(&tg(0.0)?)?;
/// ns.advance(&mut state, 20)?; // t = 1
/// let err = (ns.velocity(&state)? - tg(1.0)?)?.abs()?.max_all()?.to_scalar::<f64>()?;
/// assert!(err < 1e-9); // the time error of Crank-Nicolson on the decay; no spatial error
/// assert!(ns.operators().contains(&"time_stepping.imex_cn_rk4"));
/// # Ok::<(), pbdl_grid::Error>(())
/// ```
pub struct SpectralNavierStokes {
    grid: Grid,
    config: SpectralConfig,
    forcing: Option<KolmogorovForcing>,
    e32: OnceLock<Engine2d<f32>>,
    e64: OnceLock<Engine2d<f64>>,
}

impl std::fmt::Debug for SpectralNavierStokes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpectralNavierStokes")
            .field("grid", &self.grid)
            .field("config", &self.config)
            .field("forcing", &self.forcing)
            .finish()
    }
}

/// Runs `$body` with `$e` the engine and `$w` the spectrum of the state's precision.
macro_rules! dispatch {
    ($self:ident, $spectrum:expr, |$e:ident, $w:ident| $body:expr) => {
        match $spectrum {
            Spectrum::F32($w) => {
                let $e = $self.engine::<f32>();
                $body
            }
            Spectrum::F64($w) => {
                let $e = $self.engine::<f64>();
                $body
            }
        }
    };
}

/// Picks the engine of a float type.
trait EngineOf: SpectralFloat
where
    Complex<Self>: Pod,
{
    fn engine_of(ns: &SpectralNavierStokes) -> &Engine2d<Self>;
}

impl EngineOf for f32 {
    fn engine_of(ns: &SpectralNavierStokes) -> &Engine2d<f32> {
        ns.e32.get_or_init(|| ns.build_engine())
    }
}

impl EngineOf for f64 {
    fn engine_of(ns: &SpectralNavierStokes) -> &Engine2d<f64> {
        ns.e64.get_or_init(|| ns.build_engine())
    }
}

impl SpectralNavierStokes {
    /// A stepper on `grid` (periodic in both directions). Errors on a negative or non-finite
    /// viscosity or drag, or a non-positive time step.
    pub fn new(grid: Grid, config: SpectralConfig) -> Result<Self> {
        grid.validate()?;
        let bad = |field: &'static str, reason: String| Err(Error::Invalid { field, reason });
        if !(config.nu >= 0.0 && config.nu.is_finite()) {
            return bad("nu", format!("must be finite and >= 0, got {}", config.nu));
        }
        if !(config.drag >= 0.0 && config.drag.is_finite()) {
            return bad("drag", format!("must be finite and >= 0, got {}", config.drag));
        }
        if !(config.dt > 0.0 && config.dt.is_finite()) {
            return bad("dt", format!("must be positive and finite, got {}", config.dt));
        }
        Ok(Self { grid, config, forcing: None, e32: OnceLock::new(), e64: OnceLock::new() })
    }

    /// The same stepper with a Kolmogorov body force.
    pub fn with_forcing(mut self, forcing: KolmogorovForcing) -> Result<Self> {
        if !forcing.amplitude.is_finite() {
            return Err(Error::Invalid { field: "forcing.amplitude", reason: "must be finite".into() });
        }
        if forcing.wavenumber == 0 {
            return Err(Error::Invalid { field: "forcing.wavenumber", reason: "must be >= 1".into() });
        }
        self.forcing = Some(forcing);
        self.e32 = OnceLock::new();
        self.e64 = OnceLock::new();
        Ok(self)
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The configuration.
    pub fn config(&self) -> &SpectralConfig {
        &self.config
    }

    /// The forcing, if any.
    pub fn forcing(&self) -> Option<KolmogorovForcing> {
        self.forcing
    }

    /// The operators of one step, in order.
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = vec!["spectral.fft", "spectral.advection_dealiased_2/3"];
        if self.config.nu > 0.0 {
            ops.push("spectral.viscosity_implicit");
        }
        if self.forcing.is_some() {
            ops.push("forcing.kolmogorov");
        }
        if self.config.drag > 0.0 {
            ops.push("forcing.linear_drag");
        }
        ops.push(self.config.scheme.operator());
        ops
    }

    /// The largest stable time step for advection speeds `(sx, sy)`: the scheme's stability
    /// limit on the imaginary axis over the largest retained `k_x sx + k_y sy`. Infinite for a
    /// fluid at rest.
    pub fn stable_time_step(grid: &Grid, scheme: ImexScheme, speed: [f64; 2]) -> f64 {
        let kx = 2.0 * PI * dealias_cutoff(grid.nx) as f64 / grid.lx;
        let ky = 2.0 * PI * dealias_cutoff(grid.ny) as f64 / grid.ly;
        let rate = kx * speed[0].abs() + ky * speed[1].abs();
        if rate > 0.0 {
            scheme.imaginary_axis_limit() / rate
        } else {
            f64::INFINITY
        }
    }

    fn build_engine<F: SpectralFloat>(&self) -> Engine2d<F>
    where
        Complex<F>: Pod,
    {
        let g = &self.grid;
        let spec = EngineSpec {
            nx: g.nx,
            ny: g.ny,
            lx: g.lx,
            ly: g.ly,
            nu: self.config.nu,
            drag: self.config.drag,
            dt: self.config.dt,
            scheme: self.config.scheme,
        };
        let mut e = Engine2d::<F>::new(&spec);
        if let Some(f) = self.forcing {
            // curl f = -d f_x / dy = -a (2 pi k / ly) cos(2 pi k y / ly), on the cell centres.
            let kk = 2.0 * PI * f.wavenumber as f64 / g.ly;
            let mut field = vec![F::zero(); g.cells()];
            for j in 0..g.ny {
                let y = (j as f64 + 0.5) * g.dy();
                let val = F::c(-f.amplitude * kk * (kk * y).cos());
                field[j * g.nx..(j + 1) * g.nx].fill(val);
            }
            e.set_forcing(&field);
        }
        e
    }

    fn engine<F: EngineOf>(&self) -> &Engine2d<F>
    where
        Complex<F>: Pod,
    {
        F::engine_of(self)
    }

    /// A velocity `[1, 2, ny, nx]` sampled from `f(x, y) -> [u, v]` at the cell centres
    /// `((i + 1/2) dx, (j + 1/2) dy)`.
    pub fn sample_velocity(&self, dtype: DType, f: impl Fn(f64, f64) -> [f64; 2]) -> Result<Tensor> {
        let g = &self.grid;
        let n = g.cells();
        let mut data = vec![0.0; 2 * n];
        for j in 0..g.ny {
            for i in 0..g.nx {
                let [u, v] = f((i as f64 + 0.5) * g.dx(), (j as f64 + 0.5) * g.dy());
                data[j * g.nx + i] = u;
                data[n + j * g.nx + i] = v;
            }
        }
        Ok(Tensor::from_vec(data, (1, 2, g.ny, g.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }

    /// The state of a cell-centred velocity `[2, ny, nx]` or `[1, 2, ny, nx]` (f32 or f64; the
    /// state keeps that precision). Only the divergence-free part and the mean are kept: the
    /// vorticity form drops the rest, i.e. the velocity is projected.
    pub fn state_from_velocity(&self, velocity: &Tensor) -> Result<SpectralState> {
        let g = self.grid;
        let t = match velocity.rank() {
            3 => velocity.unsqueeze(0)?,
            _ => velocity.clone(),
        };
        if t.dims() != [1, 2, g.ny, g.nx] {
            return Err(Error::Shape {
                op: "SpectralNavierStokes::state_from_velocity",
                arg: "velocity",
                expected: format!("[2, {}, {}] or [1, 2, {}, {}] on the cell centres", g.ny, g.nx, g.ny, g.nx),
                got: velocity.dims().to_vec(),
            });
        }
        let max = t.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        if !max.is_finite() {
            return Err(Error::NonFinite { what: "initial velocity", value: max });
        }
        match t.dtype() {
            DType::F32 => Ok(self.state_from_components::<f32>(&t.flatten_all()?.to_vec1::<f32>()?)),
            DType::F64 => Ok(self.state_from_components::<f64>(&t.flatten_all()?.to_vec1::<f64>()?)),
            other => Err(Error::Invalid {
                field: "velocity",
                reason: format!("dtype {other:?}: the spectral solver runs in f32 or f64"),
            }),
        }
    }

    fn state_from_components<F: EngineOf>(&self, uv: &[F]) -> SpectralState
    where
        Complex<F>: Pod,
        Vec<Complex<F>>: IntoSpectrum,
    {
        let e = self.engine::<F>();
        let n = self.grid.cells();
        let (uh, vh) = (e.forward(&uv[..n]), e.forward(&uv[n..]));
        let du = e.derivatives(&uh).1;
        let dv = e.derivatives(&vh).0;
        // omega = dv/dx - du/dy.
        let w: Vec<Complex<F>> = dv.iter().zip(&du).map(|(a, b)| *a - *b).collect();
        let mean = [uh[0].re.wide() / n as f64, vh[0].re.wide() / n as f64];
        let speed = max_speed(uv, n);
        SpectralState { spectrum: w.into_spectrum(), mean, speed }
    }

    /// The state of a vorticity `[ny, nx]` (any leading axes of size 1) and a mean velocity.
    pub fn state_from_vorticity(&self, vorticity: &Tensor, mean: [f64; 2]) -> Result<SpectralState> {
        let g = self.grid;
        if vorticity.elem_count() != g.cells() || vorticity.dims().iter().rev().take(2).ne([g.nx, g.ny].iter()) {
            return Err(Error::Shape {
                op: "SpectralNavierStokes::state_from_vorticity",
                arg: "vorticity",
                expected: format!("[{}, {}]", g.ny, g.nx),
                got: vorticity.dims().to_vec(),
            });
        }
        let spectrum = match vorticity.dtype() {
            DType::F32 => Spectrum::F32(self.engine::<f32>().forward(&vorticity.flatten_all()?.to_vec1::<f32>()?)),
            DType::F64 => Spectrum::F64(self.engine::<f64>().forward(&vorticity.flatten_all()?.to_vec1::<f64>()?)),
            other => {
                return Err(Error::Invalid {
                    field: "vorticity",
                    reason: format!("dtype {other:?}: the spectral solver runs in f32 or f64"),
                })
            }
        };
        let mut s = SpectralState { spectrum, mean, speed: [0.0; 2] };
        let v = self.velocity(&s)?;
        s.speed = speed_of_tensor(&v)?;
        Ok(s)
    }

    /// `steps` time steps of the fast path. Errors (typed) when the velocity stops being finite.
    pub fn advance(&self, state: &mut SpectralState, steps: usize) -> Result<()> {
        let decay = (-self.config.drag * self.config.dt).exp();
        for _ in 0..steps {
            let mean = state.mean;
            let speed = dispatch!(self, &mut state.spectrum, |e, w| {
                let s = e.step(w, [to_f(mean[0]), to_f(mean[1])]);
                [s[0].wide(), s[1].wide()]
            });
            state.speed = speed;
            state.mean = [mean[0] * decay, mean[1] * decay];
            if !(speed[0].is_finite() && speed[1].is_finite()) {
                return Err(Error::NonFinite { what: "velocity", value: speed[0].max(speed[1]) });
            }
        }
        Ok(())
    }

    /// Checks the state: finite, and the time step stable for its speed (typed
    /// [`Error::Unstable`] naming the step to use).
    pub fn check(&self, state: &SpectralState) -> Result<()> {
        let v = self.velocity(state)?;
        let speed = speed_of_tensor(&v)?;
        if !(speed[0].is_finite() && speed[1].is_finite()) {
            return Err(Error::NonFinite { what: "velocity", value: speed[0].max(speed[1]) });
        }
        let stable = Self::stable_time_step(&self.grid, self.config.scheme, speed);
        if self.config.dt > stable {
            return Err(Error::Unstable {
                what: "advective rate dt (k_x |u| + k_y |v|)",
                value: self.config.dt * self.config.scheme.imaginary_axis_limit() / stable,
                limit: self.config.scheme.imaginary_axis_limit(),
                scheme: format!("{:?}", self.config.scheme),
                dt: self.config.dt,
                stable_dt: stable,
            });
        }
        Ok(())
    }

    /// The velocity on the cell centres, `[1, 2, ny, nx]` in the state's precision.
    pub fn velocity(&self, state: &SpectralState) -> Result<Tensor> {
        self.velocity_shifted(state, [0.0, 0.0], [0.0, 0.0])
    }

    /// `u` shifted by `su` and `v` by `sv` (fractions of a cell), `[1, 2, ny, nx]`.
    fn velocity_shifted(&self, state: &SpectralState, su: [f64; 2], sv: [f64; 2]) -> Result<Tensor> {
        let g = self.grid;
        let (dx, dy, mean) = (g.dx(), g.dy(), state.mean);
        let shape = (1, 2, g.ny, g.nx);
        dispatch!(self, &state.spectrum, |e, w| {
            let (uh, vh) = e.velocity_spectra(w);
            let mut u = e.inverse(&e.shift(&uh, su[0] * dx, su[1] * dy));
            let v = e.inverse(&e.shift(&vh, sv[0] * dx, sv[1] * dy));
            add_mean(&mut u, mean[0]);
            let start = u.len();
            u.extend(v);
            add_mean(&mut u[start..], mean[1]);
            Ok(Tensor::from_vec(u, shape, &Device::Cpu)?)
        })
    }

    /// The velocity interpolated spectrally to the faces of a MAC grid (`u` at
    /// `((i+1) dx, (j+1/2) dy)`, `v` at `((i+1/2) dx, (j+1) dy)`), periodic boundaries: the
    /// form [`crate::NavierStokes`] and the scene tools read.
    pub fn velocity_mac(&self, state: &SpectralState) -> Result<MacField> {
        let t = self.velocity_shifted(state, [0.5, 0.0], [0.0, 0.5])?;
        MacField::new(t, self.grid, Boundaries::periodic())
    }

    /// The cell-centred velocity `[1, 2, ny, nx]` of a periodic MAC velocity, interpolated
    /// spectrally (the inverse of [`SpectralNavierStokes::velocity_mac`]).
    pub fn centres_from_mac(&self, mac: &MacField) -> Result<Tensor> {
        let g = self.grid;
        let t = mac.values().narrow(0, 0, 1)?;
        let (dx, dy, n) = (g.dx(), g.dy(), g.cells());
        let shape = (1, 2, g.ny, g.nx);
        macro_rules! go {
            ($f:ty) => {{
                let e = self.engine::<$f>();
                let vals = t.flatten_all()?.to_vec1::<$f>()?;
                let mut u = e.inverse(&e.shift(&e.forward(&vals[..n]), -0.5 * dx, 0.0));
                u.extend(e.inverse(&e.shift(&e.forward(&vals[n..]), 0.0, -0.5 * dy)));
                Tensor::from_vec(u, shape, &Device::Cpu)?
            }};
        }
        Ok(match t.dtype() {
            DType::F32 => go!(f32),
            _ => go!(f64).to_dtype(t.dtype())?,
        })
    }

    /// The vorticity `dv/dx - du/dy` on the cell centres, `[1, 1, ny, nx]`.
    pub fn vorticity(&self, state: &SpectralState) -> Result<Tensor> {
        let g = self.grid;
        dispatch!(self, &state.spectrum, |e, w| Ok(Tensor::from_vec(e.inverse(w), (1, 1, g.ny, g.nx), &Device::Cpu)?))
    }

    /// The explicit terms of the vorticity equation, dealiased advection `-(u . grad) omega`
    /// plus the curl of the forcing, on the cell centres `[1, 1, ny, nx]`. With no forcing its
    /// integrals against `omega` and against the stream function vanish up to round-off (the
    /// truncated system conserves enstrophy and energy).
    pub fn explicit_terms(&self, state: &SpectralState) -> Result<Tensor> {
        let g = self.grid;
        let mean = state.mean;
        dispatch!(self, &state.spectrum, |e, w| {
            let n = e.explicit_terms(w, [to_f(mean[0]), to_f(mean[1])]);
            Ok(Tensor::from_vec(e.inverse(&n), (1, 1, g.ny, g.nx), &Device::Cpu)?)
        })
    }

    /// The stream function `psi` (`lap psi = -omega`, zero mean) on the cell centres,
    /// `[1, 1, ny, nx]`.
    pub fn stream_function(&self, state: &SpectralState) -> Result<Tensor> {
        let g = self.grid;
        dispatch!(self, &state.spectrum, |e, w| {
            let psi = e.stream_spectrum(w);
            Ok(Tensor::from_vec(e.inverse(&psi), (1, 1, g.ny, g.nx), &Device::Cpu)?)
        })
    }

    /// Kinetic energy per unit area `1/2 <|u|^2>` (mean over the box), in f64.
    pub fn energy(&self, state: &SpectralState) -> Result<f64> {
        let v = self.velocity(state)?.to_dtype(DType::F64)?;
        Ok(0.5 * v.sqr()?.sum_all()?.to_scalar::<f64>()? / self.grid.cells() as f64)
    }

    /// Enstrophy per unit area `1/2 <omega^2>`, in f64.
    pub fn enstrophy(&self, state: &SpectralState) -> Result<f64> {
        let w = self.vorticity(state)?.to_dtype(DType::F64)?;
        Ok(0.5 * w.sqr()?.sum_all()?.to_scalar::<f64>()? / self.grid.cells() as f64)
    }
}

/// Converts a spectrum of either precision into the state's enum.
trait IntoSpectrum {
    fn into_spectrum(self) -> Spectrum;
}
impl IntoSpectrum for Vec<Complex<f32>> {
    fn into_spectrum(self) -> Spectrum {
        Spectrum::F32(self)
    }
}
impl IntoSpectrum for Vec<Complex<f64>> {
    fn into_spectrum(self) -> Spectrum {
        Spectrum::F64(self)
    }
}

fn to_f<F: SpectralFloat>(v: f64) -> F {
    F::c(v)
}

/// Adds a mean value to every entry.
fn add_mean<F: SpectralFloat>(v: &mut [F], mean: f64) {
    let m = F::c(mean);
    v.iter_mut().for_each(|x| *x += m);
}

/// `max |u|, max |v|` of stacked components `[u..., v...]`.
fn max_speed<F: SpectralFloat>(uv: &[F], n: usize) -> [f64; 2] {
    let m = |s: &[F]| s.iter().fold(0.0f64, |a, x| a.max(x.wide().abs()));
    [m(&uv[..n]), m(&uv[n..])]
}

/// `max |u|, max |v|` of a velocity tensor `[B, 2, ny, nx]`.
pub(crate) fn speed_of_tensor(v: &Tensor) -> Result<[f64; 2]> {
    let m = |c: usize| -> Result<f64> {
        Ok(v.narrow(1, c, 1)?.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?)
    };
    Ok([m(0)?, m(1)?])
}
