//! Training and test data for metric learning, generated with pbdl-grid's solvers.
//!
//! A [`Sequence`] is 11 frames `[11, 1, n, n]` (`f32`): frame 0 is the reference, frame `k`
//! the same simulation with one parameter moved by `k/10` of its full change, so the parameter
//! changes linearly over the ten variants (the LSiM data construction). Kinds:
//!
//! - [`Kind::AdvectionDiffusion`]: a periodic scalar advected by a constant velocity and
//!   diffused ([`pbdl_grid::burgers::ScalarLaw`] without the Burgers term, RK4).
//! - [`Kind::Burgers`]: 2D scalar viscous Burgers `c_t + div(c^2/2 [1,1]) = nu lap c`, periodic.
//! - [`Kind::Smoke`]: the buoyant smoke plume of pbdl-grid's `smoke_plume` scene (closed box,
//!   MacCormack, Boussinesq buoyancy, sparse-Cholesky projection) on a square grid; the density
//!   is the frame.
//! - [`Kind::Shapes`]: no solver; a smooth disc moved and scaled along a line over a smooth
//!   background (like the paper's synthetic "Sha" test set).
//!
//! Varied parameters ([`Param`]): the strength of a smooth perturbation of the initial state,
//! the amplitude of the noise added at every step, the advection direction, the viscosity, and
//! for smoke the source position and the buoyancy. Besides the varied parameter, every variant
//! (the reference too) gets its own smooth random noise at every step ([`NOISE_FLOOR`],
//! [`SMOKE_NOISE_FLOOR`], [`SHAPES_NOISE`]), as the papers' data do: the variants then also
//! differ randomly and ranking them is not trivial for L2. Initial states are random sums of
//! low Fourier modes ([`smooth_field`]), noise is blurred white noise ([`smooth_noise`]);
//! everything is seeded ([`pbdl_core::seed`]) and cached as `.npz` ([`save_sequences`],
//! [`load_sequences`], [`cached`]).

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::burgers::ScalarLaw;
use pbdl_grid::scene::Scene;
use pbdl_grid::time_stepping::ButcherTableau;
use rand::{rngs::StdRng, Rng};
use std::f64::consts::PI;
use std::path::Path;

/// Frames per sequence: the reference and ten variants.
pub const FRAMES: usize = 11;

/// Amplitude of the independent noise every advection-diffusion / Burgers variant gets per unit
/// time (relative to the field's amplitude): enough that L2 does not rank the variants perfectly.
pub const NOISE_FLOOR: f64 = 0.15;

/// Amplitude of the independent smooth noise on every shapes frame (the disc has height 1).
pub const SHAPES_NOISE: f64 = 0.1;

/// The same for the smoke density (the source puts in density 1 per unit time).
pub const SMOKE_NOISE_FLOOR: f64 = 0.05;

/// The kind of simulation (one data set per kind in the evaluation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Periodic advection-diffusion of a scalar.
    AdvectionDiffusion,
    /// Periodic 2D scalar viscous Burgers.
    Burgers,
    /// Buoyant smoke plume in a closed box (density frames).
    Smoke,
    /// A smooth disc moving over a smooth background (no solver).
    Shapes,
}

impl Kind {
    /// Every kind, in table order.
    pub const ALL: [Kind; 4] = [Kind::AdvectionDiffusion, Kind::Burgers, Kind::Smoke, Kind::Shapes];

    /// Short name, as in the paper's tables (`Adv`, `Bur`, `Smo`, `Sha`).
    pub fn short(self) -> &'static str {
        match self {
            Kind::AdvectionDiffusion => "Adv",
            Kind::Burgers => "Bur",
            Kind::Smoke => "Smo",
            Kind::Shapes => "Sha",
        }
    }

    /// Parses [`Kind::short`] (case-insensitive).
    pub fn parse(s: &str) -> Result<Self> {
        Kind::ALL.into_iter().find(|k| k.short().eq_ignore_ascii_case(s)).ok_or_else(|| {
            Error::invalid("Kind::parse", "kind", format!("unknown kind `{s}`; use one of Adv, Bur, Smo, Sha"))
        })
    }

    fn code(self) -> u32 {
        Kind::ALL.iter().position(|&k| k == self).expect("listed") as u32
    }
}

/// The parameter that changes linearly over a sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Param {
    /// Strength of a smooth perturbation added to the initial state.
    InitPerturbation,
    /// Amplitude of the noise added at every step (`floor + t * amplitude`, each variant its own
    /// realisation).
    Noise,
    /// Direction of the advection velocity (advection-diffusion).
    Direction,
    /// Viscosity / diffusivity.
    Viscosity,
    /// Horizontal position of the smoke source.
    SourcePosition,
    /// Buoyancy factor of the smoke.
    Buoyancy,
    /// Position and size of the disc (shapes).
    ShapeMotion,
}

impl Param {
    const ALL: [Param; 7] = [
        Param::InitPerturbation,
        Param::Noise,
        Param::Direction,
        Param::Viscosity,
        Param::SourcePosition,
        Param::Buoyancy,
        Param::ShapeMotion,
    ];

    /// The parameters varied for `kind`.
    pub fn for_kind(kind: Kind) -> &'static [Param] {
        match kind {
            Kind::AdvectionDiffusion => &[Param::InitPerturbation, Param::Noise, Param::Direction],
            Kind::Burgers => &[Param::InitPerturbation, Param::Noise, Param::Viscosity],
            Kind::Smoke => &[Param::SourcePosition, Param::Buoyancy, Param::Noise],
            Kind::Shapes => &[Param::ShapeMotion],
        }
    }

    fn code(self) -> u32 {
        Param::ALL.iter().position(|&p| p == self).expect("listed") as u32
    }
}

/// One 11-frame sequence.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// What simulated it.
    pub kind: Kind,
    /// The parameter that changes linearly from frame 0 to frame 10.
    pub param: Param,
    /// The frames `[11, 1, n, n]`, `f32`, frame 0 the reference.
    pub frames: Tensor,
}

/// Settings of [`generate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DataConfig {
    /// Grid cells per side (frames are `n x n`). Default 64.
    pub resolution: usize,
    /// Seed; sequence `i` of a kind uses `seed`, the kind and `i`.
    pub seed: u64,
}

impl Default for DataConfig {
    fn default() -> Self {
        Self { resolution: 64, seed: 0 }
    }
}

fn grid_err(e: impl std::fmt::Display) -> Error {
    Error::invalid("train::data", "solver", e.to_string())
}

/// A random smooth periodic field on `n x n` cells of the unit square: low Fourier modes
/// (`|k| <= kmax`) with amplitudes decaying like `1 / |k|^2`, scaled to unit standard deviation.
pub fn smooth_field(n: usize, kmax: i32, rng: &mut StdRng) -> Vec<f64> {
    let mut modes = Vec::new();
    for kx in -kmax..=kmax {
        for ky in 0..=kmax {
            let k2 = (kx * kx + ky * ky) as f64;
            if k2 == 0.0 || k2 > (kmax * kmax) as f64 || (ky == 0 && kx < 0) {
                continue;
            }
            let amp = rng.random_range(0.0..1.0) / k2;
            let phase = rng.random_range(0.0..2.0 * PI);
            modes.push((kx as f64, ky as f64, amp, phase));
        }
    }
    let mut v = vec![0.0; n * n];
    for (j, row) in v.chunks_mut(n).enumerate() {
        let y = (j as f64 + 0.5) / n as f64;
        for (i, out) in row.iter_mut().enumerate() {
            let x = (i as f64 + 0.5) / n as f64;
            *out = modes.iter().map(|&(kx, ky, a, p)| a * (2.0 * PI * (kx * x + ky * y) + p).cos()).sum();
        }
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let std = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt().max(1e-12);
    v.iter_mut().for_each(|x| *x = (*x - mean) / std);
    v
}

fn field_tensor(v: &[f64], n: usize) -> Result<Tensor> {
    Ok(Tensor::from_slice(v, (1, 1, n, n), &Device::Cpu)?)
}

/// `t = k / 10` for the 11 frames.
fn fractions() -> [f64; FRAMES] {
    std::array::from_fn(|k| k as f64 / (FRAMES - 1) as f64)
}

/// Generates `count` sequences of `kind` (deterministic in `cfg.seed`).
pub fn generate(kind: Kind, count: usize, cfg: &DataConfig) -> Result<Vec<Sequence>> {
    if cfg.resolution < 16 {
        return Err(Error::invalid("train::generate", "resolution", "use at least 16 cells per side"));
    }
    (0..count)
        .map(|i| {
            let mut rng = pbdl_core::seed::rng(
                cfg.seed.wrapping_mul(1_000_003).wrapping_add(kind.code() as u64 * 100_000 + i as u64),
            );
            let params = Param::for_kind(kind);
            let param = params[i % params.len()];
            let frames = match kind {
                Kind::AdvectionDiffusion | Kind::Burgers => scalar_law(kind, param, cfg.resolution, &mut rng)?,
                Kind::Smoke => smoke(param, cfg.resolution, &mut rng)?,
                Kind::Shapes => shapes(cfg.resolution, &mut rng)?,
            };
            let frames = frames.to_dtype(DType::F32)?;
            crate::check::finite("train::generate", "frames", &frames)?;
            Ok(Sequence { kind, param, frames })
        })
        .collect()
}

/// Smooth random noise `[batch, 1, n, n]`: independent standard normal values per cell and
/// batch entry, blurred periodically with a Gaussian of `sigma` = 1.5 cells, scaled to unit
/// standard deviation.
pub fn smooth_noise(batch: usize, n: usize, seed: u64) -> Result<Tensor> {
    const R: usize = 4;
    let dev = Device::Cpu;
    let white = pbdl_core::seed::randn((batch, 1, n, n), 0.0, 1.0, DType::F64, &dev, seed)?;
    let g: Vec<f64> = (0..2 * R + 1).map(|i| (-((i as f64 - R as f64) / 1.5).powi(2) / 2.0).exp()).collect();
    let k: Vec<f64> = g.iter().flat_map(|a| g.iter().map(move |b| a * b)).collect();
    // Unit variance of the blurred white noise: divide by the kernel's l2 norm.
    let norm = k.iter().map(|v| v * v).sum::<f64>().sqrt();
    let kernel = Tensor::from_vec(k.iter().map(|v| v / norm).collect::<Vec<_>>(), (1, 1, 2 * R + 1, 2 * R + 1), &dev)?;
    let p = pbdl_core::conv::Conv2dParams::default().padding(R).circular();
    Ok(pbdl_core::conv::conv2d(&white, &kernel, None, &p)?)
}

/// Advection-diffusion and Burgers. Every variant gets its own smooth noise at every step
/// (amplitude `floor`, or `floor + t * amp` when the noise is the varied parameter), so that
/// the variants also differ randomly, as in the papers' data; the varied parameter sets the
/// systematic change.
fn scalar_law(kind: Kind, param: Param, n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let h = 1.0 / n as f64;
    let angle = rng.random_range(0.0..2.0 * PI);
    let (speed, burgers, nu, amp) = match kind {
        Kind::AdvectionDiffusion => (rng.random_range(0.5..1.0), 0.0, rng.random_range(2e-3..6e-3), 1.0),
        _ => (0.0, 1.0, rng.random_range(0.012..0.02), rng.random_range(0.6..1.0)),
    };
    let law = |angle: f64, nu: f64| ScalarLaw {
        dx: h,
        dy: h,
        velocity: [speed * angle.cos(), speed * angle.sin()],
        burgers: [burgers; 2],
        nu,
    };
    let c0 = (field_tensor(&smooth_field(n, 4, rng), n)? * amp)?;
    let pert = field_tensor(&smooth_field(n, 6, rng), n)?;
    let t_end = 0.6;
    let tableau = ButcherTableau::rk4();
    // |c| stays near max |c0| (maximum principle) plus perturbation and noise.
    let bound = 4.0 * amp + 3.0;
    let dt_stable = law(angle, nu * 2.0).stable_time_step(bound, n, &tableau) * 0.8;
    let steps = (t_end / dt_stable).ceil() as usize;
    let dt = t_end / steps as f64;
    let frac = fractions();
    let floor = NOISE_FLOOR * amp;
    let noise_amp = rng.random_range(0.3..0.6) * amp;
    let pert_amp = rng.random_range(0.4..0.8) * amp;
    let noise_seed: u64 = rng.random();
    let ts = Tensor::from_slice(&frac, (FRAMES, 1, 1, 1), &Device::Cpu)?;
    let floor_all = (Tensor::ones((FRAMES, 1, 1, 1), DType::F64, &Device::Cpu)? * floor)?;
    // Runs `c` ([b, 1, n, n]) with per-entry noise amplitudes `scale` ([b, 1, 1, 1]).
    let run = |law: ScalarLaw, c: Tensor, scale: &Tensor, seed: u64| -> Result<Tensor> {
        let mut c = c;
        let b = c.dim(0)?;
        for step in 0..steps {
            c = law.step(&c, dt, &tableau).map_err(grid_err)?;
            let eta = smooth_noise(b, n, seed.wrapping_add(step as u64))?;
            c = (c + eta.broadcast_mul(scale)? * dt.sqrt())?;
        }
        Ok(c)
    };
    match param {
        Param::InitPerturbation => {
            let c = c0.broadcast_add(&pert.broadcast_mul(&(&ts * pert_amp)?)?)?;
            run(law(angle, nu), c, &floor_all, noise_seed)
        }
        Param::Noise => {
            let c = c0.repeat((FRAMES, 1, 1, 1))?;
            run(law(angle, nu), c, &((&ts * noise_amp)? + floor)?, noise_seed)
        }
        Param::Direction | Param::Viscosity => {
            let one = floor_all.narrow(0, 0, 1)?;
            let frames = frac
                .iter()
                .enumerate()
                .map(|(k, &t)| {
                    let l =
                        if param == Param::Direction { law(angle + t * 0.5, nu) } else { law(angle, nu * (1.0 + t)) };
                    run(l, c0.clone(), &one, noise_seed.wrapping_add(1_000_003 * k as u64))
                })
                .collect::<Result<Vec<_>>>()?;
            Ok(Tensor::cat(&frames, 0)?)
        }
        _ => Err(Error::invalid("train::generate", "param", format!("{param:?} does not apply to {kind:?}"))),
    }
}

/// The smoke plume on an `n x n` box: one run per variant, each with its own density noise
/// (amplitude `floor`, or growing with `t` when the noise is the varied parameter).
fn smoke(param: Param, n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let x0 = rng.random_range(0.35..0.65);
    let radius = rng.random_range(0.06..0.1);
    let buoy = rng.random_range(0.6..1.4);
    let steps = rng.random_range(50..70);
    let dx_shift = rng.random_range(0.06..0.12) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let noise_amp = rng.random_range(0.5..1.0);
    let noise_seed: u64 = rng.random();
    let frames = fractions()
        .iter()
        .enumerate()
        .map(|(k, &t)| {
            let (x, b) = match param {
                Param::SourcePosition => (x0 + t * dx_shift, buoy),
                Param::Buoyancy => (x0, buoy * (1.0 + 0.5 * t)),
                _ => (x0, buoy),
            };
            let amp = SMOKE_NOISE_FLOOR + if param == Param::Noise { t * noise_amp } else { 0.0 };
            let text = format!(
                "name = \"metric_smoke\"\n[grid]\nnx = {n}\nny = {n}\nlx = 1.0\nly = 1.0\n\
                 [physics]\nkind = \"smoke\"\nnu = 0.0\nbuoyancy = {b}\n\
                 [physics.source]\ncenter = [{x}, 0.15]\nradius = {radius}\nrate = 1.0\n\
                 [time]\nsteps = {steps}\ncfl = 0.5\nspeed = 1.0\nframes = 2\n"
            );
            let mut sim = Scene::from_toml_str(&text, "metric_smoke").and_then(|s| s.build()).map_err(grid_err)?;
            let dt = sim.dt();
            let seed = noise_seed.wrapping_add(1_000_003 * k as u64);
            for step in 0..steps {
                sim.step().map_err(grid_err)?;
                if amp > 0.0 {
                    let rho = sim.fields().map_err(grid_err)?.into_iter().find(|(name, _)| name == "density");
                    if let Some((name, rho)) = rho {
                        let eta = smooth_noise(1, n, seed.wrapping_add(step as u64))?;
                        let add = (eta.to_dtype(rho.dtype())? * (amp * dt.sqrt()))?;
                        let rho = (&rho + add.reshape(rho.shape())?)?;
                        sim.set_fields(&[(name, rho)]).map_err(grid_err)?;
                    }
                }
            }
            let rho = sim
                .state()
                .density()
                .ok_or_else(|| Error::invalid("train::generate", "smoke", "the smoke scene has no density"))?;
            Ok(rho.values().to_dtype(DType::F64)?.reshape((1, 1, n, n))?)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Tensor::cat(&frames, 0)?)
}

/// A smooth disc moved and grown along a line over a smooth random background, plus independent
/// smooth noise of amplitude [`SHAPES_NOISE`] per frame.
fn shapes(n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let bg = smooth_field(n, 3, rng);
    let bg_amp = rng.random_range(0.1..0.4);
    let (cx, cy) = (rng.random_range(0.3..0.7), rng.random_range(0.3..0.7));
    let ang = rng.random_range(0.0..2.0 * PI);
    let shift = rng.random_range(0.1..0.25);
    let r0 = rng.random_range(0.08..0.15);
    let dr = rng.random_range(-0.04..0.04);
    let noise = smooth_noise(FRAMES, n, rng.random())?.squeeze(1)?.to_vec3::<f64>()?;
    let frames = fractions()
        .iter()
        .enumerate()
        .map(|(k, &t)| {
            let (px, py, r) = (cx + t * shift * ang.cos(), cy + t * shift * ang.sin(), r0 + t * dr);
            let mut v = vec![0.0; n * n];
            for (j, row) in v.chunks_mut(n).enumerate() {
                for (i, out) in row.iter_mut().enumerate() {
                    let (x, y) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                    let d = ((x - px).powi(2) + (y - py).powi(2)).sqrt();
                    // A disc with a smooth (tanh) rim a few cells wide.
                    let eta = noise[k][j][i];
                    *out =
                        0.5 * (1.0 - ((d - r) * n as f64 / 2.0).tanh()) + bg_amp * bg[j * n + i] + SHAPES_NOISE * eta;
                }
            }
            field_tensor(&v, n)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Tensor::cat(&frames, 0)?)
}

/// Writes sequences to one `.npz`: `frames` `[S, 11, n, n]` and `meta` `[S, 2]` (kind, parameter
/// codes as `u32`).
pub fn save_sequences(path: impl AsRef<Path>, seqs: &[Sequence]) -> Result<()> {
    if seqs.is_empty() {
        return Err(Error::invalid("save_sequences", "seqs", "nothing to save"));
    }
    let frames = Tensor::stack(&seqs.iter().map(|s| s.frames.squeeze(1)).collect::<candle_core::Result<Vec<_>>>()?, 0)?;
    let meta: Vec<u32> = seqs.iter().flat_map(|s| [s.kind.code(), s.param.code()]).collect();
    let meta = Tensor::from_vec(meta, (seqs.len(), 2), &Device::Cpu)?;
    pbdl_core::io::write_npz(path, &[("frames", frames), ("meta", meta)])?;
    Ok(())
}

/// Reads sequences written by [`save_sequences`].
pub fn load_sequences(path: impl AsRef<Path>) -> Result<Vec<Sequence>> {
    let path = path.as_ref();
    let frames = pbdl_core::io::read_npz_array(path, "frames")?.to_dtype(DType::F32)?;
    let meta = pbdl_core::io::read_npz_array(path, "meta")?.to_dtype(DType::U32)?.to_vec2::<u32>()?;
    if frames.rank() != 4 || frames.dim(1)? != FRAMES || frames.dim(0)? != meta.len() {
        return Err(Error::Shape {
            op: "load_sequences",
            arg: "frames",
            expected: format!("[S, {FRAMES}, n, n] with S = {} (rows of `meta`)", meta.len()),
            got: frames.dims().to_vec(),
        });
    }
    meta.iter()
        .enumerate()
        .map(|(i, m)| {
            let kind = *Kind::ALL.get(m[0] as usize).ok_or_else(|| {
                Error::invalid("load_sequences", "meta", format!("unknown kind code {} in row {i}", m[0]))
            })?;
            let param = *Param::ALL.get(m[1] as usize).ok_or_else(|| {
                Error::invalid("load_sequences", "meta", format!("unknown parameter code {} in row {i}", m[1]))
            })?;
            Ok(Sequence { kind, param, frames: frames.get(i)?.unsqueeze(1)? })
        })
        .collect()
}

/// Loads `path` if it exists, otherwise generates with `make` and writes it there (a cache).
pub fn cached(path: impl AsRef<Path>, make: impl FnOnce() -> Result<Vec<Sequence>>) -> Result<Vec<Sequence>> {
    let path = path.as_ref();
    if path.exists() {
        return load_sequences(path);
    }
    let seqs = make()?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.to_path_buf(), source })?;
    }
    save_sequences(path, &seqs)?;
    Ok(seqs)
}
