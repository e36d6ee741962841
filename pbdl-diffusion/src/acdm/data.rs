//! Our own "Inc" data: flow past a cylinder simulated with [`pbdl_grid::Fluid`].
//!
//! Geometry of the ACDM benchmark's incompressible set: a 4 x 2 channel, a cylinder of diameter
//! `D = 0.6` centred at `(1, 1)`, uniform inflow `U = 0.5` on the left, outflow on the right,
//! no-slip walls top and bottom (PhiFlow's zero extrapolation in the official generator), and
//! `nu = U D / Re = 0.3 / Re`. MacCormack advection, implicit viscosity, masked pressure
//! projection (the official generator: MacCormack, explicit diffusion, CG). A transverse kick
//! behind the cylinder at `t = 0` breaks the symmetry (the official run used a skewed warm-up
//! inflow profile instead); frames are kept after a warm-up.
//!
//! Each frame holds `[vx, vy, p]` at cell centres, averaged over `downsample x downsample` blocks
//! of the simulation grid. The pressure comes out of the projection: on a face between two
//! fluid cells the projection subtracts `dt grad p`, so `p` follows by summing those face
//! differences over the fluid cells (exact up to a constant; the fluid mean is removed).
//! Solid cells are 0 in every field.

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::advect::mac_cormack;
use pbdl_grid::diffuse::ImplicitDiffusion;
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, Grid, MacField, Obstacle};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Domain width.
pub const LX: f64 = 4.0;
/// Domain height.
pub const LY: f64 = 2.0;
/// Cylinder diameter.
pub const DIAMETER: f64 = 0.6;
/// Cylinder centre.
pub const CENTER: [f64; 2] = [1.0, 1.0];
/// Inflow speed.
pub const INFLOW: f64 = 0.5;
/// Physical fields per frame (`vx`, `vy`, `p`); the model adds the Reynolds-number channel.
pub const FIELDS: usize = 3;
/// Channels per frame the models see: `[vx, vy, p, Re]`.
pub const CHANNELS: usize = 4;
/// Names of the model channels.
pub const CHANNEL_NAMES: [&str; CHANNELS] = ["vx", "vy", "p", "Re"];

/// Settings of the cylinder-flow generator.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CylinderConfig {
    /// Simulation cells along x (the domain is 2:1, so `ny = nx / 2`).
    pub sim_nx: usize,
    /// Block size of the average that turns the simulation grid into the data grid.
    pub downsample: usize,
    /// Solver time step.
    pub dt: f64,
    /// Solver steps between stored frames.
    pub frame_stride: usize,
    /// Solver steps before the first stored frame (the wake must shed by then).
    pub warmup_steps: usize,
    /// Stored frames per Reynolds number.
    pub frames: usize,
    /// Transverse kick at `t = 0`, as a fraction of the inflow.
    pub kick: f64,
}

impl Default for CylinderConfig {
    /// 128x64 simulation, 64x32 data, dt 0.05, frames every 2 steps (the official spacing).
    fn default() -> Self {
        Self { sim_nx: 128, downsample: 2, dt: 0.05, frame_stride: 2, warmup_steps: 1200, frames: 400, kick: 0.3 }
    }
}

impl CylinderConfig {
    /// A small, fast configuration for tests: 64x32 simulated and stored, short warm-up.
    pub fn tiny() -> Self {
        Self { sim_nx: 64, downsample: 1, dt: 0.05, frame_stride: 2, warmup_steps: 400, frames: 200, kick: 0.3 }
    }

    /// Data grid `(nx, ny)`.
    pub fn data_size(&self) -> (usize, usize) {
        (self.sim_nx / self.downsample, self.sim_nx / 2 / self.downsample)
    }

    /// Time between stored frames.
    pub fn frame_dt(&self) -> f64 {
        self.dt * self.frame_stride as f64
    }

    /// Checks every setting; the error names the one to change.
    pub fn validate(&self) -> Result<()> {
        let bad =
            |name: &'static str, value: String, hint: &'static str| Err(Error::InvalidConfig { name, value, hint });
        if self.sim_nx < 16 || self.sim_nx % 2 != 0 {
            return bad("sim_nx", self.sim_nx.to_string(), "use an even number of cells >= 16 (the domain is 2:1)");
        }
        if self.downsample == 0 || self.sim_nx % (2 * self.downsample) != 0 {
            return bad("downsample", self.downsample.to_string(), "use a block size >= 1 that divides sim_nx / 2");
        }
        if !(self.dt > 0.0 && self.dt.is_finite()) {
            return bad("dt", self.dt.to_string(), "use a positive finite time step (0.05 as the official data)");
        }
        if self.frame_stride == 0 {
            return bad("frame_stride", "0".into(), "use at least 1 solver step between frames");
        }
        if self.frames < 3 {
            return bad("frames", self.frames.to_string(), "store at least 3 frames (2 conditioning + 1 target)");
        }
        if !self.kick.is_finite() {
            return bad("kick", self.kick.to_string(), "use a finite kick (0.3 of the inflow starts the shedding)");
        }
        Ok(())
    }

    /// A file name that identifies this configuration and the Reynolds numbers.
    pub fn cache_name(&self, re: &[f64]) -> String {
        let res: Vec<String> = re.iter().map(|r| format!("{r:.0}")).collect();
        format!(
            "acdm_cyl_n{}_ds{}_dt{}_s{}_w{}_f{}_k{}_re{}.npz",
            self.sim_nx,
            self.downsample,
            self.dt,
            self.frame_stride,
            self.warmup_steps,
            self.frames,
            self.kick,
            res.join("-")
        )
    }
}

/// One simulated flow: its Reynolds number and its frames.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// Reynolds number `U D / nu`.
    pub re: f64,
    /// Frames `[T, 3, ny, nx]` (`vx`, `vy`, `p`), physical units, `f32`.
    pub frames: Tensor,
}

/// Per-channel mean and standard deviation of `[vx, vy, p, Re]` (training data).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// Means.
    pub mean: [f64; CHANNELS],
    /// Standard deviations (> 0).
    pub std: [f64; CHANNELS],
}

impl Normalization {
    /// Statistics of the given sequences (fields over all frames and cells, `Re` over sequences).
    pub fn from_sequences(seqs: &[Sequence]) -> Result<Self> {
        if seqs.is_empty() {
            return Err(Error::InvalidConfig {
                name: "sequences",
                value: "[]".into(),
                hint: "give at least one training sequence to compute statistics from",
            });
        }
        let mut mean = [0.0; CHANNELS];
        let mut std = [0.0; CHANNELS];
        for c in 0..FIELDS {
            let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
            for q in seqs {
                let x = q.frames.narrow(1, c, 1)?.to_dtype(DType::F64)?;
                s += x.sum_all()?.to_scalar::<f64>()?;
                s2 += x.sqr()?.sum_all()?.to_scalar::<f64>()?;
                n += x.elem_count() as f64;
            }
            mean[c] = s / n;
            std[c] = (s2 / n - mean[c] * mean[c]).max(0.0).sqrt().max(1e-8);
        }
        let re: Vec<f64> = seqs.iter().map(|q| q.re).collect();
        mean[FIELDS] = re.iter().sum::<f64>() / re.len() as f64;
        let var = re.iter().map(|r| (r - mean[FIELDS]).powi(2)).sum::<f64>() / re.len() as f64;
        // One training Re would give std 0: fall back to the mean's scale.
        std[FIELDS] = if var > 0.0 { var.sqrt() } else { mean[FIELDS].abs().max(1.0) };
        Ok(Self { mean, std })
    }

    /// The normalised Reynolds-number channel value.
    pub fn re_value(&self, re: f64) -> f64 {
        (re - self.mean[FIELDS]) / self.std[FIELDS]
    }

    /// Normalised model frames `[T, 4, ny, nx]` of a sequence (the Re channel constant).
    pub fn normalize(&self, seq: &Sequence) -> Result<Tensor> {
        let (t, c, ny, nx) = seq.frames.dims4()?;
        if c != FIELDS {
            return Err(Error::shape("Normalization::normalize frames", [t, FIELDS, ny, nx], [t, c, ny, nx]));
        }
        let mut chans = Vec::with_capacity(CHANNELS);
        for k in 0..FIELDS {
            chans.push(seq.frames.narrow(1, k, 1)?.affine(1.0 / self.std[k], -self.mean[k] / self.std[k])?);
        }
        chans.push(Tensor::full(self.re_value(seq.re) as f32, (t, 1, ny, nx), &Device::Cpu)?);
        Ok(Tensor::cat(&chans, 1)?)
    }

    /// Physical `[.., 3, ny, nx]` fields from normalised `[.., 4 or 3, ny, nx]` frames (any rank
    /// with the channel axis second to the spatial axes).
    pub fn denormalize(&self, x: &Tensor) -> Result<Tensor> {
        let r = x.rank();
        if r < 3 || x.dim(r - 3)? < FIELDS {
            return Err(Error::shape("Normalization::denormalize", "[.., >=3, ny, nx]", x.dims()));
        }
        let mut chans = Vec::with_capacity(FIELDS);
        for k in 0..FIELDS {
            chans.push(x.narrow(r - 3, k, 1)?.affine(self.std[k], self.mean[k])?);
        }
        Ok(Tensor::cat(&chans, r - 3)?)
    }
}

/// A set of simulated sequences with the statistics of its training part.
#[derive(Clone, Debug)]
pub struct CylinderDataset {
    /// Generator settings.
    pub config: CylinderConfig,
    /// One sequence per Reynolds number, in the order asked for.
    pub sequences: Vec<Sequence>,
    /// Wall-clock seconds the simulation took (0 when read from the cache).
    pub seconds: f64,
}

impl CylinderDataset {
    /// The sequence of Reynolds number `re`, if present.
    pub fn get(&self, re: f64) -> Option<&Sequence> {
        self.sequences.iter().find(|s| (s.re - re).abs() < 1e-9)
    }

    /// Writes the dataset as `.npz` (`re`: `[K]`, `frames_k`: `[T, 3, ny, nx]`), atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let re = Tensor::new(self.sequences.iter().map(|s| s.re).collect::<Vec<f64>>(), &Device::Cpu)?;
        let mut arrays: Vec<(String, Tensor)> = vec![("re".into(), re)];
        for (k, s) in self.sequences.iter().enumerate() {
            arrays.push((format!("frames_{k}"), s.frames.clone()));
        }
        pbdl_core::io::write_npz(path, &arrays)?;
        Ok(())
    }

    /// Reads a dataset written by [`CylinderDataset::save`].
    pub fn load(path: &Path, config: CylinderConfig) -> Result<Self> {
        let re = pbdl_core::io::read_npz_array(path, "re")?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
        let mut sequences = Vec::with_capacity(re.len());
        for (k, &r) in re.iter().enumerate() {
            let frames = pbdl_core::io::read_npz_array(path, &format!("frames_{k}"))?.to_dtype(DType::F32)?;
            sequences.push(Sequence { re: r, frames });
        }
        Ok(Self { config, sequences, seconds: 0.0 })
    }

    /// Reads a directory of shards written by `cargo xtask data acdm --shard i/n` (one Reynolds
    /// number per item, see [`pbdl_core::shard`]), checked, in item order; the config is the one
    /// the manifests record.
    pub fn load_shards(dir: &Path) -> Result<Self> {
        let set = pbdl_core::shard::open_shards(dir)?;
        let config: CylinderConfig =
            serde_json::from_value(set.config["cylinder"].clone()).map_err(|e| Error::InvalidConfig {
                name: "shards",
                value: e.to_string(),
                hint: "not a directory of ACDM cylinder shards",
            })?;
        let mut sequences = Vec::with_capacity(set.files.len());
        for f in &set.files {
            sequences.extend(Self::load(f, config.clone())?.sequences);
        }
        Ok(Self { config, sequences, seconds: 0.0 })
    }

    /// Reads `dir/<config.cache_name(re)>` when it exists, otherwise simulates and writes it.
    pub fn cached(dir: &Path, config: &CylinderConfig, re: &[f64]) -> Result<Self> {
        let path = dir.join(config.cache_name(re));
        if path.exists() {
            if let Ok(d) = Self::load(&path, config.clone()) {
                if d.sequences.len() == re.len() {
                    return Ok(d);
                }
            }
        }
        let d = generate(config, re)?;
        std::fs::create_dir_all(dir).map_err(|e| pbdl_core::Error::io(dir, e))?;
        d.save(&path)?;
        Ok(d)
    }
}

/// The default cache directory, `target/pbdl/acdm` of the workspace.
pub fn default_cache_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("target").join("pbdl").join("acdm")
}

/// Simulates one sequence per Reynolds number (in parallel over Re with rayon).
pub fn generate(config: &CylinderConfig, re: &[f64]) -> Result<CylinderDataset> {
    config.validate()?;
    for &r in re {
        if !(r > 0.0 && r.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "re",
                value: r.to_string(),
                hint: "Reynolds numbers must be positive and finite (the official range is 100..1000)",
            });
        }
    }
    let t = std::time::Instant::now();
    use rayon::prelude::*;
    let sequences = re.par_iter().map(|&r| simulate(config, r)).collect::<Result<Vec<_>>>()?;
    Ok(CylinderDataset { config: config.clone(), sequences, seconds: t.elapsed().as_secs_f64() })
}

/// Simulates the flow at one Reynolds number.
pub fn simulate(config: &CylinderConfig, re: f64) -> Result<Sequence> {
    config.validate()?;
    let (nx, ny) = (config.sim_nx, config.sim_nx / 2);
    let grid = Grid::new(nx, ny, LX, LY)?;
    let bc = Boundaries::new(Bc::Inflow { velocity: [INFLOW, 0.0] }, Bc::Outflow, Bc::NoSlip, Bc::NoSlip)?;
    let nu = INFLOW * DIAMETER / re;
    let fluid_config = FluidConfig {
        dt: config.dt,
        nu,
        advection: pbdl_grid::fluid::Advection::MacCormack,
        density_advection: pbdl_grid::fluid::Advection::MacCormack,
        buoyancy: None,
        inflow: None,
        obstacles: vec![Obstacle::Cylinder { center: CENTER, radius: 0.5 * DIAMETER }],
    };
    let fluid = Fluid::new(grid, bc, None, fluid_config)?;
    let fluid_mask = fluid.mask().ok_or_else(|| Error::InvalidConfig {
        name: "sim_nx",
        value: nx.to_string(),
        hint: "the grid is too coarse to resolve the cylinder",
    })?;
    let solid: Vec<bool> =
        (0..ny).flat_map(|j| (0..nx).map(move |i| (j, i))).map(|(j, i)| fluid_mask.is_solid(j, i)).collect();
    let (d, kick) = (DIAMETER, config.kick * INFLOW);
    let u0 = MacField::from_fn(grid, bc, DType::F32, |x, y| {
        let behind = (x - CENTER[0] - 1.5 * d).abs() < 0.5 * d && (y - CENTER[1] - 0.5 * d).abs() < 0.5 * d;
        [INFLOW, if behind { kick } else { 0.0 }]
    })?;
    let mut u = fluid.project(&u0)?;
    let visc = ImplicitDiffusion::new(&u, nu, config.dt)?;
    let total = config.warmup_steps + config.frames * config.frame_stride;
    let mut frames = Vec::with_capacity(config.frames);
    for step in 1..=total {
        // Fluid::step's order for this config (advect, implicit viscosity, project), spelled
        // out to keep the pre-projection velocity for the pressure.
        let adv = mac_cormack(&u, &u, config.dt)?;
        let v = visc.apply(&adv)?;
        let next = fluid.project(&v)?;
        let keep = step > config.warmup_steps && (step - config.warmup_steps) % config.frame_stride == 0;
        if keep {
            let frame = centred_frame(&v, &next, &solid, grid, config.dt)?;
            frames.push(downsample(&frame, ny, nx, config.downsample)?);
        }
        u = next;
    }
    let speed = u.max_abs()?;
    if !speed.is_finite() {
        return Err(Error::NonFinite { what: format!("cylinder flow at Re {re}"), step: total as u64 });
    }
    let frames = Tensor::stack(&frames, 0)?;
    Ok(Sequence { re, frames })
}

/// `[3, ny, nx]` (`vx`, `vy`, `p`) at cell centres from the pre-projection velocity `v` and the
/// projected one `u`.
fn centred_frame(v: &MacField, u: &MacField, solid: &[bool], grid: Grid, dt: f64) -> Result<Tensor> {
    let (nx, ny) = (grid.nx, grid.ny);
    let n = nx * ny;
    let uv = u.values().flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    let vv = v.values().flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    let mut out = vec![0.0f64; 3 * n];
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            if solid[k] {
                continue;
            }
            // The faces x = 0 (inflow) and y = 0 (wall) are not stored.
            let west = if i == 0 { INFLOW } else { uv[k - 1] };
            let south = if j == 0 { 0.0 } else { uv[n + k - nx] };
            out[k] = 0.5 * (west + uv[k]);
            out[n + k] = 0.5 * (south + uv[n + k]);
        }
    }
    // Pressure: p[east] - p[here] = dx * (v - u) / dt on faces between fluid cells; a flood fill
    // from every not-yet-visited fluid cell (one component in practice).
    let (dx, dy) = (grid.dx(), grid.dy());
    let mut p = vec![f64::NAN; n];
    let mut stack = Vec::new();
    for start in 0..n {
        if solid[start] || !p[start].is_nan() {
            continue;
        }
        p[start] = 0.0;
        stack.push(start);
        while let Some(k) = stack.pop() {
            let (j, i) = (k / nx, k % nx);
            let pk = p[k];
            let mut next = [None; 4];
            if i + 1 < nx {
                next[0] = Some((k + 1, pk + dx * (vv[k] - uv[k]) / dt));
            }
            if i > 0 {
                next[1] = Some((k - 1, pk - dx * (vv[k - 1] - uv[k - 1]) / dt));
            }
            if j + 1 < ny {
                next[2] = Some((k + nx, pk + dy * (vv[n + k] - uv[n + k]) / dt));
            }
            if j > 0 {
                next[3] = Some((k - nx, pk - dy * (vv[n + k - nx] - uv[n + k - nx]) / dt));
            }
            for (m, val) in next.into_iter().flatten() {
                if !solid[m] && p[m].is_nan() {
                    p[m] = val;
                    stack.push(m);
                }
            }
        }
    }
    let fluid: Vec<f64> = p.iter().cloned().filter(|x| !x.is_nan()).collect();
    let mean = fluid.iter().sum::<f64>() / fluid.len().max(1) as f64;
    for (k, x) in p.iter().enumerate() {
        out[2 * n + k] = if x.is_nan() { 0.0 } else { x - mean };
    }
    Ok(Tensor::from_vec(out, (3, ny, nx), &Device::Cpu)?.to_dtype(DType::F32)?)
}

/// Block average `[c, ny, nx] -> [c, ny / f, nx / f]`.
fn downsample(x: &Tensor, ny: usize, nx: usize, f: usize) -> Result<Tensor> {
    if f == 1 {
        return Ok(x.clone());
    }
    let c = x.dim(0)?;
    Ok(x.reshape((c, ny / f, f, nx / f, f))?.mean(4)?.mean(2)?)
}

/// Index `(j, i)` of the data cell nearest to the point `(x, y)`.
pub fn cell_of(config: &CylinderConfig, x: f64, y: f64) -> (usize, usize) {
    let (nx, ny) = config.data_size();
    let i = ((x / LX * nx as f64 - 0.5).round().max(0.0) as usize).min(nx - 1);
    let j = ((y / LY * ny as f64 - 0.5).round().max(0.0) as usize).min(ny - 1);
    (j, i)
}

/// Where the shedding probe sits: on the wake axis, 1.5 diameters behind the cylinder centre.
///
/// The digest's `(0.25 W, 0.5 H)` is the cylinder centre itself in this geometry (`x = 1`,
/// `y = 1`), where every field is 0; the probe therefore moves downstream into the wake.
pub const PROBE: [f64; 2] = [CENTER[0] + 1.5 * DIAMETER, CENTER[1]];

/// Training Reynolds numbers of the CPU-sized benchmark (interior of the official 100..1000).
pub const TRAIN_RE: [f64; 10] = [150.0, 200.0, 250.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0, 900.0];
/// Held-out Reynolds numbers (extrapolation on both sides, as the official test sets).
pub const TEST_RE: [f64; 2] = [100.0, 950.0];

/// The generator settings of the training data: the default (400 frames per Re).
pub fn train_config() -> CylinderConfig {
    CylinderConfig::default()
}

/// The generator settings of the held-out ground truth: 1002 frames (2 to start + 1000 steps).
pub fn test_config() -> CylinderConfig {
    CylinderConfig { frames: 1002, ..CylinderConfig::default() }
}
