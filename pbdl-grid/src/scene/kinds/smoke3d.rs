//! The 3D buoyant smoke plume (`smoke` with `grid.nz > 1`) via [`Smoke3d`]: a closed box of
//! no-slip walls (the only 3D wall layout so far), a density sphere, Boussinesq buoyancy along
//! `+y`. `density_advection = "conservative"` moves the density with the 3D flux-corrected
//! transport ([`crate::grid3d::conservative`]): its mass is what the source injected.

use super::{c, FieldInput, PhysicsKind, Setup};
use crate::fluid::Advection;
use crate::grid3d::smoke::{Smoke3d, Smoke3dConfig, Smoke3dState, SphereSource};
use crate::grid3d::{Advection3d, BoxPressure, Grid3d, MacField3d};
use crate::scene::{SceneResult, Source, State};
use crate::{Bc, Boundaries};
use candle_core::Tensor;

/// The stepper and its state.
pub(super) struct Smoke3dKind {
    smoke: Smoke3d,
    state: Smoke3dState,
}

/// The 3D scheme of `a`; `conservative` only for the density.
fn advection3d(setup: &Setup<'_>, field: &str, a: Advection, density: bool) -> SceneResult<Advection3d> {
    match a {
        Advection::SemiLagrangian => Ok(Advection3d::SemiLagrangian),
        Advection::MacCormack => Ok(Advection3d::MacCormack),
        Advection::Conservative if density => Ok(Advection3d::Conservative),
        other => Err(setup.invalid(
            field,
            format!(
                "{other:?} has no 3D form yet; 3D smoke takes semi_lagrangian or mac_cormack{}",
                if density { " (or conservative for the density)" } else { "" }
            ),
        )),
    }
}

impl Smoke3dKind {
    /// Builds the 3D plume. Only the default closed box of no-slip walls is accepted.
    pub fn build(
        setup: &Setup<'_>,
        nu: f64,
        buoyancy: f64,
        boundaries: &Boundaries,
        source: &Source,
        advection: Advection,
        density_advection: Option<Advection>,
    ) -> SceneResult<(Self, f64)> {
        if boundaries.faces().iter().any(|(_, b)| *b != Bc::NoSlip) {
            return Err(setup.invalid(
                "physics.boundaries",
                "3D smoke runs in a closed box of no-slip walls only (inflow, outflow, free-slip and periodic faces have no 3D form yet); remove the key".into(),
            ));
        }
        if !setup.scene.obstacles.is_empty() {
            return Err(setup.invalid("obstacles", "3D smoke has no obstacles yet".into()));
        }
        let g = setup.scene.grid;
        let grid = Grid3d::new(g.nx, g.ny, g.nz, g.lx, g.ly, g.lz)?;
        let [x0, y0] = g.origin;
        let centre = [source.center[0] - x0, source.center[1] - y0, source.z.unwrap_or(0.5 * g.lz)];
        let advection = advection3d(setup, "physics.advection", advection, false)?;
        let density_advection = match density_advection {
            None => advection,
            Some(a) => advection3d(setup, "physics.density_advection", a, true)?,
        };
        // Nothing moves at rest: the step comes from `time.speed` (or `time.dt`).
        let dt = setup.pick_dt(0.0, f64::INFINITY)?;
        let config = Smoke3dConfig {
            dt,
            nu,
            viscosity: Default::default(),
            advection,
            density_advection,
            buoyancy,
            source: Some(SphereSource { centre, radius: source.radius, rate: source.rate }),
        };
        let smoke = Smoke3d::new(grid, config, BoxPressure::default())?;
        let state = smoke.rest(1, setup.dtype)?;
        Ok((Self { smoke, state }, dt))
    }
}

/// Cell-centred velocity `[3, nz, ny, nx]` of a walled MAC velocity (batch 0): the mean of the
/// two faces of each cell, the lower wall face being 0.
fn centred(u: &MacField3d) -> SceneResult<Tensor> {
    let v = c(u.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?;
    let mut comps = Vec::with_capacity(3);
    for (comp, axis) in [(0usize, 3usize), (1, 2), (2, 1)] {
        let f = c(v.narrow(0, comp, 1))?;
        // Shift by one face along the component's own axis, a zero (wall) face entering first.
        let n = f.dims()[axis];
        let zero = c(f.narrow(axis, 0, 1).and_then(|t| t.zeros_like()))?;
        let lower = c(Tensor::cat(&[&zero, &c(f.narrow(axis, 0, n - 1))?], axis))?;
        comps.push(c((&f + &lower).and_then(|t| t.affine(0.5, 0.0)))?);
    }
    c(Tensor::cat(&comps, 0))
}

impl PhysicsKind for Smoke3dKind {
    fn state(&self) -> State {
        State::Smoke3d(self.state.clone())
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        if (dt - self.smoke.config().dt).abs() > 1e-15 * dt {
            let config = Smoke3dConfig { dt, ..self.smoke.config().clone() };
            self.smoke = Smoke3d::new(*self.smoke.grid(), config, BoxPressure::default())?;
        }
        self.state = self.smoke.step(&self.state, None)?;
        Ok(())
    }

    /// Finite velocity and density.
    fn check(&self, _dt: f64) -> SceneResult<()> {
        for (what, t) in [("velocity", self.state.velocity.values()), ("density", &self.state.density)] {
            let m = super::max_abs(t)?;
            if !m.is_finite() {
                return Err(crate::Error::NonFinite { what, value: m }.into());
            }
        }
        Ok(())
    }

    /// `density` `[1, nz, ny, nx]`, `velocity` `[3, nz, ny, nx]` on the cell centres (face
    /// values averaged) and `velocity_mac` (as stored; the last face of each component along
    /// its axis is the wall).
    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        let sq = |t: &Tensor| c(t.narrow(0, 0, 1).and_then(|t| t.squeeze(0)));
        Ok(vec![
            ("density".into(), sq(&self.state.density)?),
            ("velocity".into(), centred(&self.state.velocity)?),
            ("velocity_mac".into(), sq(self.state.velocity.values())?),
        ])
    }

    /// Takes `density` (`[1, Z, Y, X]` or a trajectory) and/or `velocity_mac` (`[3, Z, Y, X]` or
    /// a trajectory) of the grid's size; what is not given is kept.
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let g = *self.smoke.grid();
        let last = |name: &str, channels: usize| -> SceneResult<Option<Tensor>> {
            let Some(t) = input.find(name) else { return Ok(None) };
            let t = match t.rank() {
                4 => c(t.unsqueeze(0))?,
                5 if t.dims()[0] >= 1 => c(t.narrow(0, t.dims()[0] - 1, 1))?,
                _ => t,
            };
            if t.dims() != [1, channels, g.nz, g.ny, g.nx] {
                return Err(input.invalid(
                    name,
                    format!(
                        "expected [{channels}, {}, {}, {}] (or a trajectory of it), got {:?}",
                        g.nz,
                        g.ny,
                        g.nx,
                        t.dims()
                    ),
                ));
            }
            Ok(Some(c(t.to_dtype(input.dtype))?))
        };
        let mut used = Vec::new();
        if let Some(rho) = last("density", 1)? {
            self.state.density = rho;
            used.push("density".to_string());
        }
        if let Some(u) = last("velocity_mac", 3)? {
            self.state.velocity = MacField3d::new(u, g)?;
            used.push("velocity_mac".to_string());
        }
        if used.is_empty() {
            return Err(input.invalid(
                "density",
                format!("the file has no array `density` or `velocity_mac` (3D); it has {:?}", input.names()),
            ));
        }
        Ok(used)
    }

    fn operators(&self) -> Vec<&'static str> {
        self.smoke.operators().to_vec()
    }
}
