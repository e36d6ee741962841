//! A scene built into a stepper and a state.

use super::{Forcing, Physics, Scene, SceneError, SceneResult};
use crate::advect::MomentumRhs;
use crate::burgers::ScalarLaw;
use crate::fluid::Advection;
use crate::obstacle::Obstacle as SolidShape;
use crate::stability::stable_time_step;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau, Scheme};
use crate::{
    fd, Bc, Boundaries, CenteredField, Error, Fluid, FluidConfig, FluidState, Grid, MacField, NavierStokes,
    NavierStokesConfig, PressureSolver, ScalarBc, ScalarBoundaries,
};
use candle_core::{DType, Device, Tensor};
use pbdl_core::sample::{resize2d, Resize};
use std::sync::Arc;

/// The evolving state of a simulation.
#[derive(Clone, Debug)]
pub enum State {
    /// A cell-centred scalar `[1, 1, ny, nx]`.
    Scalar(Tensor),
    /// A staggered velocity.
    Velocity(MacField),
    /// A staggered velocity and a cell-centred density (the smoke scene).
    Smoke(FluidState),
}

impl State {
    /// The velocity of a velocity or smoke state.
    pub fn velocity(&self) -> Option<&MacField> {
        match self {
            State::Velocity(u) => Some(u),
            State::Smoke(s) => Some(&s.velocity),
            State::Scalar(_) => None,
        }
    }

    /// The density of a smoke state.
    pub fn density(&self) -> Option<&CenteredField> {
        match self {
            State::Smoke(s) => s.density.as_ref(),
            _ => None,
        }
    }
}

/// The stepper: one variant per physics kind, each holding only its operators.
enum Stepper {
    Law {
        law: ScalarLaw,
        tableau: ButcherTableau,
    },
    Heat {
        template: CenteredField,
        kappa: f64,
        tableau: ButcherTableau,
    },
    Poisson {
        solver: Arc<PressureSolver>,
        source: CenteredField,
        solved: bool,
    },
    Burgers2d {
        rhs: MomentumRhs,
        tableau: ButcherTableau,
    },
    Fluid {
        ns: Box<NavierStokes>,
        forcing: Option<(Tensor, f64)>,
    },
    /// Smoke and obstacle flows ([`crate::Fluid`]); `rate` is the density inflow rate.
    Smoke {
        fluid: Box<Fluid>,
        rate: Option<Tensor>,
    },
}

/// A built scene: its stepper (with only the operators the scene needs), the current state and
/// the time step.
pub struct Simulation {
    scene: Scene,
    grid: Option<Grid>,
    stepper: Stepper,
    state: State,
    operators: Vec<&'static str>,
    dt: f64,
    steps: usize,
    step: usize,
    dtype: DType,
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("scene", &self.scene.name)
            .field("operators", &self.operators)
            .field("dt", &self.dt)
            .field("steps", &self.steps)
            .finish()
    }
}

/// The recorded frames of a run.
#[derive(Clone, Debug)]
pub struct Trajectory {
    /// Simulation time of each frame.
    pub times: Vec<f64>,
    /// Step index of each frame.
    pub steps: Vec<usize>,
    /// Field name and its frames, each `[C, ny, nx]`.
    pub fields: Vec<(String, Vec<Tensor>)>,
}

impl Trajectory {
    /// Each field stacked to `[T, C, ny, nx]`.
    pub fn stacked(&self) -> SceneResult<Vec<(String, Tensor)>> {
        let mut out = Vec::new();
        for (name, frames) in &self.fields {
            out.push((name.clone(), Tensor::stack(frames, 0).map_err(Error::from)?));
        }
        Ok(out)
    }
}

fn scheme_name(s: Scheme) -> &'static str {
    match s {
        Scheme::Rk4 => "time_stepping.rk4",
        Scheme::SspRk3 => "time_stepping.ssp_rk3",
        Scheme::ForwardEuler => "time_stepping.forward_euler",
    }
}

fn boundary_speed(bc: &Boundaries) -> f64 {
    bc.faces()
        .iter()
        .map(|(_, b)| match b {
            Bc::MovingWall { velocity } => velocity.abs(),
            Bc::Inflow { velocity } => velocity[0].abs().max(velocity[1].abs()),
            _ => 0.0,
        })
        .fold(0.0, f64::max)
}

fn max_abs(t: &Tensor) -> SceneResult<f64> {
    Ok(t.abs()
        .map_err(Error::from)?
        .max_all()
        .map_err(Error::from)?
        .to_dtype(DType::F64)
        .map_err(Error::from)?
        .to_scalar::<f64>()
        .map_err(Error::from)?)
}

fn c<T>(r: candle_core::Result<T>) -> SceneResult<T> {
    r.map_err(|e| SceneError::Grid(Error::from(e)))
}

impl Simulation {
    pub(super) fn new(scene: Scene) -> SceneResult<Self> {
        let g = scene.grid;
        let dtype = scene.precision.dtype();
        let tableau = scene.time.scheme.tableau();
        let (x0, y0) = (g.origin[0], g.origin[1]);
        let grid = if g.ny > 1 { Some(Grid::new(g.nx, g.ny, g.lx, g.ly)?) } else { None };
        let (dx, dy) = (g.lx / g.nx as f64, g.ly / g.ny as f64);
        let h = if g.ny > 1 { dx.min(dy) } else { dx };
        let invalid = |field: &str, reason: String| SceneError::Invalid {
            scene: scene.name.clone(),
            field: field.into(),
            reason,
        };
        if !scene.obstacles.is_empty() && !matches!(scene.physics, Physics::Cylinder { .. } | Physics::Smoke { .. }) {
            return Err(invalid(
                "obstacles",
                "this physics kind has no obstacle handling; use kind = \"cylinder\"".into(),
            ));
        }
        let scalar = |bc_periodic: bool| -> SceneResult<Tensor> {
            let mut data = vec![0.0; g.nx * g.ny];
            for j in 0..g.ny {
                for i in 0..g.nx {
                    let (x, y) = (x0 + (i as f64 + 0.5) * dx, y0 + (j as f64 + 0.5) * dy);
                    data[j * g.nx + i] = scene.init.scalar(x, y, g.lx, g.ly, bc_periodic);
                }
            }
            c(Tensor::from_vec(data, (1, 1, g.ny, g.nx), &Device::Cpu).and_then(|t| t.to_dtype(dtype)))
        };
        let velocity = |grid: Grid, bc: Boundaries| -> SceneResult<MacField> {
            let f = scene.init.velocity(g.lx, g.ly);
            Ok(MacField::from_fn(grid, bc, dtype, move |x, y| f(x + x0, y + y0))?)
        };
        // The step: a fixed dt, or cfl * h / speed capped at 0.9 of the stable step.
        let pick_dt = |speed: f64, stable: f64| -> SceneResult<f64> {
            match scene.time.dt {
                Some(dt) if dt > stable * (1.0 + 1e-12) => Err(invalid(
                    "time.dt",
                    format!("{dt:.3e} exceeds the stable step {stable:.3e} of {} for this scene", tableau.name),
                )),
                Some(dt) => Ok(match (scene.time.t_end, scene.time.steps) {
                    (Some(te), None) => te / (te / dt - 1e-9).ceil(),
                    _ => dt,
                }),
                None => {
                    let s = scene.time.speed.unwrap_or(speed);
                    let adv = if s > 0.0 { scene.time.cfl * h / s } else { f64::INFINITY };
                    let dt = adv.min(0.9 * stable);
                    if dt.is_finite() {
                        // A whole number of steps ends at t_end.
                        Ok(match (scene.time.t_end, scene.time.steps) {
                            (Some(te), None) => te / (te / dt).ceil(),
                            _ => dt,
                        })
                    } else {
                        Err(invalid("time.dt", "nothing moves or diffuses; give time.dt".into()))
                    }
                }
            }
        };
        let ts = scheme_name(scene.time.scheme);
        let (stepper, state, mut operators, dt): (Stepper, State, Vec<&'static str>, f64) = match &scene.physics {
            Physics::Burgers1d { nu } => {
                let law = ScalarLaw { dx, dy, velocity: [0.0; 2], burgers: [1.0, 0.0], nu: *nu };
                let u = scalar(true)?;
                let m = max_abs(&u)?;
                let stable = law.stable_time_step(scene.time.speed.unwrap_or(m), g.ny, &tableau);
                let dt = pick_dt(m, stable)?;
                let mut ops = law.operators();
                ops.push(ts);
                (Stepper::Law { law, tableau }, State::Scalar(u), ops, dt)
            }
            Physics::AdvectionDiffusion { velocity, nu } => {
                let law = ScalarLaw { dx, dy, velocity: *velocity, burgers: [0.0; 2], nu: *nu };
                let stable = law.stable_time_step(0.0, g.ny, &tableau);
                let dt = pick_dt(velocity[0].abs().max(velocity[1].abs()), stable)?;
                let mut ops = law.operators();
                ops.push(ts);
                (Stepper::Law { law, tableau }, State::Scalar(scalar(true)?), ops, dt)
            }
            Physics::Heat { kappa, boundaries } => {
                let grid = grid.expect("validated 2D");
                let t0 = scalar(boundaries.is_periodic())?;
                let template = CenteredField::new(t0.clone(), grid, *boundaries)?;
                let stable = stable_time_step(&grid, [0.0, 0.0], *kappa, &tableau);
                let dt = pick_dt(0.0, stable)?;
                let mut ops = vec![];
                if *kappa > 0.0 {
                    ops.push("diffuse.laplacian");
                }
                ops.push(ts);
                (Stepper::Heat { template, kappa: *kappa, tableau }, State::Scalar(t0), ops, dt)
            }
            Physics::Poisson { boundaries } => {
                let grid = grid.expect("validated 2D");
                let solver = PressureSolver::for_scalar(grid, boundaries, false)?;
                let source = CenteredField::new(scalar(boundaries.is_periodic())?, grid, *boundaries)?;
                let ops = vec![if solver.method_name() == "fft" { "poisson.fft" } else { "poisson.sparse_cholesky" }];
                let phi = c(source.values().zeros_like())?;
                (Stepper::Poisson { solver, source, solved: false }, State::Scalar(phi), ops, 1.0)
            }
            Physics::Burgers2d { nu, boundaries } => {
                let grid = grid.expect("validated 2D");
                let u = velocity(grid, *boundaries)?;
                let speed = u.max_abs()?.max(boundary_speed(boundaries));
                let s = scene.time.speed.unwrap_or(speed);
                let dt = pick_dt(speed, stable_time_step(&grid, [s, s], *nu, &tableau))?;
                let rhs = MomentumRhs::new(&u, true, *nu);
                let mut ops = vec!["advect.flux_form"];
                if *nu > 0.0 {
                    ops.push("diffuse.explicit");
                }
                ops.push(ts);
                (Stepper::Burgers2d { rhs, tableau }, State::Velocity(u), ops, dt)
            }
            Physics::NavierStokes { nu, boundaries, forcing } => {
                let grid = grid.expect("validated 2D");
                let u = velocity(grid, *boundaries)?;
                let speed = u.max_abs()?.max(boundary_speed(boundaries));
                let s = scene.time.speed.unwrap_or(speed);
                let dt = pick_dt(speed, stable_time_step(&grid, [s, s], *nu, &tableau))?;
                let ns = NavierStokes::new(
                    grid,
                    *boundaries,
                    NavierStokesConfig { nu: *nu, dt, scheme: scene.time.scheme },
                )?;
                let u = ns.project(&u)?;
                let mut ops: Vec<&'static str> = ns.operators().to_vec();
                let forcing = match forcing {
                    None => None,
                    Some(Forcing::Kolmogorov { amplitude, wavenumber, drag }) => {
                        if boundaries.x_lo != Bc::Periodic {
                            return Err(invalid(
                                "physics.forcing",
                                "Kolmogorov forcing needs periodic x faces (it is divergence-free only then)".into(),
                            ));
                        }
                        let (a, k) = (*amplitude, *wavenumber as f64);
                        let f = MacField::from_fn(grid, *boundaries, dtype, move |_, y| {
                            [a * (2.0 * std::f64::consts::PI * k * y / g.ly).sin(), 0.0]
                        })?;
                        ops.push("forcing.kolmogorov");
                        if *drag > 0.0 {
                            ops.push("forcing.linear_drag");
                        }
                        Some((f.into_values(), *drag))
                    }
                };
                (Stepper::Fluid { ns: Box::new(ns), forcing }, State::Velocity(u), ops, dt)
            }
            Physics::Smoke { nu, buoyancy, boundaries, source, advection } => {
                let grid = grid.expect("validated 2D");
                let u = velocity(grid, *boundaries)?;
                let speed = u.max_abs()?.max(boundary_speed(boundaries));
                let s = scene.time.speed.unwrap_or(speed);
                let dt = pick_dt(speed, fluid_stable_dt(&grid, *advection, s, *nu))?;
                let density_advection = if *advection == Advection::SemiLagrangian {
                    Advection::SemiLagrangian
                } else {
                    Advection::MacCormack
                };
                let config = FluidConfig {
                    dt,
                    nu: *nu,
                    advection: *advection,
                    density_advection,
                    buoyancy: Some(*buoyancy),
                    inflow: Some(SolidShape::Cylinder {
                        center: [source.center[0] - x0, source.center[1] - y0],
                        radius: source.radius,
                    }),
                    obstacles: solid_shapes(&scene),
                };
                let fluid = Fluid::new(grid, *boundaries, Some(density_boundaries(boundaries)), config)?;
                let mut state = fluid.rest(1, dtype)?;
                state.velocity = fluid.project(&u)?;
                let rate = c(Tensor::new(&[source.rate], &Device::Cpu).and_then(|t| t.to_dtype(dtype)))?;
                let ops = fluid.operators().to_vec();
                (Stepper::Smoke { fluid: Box::new(fluid), rate: Some(rate) }, State::Smoke(state), ops, dt)
            }
            Physics::Cylinder { nu, inflow, advection, kick } => {
                let grid = grid.expect("validated 2D");
                let bc =
                    Boundaries::new(Bc::Inflow { velocity: [*inflow, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip)?;
                let shapes = solid_shapes(&scene);
                // The kick: a transverse velocity in a square of one diameter behind the first circle.
                let behind = shapes.iter().find_map(|o| match *o {
                    SolidShape::Cylinder { center, radius } => Some((center, radius)),
                    _ => None,
                });
                let (u_in, k) = (*inflow, *kick * *inflow);
                let f = scene.init.velocity(g.lx, g.ly);
                let uniform = matches!(scene.init, super::Init::Zero);
                let u = MacField::from_fn(grid, bc, dtype, move |x, y| {
                    let mut v = if uniform { [u_in, 0.0] } else { f(x + x0, y + y0) };
                    if let Some((c, r)) = behind {
                        let d = 2.0 * r;
                        if (x - c[0] - 1.5 * d).abs() < 0.5 * d && (y - c[1] - 0.5 * d).abs() < 0.5 * d {
                            v[1] += k;
                        }
                    }
                    v
                })?;
                let speed = u.max_abs()?.max(boundary_speed(&bc));
                let s = scene.time.speed.unwrap_or(speed);
                let dt = pick_dt(speed, fluid_stable_dt(&grid, *advection, s, *nu))?;
                let config = FluidConfig {
                    dt,
                    nu: *nu,
                    advection: *advection,
                    density_advection: Advection::MacCormack,
                    buoyancy: None,
                    inflow: None,
                    obstacles: shapes,
                };
                let fluid = Fluid::new(grid, bc, None, config)?;
                let u = fluid.project(&u)?;
                let ops = fluid.operators().to_vec();
                (Stepper::Smoke { fluid: Box::new(fluid), rate: None }, State::Velocity(u), ops, dt)
            }
        };
        operators.dedup();
        let (steps, dt) = match (scene.time.steps, scene.time.t_end) {
            (Some(n), _) => (n, dt),
            (None, Some(te)) => {
                // dt already divides t_end (up to round-off) unless it was given.
                let n = (te / dt - 1e-9).ceil().max(1.0) as usize;
                (n, te / n as f64)
            }
            (None, None) => unreachable!("validated"),
        };
        let steps = if matches!(stepper, Stepper::Poisson { .. }) { 1 } else { steps };
        Ok(Self { scene, grid, stepper, state, operators, dt, steps, step: 0, dtype })
    }

    /// The operators this stepper runs, e.g. `["advect.flux_form", "diffuse.explicit",
    /// "pressure.fft", "time_stepping.rk4"]`. Absent here means absent from the step.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The scene it was built from.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The time step.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Steps of the planned run (`time.steps`, or `t_end / dt`).
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Steps taken so far.
    pub fn step_index(&self) -> usize {
        self.step
    }

    /// Simulation time.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.dt
    }

    /// The current state.
    pub fn state(&self) -> &State {
        &self.state
    }

    /// The grid (`None` for 1D scenes).
    pub fn grid(&self) -> Option<&Grid> {
        self.grid.as_ref()
    }

    /// Name of the scalar a scalar scene evolves (`None` for velocity scenes).
    pub fn scalar_name(&self) -> Option<&'static str> {
        match self.scene.physics {
            Physics::Burgers1d { .. } => Some("u"),
            Physics::Heat { .. } => Some("temperature"),
            Physics::Poisson { .. } => Some("phi"),
            Physics::AdvectionDiffusion { .. } => Some("concentration"),
            _ => None,
        }
    }

    /// One time step. Errors (typed) when the state stops being finite or the step becomes
    /// unstable for the current state.
    pub fn step(&mut self) -> SceneResult<()> {
        let dt = self.dt;
        self.state = match (&mut self.stepper, &self.state) {
            (Stepper::Law { law, tableau }, State::Scalar(u)) => State::Scalar(law.step(u, dt, tableau)?),
            (Stepper::Heat { template, kappa, tableau }, State::Scalar(t)) => {
                let k = *kappa;
                let v = projected_runge_kutta(
                    t,
                    dt,
                    tableau,
                    |x| Ok(fd::laplacian(&template.with_values(x.clone())?)?.into_values().affine(k, 0.0)?),
                    |x| Ok(x.clone()),
                )?;
                State::Scalar(v)
            }
            (Stepper::Poisson { solver, source, solved }, State::Scalar(p)) => {
                if *solved {
                    State::Scalar(p.clone())
                } else {
                    *solved = true;
                    State::Scalar(crate::pressure::solve_poisson(source, solver)?.into_values())
                }
            }
            (Stepper::Burgers2d { rhs, tableau }, State::Velocity(u)) => {
                let v = projected_runge_kutta(u.values(), dt, tableau, |x| Ok(rhs.apply(x)?), |x| Ok(x.clone()))?;
                State::Velocity(u.with_values(v)?)
            }
            (Stepper::Fluid { ns, forcing }, State::Velocity(u)) => {
                let mut v = ns.step(u)?;
                if let Some((f, drag)) = forcing {
                    // Operator splitting: u += dt (f - drag u); f is divergence-free, so no projection.
                    let vals = c(v.values().affine(1.0 - dt * *drag, 0.0).and_then(|x| x + f.affine(dt, 0.0)?))?;
                    v = v.with_values(vals)?;
                }
                State::Velocity(v)
            }
            (Stepper::Smoke { fluid, .. }, State::Velocity(u)) => {
                let s = FluidState { velocity: u.clone(), density: None };
                State::Velocity(fluid.step(&s, None)?.velocity)
            }
            (Stepper::Smoke { fluid, rate }, State::Smoke(s)) => State::Smoke(fluid.step(s, rate.as_ref())?),
            _ => unreachable!("stepper and state are built together"),
        };
        self.step += 1;
        Ok(())
    }

    /// Checks the state: finite, and (scalar laws) the step still stable for its largest value.
    pub fn check(&self) -> SceneResult<()> {
        match (&self.stepper, &self.state) {
            (Stepper::Law { law, tableau }, State::Scalar(u)) => {
                let m = max_abs(u)?;
                if !m.is_finite() {
                    return Err(Error::NonFinite { what: "scalar", value: m }.into());
                }
                let stable = law.stable_time_step(m, self.scene.grid.ny, tableau);
                if self.dt > stable * (1.0 + 1e-12) {
                    return Err(Error::Unstable {
                        what: "time step for the current max |u|",
                        value: self.dt,
                        limit: stable,
                        scheme: tableau.name.clone(),
                        dt: self.dt,
                        stable_dt: stable,
                    }
                    .into());
                }
            }
            (Stepper::Fluid { ns, .. }, State::Velocity(u)) => {
                ns.check(u)?;
            }
            (_, State::Scalar(t)) => {
                let m = max_abs(t)?;
                if !m.is_finite() {
                    return Err(Error::NonFinite { what: "scalar", value: m }.into());
                }
            }
            (_, State::Velocity(u)) => {
                let m = u.max_abs()?;
                if !m.is_finite() {
                    return Err(Error::NonFinite { what: "velocity", value: m }.into());
                }
            }
            (_, State::Smoke(s)) => {
                let m = s.velocity.max_abs()?;
                if !m.is_finite() {
                    return Err(Error::NonFinite { what: "velocity", value: m }.into());
                }
                if let Some(rho) = &s.density {
                    let m = max_abs(rho.values())?;
                    if !m.is_finite() {
                        return Err(Error::NonFinite { what: "density", value: m }.into());
                    }
                }
            }
        }
        Ok(())
    }

    /// The output fields of the current state, each `[C, ny, nx]` on cell centres: the scalar
    /// (`u`, `temperature`, `phi` + `source`, `concentration`), or `velocity` (`[2, ny, nx]`,
    /// face values averaged to the centres), `velocity_mac` (the staggered values as stored:
    /// `u` at `((i+1) dx, (j+1/2) dy)`, `v` at `((i+1/2) dx, (j+1) dy)`) and `vorticity`
    /// (`[1, ny, nx]`, at the cell corners `((i+1) dx, (j+1) dy)`).
    pub fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        match &self.state {
            State::Scalar(t) => {
                let mut out = vec![(self.scalar_name().unwrap_or("scalar").to_string(), c(t.squeeze(0))?)];
                if let Stepper::Poisson { source, .. } = &self.stepper {
                    out.push(("source".into(), c(source.values().squeeze(0))?));
                }
                Ok(out)
            }
            State::Velocity(_) | State::Smoke(_) => {
                let u = self.state.velocity().expect("velocity state");
                let (centred, vort) = centre_velocity(u)?;
                let mut out = Vec::new();
                if let Some(rho) = self.state.density() {
                    out.push(("density".into(), c(rho.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?));
                }
                out.extend([
                    ("velocity".into(), centred),
                    ("velocity_mac".into(), c(u.values().narrow(0, 0, 1).and_then(|t| t.squeeze(0)))?),
                    ("vorticity".into(), vort),
                ]);
                Ok(out)
            }
        }
    }

    /// Replaces the state by given fields (the `--init` of `cargo xtask sim`). Velocity scenes
    /// take `velocity` on cell centres (`[2, Y, X]`, `[1, 2, Y, X]` or a trajectory
    /// `[T, 2, Y, X]`, whose last frame is used), resampled bilinearly when `Y, X` differ from
    /// the grid, averaged to the faces and projected; `velocity_mac` (`[2, Y, X]` or a trajectory)
    /// is preferred when its `Y, X` equal the grid's (taken as is, then projected). Scalar scenes take their scalar by name (`u`,
    /// `temperature`, `source` for Poisson, `concentration`) as `[Y, X]`, `[1, Y, X]` or
    /// `[T, 1, Y, X]` (1D: `[X]` too). The smoke scene takes `density` (`[Y, X]`, `[1, Y, X]`
    /// or `[T, 1, Y, X]`, resampled like the velocity), the velocity, or both; what is not given
    /// is kept. Returns the names used.
    pub fn set_fields(&mut self, arrays: &[(String, Tensor)]) -> SceneResult<Vec<String>> {
        let g = self.scene.grid;
        let invalid = |field: &str, reason: String| SceneError::Invalid {
            scene: self.scene.name.clone(),
            field: format!("init file: {field}"),
            reason,
        };
        let find = |name: &str| arrays.iter().find(|(n, _)| n == name).map(|(_, t)| t.clone());
        let to4 = |name: &str, t: &Tensor, channels: usize| -> SceneResult<Tensor> {
            let t = c(t.to_dtype(DType::F64))?;
            let t = match t.rank() {
                1 if channels == 1 => c(t.reshape((1, 1, 1, t.dims()[0])))?,
                2 if channels == 1 => c(t.unsqueeze(0).and_then(|t| t.unsqueeze(0)))?,
                3 => c(t.unsqueeze(0))?,
                4 => {
                    let n = t.dims()[0];
                    c(t.narrow(0, n - 1, 1))?
                }
                _ => return Err(invalid(name, format!("expected [C, Y, X] or [T, C, Y, X], got {:?}", t.dims()))),
            };
            if t.dims()[1] != channels {
                return Err(invalid(name, format!("expected {channels} channel(s), got shape {:?}", t.dims())));
            }
            if !max_abs(&t)?.is_finite() {
                return Err(invalid(name, "contains NaN or Inf".into()));
            }
            let (h, w) = (t.dims()[2], t.dims()[3]);
            if (h, w) == (g.ny, g.nx) {
                Ok(t)
            } else {
                Ok(resize2d(&t, (g.ny, g.nx), Resize::Bilinear { align_corners: false }).map_err(Error::from)?)
            }
        };
        match &self.state {
            State::Scalar(_) => {
                let name = if matches!(self.stepper, Stepper::Poisson { .. }) {
                    "source"
                } else {
                    self.scalar_name().unwrap_or("scalar")
                };
                let t = find(name).ok_or_else(|| {
                    invalid(name, format!("the file has no array `{name}`; it has {:?}", names(arrays)))
                })?;
                let t = c(to4(name, &t, 1)?.to_dtype(self.dtype))?;
                match &mut self.stepper {
                    Stepper::Poisson { source, solved, .. } => {
                        *source = source.with_values(t)?;
                        *solved = false;
                    }
                    Stepper::Heat { template, .. } => {
                        self.state = State::Scalar(template.with_values(t)?.into_values());
                    }
                    _ => self.state = State::Scalar(t),
                }
                Ok(vec![name.into()])
            }
            State::Velocity(_) | State::Smoke(_) => {
                let u = self.state.velocity().expect("velocity state");
                let grid = *u.grid();
                let bc = *u.bc();
                let mut used = Vec::new();
                let density = match (&self.state, find("density")) {
                    (State::Smoke(s), Some(t)) => {
                        let rho = s.density.as_ref().expect("smoke state has a density");
                        used.push("density".to_string());
                        Some(rho.with_values(c(to4("density", &t, 1)?.to_dtype(self.dtype))?)?)
                    }
                    (State::Smoke(s), None) => s.density.clone(),
                    _ => None,
                };
                let has_velocity = find("velocity").is_some() || find("velocity_mac").is_some();
                if let (State::Smoke(s), false, false) = (&self.state, has_velocity, used.is_empty()) {
                    self.state = State::Smoke(FluidState { velocity: s.velocity.clone(), density });
                    return Ok(used);
                }
                // The staggered values are used as they are when their shape matches the grid
                // (last frame of a trajectory); otherwise the centred `velocity` is resampled.
                let mac = find("velocity_mac").and_then(|t| {
                    let t = t.to_dtype(DType::F64).ok()?;
                    let t = if t.rank() == 3 { t.unsqueeze(0).ok()? } else { t };
                    let t = t.narrow(0, t.dims().first().copied()?.checked_sub(1)?, 1).ok()?;
                    (t.dims() == [1, 2, g.ny, g.nx]).then_some(t)
                });
                let (mac, name) = if let Some(t) = mac {
                    (t, "velocity_mac")
                } else if let Some(t) = find("velocity") {
                    (faces_from_centres(&to4("velocity", &t, 2)?, &bc)?, "velocity")
                } else {
                    let also = if matches!(self.state, State::Smoke(_)) { ", `density`" } else { "" };
                    return Err(invalid(
                        "velocity",
                        format!("the file has no array `velocity` or `velocity_mac`{also}; it has {:?}", names(arrays)),
                    ));
                };
                let field = MacField::new(c(mac.to_dtype(self.dtype))?, grid, bc)?;
                let field = match &self.stepper {
                    Stepper::Fluid { ns, .. } => ns.project(&field)?,
                    Stepper::Smoke { fluid, .. } => fluid.project(&field)?,
                    _ => field,
                };
                used.insert(0, name.to_string());
                self.state = match self.state {
                    State::Smoke(_) => State::Smoke(FluidState { velocity: field, density }),
                    _ => State::Velocity(field),
                };
                Ok(used)
            }
        }
    }

    /// Runs the remaining planned steps, recording `time.frames` evenly spaced frames (the
    /// current state first). `on_step(step)` is called after every step (progress bars). The
    /// state is checked at every frame (see [`Simulation::check`]).
    pub fn run(&mut self, mut on_step: impl FnMut(usize)) -> SceneResult<Trajectory> {
        self.run_observed(|_, k| on_step(k))
    }

    /// [`Simulation::run`] with `on_step(state, step)` seeing the state after every step (probes,
    /// invariant checks).
    pub fn run_observed(&mut self, mut on_step: impl FnMut(&State, usize)) -> SceneResult<Trajectory> {
        let total = self.steps.saturating_sub(self.step);
        let frames = self.scene.time.frames.clamp(1, total + 1);
        let mut record: Vec<usize> = (0..frames)
            .map(|k| if frames == 1 { total } else { (k as f64 * total as f64 / (frames - 1) as f64).round() as usize })
            .collect();
        record.dedup();
        let mut traj = Trajectory { times: vec![], steps: vec![], fields: vec![] };
        let push = |sim: &Simulation, traj: &mut Trajectory| -> SceneResult<()> {
            sim.check()?;
            let f = sim.fields()?;
            if traj.fields.is_empty() {
                traj.fields = f.iter().map(|(n, _)| (n.clone(), vec![])).collect();
            }
            for ((_, frames), (_, t)) in traj.fields.iter_mut().zip(f) {
                frames.push(t);
            }
            traj.times.push(sim.time());
            traj.steps.push(sim.step);
            Ok(())
        };
        let start = self.step;
        let mut next = 0;
        if record.first() == Some(&0) {
            push(self, &mut traj)?;
            next = 1;
        }
        for k in 1..=total {
            self.step()?;
            on_step(&self.state, self.step);
            if record.get(next) == Some(&k) {
                push(self, &mut traj)?;
                next += 1;
            }
        }
        debug_assert_eq!(self.step, start + total);
        Ok(traj)
    }
}

fn names(arrays: &[(String, Tensor)]) -> Vec<&str> {
    arrays.iter().map(|(n, _)| n.as_str()).collect()
}

/// The normal face value at a lower face that is not stored (wall 0, inflow given).
fn lower_normal(b: Bc, comp: usize) -> f64 {
    match b {
        Bc::Inflow { velocity } => velocity[comp],
        _ => 0.0,
    }
}

/// Cell-centred velocity `[2, ny, nx]` and corner vorticity `[1, ny, nx]` of a MAC field
/// (batch 0).
fn centre_velocity(u: &MacField) -> SceneResult<(Tensor, Tensor)> {
    let g = *u.grid();
    let bc = *u.bc();
    let (nx, ny, n) = (g.nx, g.ny, g.cells());
    let vals = c(u
        .values()
        .narrow(0, 0, 1)
        .and_then(|t| t.to_dtype(DType::F64))
        .and_then(|t| t.flatten_all())
        .and_then(|t| t.to_vec1::<f64>()))?;
    let (uu, vv) = vals.split_at(n);
    let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
    let mut out = vec![0.0; 2 * n];
    let mut w = vec![0.0; n];
    for j in 0..ny {
        for i in 0..nx {
            let left = if i > 0 {
                uu[j * nx + i - 1]
            } else if px {
                uu[j * nx + nx - 1]
            } else {
                lower_normal(bc.x_lo, 0)
            };
            let below = if j > 0 {
                vv[(j - 1) * nx + i]
            } else if py {
                vv[(ny - 1) * nx + i]
            } else {
                lower_normal(bc.y_lo, 1)
            };
            out[j * nx + i] = 0.5 * (left + uu[j * nx + i]);
            out[n + j * nx + i] = 0.5 * (below + vv[j * nx + i]);
            // Corner ((i+1) dx, (j+1) dy); one-sided (clamped) at non-periodic upper faces.
            let ir = if i + 1 < nx {
                i + 1
            } else if px {
                0
            } else {
                i
            };
            let ju = if j + 1 < ny {
                j + 1
            } else if py {
                0
            } else {
                j
            };
            w[j * nx + i] = (vv[j * nx + ir] - vv[j * nx + i]) / g.dx() - (uu[ju * nx + i] - uu[j * nx + i]) / g.dy();
        }
    }
    let dtype = u.values().dtype();
    let v = c(Tensor::from_vec(out, (2, ny, nx), &Device::Cpu).and_then(|t| t.to_dtype(dtype)))?;
    let w = c(Tensor::from_vec(w, (1, ny, nx), &Device::Cpu).and_then(|t| t.to_dtype(dtype)))?;
    Ok((v, w))
}

/// Face values of a cell-centred velocity `[1, 2, ny, nx]` (f64): the mean of the two cells
/// beside each face; stored boundary faces fixed by a condition get its value.
fn faces_from_centres(t: &Tensor, bc: &Boundaries) -> SceneResult<Tensor> {
    let (_, _, ny, nx) = c(t.dims4())?;
    let n = nx * ny;
    let vals = c(t.flatten_all().and_then(|t| t.to_vec1::<f64>()))?;
    let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
    let mut out = vec![0.0; 2 * n];
    let fixed = |b: Bc, comp: usize| match b {
        Bc::Inflow { velocity } => Some(velocity[comp]),
        Bc::NoSlip | Bc::FreeSlip | Bc::MovingWall { .. } => Some(0.0),
        _ => None,
    };
    for j in 0..ny {
        for i in 0..nx {
            let ir = if i + 1 < nx {
                i + 1
            } else if px {
                0
            } else {
                i
            };
            let ju = if j + 1 < ny {
                j + 1
            } else if py {
                0
            } else {
                j
            };
            out[j * nx + i] = 0.5 * (vals[j * nx + i] + vals[j * nx + ir]);
            out[n + j * nx + i] = 0.5 * (vals[n + j * nx + i] + vals[n + ju * nx + i]);
            if i + 1 == nx {
                if let Some(v) = fixed(bc.x_hi, 0) {
                    out[j * nx + i] = v;
                }
            }
            if j + 1 == ny {
                if let Some(v) = fixed(bc.y_hi, 1) {
                    out[n + j * nx + i] = v;
                }
            }
        }
    }
    c(Tensor::from_vec(out, (1, 2, ny, nx), &Device::Cpu))
}

/// The largest stable step of the [`Fluid`] velocity advection for speed `s`: infinite for the
/// semi-Lagrangian and MacCormack paths, the RK4 limit for the central flux form.
fn fluid_stable_dt(grid: &Grid, advection: Advection, s: f64, nu: f64) -> f64 {
    match advection {
        Advection::CentralRk4 => stable_time_step(grid, [s, s], nu, &ButcherTableau::rk4()),
        _ => f64::INFINITY,
    }
}

/// The scene's obstacles in solver coordinates (the grid's origin at 0).
fn solid_shapes(scene: &Scene) -> Vec<SolidShape> {
    let [x0, y0] = scene.grid.origin;
    scene
        .obstacles
        .iter()
        .map(|o| match *o {
            super::Obstacle::Circle { center, radius } => {
                SolidShape::Cylinder { center: [center[0] - x0, center[1] - y0], radius }
            }
            super::Obstacle::Box { lower, upper } => {
                SolidShape::Box { lo: [lower[0] - x0, lower[1] - y0], hi: [upper[0] - x0, upper[1] - y0] }
            }
        })
        .collect()
}

/// Density conditions matching velocity ones: periodic where the velocity is, zero gradient
/// (walls, inflow, outflow) elsewhere.
fn density_boundaries(b: &Boundaries) -> ScalarBoundaries {
    let f = |bc: Bc| if bc == Bc::Periodic { ScalarBc::Periodic } else { ScalarBc::Neumann };
    ScalarBoundaries { x_lo: f(b.x_lo), x_hi: f(b.x_hi), y_lo: f(b.y_lo), y_hi: f(b.y_hi) }
}
