//! A scene built into a simulation: its physics kind (stepper and state, see [`super::kinds`]),
//! the time step and the planned steps.

use super::kinds::{self, FieldInput, PhysicsKind, Setup};
use super::{Physics, Scene, SceneResult, TimeSpec};
use crate::{CenteredField, Error, FluidState, Grid, MacField};
use candle_core::{DType, Tensor};
use std::sync::OnceLock;

/// The evolving state of a simulation.
#[derive(Clone, Debug)]
pub enum State {
    /// A cell-centred scalar `[1, 1, ny, nx]`.
    Scalar(Tensor),
    /// A staggered velocity.
    Velocity(MacField),
    /// A staggered velocity and a cell-centred density (the smoke scene).
    Smoke(FluidState),
    /// A cell-centred 3D velocity `[1, 3, nz, ny, nx]` (3D `navier_stokes_spectral` scenes).
    Velocity3d(Tensor),
    /// A walled 3D MAC velocity and a density (3D `smoke` scenes).
    Smoke3d(crate::grid3d::smoke::Smoke3dState),
}

impl State {
    /// The velocity of a velocity or smoke state.
    pub fn velocity(&self) -> Option<&MacField> {
        match self {
            State::Velocity(u) => Some(u),
            State::Smoke(s) => Some(&s.velocity),
            State::Scalar(_) | State::Velocity3d(_) | State::Smoke3d(_) => None,
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

/// A built scene: its physics kind (a stepper with only the operators the scene needs, owning the
/// state), the time step and the planned steps.
pub struct Simulation {
    scene: Scene,
    grid: Option<Grid>,
    kind: Box<dyn PhysicsKind>,
    /// The kind's state as of the last step or `set_fields` (shared tensors, not a copy), made
    /// when first asked for: a kind whose public state is derived (the spectral solver's face
    /// velocity) pays for it only when someone looks.
    state: OnceLock<State>,
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

impl Simulation {
    pub(super) fn new(scene: Scene) -> SceneResult<Self> {
        let setup = Setup::new(&scene)?;
        refuse_obstacles(&setup)?;
        let (kind, dt) = kinds::build(&setup)?;
        let (grid, dtype) = (setup.grid, setup.dtype);
        let mut operators = kind.operators();
        operators.dedup();
        let (steps, dt) = plan_steps(&setup, dt)?;
        let steps = kind.planned_steps(steps);
        Ok(Self { scene, grid, kind, state: OnceLock::new(), operators, dt, steps, step: 0, dtype })
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
        self.state.get_or_init(|| self.kind.state())
    }

    /// The grid (`None` for 1D scenes).
    pub fn grid(&self) -> Option<&Grid> {
        self.grid.as_ref()
    }

    /// Name of the scalar a scalar scene evolves (`None` for velocity scenes).
    pub fn scalar_name(&self) -> Option<&'static str> {
        self.kind.scalar_name()
    }

    /// One time step. Errors (typed) when the state stops being finite or the step becomes
    /// unstable for the current state.
    pub fn step(&mut self) -> SceneResult<()> {
        self.kind.step(self.dt)?;
        self.state = OnceLock::new();
        self.step += 1;
        Ok(())
    }

    /// Checks the state: finite, and (scalar laws) the step still stable for its largest value.
    pub fn check(&self) -> SceneResult<()> {
        self.kind.check(self.dt)
    }

    /// The output fields of the current state, each `[C, ny, nx]` on cell centres: the scalar
    /// (`u`, `temperature`, `phi` + `source`, `concentration`), or `velocity` (`[2, ny, nx]`,
    /// face values averaged to the centres), `velocity_mac` (the staggered values as stored:
    /// `u` at `((i+1) dx, (j+1/2) dy)`, `v` at `((i+1/2) dx, (j+1) dy)`) and `vorticity`
    /// (`[1, ny, nx]`, at the cell corners `((i+1) dx, (j+1) dy)`). `navier_stokes_spectral`
    /// differs: its `velocity` and `vorticity` are the spectral solution at the cell centres, and
    /// `velocity_mac` its spectral interpolation to the faces.
    pub fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        self.kind.fields()
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
        let input = FieldInput { arrays, scene: &self.scene.name, shape: (g.ny, g.nx), dtype: self.dtype };
        let used = self.kind.set_fields(&input)?;
        self.state = OnceLock::new();
        Ok(used)
    }

    /// Runs the remaining planned steps, recording `time.frames` evenly spaced frames (the
    /// current state first). `on_step(step)` is called after every step (progress bars). The
    /// state is checked at every frame (see [`Simulation::check`]).
    pub fn run(&mut self, mut on_step: impl FnMut(usize)) -> SceneResult<Trajectory> {
        self.run_frames(|_, k| on_step(k))
    }

    /// [`Simulation::run`] with `on_step(state, step)` seeing the state after every step (probes,
    /// invariant checks).
    pub fn run_observed(&mut self, mut on_step: impl FnMut(&State, usize)) -> SceneResult<Trajectory> {
        self.run_frames(|sim, k| on_step(sim.state(), k))
    }

    /// The loop of [`Simulation::run`]: `on_step` sees the simulation after every step.
    fn run_frames(&mut self, mut on_step: impl FnMut(&Simulation, usize)) -> SceneResult<Trajectory> {
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
            on_step(self, self.step);
            if record.get(next) == Some(&k) {
                push(self, &mut traj)?;
                next += 1;
            }
        }
        debug_assert_eq!(self.step, start + total);
        Ok(traj)
    }
}

/// Obstacles need a kind that handles them (`cylinder`, `smoke`).
fn refuse_obstacles(setup: &Setup<'_>) -> SceneResult<()> {
    let scene = setup.scene;
    if !scene.obstacles.is_empty() && !matches!(scene.physics, Physics::Cylinder { .. } | Physics::Smoke { .. }) {
        return Err(
            setup.invalid("obstacles", "this physics kind has no obstacle handling; use kind = \"cylinder\"".into())
        );
    }
    Ok(())
}

/// The planned steps and the final step: `time.steps` steps of `dt`, or a whole number of steps
/// ending at `time.t_end`.
fn plan_steps(setup: &Setup<'_>, dt: f64) -> SceneResult<(usize, f64)> {
    let TimeSpec { steps, t_end, .. } = setup.scene.time;
    match (steps, t_end) {
        (Some(n), _) => Ok((n, dt)),
        (None, Some(te)) => {
            // dt already divides t_end (up to round-off) unless it was given.
            let n = (te / dt - 1e-9).ceil().max(1.0) as usize;
            Ok((n, te / n as f64))
        }
        (None, None) => Err(setup.invalid("time", "give `steps` or `t_end`".into())),
    }
}
