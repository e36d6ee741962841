//! Training data: buoyant smoke plumes simulated by pbdl-grid's [`Fluid`] at the high
//! resolution, box-downsampled by the upscaling factor for the low-resolution input.
//!
//! A scene is an `N x N` box (`N = lr_resolution * factor`, `dx = 1`) with no-slip side walls
//! and floor and an open top. Smoke enters through a disc near the floor; every scene draws its
//! disc position and radius, its Boussinesq coefficient and the seed of a noisy inflow (the rate
//! times `1 + noise * xi`, `xi` uniform in `[-1, 1]` per cell and step), so that plumes differ in
//! shape and speed. Each kept frame is `steps_per_frame` solver steps after the previous one;
//! the first `warmup` frames (smoke still near the floor) are dropped.
//!
//! A [`Clip`] holds, per frame `t`:
//! * `hr_density` `[T, 1, N, N]`: the solver's density (cell centres, row 0 at the bottom,
//!   y up), divided by [`SmokeData::density_scale`] so that values are roughly in `[0, 1]`;
//! * `lr_density` `[T, 1, n, n]`: its `factor x factor` box average;
//! * `lr_velocity` `[T, 2, n, n]`: the cell-centred velocity box-averaged the same way, in
//!   low-resolution cells per frame (x component first), the format `upscale` accepts.
//!
//! ```
//! use pbdl_temporal::data::{generate, SmokeData};
//!
//! let cfg = SmokeData { lr_resolution: 8, train_scenes: 1, test_scenes: 1, frames: 3, warmup: 2, ..SmokeData::default() };
//! let data = generate(&cfg)?;
//! assert_eq!(data.train[0].hr_density.dims(), [3, 1, 32, 32]);
//! assert_eq!(data.test[0].lr_velocity.dims(), [3, 2, 8, 8]);
//! # Ok::<(), pbdl_temporal::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::fluid::Advection;
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle, ScalarBoundaries};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The smoke data set. The default is the CPU-size case: 16^2 -> 64^2, 12 training and 4
/// held-out scenes of 48 frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SmokeData {
    /// Low-resolution cells per side (>= 4). Default 16.
    pub lr_resolution: usize,
    /// Upscaling factor (>= 2; the high resolution is `lr_resolution * factor`). Default 4.
    pub factor: usize,
    /// Training scenes (>= 1). Default 12.
    pub train_scenes: usize,
    /// Held-out scenes (>= 1), drawn with another random stream. Default 4.
    pub test_scenes: usize,
    /// Frames kept per scene (>= 1). Default 48.
    pub frames: usize,
    /// Frames simulated and dropped before the first kept one. Default 24.
    pub warmup: usize,
    /// Solver steps per frame (>= 1). Default 1.
    pub steps_per_frame: usize,
    /// Solver time step (> 0, high-resolution cells as length unit). Default 1.
    pub dt: f64,
    /// Range of the Boussinesq coefficient (force `beta rho` upwards). Default `[0.03, 0.08]`.
    pub buoyancy: [f64; 2],
    /// Density added per unit time inside the inflow disc (> 0). Default 0.25.
    pub rate: f64,
    /// Relative inflow noise amplitude in `[0, 1]`. Default 0.5.
    pub noise: f64,
    /// Range of the disc radius as a fraction of the width. Default `[0.05, 0.1]`.
    pub source_radius: [f64; 2],
    /// Height of the disc centre as a fraction of the height. Default 0.15.
    pub source_y: f64,
    /// Range of the disc's `x` position as fractions of the width. Default `[0.3, 0.7]`.
    pub source_x: [f64; 2],
    /// The solver's density is divided by this (> 0) to bring it roughly into `[0, 1]`.
    /// Default 4.
    pub density_scale: f64,
    /// Seed of the scene parameters and the inflow noise. Default 0.
    pub seed: u64,
}

impl Default for SmokeData {
    fn default() -> Self {
        Self {
            lr_resolution: 16,
            factor: 4,
            train_scenes: 12,
            test_scenes: 4,
            frames: 48,
            warmup: 24,
            steps_per_frame: 1,
            dt: 1.0,
            buoyancy: [0.03, 0.08],
            rate: 0.25,
            noise: 0.5,
            source_radius: [0.05, 0.1],
            source_y: 0.15,
            source_x: [0.3, 0.7],
            density_scale: 4.0,
            seed: 0,
        }
    }
}

/// One scene's drawn parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SmokeScene {
    /// Disc centre `x` as a fraction of the width.
    pub source_x: f64,
    /// Disc radius as a fraction of the width.
    pub source_radius: f64,
    /// Boussinesq coefficient.
    pub buoyancy: f64,
    /// Seed of this scene's inflow noise.
    pub noise_seed: u64,
}

impl SmokeData {
    /// The high resolution `lr_resolution * factor`.
    pub fn hr_resolution(&self) -> usize {
        self.lr_resolution * self.factor
    }

    /// Checks every field (typed [`Error::Config`] naming it).
    pub fn validate(&self) -> Result<()> {
        if self.lr_resolution < 4 || self.factor < 2 {
            return Err(Error::config(
                "lr_resolution / factor",
                format!("{} / {}; use at least 4 cells and a factor of at least 2", self.lr_resolution, self.factor),
            ));
        }
        if self.train_scenes == 0 || self.test_scenes == 0 || self.frames == 0 || self.steps_per_frame == 0 {
            return Err(Error::config(
                "train_scenes / test_scenes / frames / steps_per_frame",
                "use at least one of each",
            ));
        }
        let pos = |x: f64| x > 0.0 && x.is_finite();
        let range = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] <= r[1];
        if !(pos(self.dt) && pos(self.rate) && pos(self.density_scale) && range(self.buoyancy)) {
            return Err(Error::config(
                "dt / rate / density_scale / buoyancy",
                format!(
                    "{} / {} / {} / {:?}: the first three must be positive, buoyancy a finite [lo, hi]",
                    self.dt, self.rate, self.density_scale, self.buoyancy
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.noise) {
            return Err(Error::config("noise", format!("{}; use a value in [0, 1]", self.noise)));
        }
        let [a, b] = self.source_x;
        let [r0, r1] = self.source_radius;
        let inside = range(self.source_x)
            && range(self.source_radius)
            && r0 > 0.0
            && a - r1 > 0.0
            && b + r1 < 1.0
            && self.source_y - r1 > 0.0
            && self.source_y + r1 < 1.0;
        if !inside {
            return Err(Error::config(
                "source_x / source_radius / source_y",
                format!(
                    "{:?} / {:?} / {}: every disc must lie inside the box",
                    self.source_x, self.source_radius, self.source_y
                ),
            ));
        }
        Ok(())
    }

    /// The drawn scenes: `(training, held-out)`, from independent streams of [`SmokeData::seed`].
    pub fn scenes(&self) -> (Vec<SmokeScene>, Vec<SmokeScene>) {
        let draw = |stream: u64, count: usize| {
            let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(self.seed, stream));
            (0..count)
                .map(|_| SmokeScene {
                    source_x: rng.random_range(self.source_x[0]..=self.source_x[1]),
                    source_radius: rng.random_range(self.source_radius[0]..=self.source_radius[1]),
                    buoyancy: rng.random_range(self.buoyancy[0]..=self.buoyancy[1]),
                    noise_seed: rng.random(),
                })
                .collect()
        };
        (draw(1, self.train_scenes), draw(2, self.test_scenes))
    }
}

/// One simulated scene: high-resolution density and its low-resolution input, `T` frames, f32.
#[derive(Clone, Debug)]
pub struct Clip {
    /// The scene's parameters.
    pub scene: SmokeScene,
    /// High-resolution density `[T, 1, N, N]` (divided by the density scale).
    pub hr_density: Tensor,
    /// Box-downsampled density `[T, 1, n, n]`.
    pub lr_density: Tensor,
    /// Box-downsampled cell-centred velocity `[T, 2, n, n]` in low-resolution cells per frame.
    pub lr_velocity: Tensor,
}

impl Clip {
    /// Frames in the clip.
    pub fn frames(&self) -> usize {
        self.hr_density.dims()[0]
    }

    /// Frames `start..start + len` of every array.
    pub fn window(&self, start: usize, len: usize) -> Result<Clip> {
        if start + len > self.frames() || len == 0 {
            return Err(Error::config("window", format!("{start}..{} of a {}-frame clip", start + len, self.frames())));
        }
        Ok(Clip {
            scene: self.scene.clone(),
            hr_density: self.hr_density.narrow(0, start, len)?,
            lr_density: self.lr_density.narrow(0, start, len)?,
            lr_velocity: self.lr_velocity.narrow(0, start, len)?,
        })
    }
}

/// Training and held-out clips.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The settings they were generated with.
    pub config: SmokeData,
    /// Training clips.
    pub train: Vec<Clip>,
    /// Held-out clips.
    pub test: Vec<Clip>,
}

/// `factor x factor` box average of `x` `[B, C, H, W]` (H, W multiples of `factor`).
pub fn box_downsample(x: &Tensor, factor: usize) -> Result<Tensor> {
    let d = x.dims();
    if d.len() != 4 || factor == 0 || d[2] % factor != 0 || d[3] % factor != 0 {
        return Err(Error::input(
            "box_downsample input",
            format!("{d:?}: expected [B, C, H, W] with H and W multiples of the factor {factor}"),
        ));
    }
    let (b, c, h, w) = (d[0], d[1], d[2], d[3]);
    let (hl, wl) = (h / factor, w / factor);
    Ok(x.reshape((b, c, hl, factor, wl, factor))?.mean(5)?.mean(3)?)
}

/// Cell-centred velocity `[B, 2, n, n]` of a MAC velocity: each component the mean of its two
/// faces. The unstored faces at `x = 0` and `y = 0` are taken as walls at rest (0), as in these
/// scenes; for other boundaries at the low sides the first column / row is off.
pub fn centred_velocity(u: &MacField) -> Result<Tensor> {
    let v = u.values();
    let shift = |c: usize, axis: usize| -> Result<Tensor> {
        let comp = v.narrow(1, c, 1)?;
        let n = comp.dim(axis)?;
        let zeros = comp.narrow(axis, 0, 1)?.zeros_like()?;
        let lower = Tensor::cat(&[&zeros, &comp.narrow(axis, 0, n - 1)?], axis)?;
        Ok(((comp + lower)? * 0.5)?)
    };
    Ok(Tensor::cat(&[shift(0, 3)?, shift(1, 2)?], 1)?)
}

/// The solver of `scene` on an `N x N` box.
fn fluid(cfg: &SmokeData, scene: &SmokeScene) -> Result<Fluid> {
    let n = cfg.hr_resolution();
    let grid = Grid::square(n, n as f64)?;
    let bc = Boundaries { x_lo: Bc::NoSlip, x_hi: Bc::NoSlip, y_lo: Bc::NoSlip, y_hi: Bc::Outflow };
    let fc = FluidConfig {
        dt: cfg.dt,
        nu: 0.0,
        advection: Advection::MacCormack,
        density_advection: Advection::MacCormack,
        buoyancy: Some(scene.buoyancy),
        inflow: Some(Obstacle::Cylinder {
            center: [scene.source_x * grid.lx, cfg.source_y * grid.ly],
            radius: scene.source_radius * grid.lx,
        }),
        obstacles: vec![],
    };
    Ok(Fluid::new(grid, bc, Some(ScalarBoundaries::neumann()), fc)?)
}

/// Simulates one scene: `warmup + frames` frames from rest, keeping the last `frames`.
pub fn simulate(cfg: &SmokeData, scene: &SmokeScene) -> Result<Clip> {
    cfg.validate()?;
    let n = cfg.hr_resolution();
    let fluid = fluid(cfg, scene)?;
    let mut state: FluidState = fluid.rest(1, DType::F32)?;
    let mut rng = pbdl_core::seed::rng(scene.noise_seed);
    let (mut den, mut vel) = (Vec::with_capacity(cfg.frames), Vec::with_capacity(cfg.frames));
    // Velocity in high-resolution cells per unit time -> low-resolution cells per frame.
    let vel_scale = cfg.dt * cfg.steps_per_frame as f64 / cfg.factor as f64;
    for frame in 0..cfg.warmup + cfg.frames {
        for _ in 0..cfg.steps_per_frame {
            let xi: Vec<f32> =
                (0..n * n).map(|_| (cfg.rate * (1.0 + cfg.noise * rng.random_range(-1.0..=1.0))) as f32).collect();
            let rate = Tensor::from_vec(xi, (1, 1, n, n), &Device::Cpu)?;
            state = fluid.step(&state, Some(&rate))?;
        }
        if frame >= cfg.warmup {
            let d = state
                .density
                .as_ref()
                .ok_or_else(|| Error::NonFinite {
                    what: "plume density",
                    detail: "the solver returned no density".into(),
                })?
                .values();
            den.push((d / cfg.density_scale)?);
            vel.push((centred_velocity(&state.velocity)? * vel_scale)?);
        }
    }
    let hr_density = Tensor::cat(&den, 0)?;
    let hr_velocity = Tensor::cat(&vel, 0)?;
    let m = hr_density.abs()?.max_all()?.to_scalar::<f32>()? + hr_velocity.abs()?.max_all()?.to_scalar::<f32>()?;
    if !m.is_finite() {
        return Err(Error::NonFinite { what: "simulated smoke", detail: format!("scene {scene:?}") });
    }
    Ok(Clip {
        scene: scene.clone(),
        lr_density: box_downsample(&hr_density, cfg.factor)?,
        lr_velocity: box_downsample(&hr_velocity, cfg.factor)?,
        hr_density,
    })
}

/// Simulates every scene of `cfg` (in parallel over scenes).
pub fn generate(cfg: &SmokeData) -> Result<Dataset> {
    cfg.validate()?;
    let (train, test) = cfg.scenes();
    let run = |s: &[SmokeScene]| -> Result<Vec<Clip>> { s.par_iter().map(|sc| simulate(cfg, sc)).collect() };
    Ok(Dataset { config: cfg.clone(), train: run(&train)?, test: run(&test)? })
}
