//! The 3D buoyant smoke plume (`smoke` with `grid.nz > 1`) via [`Smoke3d`]: per-face walls
//! (`physics.boundaries` for x and y, `physics.boundaries_z` for z: `no_slip` (default),
//! `free_slip`, `periodic`, `outflow` on upper faces), obstacles (the top-level 2D `obstacles`
//! extruded through the depth, `physics.obstacles3d` spheres and boxes), a density sphere,
//! Boussinesq buoyancy along `+y`. `density_advection = "conservative"` moves the density with the 3D flux-corrected
//! transport ([`crate::grid3d::conservative`]): its mass is what the source injected.

use super::{c, FieldInput, PhysicsKind, Setup};
use crate::fluid::Advection;
use crate::grid3d::smoke::{
    InflowFace3d, InflowPatch3d, Obstacle3d, PatchShape3d, Smoke3d, Smoke3dBoundaries, Smoke3dConfig, Smoke3dState,
    SphereSource,
};
use crate::grid3d::{Advection3d, BoxPressure, Face3d, Grid3d, MacField3d, Walls3d};
use crate::scene::{BoundariesZ, Obstacle, SceneResult, Source, State};
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

/// The scene keys of a 3D smoke plume.
pub(super) struct Smoke3dKeys<'a> {
    pub nu: f64,
    pub buoyancy: f64,
    pub boundaries: &'a Boundaries,
    pub boundaries_z: Option<&'a BoundariesZ>,
    pub obstacles3d: &'a [Obstacle3d],
    pub inflow_patch: Option<&'a InflowPatch3d>,
    pub source: &'a Source,
    pub advection: Advection,
    pub density_advection: Option<Advection>,
}

/// The 3D face of a scene's `Bc` (the key names it in the error).
fn face3d(setup: &Setup<'_>, key: &str, b: Bc) -> SceneResult<Face3d> {
    match b {
        Bc::NoSlip => Ok(Face3d::NoSlip),
        Bc::FreeSlip => Ok(Face3d::FreeSlip),
        Bc::Periodic => Ok(Face3d::Periodic),
        Bc::Outflow => Ok(Face3d::Outflow),
        other => Err(setup.invalid(
            key,
            format!(
                "{other:?} has no 3D form yet; 3D smoke faces take no_slip, free_slip, periodic (in pairs) or \
                 outflow (upper faces)"
            ),
        )),
    }
}

impl Smoke3dKind {
    /// Builds the 3D plume: faces from `physics.boundaries` (x, y) and `physics.boundaries_z`,
    /// obstacles from the top-level `obstacles` (2D shapes extruded through the depth) and
    /// `physics.obstacles3d`, in scene coordinates (the grid's origin shifts x and y).
    pub fn build(setup: &Setup<'_>, keys: Smoke3dKeys<'_>) -> SceneResult<(Self, f64)> {
        let b = keys.boundaries;
        let z = keys.boundaries_z.copied().unwrap_or(BoundariesZ { z_lo: Bc::NoSlip, z_hi: Bc::NoSlip });
        let walls = Walls3d {
            x_lo: face3d(setup, "physics.boundaries.x_lo", b.x_lo)?,
            x_hi: face3d(setup, "physics.boundaries.x_hi", b.x_hi)?,
            y_lo: face3d(setup, "physics.boundaries.y_lo", b.y_lo)?,
            y_hi: face3d(setup, "physics.boundaries.y_hi", b.y_hi)?,
            z_lo: face3d(setup, "physics.boundaries_z.z_lo", z.z_lo)?,
            z_hi: face3d(setup, "physics.boundaries_z.z_hi", z.z_hi)?,
        };
        let g = setup.scene.grid;
        let [x0, y0] = g.origin;
        let mut obstacles: Vec<Obstacle3d> = setup
            .scene
            .obstacles
            .iter()
            .map(|o| match *o {
                Obstacle::Circle { center, radius } => {
                    Obstacle3d::Cylinder { center: [center[0] - x0, center[1] - y0], radius }
                }
                Obstacle::Box { lower, upper } => Obstacle3d::Box {
                    lower: [lower[0] - x0, lower[1] - y0, 0.0],
                    upper: [upper[0] - x0, upper[1] - y0, g.lz],
                },
            })
            .collect();
        let n2d = obstacles.len();
        obstacles.extend(keys.obstacles3d.iter().map(|o| match *o {
            Obstacle3d::Sphere { center, radius } => {
                Obstacle3d::Sphere { center: [center[0] - x0, center[1] - y0, center[2]], radius }
            }
            Obstacle3d::Box { lower, upper } => Obstacle3d::Box {
                lower: [lower[0] - x0, lower[1] - y0, lower[2]],
                upper: [upper[0] - x0, upper[1] - y0, upper[2]],
            },
            Obstacle3d::Cylinder { center, radius } => {
                Obstacle3d::Cylinder { center: [center[0] - x0, center[1] - y0], radius }
            }
        }));
        let grid = Grid3d::new(g.nx, g.ny, g.nz, g.lx, g.ly, g.lz)?;
        let source = keys.source;
        let centre = [source.center[0] - x0, source.center[1] - y0, source.z.unwrap_or(0.5 * g.lz)];
        let advection = advection3d(setup, "physics.advection", keys.advection, false)?;
        let density_advection = match keys.density_advection {
            None => advection,
            Some(a) => advection3d(setup, "physics.density_advection", a, true)?,
        };
        // Nothing moves at rest: the step comes from `time.speed` (or `time.dt`).
        let dt = setup.pick_dt(0.0, f64::INFINITY)?;
        let config = Smoke3dConfig {
            dt,
            nu: keys.nu,
            viscosity: Default::default(),
            advection,
            density_advection,
            buoyancy: keys.buoyancy,
            source: Some(SphereSource { centre, radius: source.radius, rate: source.rate }),
        };
        // The patch's coordinates are the face's two other axes; x and y shift by the origin.
        let inflow = keys.inflow_patch.map(|p| {
            let shift = match p.face {
                InflowFace3d::XLo => [y0, 0.0],
                InflowFace3d::YLo => [x0, 0.0],
                InflowFace3d::ZLo => [x0, y0],
            };
            let shape = match p.shape {
                PatchShape3d::Disc { center, radius } => {
                    PatchShape3d::Disc { center: [center[0] - shift[0], center[1] - shift[1]], radius }
                }
                PatchShape3d::Rect { lower, upper } => PatchShape3d::Rect {
                    lower: [lower[0] - shift[0], lower[1] - shift[1]],
                    upper: [upper[0] - shift[0], upper[1] - shift[1]],
                },
            };
            InflowPatch3d { shape, ..*p }
        });
        let boundaries = Smoke3dBoundaries { walls, obstacles, inflow };
        let smoke = Smoke3d::with_boundaries(grid, config, boundaries, BoxPressure::default())
            .map_err(|e| scene_error(setup, e, n2d))?;
        let state = smoke.rest(1, setup.dtype)?;
        Ok((Self { smoke, state }, dt))
    }
}

/// A stepper's typed error as a scene error naming the key: a face error names
/// `physics.boundaries.<face>` (or `physics.boundaries_z.<face>`), an obstacle error `obstacles`
/// or `physics.obstacles3d` (by the index in the combined list: the first `n2d` are the
/// top-level ones), `pressure` the grid size, anything else `physics`.
fn scene_error(setup: &Setup<'_>, e: crate::Error, n2d: usize) -> crate::scene::SceneError {
    match e {
        crate::Error::Boundary { face, reason } => {
            let key = if face.starts_with('z') { "physics.boundaries_z" } else { "physics.boundaries" };
            setup.invalid(&format!("{key}.{face}"), reason)
        }
        crate::Error::Invalid { field: "obstacles", reason } => {
            // The reason starts with `obstacles[k]` when it is about one obstacle.
            let k = reason
                .strip_prefix("obstacles[")
                .and_then(|r| r.split(']').next())
                .and_then(|k| k.parse::<usize>().ok());
            match k {
                Some(k) if k >= n2d => setup.invalid(&format!("physics.obstacles3d[{}]", k - n2d), reason),
                Some(k) => setup.invalid(&format!("obstacles[{k}]"), reason),
                None => setup.invalid("obstacles", reason),
            }
        }
        crate::Error::Invalid { field: "pressure", reason } => setup.invalid("grid", reason),
        crate::Error::Invalid { field: "inflow", reason } => setup.invalid("physics.inflow_patch", reason),
        crate::Error::Invalid { field, reason } => setup.invalid(&format!("physics.{field}"), reason),
        other => other.into(),
    }
}

/// Cell-centred velocity `[3, nz, ny, nx]` of a walled MAC velocity (batch 0): the mean of the
/// two faces of each cell, the lower wall face being 0 (the wrapped last face on a periodic axis).
fn centred(u: &MacField3d, walls: &Walls3d) -> SceneResult<Tensor> {
    let v = c(u.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?;
    let mut comps = Vec::with_capacity(3);
    for (comp, axis) in [(0usize, 3usize), (1, 2), (2, 1)] {
        let f = c(v.narrow(0, comp, 1))?;
        // Shift by one face along the component's own axis, a zero (wall) face entering first.
        let n = f.dims()[axis];
        let first = if walls.periodic(comp) {
            c(f.narrow(axis, n - 1, 1))?
        } else {
            c(f.narrow(axis, 0, 1).and_then(|t| t.zeros_like()))?
        };
        let lower = c(Tensor::cat(&[&first, &c(f.narrow(axis, 0, n - 1))?], axis))?;
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
            let boundaries = self.smoke.boundaries().clone();
            self.smoke = Smoke3d::with_boundaries(*self.smoke.grid(), config, boundaries, BoxPressure::default())?;
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
            ("velocity".into(), centred(&self.state.velocity, &self.smoke.boundaries().walls)?),
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
