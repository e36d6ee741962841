//! Training and test data for metric learning, generated with pbdl-grid's solvers.
//!
//! A [`Sequence`] is 11 frames `[11, 1, n, n]` (`f32`): frame 0 is the reference, frame `k`
//! the same simulation with one parameter moved by `k` steps, so the parameter changes linearly
//! over the ten variants (the LSiM data construction). The generators follow the authors' public
//! data-generation scripts (tum-pbs/VOLSIM `data/generation_scripts`, the 3D successor of the LSiM
//! data pipeline) in 2D; `docs/metric-training.md` lists every difference that remains.
//!
//! - [`Kind::AdvectionDiffusion`]: a density moved by a periodic velocity field (semi-Lagrangian
//!   advection, explicit diffusion, 120 steps of `dt = 1` in cell units); the velocity starts as
//!   a sum of sines, gets a time-dependent sine forcing and new random noise at every step.
//! - [`Kind::Burgers`]: the 2D vector Burgers equation (the velocity advects itself, explicit
//!   viscosity, the same forcing and per-step noise); the frame is the x component.
//! - [`Kind::Smoke`]: the buoyant smoke plume of pbdl-grid's `smoke_plume` scene (closed box,
//!   MacCormack, Boussinesq buoyancy, sparse-Cholesky projection), with Gaussian white noise
//!   added to the velocity at every step; the density is the frame.
//! - [`Kind::Shapes`]: no solver; one to five discs or squares moving along straight lines
//!   (hard or smoothed edges, with or without white noise per frame), like the papers' "Sha".
//!
//! The noise is injected into the simulation (into the velocity), so it is transported and
//! mixed by the flow, and every variant (the reference too) draws its own noise at every step:
//! the variants differ randomly besides the systematic change, and by more the longer the
//! simulation runs. Advection-diffusion and Burgers use PhiFlow's `Noise(scale=10,
//! smoothness=1)` spectrum ([`spectral_noise`]). Everything is seeded ([`pbdl_core::seed`]) and
//! cached as `.npz` ([`save_sequences`], [`load_sequences`], [`cached`]).

use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::advect::semi_lagrangian;
use pbdl_grid::scene::Scene;
use pbdl_grid::{Boundaries, CenteredField, Grid, MacField, ScalarBoundaries};
use rand::{rngs::StdRng, Rng};
use std::f64::consts::PI;
use std::path::Path;

/// Frames per sequence: the reference and ten variants.
pub const FRAMES: usize = 11;

/// Simulation steps of advection-diffusion and Burgers (the scripts save step 120).
pub const STEPS: usize = 120;

/// The scripts' grid: their velocities, forcing and noise are in cells per step at 128 cells.
const SCRIPT_RES: f64 = 128.0;

/// Standard deviation of the white noise on the shapes frames (the shapes have value 1).
pub const SHAPES_NOISE: f64 = 0.25;

/// Standard deviation of the white noise added to the smoke velocity faces at every step,
/// relative to the current maximum speed (mantaflow: 0.125 cells per time unit per step).
pub const SMOKE_NOISE: f64 = 0.125;

/// The kind of simulation (one data set per kind in the evaluation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Periodic advection-diffusion of a density by a forced, noisy velocity.
    AdvectionDiffusion,
    /// Periodic 2D vector Burgers with forcing and noise (x velocity frames).
    Burgers,
    /// Buoyant smoke plume in a closed box (density frames).
    Smoke,
    /// Discs and squares moving along lines (no solver).
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

/// The parameter that changes linearly over a sequence. For advection-diffusion and Burgers
/// these are the scripts' modes (`f1`..`f5`, `f7`, `o1`, `o2`, `od`, `noise`), each used with
/// both signs in turn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Param {
    /// Constant part of the initial velocity (`f1`).
    VelocityOffset,
    /// Amplitude of the sine of the initial velocity and forcing with 1 period per domain (`f2`).
    Wave1,
    /// The same, 2 periods (`f3`).
    Wave2,
    /// The same, 4 periods (`f4`).
    Wave4,
    /// The same, 8 periods (`f5`).
    Wave8,
    /// Spatial shift of the forcing (`f7`).
    ForcingShift,
    /// Phase of the velocity sines (`o1`).
    Phase1,
    /// Phase of the other velocity sines (`o2`).
    Phase2,
    /// Phase of the initial density (`od`, advection-diffusion only).
    DensityPhase,
    /// Strength of the noise added at every step.
    Noise,
    /// Horizontal position of the smoke source.
    SourcePosition,
    /// Buoyancy factor of the smoke.
    Buoyancy,
    /// Positions of the moving shapes.
    ShapeMotion,
}

impl Param {
    const ALL: [Param; 13] = [
        Param::VelocityOffset,
        Param::Wave1,
        Param::Wave2,
        Param::Wave4,
        Param::Wave8,
        Param::ForcingShift,
        Param::Phase1,
        Param::Phase2,
        Param::DensityPhase,
        Param::Noise,
        Param::SourcePosition,
        Param::Buoyancy,
        Param::ShapeMotion,
    ];

    /// The parameters varied for `kind` (sequence `i` uses entry `i % len`).
    pub fn for_kind(kind: Kind) -> &'static [Param] {
        use Param::*;
        match kind {
            Kind::AdvectionDiffusion => {
                &[VelocityOffset, Wave1, Wave2, Wave4, Wave8, ForcingShift, Phase1, Phase2, DensityPhase, Noise]
            }
            Kind::Burgers => &[VelocityOffset, Wave1, Wave2, Wave4, Wave8, ForcingShift, Phase1, Phase2, Noise],
            Kind::Smoke => &[SourcePosition, Buoyancy, Noise],
            Kind::Shapes => &[ShapeMotion],
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

/// Generates `count` sequences of `kind` (deterministic in `cfg.seed`).
pub fn generate(kind: Kind, count: usize, cfg: &DataConfig) -> Result<Vec<Sequence>> {
    generate_items(kind, 0..count, cfg)
}

/// Generates sequences `items` of `kind`: sequence `i` depends only on `cfg`, `kind` and `i`, so
/// the data set can be made in pieces (`--shard i/n`, see [`pbdl_core::shard`]) that equal one
/// run of [`generate`].
pub fn generate_items(kind: Kind, items: std::ops::Range<usize>, cfg: &DataConfig) -> Result<Vec<Sequence>> {
    if cfg.resolution < 16 {
        return Err(Error::invalid("train::generate", "resolution", "use at least 16 cells per side"));
    }
    let one = |i: usize| -> Result<Sequence> {
        let mut rng = pbdl_core::seed::rng(
            cfg.seed.wrapping_mul(1_000_003).wrapping_add(kind.code() as u64 * 100_000 + i as u64),
        );
        let params = Param::for_kind(kind);
        let param = params[i % params.len()];
        // Every other pass over the modes changes the parameter the other way (`f1neg`, ...).
        let sign = if (i / params.len()) % 2 == 0 { 1.0 } else { -1.0 };
        let n = cfg.resolution;
        let frames = match kind {
            Kind::AdvectionDiffusion | Kind::Burgers => transport(kind, param, sign, n, &mut rng)?,
            Kind::Smoke => smoke(param, sign, n, &mut rng)?,
            Kind::Shapes => shapes(i % 4, n, &mut rng)?,
        };
        let frames = frames.to_dtype(DType::F32)?;
        crate::check::finite("train::generate", "frames", &frames)?;
        Ok(Sequence { kind, param, frames })
    };
    // Many small operations per sequence: their parallel regions cost more in wake-ups than
    // they gain (2 threads at 64^2: 1.18x slower than one thread), so small sequences run with
    // every region inline (`threads::serial`; the numbers do not change, pinned in
    // tests/data_pin_tests.rs). Running sequences side by side instead was measured and not
    // kept: smoke 0.68x, but advection-diffusion 1.72x and Burgers 1.41x the one-thread time
    // (their large temporary tensors page-fault, and two threads fault into one address space).
    if pbdl_core::threads::parallel(cfg.resolution * cfg.resolution) {
        items.map(one).collect()
    } else {
        pbdl_core::threads::serial(|| items.map(one).collect())
    }
}

/// PhiFlow's `Noise(scale=10, smoothness=1)` on an `n x n` periodic grid, `[batch, channels,
/// n, n]`: complex Gaussian Fourier coefficients with amplitude `1 / kappa^2` (`kappa` in
/// periods per domain) above the scripts' high-pass cut at `kappa = 4.05` (their `k^2 > 0.1`
/// with `k = 10 f` at 128 cells), the real part of the inverse transform, scaled to zero mean and
/// unit standard deviation per batch entry (over channels and cells).
pub fn spectral_noise(batch: usize, channels: usize, n: usize, seed: u64) -> Result<Tensor> {
    let cut2 = 0.1 * (SCRIPT_RES / 10.0) * (SCRIPT_RES / 10.0);
    Ok(pbdl_core::noise::power_law_noise(batch, channels, n, cut2, seed)?)
}

/// Random parameters of the scripts' `generateParams` in 2D: `[axis][component]` matrices.
#[derive(Clone, Copy)]
struct Waves {
    f: [[[f64; 2]; 2]; 6],
    f6: [[f64; 2]; 2],
    o1: [[f64; 2]; 2],
    o2: [[f64; 2]; 2],
    fd: [[f64; 2]; 2],
    od: [[f64; 2]; 2],
    nu: f64,
}

impl Waves {
    fn random(rng: &mut StdRng) -> Self {
        fn m(rng: &mut StdRng, lo: f64, hi: f64) -> [[f64; 2]; 2] {
            std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(lo..hi)))
        }
        let mut f = [
            m(rng, -0.2, 0.2),
            m(rng, -0.2, 0.2),
            m(rng, -0.15, 0.15),
            m(rng, -0.15, 0.15),
            m(rng, -0.1, 0.1),
            m(rng, -50.0, 50.0),
        ];
        let (o1, o2) = (m(rng, 0.0, 100.0), m(rng, 0.0, 100.0));
        let nu = 0.0002 * (1.0 + rng.random_range(0.0..500.0));
        // Smooth switch between a "static" (large initial velocity) and a "forced" case.
        let sf = m(rng, 0.0, 1.0);
        for fi in f.iter_mut().take(5) {
            for a in 0..2 {
                for c in 0..2 {
                    fi[a][c] *= 1.0 + 2.0 * sf[a][c];
                }
            }
        }
        let f6 = sf.map(|r| r.map(|s| (1.0 - s) * 0.1));
        let fd = std::array::from_fn(|_| std::array::from_fn(|_| 1.0 / (1.0 + rng.random_range(0..6) as f64)));
        let od = m(rng, 0.0, 100.0);
        Self { f, f6, o1, o2, fd, od, nu }
    }
}

/// Per-variant steps of the scripts (`vf1`..`vf5`, `vf7`, `vo1`, `vo2`, `vod`, `vnoise`) and the
/// constant noise strength, for the training kinds.
fn steps_of(kind: Kind) -> ([f64; 10], f64) {
    match kind {
        Kind::AdvectionDiffusion => ([0.021, 0.010, 0.020, 0.035, 0.040, 0.300, 0.25, 0.15, 0.10, 0.005], 0.025),
        _ => ([0.014, 0.005, 0.007, 0.015, 0.030, 0.300, 0.06, 0.12, 0.0, 0.01], 0.060),
    }
}

/// `[11, 2, n, n]` of `sum_a f(variant, component, a, d_a)` with `d_0 = x`, `d_1 = y` in
/// [0, 1): the scripts' fields are sums of one function per axis, so two 1D tables suffice.
fn separable(n: usize, f: impl Fn(usize, usize, usize, f64) -> f64) -> Result<Tensor> {
    let table = |a: usize| -> Vec<f64> {
        (0..FRAMES * 2 * n).map(|idx| f(idx / (2 * n), (idx / n) % 2, a, (idx % n) as f64 / n as f64)).collect()
    };
    let gx = Tensor::from_vec(table(0), (FRAMES, 2, 1, n), &Device::Cpu)?;
    let gy = Tensor::from_vec(table(1), (FRAMES, 2, n, 1), &Device::Cpu)?;
    Ok(gx.broadcast_add(&gy)?)
}

/// Periodic 5-point Laplacian (cell units) of `[b, c, n, n]`.
fn laplacian(x: &Tensor) -> Result<Tensor> {
    let mut sum = (x * -4.0)?;
    for dim in [2, 3] {
        sum = ((sum + x.roll(1, dim)?)? + x.roll(-1, dim)?)?;
    }
    Ok(sum)
}

/// Advection-diffusion and Burgers as the scripts' PhiFlow solvers, in cell units (`dt = 1`).
/// The eleven variants run as one batch with the varied parameter at `k` steps; velocities,
/// forcing and noise are scaled by `n / 128` to keep the scripts' motion relative to the domain,
/// the viscosity by `(n / 128)^2`.
fn transport(kind: Kind, param: Param, sign: f64, n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let mut w = Waves::random(rng);
    let (steps, strength) = steps_of(kind);
    let noise_seed: u64 = rng.random();
    let r = n as f64 / SCRIPT_RES;
    let slot = match param {
        Param::VelocityOffset => 0,
        Param::Wave1 => 1,
        Param::Wave2 => 2,
        Param::Wave4 => 3,
        Param::Wave8 => 4,
        Param::ForcingShift => 5,
        Param::Phase1 => 6,
        Param::Phase2 => 7,
        Param::DensityPhase if kind == Kind::AdvectionDiffusion => 8,
        Param::Noise => 9,
        _ => return Err(Error::invalid("train::generate", "param", format!("{param:?} does not apply to {kind:?}"))),
    };
    let step = sign * steps[slot];
    let noise: Vec<f64> = (0..FRAMES).map(|k| if slot == 9 { steps[9] * k as f64 } else { strength }).collect();
    // Parameters of variant `b`.
    let var = |b: usize| -> Waves {
        let mut v = w;
        let add = |m: &mut [[f64; 2]; 2]| m.iter_mut().flatten().for_each(|x| *x += step * b as f64);
        match slot {
            0..=5 => add(&mut v.f[slot]),
            6 => add(&mut v.o1),
            7 => add(&mut v.o2),
            8 => add(&mut v.od),
            _ => {}
        }
        v
    };
    let vars: Vec<Waves> = (0..FRAMES).map(var).collect();
    w.nu *= r * r;
    let two_pi = 2.0 * PI;
    // Initial velocity ("vectorComplex") and density ("scalarSimple", cubed).
    let vel0 = (separable(n, |b, c, a, d| {
        let p = &vars[b];
        p.f[0][a][c]
            + p.f[1][a][c] * (two_pi * d + p.o1[a][c]).sin()
            + p.f[2][a][c] * (2.0 * two_pi * d + p.o2[a][c]).sin()
            + p.f[3][a][c] * (4.0 * two_pi * d + 0.4 * p.o1[a][c]).sin()
            + p.f[4][a][c] * (8.0 * two_pi * d + 0.3 * p.o2[a][c]).sin()
    })? * r)?;
    let dens0 = separable(n, |b, _, a, d| {
        let p = &vars[b];
        (0..2).map(|c| (p.fd[a][c] * d * 12.0 * two_pi + p.od[a][c]).sin()).sum::<f64>()
    })?
    .narrow(1, 0, 1)?;
    let dens0 = (&dens0 * &dens0)?.mul(&dens0)?.contiguous()?;
    let grid = Grid::square(n, n as f64).map_err(grid_err)?;
    let mut vel = MacField::new(vel0, grid, Boundaries::periodic()).map_err(grid_err)?;
    let mut dens = CenteredField::new(dens0, grid, ScalarBoundaries::periodic()).map_err(grid_err)?;
    let strengths = Tensor::from_vec(noise, (FRAMES, 1, 1, 1), &Device::Cpu)?;
    for age in 0..STEPS {
        // Forcing ("vectorForcing") of this step; its time dependence uses the scripts' age / 128.
        let t = age as f64 / SCRIPT_RES;
        let force = (separable(n, |b, c, a, d| {
            let p = &vars[b];
            let d = d + (0.5 * p.f[5][a][c] + p.f[5][a][c] * (t * 3.0).sin()) / SCRIPT_RES;
            (p.f[1][a][c] * (two_pi * d).sin()
                + p.f[2][a][c] * (2.0 * two_pi * d + p.o1[a][c]).sin()
                + p.f[3][a][c] * (4.0 * two_pi * d + p.o2[a][c]).sin()
                + p.f[4][a][c] * (8.0 * two_pi * d + 0.7 * p.o1[a][c]).sin())
                * p.f6[a][c]
        })? * r)?;
        let eta = spectral_noise(FRAMES, 2, n, noise_seed.wrapping_add(age as u64))?.broadcast_mul(&strengths)?;
        if kind == Kind::AdvectionDiffusion {
            let d = semi_lagrangian(&dens, &vel, 1.0).map_err(grid_err)?;
            let d = (d.values() + (laplacian(d.values())? * w.nu)?)?;
            dens = dens.with_values(d).map_err(grid_err)?;
        } else {
            let u = semi_lagrangian(&vel, &vel, 1.0).map_err(grid_err)?;
            let u = (u.values() + (laplacian(u.values())? * (0.1 * w.nu))?)?;
            vel = vel.with_values(u).map_err(grid_err)?;
        }
        let u = ((vel.values() + force)? + (eta * r)?)?;
        vel = vel.with_values(u).map_err(grid_err)?;
    }
    Ok(match kind {
        Kind::AdvectionDiffusion => dens.values().clone(),
        _ => vel.values().narrow(1, 0, 1)?.contiguous()?,
    })
}

/// The smoke plume on an `n x n` box, one run per variant. At every step Gaussian white noise of
/// [`SMOKE_NOISE`] times the current maximum speed is added to every velocity face, drawn anew
/// per variant and step; when the noise is the varied parameter, uniform noise of `0.017 k`
/// (relative) with one seed shared by all variants instead (the mantaflow script's modes).
/// Per variant `k` the source moves by `k / 128` of the box (one cell of the script's 128) or the
/// buoyancy grows by `1.7 k` per cent.
fn smoke(param: Param, sign: f64, n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let x0 = rng.random_range(0.4..0.6);
    let radius = rng.random_range(0.06..0.1);
    let buoy = rng.random_range(0.6..1.4);
    let steps = rng.random_range(50..70);
    let noise_seed: u64 = rng.random();
    let frames = (0..FRAMES)
        .map(|k| {
            let kf = k as f64;
            let (x, b) = match param {
                Param::SourcePosition => (x0 + sign * kf / SCRIPT_RES, buoy),
                Param::Buoyancy => (x0, buoy * (1.0 + 0.017 * kf)),
                _ => (x0, buoy),
            };
            let text = format!(
                "name = \"metric_smoke\"\n[grid]\nnx = {n}\nny = {n}\nlx = 1.0\nly = 1.0\n\
                 [physics]\nkind = \"smoke\"\nnu = 0.0\nbuoyancy = {b}\n\
                 [physics.source]\ncenter = [{x}, 0.15]\nradius = {radius}\nrate = 1.0\n\
                 [time]\nsteps = {steps}\ncfl = 0.5\nspeed = 1.0\nframes = 2\n"
            );
            let mut sim = Scene::from_toml_str(&text, "metric_smoke").and_then(|s| s.build()).map_err(grid_err)?;
            let shared = param == Param::Noise;
            for step in 0..steps {
                sim.step().map_err(grid_err)?;
                let fields = sim.fields().map_err(grid_err)?;
                let Some((_, u)) = fields.into_iter().find(|(name, _)| name == "velocity_mac") else {
                    return Err(Error::invalid("train::generate", "smoke", "the smoke scene has no velocity_mac"));
                };
                let speed = u.abs()?.flatten_all()?.max(0)?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
                if speed == 0.0 || (shared && k == 0) {
                    continue;
                }
                let seed = if shared {
                    noise_seed.wrapping_add(step as u64)
                } else {
                    noise_seed.wrapping_add(1_000_003 * (k as u64 + 1)).wrapping_add(step as u64)
                };
                let eta = if shared {
                    let a = 0.017 * kf * speed;
                    pbdl_core::seed::rand_uniform(u.shape(), -a, a, u.dtype(), &Device::Cpu, seed)?
                } else {
                    pbdl_core::seed::randn(u.shape(), 0.0, SMOKE_NOISE * speed, u.dtype(), &Device::Cpu, seed)?
                };
                sim.set_fields(&[("velocity_mac".to_string(), (&u + eta)?)]).map_err(grid_err)?;
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

/// The scripts' shapes: 1 to 5 discs or squares (even odds) each moving from a random start to a
/// random end at least `0.3 n` away (positions kept a quarter of the path from the walls), radius
/// 10-20 % of the path (squares: half side `0.85 r`), value 1 on 0. `mode` (sequence index mod
/// 4): 0 hard edges, 1 smoothed edges, 2 hard with white noise, 3 smoothed with white noise
/// (standard deviation [`SHAPES_NOISE`], new per frame).
fn shapes(mode: usize, n: usize, rng: &mut StdRng) -> Result<Tensor> {
    let nf = n as f64;
    let count = rng.random_range(1..6);
    let shapes: Vec<(bool, [f64; 2], [f64; 2], f64)> = (0..count)
        .map(|_| loop {
            let mut s = [rng.random_range(0.0..nf), rng.random_range(0.0..nf)];
            let mut e = [rng.random_range(0.0..nf), rng.random_range(0.0..nf)];
            let m = 0.25 * ((e[0] - s[0]).powi(2) + (e[1] - s[1]).powi(2)).sqrt();
            for p in [&mut s, &mut e] {
                p.iter_mut().for_each(|x| *x = x.clamp(m, nf - m));
            }
            let dist = ((e[0] - s[0]).powi(2) + (e[1] - s[1]).powi(2)).sqrt();
            if dist > 0.3 * nf {
                let r = rng.random_range(0.1..0.2) * dist;
                break (rng.random_bool(0.5), s, e, r);
            }
        })
        .collect();
    let smooth = mode % 2 == 1;
    let noisy = mode >= 2;
    let seed: u64 = rng.random();
    let frames = (0..FRAMES)
        .map(|k| {
            let t = k as f64 / (FRAMES - 1) as f64;
            let mut v = vec![0.0; n * n];
            for &(disc, s, e, r) in &shapes {
                let p = [s[0] + t * (e[0] - s[0]), s[1] + t * (e[1] - s[1])];
                for (idx, out) in v.iter_mut().enumerate() {
                    let (x, y) = ((idx % n) as f64 + 0.5 - p[0], (idx / n) as f64 + 0.5 - p[1]);
                    // Signed distance to the boundary (cells), negative inside.
                    let sd = if disc {
                        (x * x + y * y).sqrt() - r
                    } else {
                        let h = 0.85 * r;
                        let (qx, qy) = (x.abs() - h, y.abs() - h);
                        (qx.max(0.0).powi(2) + qy.max(0.0).powi(2)).sqrt() + qx.max(qy).min(0.0)
                    };
                    let val = if smooth {
                        (0.5 - sd / 2.0).clamp(0.0, 1.0)
                    } else if sd <= 0.0 {
                        1.0
                    } else {
                        0.0
                    };
                    *out = f64::max(*out, val);
                }
            }
            let mut f = Tensor::from_vec(v, (1, 1, n, n), &Device::Cpu)?;
            if noisy {
                let eta =
                    pbdl_core::seed::randn((1, 1, n, n), 0.0, SHAPES_NOISE, DType::F64, &Device::Cpu, seed + k as u64)?;
                f = (f + eta)?;
            }
            Ok(f)
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

/// The generator name of sharded metric data (`cargo xtask data metric`): `pbdl-metrics/<kind>`.
pub fn shard_generator(kind: Kind) -> String {
    format!("pbdl-metrics/{}", kind.short())
}

/// Reads a directory of shards written by `cargo xtask data metric --shard i/n` (one sequence
/// per item file, see [`pbdl_core::shard`]), checked (every item once, hashes as recorded), in
/// item order: the same sequences as one [`generate`] call with the same settings.
pub fn load_shard_dir(dir: impl AsRef<Path>) -> Result<Vec<Sequence>> {
    let set = pbdl_core::shard::open_shards(dir.as_ref())?;
    if !set.generator.starts_with("pbdl-metrics/") {
        return Err(Error::invalid(
            "load_shard_dir",
            "dir",
            format!("{} holds `{}` data, not metric sequences", dir.as_ref().display(), set.generator),
        ));
    }
    let mut out = Vec::with_capacity(set.files.len());
    for f in &set.files {
        out.extend(load_sequences(f)?);
    }
    Ok(out)
}

/// Loads `path` if it holds readable sequences, otherwise generates with `make` and writes it
/// there atomically (a cache; see [`pbdl_core::data::cached`]).
pub fn cached(path: impl AsRef<Path>, make: impl FnOnce() -> Result<Vec<Sequence>>) -> Result<Vec<Sequence>> {
    pbdl_core::data::cached(
        path,
        |p: &Path| load_sequences(p),
        make,
        |p: &Path, seqs: &Vec<Sequence>| save_sequences(p, seqs),
    )
}
