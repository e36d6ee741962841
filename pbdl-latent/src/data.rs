//! Training data: buoyant smoke plumes from pbdl-grid's [`Fluid`] stepper, one scene per inflow
//! position, with the pressure of every step's solve kept.
//!
//! A scene is an `n x n` box (`dx = 1`) with no-slip side walls and floor and an open top
//! (outflow): smoke enters through a disc near the floor at a constant rate, rises under
//! Boussinesq buoyancy and leaves through the top. The scene parameter is the disc's `x`
//! position (a fraction of the width), drawn uniformly in [`PlumeData::source_x`]; it is the
//! supervised parameter of latent space subdivision. Frame `t` of a [`Sequence`] holds the state
//! `s_t` (velocity, density) and the pressure `p_t` of the solve of the step `s_t -> s_{t+1}`
//! (in the solve's units: `u <- u - G p`).
//!
//! ```
//! use pbdl_latent::data::{generate, PlumeData};
//!
//! let cfg = PlumeData { resolution: 16, train_scenes: 2, test_scenes: 1, frames: 6, ..PlumeData::default() };
//! let data = generate(&cfg)?;
//! assert_eq!(data.train.len(), 2);
//! assert_eq!(data.test[0].pressure.dims(), [6, 1, 16, 16]);
//! # Ok::<(), pbdl_latent::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::fluid::Advection;
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, FluidState, Grid, Obstacle, ScalarBoundaries};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The smoke-plume data set: resolution, number of scenes and frames, physics. The default is
/// the CPU-size 2D case: 32^2 cells, 12 training and 4 held-out scenes of 160 frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlumeData {
    /// Cells per side (the box is `resolution x resolution`, `dx = 1`; >= 8). Default 32.
    pub resolution: usize,
    /// Training scenes (>= 1). Default 12.
    pub train_scenes: usize,
    /// Held-out scenes (>= 1), drawn from the same parameter range with another stream.
    /// Default 4.
    pub test_scenes: usize,
    /// Frames (solver steps) per scene (>= 2). Default 160.
    pub frames: usize,
    /// Time step (> 0). Default 1.
    pub dt: f64,
    /// Boussinesq coefficient (force `beta rho` upwards). Default 0.05.
    pub buoyancy: f64,
    /// Density added per unit time inside the inflow disc (> 0). Default 0.5.
    pub rate: f64,
    /// Inflow disc radius as a fraction of the width. Default 0.08.
    pub source_radius: f64,
    /// Height of the disc centre as a fraction of the height. Default 0.15.
    pub source_y: f64,
    /// Range of the disc's `x` position as fractions of the width (the scene parameter).
    /// Default `[0.3, 0.7]`.
    pub source_x: [f64; 2],
    /// Kinematic viscosity (>= 0). Default 0.
    pub nu: f64,
    /// Seed of the scene parameters. Default 0.
    pub seed: u64,
}

impl Default for PlumeData {
    fn default() -> Self {
        Self {
            resolution: 32,
            train_scenes: 12,
            test_scenes: 4,
            frames: 160,
            dt: 1.0,
            buoyancy: 0.05,
            rate: 0.5,
            source_radius: 0.08,
            source_y: 0.15,
            source_x: [0.3, 0.7],
            nu: 0.0,
            seed: 0,
        }
    }
}

impl PlumeData {
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
        let valid =
            pos(self.dt) && pos(self.rate) && self.buoyancy.is_finite() && self.nu >= 0.0 && self.nu.is_finite();
        if !valid {
            return Err(Error::config(
                "dt / rate / buoyancy / nu",
                format!(
                    "{} / {} / {} / {}: dt and rate must be positive, buoyancy finite, nu >= 0",
                    self.dt, self.rate, self.buoyancy, self.nu
                ),
            ));
        }
        let [a, b] = self.source_x;
        let r = self.source_radius;
        if !(pos(r) && a - r > 0.0 && b + r < 1.0 && a <= b && self.source_y - r > 0.0 && self.source_y + r < 1.0) {
            return Err(Error::config(
                "source_x / source_radius / source_y",
                format!("{:?} / {r} / {}: the disc must lie inside the box", self.source_x, self.source_y),
            ));
        }
        Ok(())
    }

    /// The scene parameters (disc `x` fractions) of the training and held-out scenes.
    pub fn parameters(&self) -> (Vec<f64>, Vec<f64>) {
        let draw = |stream: u64, count: usize| {
            let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(self.seed, stream));
            (0..count).map(|_| rng.random_range(self.source_x[0]..=self.source_x[1])).collect()
        };
        (draw(1, self.train_scenes), draw(2, self.test_scenes))
    }

    /// The scene with disc position `param`.
    pub fn scene(&self, param: f64) -> PlumeScene {
        PlumeScene { data: self.clone(), param }
    }
}

/// One plume scene: the data settings and its disc position.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlumeScene {
    /// The data set's settings.
    pub data: PlumeData,
    /// The disc's `x` position as a fraction of the width.
    pub param: f64,
}

impl PlumeScene {
    /// The grid: `n x n` cells of size 1.
    pub fn grid(&self) -> Result<Grid> {
        let n = self.data.resolution;
        Ok(Grid::square(n, n as f64)?)
    }

    /// Walls and floor no-slip, top open.
    pub fn boundaries() -> Boundaries {
        Boundaries { x_lo: Bc::NoSlip, x_hi: Bc::NoSlip, y_lo: Bc::NoSlip, y_hi: Bc::Outflow }
    }

    /// The solver of this scene (MacCormack transport, Boussinesq buoyancy, the inflow disc).
    pub fn fluid(&self) -> Result<Fluid> {
        let g = self.grid()?;
        let d = &self.data;
        let cfg = FluidConfig {
            dt: d.dt,
            nu: d.nu,
            advection: Advection::MacCormack,
            density_advection: Advection::MacCormack,
            buoyancy: Some(d.buoyancy),
            inflow: Some(Obstacle::Cylinder {
                center: [self.param * g.lx, d.source_y * g.ly],
                radius: d.source_radius * g.lx,
            }),
            obstacles: vec![],
        };
        Ok(Fluid::new(g, Self::boundaries(), Some(ScalarBoundaries::neumann()), cfg)?)
    }

    /// The inflow rate as the solver takes it.
    pub fn rate(&self) -> Result<Tensor> {
        Ok(Tensor::new(&[self.data.rate as f32], &Device::Cpu)?)
    }

    /// The state at rest, no smoke (f32, batch 1).
    pub fn start(&self, fluid: &Fluid) -> Result<FluidState> {
        Ok(fluid.rest(1, DType::F32)?)
    }
}

/// One simulated scene, `T` frames, f32.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// The disc position (scene parameter).
    pub param: f64,
    /// MAC velocity `[T, 2, n, n]` (`u` then `v`, as pbdl-grid stores them).
    pub velocity: Tensor,
    /// Smoke density `[T, 1, n, n]`.
    pub density: Tensor,
    /// Pressure of the step from frame `t` `[T, 1, n, n]`.
    pub pressure: Tensor,
}

impl Sequence {
    /// Frames in the sequence.
    pub fn frames(&self) -> usize {
        self.pressure.dims()[0]
    }
}

/// Training and held-out scenes.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The settings it was generated with.
    pub config: PlumeData,
    /// Training scenes.
    pub train: Vec<Sequence>,
    /// Held-out scenes.
    pub test: Vec<Sequence>,
}

/// Simulates one scene for `frames` steps from rest, keeping every step's pressure.
pub fn simulate(scene: &PlumeScene, frames: usize) -> Result<Sequence> {
    let fluid = scene.fluid()?;
    let rate = scene.rate()?;
    let mut state = scene.start(&fluid)?;
    let (mut vel, mut den, mut pre) = (Vec::with_capacity(frames), Vec::with_capacity(frames), Vec::new());
    for _ in 0..frames {
        let before = fluid.step_unprojected(&state, Some(&rate))?;
        let (velocity, pressure) = fluid.project_keep_pressure(&before.velocity)?;
        vel.push(state.velocity.values().clone());
        den.push(state.density.as_ref().expect("the plume has a density").values().clone());
        pre.push(pressure.values().clone());
        state = FluidState { velocity, density: before.density };
    }
    let seq = Sequence {
        param: scene.param,
        velocity: Tensor::cat(&vel, 0)?,
        density: Tensor::cat(&den, 0)?,
        pressure: Tensor::cat(&pre, 0)?,
    };
    let m = seq.pressure.abs()?.max_all()?.to_scalar::<f32>()?;
    if !m.is_finite() {
        return Err(Error::NonFinite { what: "simulated pressure", detail: format!("scene x = {}", scene.param) });
    }
    Ok(seq)
}

/// Simulates every scene of `cfg` (in parallel over scenes).
pub fn generate(cfg: &PlumeData) -> Result<Dataset> {
    cfg.validate()?;
    let (train_p, test_p) = cfg.parameters();
    let run =
        |ps: &[f64]| -> Result<Vec<Sequence>> { ps.par_iter().map(|&p| simulate(&cfg.scene(p), cfg.frames)).collect() };
    Ok(Dataset { config: cfg.clone(), train: run(&train_p)?, test: run(&test_p)? })
}
