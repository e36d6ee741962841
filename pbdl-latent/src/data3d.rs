//! 3D training data: buoyant smoke plumes from pbdl-grid's [`Smoke3d`] stepper, one scene per
//! inflow position, with the pressure of every step's solve kept (the 3D counterpart of
//! [`crate::data`]).
//!
//! A scene is an `n^3` closed box (`dx = 1`, no-slip walls: [`Smoke3d`] has no open top): smoke
//! enters through a sphere near the floor at a constant rate and rises under Boussinesq
//! buoyancy. The scene parameter is the sphere's `x` position (a fraction of the width), drawn
//! uniformly in [`PlumeData3d::source_x`]. Frame `t` of a [`Sequence3d`] holds the state `s_t`
//! (velocity, density) and the pressure `p_t` of the solve of the step `s_t -> s_{t+1}`, taken
//! through [`Smoke3d::step_unprojected`] and [`Smoke3d::project_keep_pressure`] (in the solve's
//! units: `u <- u - G p`).
//!
//! ```
//! use pbdl_latent::data3d::{generate3d, PlumeData3d};
//!
//! let cfg = PlumeData3d { resolution: 8, train_scenes: 1, test_scenes: 1, frames: 3, ..PlumeData3d::default() };
//! let data = generate3d(&cfg)?;
//! assert_eq!(data.test[0].pressure.dims(), [3, 1, 8, 8, 8]);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_grid::grid3d::{Advection3d, BoxPressure, Grid3d, Smoke3d, Smoke3dConfig, Smoke3dState, SphereSource};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The 3D smoke-plume data set: resolution, number of scenes and frames, physics. The default is
/// a CPU-size case: 32^3 cells, 6 training and 2 held-out scenes of 48 frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlumeData3d {
    /// Cells per side (the box is `n^3`, `dx = 1`; >= 8). Default 32.
    pub resolution: usize,
    /// Training scenes (>= 1). Default 6.
    pub train_scenes: usize,
    /// Held-out scenes (>= 1), drawn from the same parameter range with another stream.
    /// Default 2.
    pub test_scenes: usize,
    /// Frames (solver steps) per scene (>= 2). Default 48.
    pub frames: usize,
    /// Time step (> 0). Default 1.
    pub dt: f64,
    /// Boussinesq coefficient (force `beta rho` along `+y`). Default 0.05.
    pub buoyancy: f64,
    /// Density added per unit time inside the inflow sphere (> 0). Default 0.5.
    pub rate: f64,
    /// Inflow sphere radius as a fraction of the width (at least one cell is used). Default 0.1.
    pub source_radius: f64,
    /// Height of the sphere centre as a fraction of the height. Default 0.15.
    pub source_y: f64,
    /// Range of the sphere's `x` position as fractions of the width (the scene parameter);
    /// `z` is the box's middle. Default `[0.3, 0.7]`.
    pub source_x: [f64; 2],
    /// Seed of the scene parameters. Default 0.
    pub seed: u64,
}

impl Default for PlumeData3d {
    fn default() -> Self {
        Self {
            resolution: 32,
            train_scenes: 6,
            test_scenes: 2,
            frames: 48,
            dt: 1.0,
            buoyancy: 0.05,
            rate: 0.5,
            source_radius: 0.1,
            source_y: 0.15,
            source_x: [0.3, 0.7],
            seed: 0,
        }
    }
}

impl PlumeData3d {
    /// Checks every field (typed [`Error::Config`] naming it).
    pub fn validate(&self) -> Result<()> {
        if self.resolution < 8 {
            return Err(Error::config("resolution", format!("{}; use at least 8 cells per side", self.resolution)));
        }
        if self.train_scenes == 0 || self.test_scenes == 0 {
            return Err(Error::config("train_scenes / test_scenes", "use at least one scene of each"));
        }
        if self.frames < 2 {
            return Err(Error::config("frames", format!("{}; use at least 2", self.frames)));
        }
        let pos = |x: f64| x > 0.0 && x.is_finite();
        if !(pos(self.dt) && pos(self.rate) && self.buoyancy.is_finite()) {
            return Err(Error::config(
                "dt / rate / buoyancy",
                format!(
                    "{} / {} / {}: dt and rate must be positive, buoyancy finite",
                    self.dt, self.rate, self.buoyancy
                ),
            ));
        }
        let [a, b] = self.source_x;
        let r = self.radius_fraction();
        if !(pos(self.source_radius)
            && a - r > 0.0
            && b + r < 1.0
            && a <= b
            && self.source_y - r > 0.0
            && self.source_y + r < 1.0)
        {
            return Err(Error::config(
                "source_x / source_radius / source_y",
                format!("{:?} / {r} / {}: the sphere must lie inside the box", self.source_x, self.source_y),
            ));
        }
        Ok(())
    }

    /// The sphere radius as a fraction of the width: `source_radius`, at least one cell.
    fn radius_fraction(&self) -> f64 {
        self.source_radius.max(1.0 / self.resolution.max(1) as f64)
    }

    /// The scene parameters (sphere `x` fractions) of the training and held-out scenes.
    pub fn parameters(&self) -> (Vec<f64>, Vec<f64>) {
        let draw = |stream: u64, count: usize| {
            let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(self.seed, stream));
            (0..count).map(|_| rng.random_range(self.source_x[0]..=self.source_x[1])).collect()
        };
        (draw(1, self.train_scenes), draw(2, self.test_scenes))
    }

    /// The scene with sphere position `param`.
    pub fn scene(&self, param: f64) -> PlumeScene3d {
        PlumeScene3d { data: self.clone(), param }
    }
}

/// One 3D plume scene: the data settings and its sphere position.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlumeScene3d {
    /// The data set's settings.
    pub data: PlumeData3d,
    /// The sphere's `x` position as a fraction of the width.
    pub param: f64,
}

impl PlumeScene3d {
    /// The grid: `n^3` cells of size 1.
    pub fn grid(&self) -> Result<Grid3d> {
        let n = self.data.resolution;
        Ok(Grid3d::cube(n, n as f64)?)
    }

    /// The solver of this scene (MacCormack transport, Boussinesq buoyancy, the inflow sphere,
    /// inviscid, [`BoxPressure::Auto`]: sparse Cholesky up to 32^3, MIC(0)-CG above).
    pub fn smoke(&self) -> Result<Smoke3d> {
        let g = self.grid()?;
        let d = &self.data;
        let cfg = Smoke3dConfig {
            dt: d.dt,
            nu: 0.0,
            viscosity: Default::default(),
            advection: Advection3d::MacCormack,
            density_advection: Advection3d::MacCormack,
            buoyancy: d.buoyancy,
            source: Some(SphereSource {
                centre: [self.param * g.lx, d.source_y * g.ly, 0.5 * g.lz],
                radius: d.radius_fraction() * g.lx,
                rate: d.rate,
            }),
        };
        Ok(Smoke3d::new(g, cfg, BoxPressure::Auto)?)
    }

    /// The state at rest, no smoke (f32, batch 1).
    pub fn start(&self, smoke: &Smoke3d) -> Result<Smoke3dState> {
        Ok(smoke.rest(1, DType::F32)?)
    }
}

/// One simulated 3D scene, `T` frames, f32.
#[derive(Clone, Debug)]
pub struct Sequence3d {
    /// The sphere position (scene parameter).
    pub param: f64,
    /// MAC velocity `[T, 3, n, n, n]` (`u`, `v`, `w`, as pbdl-grid stores them).
    pub velocity: Tensor,
    /// Smoke density `[T, 1, n, n, n]`.
    pub density: Tensor,
    /// Pressure of the step from frame `t`, `[T, 1, n, n, n]`.
    pub pressure: Tensor,
    /// Wall-clock seconds of the solver steps (split step: unprojected + projection).
    pub solver_seconds: f64,
}

impl Sequence3d {
    /// Frames in the sequence.
    pub fn frames(&self) -> usize {
        self.pressure.dims()[0]
    }
}

/// Training and held-out 3D scenes.
#[derive(Clone, Debug)]
pub struct Dataset3d {
    /// The settings it was generated with.
    pub config: PlumeData3d,
    /// Training scenes.
    pub train: Vec<Sequence3d>,
    /// Held-out scenes.
    pub test: Vec<Sequence3d>,
}

impl Dataset3d {
    /// Mean wall-clock milliseconds of one solver step over all scenes.
    pub fn solver_ms_per_step(&self) -> f64 {
        let all = self.train.iter().chain(&self.test);
        let (secs, steps) = all.fold((0.0, 0usize), |(s, n), q| (s + q.solver_seconds, n + q.frames()));
        1e3 * secs / steps.max(1) as f64
    }
}

/// Simulates one scene for `frames` steps from rest, keeping every step's pressure.
pub fn simulate3d(scene: &PlumeScene3d, frames: usize) -> Result<Sequence3d> {
    let smoke = scene.smoke()?;
    let mut state = scene.start(&smoke)?;
    let (mut vel, mut den, mut pre) = (Vec::with_capacity(frames), Vec::with_capacity(frames), Vec::new());
    let mut seconds = 0.0;
    for _ in 0..frames {
        let t0 = std::time::Instant::now();
        let before = smoke.step_unprojected(&state, None)?;
        let (velocity, pressure) = smoke.project_keep_pressure(&before.velocity)?;
        seconds += t0.elapsed().as_secs_f64();
        vel.push(state.velocity.values().clone());
        den.push(state.density.clone());
        pre.push(pressure);
        state = Smoke3dState { velocity, density: before.density };
    }
    let seq = Sequence3d {
        param: scene.param,
        velocity: Tensor::cat(&vel, 0)?,
        density: Tensor::cat(&den, 0)?,
        pressure: Tensor::cat(&pre, 0)?,
        solver_seconds: seconds,
    };
    let m = seq.pressure.abs()?.sum_all()?.to_scalar::<f32>()?;
    if !m.is_finite() {
        return Err(Error::NonFinite { what: "simulated 3D pressure", detail: format!("scene x = {}", scene.param) });
    }
    Ok(seq)
}

/// Simulates every scene of `cfg` (in parallel over scenes).
pub fn generate3d(cfg: &PlumeData3d) -> Result<Dataset3d> {
    cfg.validate()?;
    let (train_p, test_p) = cfg.parameters();
    let run = |ps: &[f64]| -> Result<Vec<Sequence3d>> {
        ps.par_iter().map(|&p| simulate3d(&cfg.scene(p), cfg.frames)).collect()
    };
    Ok(Dataset3d { config: cfg.clone(), train: run(&train_p)?, test: run(&test_p)? })
}
