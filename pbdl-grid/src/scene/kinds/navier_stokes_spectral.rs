//! Pseudo-spectral Navier-Stokes (`navier_stokes_spectral`) via [`SpectralNavierStokes`]: the
//! velocity lives on the cell centres; the scene's MAC state is its spectral interpolation to the
//! faces.

use super::{c, FieldInput, PhysicsKind, Setup};
use crate::grid3d::Grid3d;
use crate::scene::{Forcing, SceneResult, State};
use crate::spectral::{
    ImexScheme, KolmogorovForcing, SpectralConfig, SpectralNavierStokes, SpectralNavierStokes3d, SpectralState,
    SpectralState3d,
};
use crate::time_stepping::Scheme;
use candle_core::{Device, Tensor};

/// The stepper and its state.
pub(super) struct SpectralKind {
    ns: SpectralNavierStokes,
    state: SpectralState,
}

impl SpectralKind {
    /// Builds the stepper from the scene (boundaries are periodic: validation refused others).
    pub fn build(setup: &Setup<'_>, nu: f64, forcing: Option<&Forcing>) -> SceneResult<(Self, f64)> {
        let grid = setup.grid2d()?;
        let scheme = imex_scheme(setup)?;
        let g = setup.scene.grid;
        let f = setup.scene.init.velocity(g.lx, g.ly);
        let (x0, y0) = (g.origin[0], g.origin[1]);
        // The initial velocity on the cell centres, the points of the spectral solution.
        let probe = SpectralNavierStokes::new(grid, SpectralConfig { nu, dt: 1.0, scheme, drag: 0.0 })?;
        let u0 = probe.sample_velocity(setup.dtype, |x, y| f(x + x0, y + y0))?;
        let speed = super::max_abs(&u0)?;
        let s = setup.scene.time.speed.unwrap_or(speed);
        let dt = setup.pick_dt(speed, SpectralNavierStokes::stable_time_step(&grid, scheme, [s, s]))?;
        let mut ns = SpectralNavierStokes::new(grid, SpectralConfig { nu, dt, scheme, drag: 0.0 })?;
        if let Some(Forcing::Kolmogorov { amplitude, wavenumber, drag }) = forcing.copied() {
            ns = SpectralNavierStokes::new(grid, SpectralConfig { nu, dt, scheme, drag })?
                .with_forcing(KolmogorovForcing { amplitude, wavenumber })?;
        }
        let state = ns.state_from_velocity(&u0)?;
        Ok((Self { ns, state }, dt))
    }
}

impl PhysicsKind for SpectralKind {
    /// The velocity interpolated spectrally to the faces (computed when asked for).
    fn state(&self) -> State {
        match self.ns.velocity_mac(&self.state) {
            Ok(u) => State::Velocity(u),
            // Only a non-finite state can fail here; step and check report it as an error.
            Err(_) => State::Scalar(Tensor::zeros((1, 1, 1, 1), self.state.dtype(), &Device::Cpu).expect("1 element")),
        }
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        // The planned step may be the scene's last rounding of dt; rebuild the stepper if so.
        if (dt - self.ns.config().dt).abs() > 1e-15 * dt {
            let cfg = SpectralConfig { dt, ..*self.ns.config() };
            let mut ns = SpectralNavierStokes::new(*self.ns.grid(), cfg)?;
            if let Some(f) = self.ns.forcing() {
                ns = ns.with_forcing(f)?;
            }
            self.ns = ns;
        }
        self.ns.advance(&mut self.state, 1)?;
        Ok(())
    }

    /// Finite and the step stable for the velocity ([`SpectralNavierStokes::check`]).
    fn check(&self, _dt: f64) -> SceneResult<()> {
        self.ns.check(&self.state)?;
        Ok(())
    }

    /// `velocity` and `vorticity` on the cell centres (the spectral solution at its points) and
    /// `velocity_mac` (interpolated spectrally to the faces, so a frame can start a
    /// `navier_stokes` scene).
    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        let sq = |t: Tensor| c(t.squeeze(0));
        let mac = self.ns.velocity_mac(&self.state)?;
        Ok(vec![
            ("velocity".into(), sq(self.ns.velocity(&self.state)?)?),
            ("velocity_mac".into(), sq(mac.values().clone())?),
            ("vorticity".into(), sq(self.ns.vorticity(&self.state)?)?),
        ])
    }

    /// Takes `velocity` on the cell centres (resampled bilinearly when its size differs), or
    /// else `velocity_mac` of the grid's size (interpolated spectrally to the centres).
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let dtype = input.dtype;
        if let Some(t) = input.find("velocity") {
            let u = c(input.to4("velocity", &t, 2)?.to_dtype(dtype))?;
            self.state = self.ns.state_from_velocity(&u)?;
            return Ok(vec!["velocity".into()]);
        }
        let (ny, nx) = input.shape;
        if let Some(t) = input.find("velocity_mac") {
            let u = input.to4("velocity_mac", &t, 2)?;
            if u.dims() == [1, 2, ny, nx] {
                let mac = crate::MacField::new(c(u.to_dtype(dtype))?, *self.ns.grid(), crate::Boundaries::periodic())?;
                let centred = self.ns.centres_from_mac(&mac)?;
                self.state = self.ns.state_from_velocity(&centred)?;
                return Ok(vec!["velocity_mac".into()]);
            }
        }
        Err(input.invalid(
            "velocity",
            format!(
                "the file has no array `velocity` ([2, Y, X] on cell centres) or `velocity_mac` of the grid's size [2, {ny}, {nx}]; it has {:?}",
                input.names()
            ),
        ))
    }

    fn operators(&self) -> Vec<&'static str> {
        self.ns.operators()
    }
}

/// The IMEX scheme of `time.scheme`.
fn imex_scheme(setup: &Setup<'_>) -> SceneResult<ImexScheme> {
    match setup.scene.time.scheme {
        Scheme::Rk4 => Ok(ImexScheme::CnRk4),
        Scheme::SspRk3 => Ok(ImexScheme::CnRk3),
        Scheme::ForwardEuler => Err(setup.invalid(
            "time.scheme",
            "forward_euler is unstable for spectral advection at every step size; use rk4 or ssp_rk3".into(),
        )),
    }
}

/// The 3D form (`grid.nz > 1`): [`SpectralNavierStokes3d`] and its state.
pub(super) struct SpectralKind3d {
    ns: SpectralNavierStokes3d,
    state: SpectralState3d,
}

impl SpectralKind3d {
    /// Builds the 3D stepper (no forcing in 3D: a typed error names the key).
    pub fn build(setup: &Setup<'_>, nu: f64, forcing: Option<&Forcing>) -> SceneResult<(Self, f64)> {
        if forcing.is_some() {
            return Err(setup
                .invalid("physics.forcing", "3D spectral scenes take no forcing yet; remove it or use nz = 1".into()));
        }
        let g = setup.scene.grid;
        let grid = Grid3d::new(g.nx, g.ny, g.nz, g.lx, g.ly, g.lz)?;
        let scheme = imex_scheme(setup)?;
        let f = setup.scene.init.velocity3d([g.lx, g.ly, g.lz]);
        let (x0, y0) = (g.origin[0], g.origin[1]);
        let probe = SpectralNavierStokes3d::new(grid, SpectralConfig { nu, dt: 1.0, scheme, drag: 0.0 })?;
        let u0 = probe.sample_velocity(setup.dtype, |x, y, z| f(x + x0, y + y0, z))?;
        let speed = super::max_abs(&u0)?;
        let s = setup.scene.time.speed.unwrap_or(speed);
        let dt = setup.pick_dt(speed, SpectralNavierStokes3d::stable_time_step(&grid, scheme, [s, s, s]))?;
        let ns = SpectralNavierStokes3d::new(grid, SpectralConfig { nu, dt, scheme, drag: 0.0 })?;
        let state = ns.state_from_velocity(&u0)?;
        Ok((Self { ns, state }, dt))
    }
}

impl PhysicsKind for SpectralKind3d {
    fn state(&self) -> State {
        match self.ns.velocity(&self.state) {
            Ok(u) => State::Velocity3d(u),
            Err(_) => State::Scalar(Tensor::zeros((1, 1, 1, 1), self.state.dtype(), &Device::Cpu).expect("1 element")),
        }
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        if (dt - self.ns.config().dt).abs() > 1e-15 * dt {
            self.ns = SpectralNavierStokes3d::new(*self.ns.grid(), SpectralConfig { dt, ..*self.ns.config() })?;
        }
        self.ns.advance(&mut self.state, 1)?;
        Ok(())
    }

    fn check(&self, _dt: f64) -> SceneResult<()> {
        self.ns.check(&self.state)?;
        Ok(())
    }

    /// `velocity` and `vorticity`, each `[3, nz, ny, nx]` on the cell centres.
    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        let sq = |t: Tensor| c(t.squeeze(0));
        Ok(vec![
            ("velocity".into(), sq(self.ns.velocity(&self.state)?)?),
            ("vorticity".into(), sq(self.ns.vorticity(&self.state)?)?),
        ])
    }

    /// Takes `velocity` `[3, Z, Y, X]`, `[1, 3, Z, Y, X]` or the last frame of `[T, 3, Z, Y, X]`,
    /// of the grid's size (3D fields are not resampled).
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let g = *self.ns.grid();
        let Some(t) = input.find("velocity") else {
            return Err(
                input.invalid("velocity", format!("the file has no array `velocity`; it has {:?}", input.names()))
            );
        };
        let t = match t.rank() {
            4 => c(t.unsqueeze(0))?,
            5 if t.dims()[0] >= 1 => c(t.narrow(0, t.dims()[0] - 1, 1))?,
            _ => t,
        };
        if t.dims() != [1, 3, g.nz, g.ny, g.nx] {
            return Err(input.invalid(
                "velocity",
                format!(
                    "expected [3, {}, {}, {}] (or a trajectory of it) for this 3D grid, got {:?}",
                    g.nz,
                    g.ny,
                    g.nx,
                    t.dims()
                ),
            ));
        }
        self.state = self.ns.state_from_velocity(&c(t.to_dtype(input.dtype))?)?;
        Ok(vec!["velocity".into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.ns.operators()
    }
}
