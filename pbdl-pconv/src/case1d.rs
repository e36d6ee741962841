//! SFBC test case I at CPU size: periodic 1D compressible SPH (pbdl-particles' `periodic_1d_noise`
//! scene), three learning tasks, one network per basis, test errors and rollouts.
//!
//! Tasks (after SFBC's test case I; the targets are ours where noted):
//! * [`Task::Density`]: input `[1]`, target the SPH density `Σ_j m_j W(|x_ij|)` (self included;
//!   Wendland C2 with support = the convolution radius) over `ρ0`: an even function of offsets.
//! * [`Task::DensityGradient`]: input `[1]`, target `Σ_j m_j ∂W/∂x (x_i - x_j)` times `R / ρ0`:
//!   odd. An even-only basis cannot represent it.
//! * [`Task::Update`]: input `[1, v_i]`, target the velocity change over one frame
//!   `v(t + Δ) - v(t)` of the solver (SFBC predicts the position change; the velocity change is
//!   its physics part). Rollouts integrate `v += prediction`, `x += Δ (v_old + v_new) / 2`.
//!
//! Errors are reported as relative MSE (MSE over the test targets' variance, `1 - R²`); targets
//! are standardised by the training set's scale.
//!
//! ```no_run
//! use pbdl_pconv::case1d::{Case1dConfig, Dataset1d, Task, TrainConfig, train_and_evaluate};
//! use pbdl_pconv::Basis;
//!
//! let cfg = Case1dConfig::default();
//! let data = Dataset1d::generate(&cfg)?;
//! let result = train_and_evaluate(&data, Task::DensityGradient, Basis::Fourier, &TrainConfig::default(), 0)?;
//! println!("fourier on the density gradient: relative MSE {:.3e}", result.test_rel_mse);
//! # Ok::<(), pbdl_pconv::Error>(())
//! ```

use crate::basis::Basis;
use crate::error::{Error, Result};
use crate::filter::FilterSpec;
use crate::graph::PairGraph;
use crate::net::{BasisNetwork, NetworkConfig};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use pbdl_particles::kernels::{Kernel, KernelKind};
use pbdl_particles::scene::Scene;
use pbdl_particles::{Domain, Evolve};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::io::Write as _;
use std::sync::Arc;

/// Data of the experiment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Case1dConfig {
    /// Particles per simulation (SFBC: 2048).
    pub particles: usize,
    /// Time between frames in units of `R / c0` (radius over sound speed). SFBC's frames are
    /// 16 ms apart, during which sound crosses 20 radii: no network with a receptive field of a
    /// few radii can predict that step, so we keep the learned step within the field (0.5).
    pub frame_courant: f64,
    /// Frames kept per simulation (after `skip_frames`).
    pub frames: usize,
    /// Frames dropped at the start (the initial transient).
    pub skip_frames: usize,
    /// Seeds of the training simulations.
    pub train_seeds: Vec<u64>,
    /// Seeds of the held-out simulations.
    pub test_seeds: Vec<u64>,
    /// Convolution radius in particle spacings (SFBC: 8).
    pub radius_in_spacings: f64,
}

impl Default for Case1dConfig {
    fn default() -> Self {
        Case1dConfig {
            particles: 2048,
            frame_courant: 0.5,
            frames: 48,
            skip_frames: 2,
            train_seeds: (0..8).collect(),
            test_seeds: (100..102).collect(),
            radius_in_spacings: 8.0,
        }
    }
}

impl Case1dConfig {
    /// A small version for tests: 256 particles, 3 + 1 simulations of 12 frames.
    pub fn small() -> Self {
        Case1dConfig {
            particles: 256,
            frames: 12,
            train_seeds: vec![0, 1, 2],
            test_seeds: vec![100],
            ..Default::default()
        }
    }
}

/// One frame: positions, velocities, and the solver's next frame's velocities.
#[derive(Clone, Debug)]
pub struct Frame1d {
    /// Positions in `[-1, 1)`.
    pub x: Vec<f64>,
    /// Velocities.
    pub v: Vec<f64>,
}

/// Simulations of one split.
#[derive(Clone, Debug)]
pub struct Simulation1d {
    /// The seed the scene was built with.
    pub seed: u64,
    /// Frames `frame_dt` apart.
    pub frames: Vec<Frame1d>,
}

/// Training and test simulations with the geometry they share.
#[derive(Clone, Debug)]
pub struct Dataset1d {
    /// The configuration it was made from.
    pub config: Case1dConfig,
    /// Training simulations.
    pub train: Vec<Simulation1d>,
    /// Held-out simulations.
    pub test: Vec<Simulation1d>,
    /// Particle mass.
    pub mass: f64,
    /// Rest density.
    pub rho0: f64,
    /// Convolution radius.
    pub radius: f64,
    /// Time between frames.
    pub frame_dt: f64,
}

const X_LO: f64 = -1.0;
const X_HI: f64 = 1.0;

impl Dataset1d {
    /// Runs the SPH solver for every seed (the scene `periodic_1d_noise` with `particles`).
    pub fn generate(cfg: &Case1dConfig) -> Result<Self> {
        if cfg.particles < 16
            || cfg.frames < 3
            || !(cfg.frame_courant > 0.0 && cfg.frame_courant.is_finite())
            || cfg.train_seeds.is_empty()
            || cfg.test_seeds.is_empty()
        {
            return Err(Error::Config {
                field: "case1d",
                reason: format!("{cfg:?}; need >= 16 particles, >= 3 frames, frame_courant > 0, train and test seeds"),
            });
        }
        let mut scene = Scene::builtin("periodic_1d_noise")?;
        let p1 = scene.periodic_1d.as_mut().expect("builtin periodic_1d_noise has a [periodic_1d] section");
        p1.n = cfg.particles;
        p1.x_lo = X_LO;
        p1.x_hi = X_HI;
        let rho0 = p1.rho0;
        let spacing = (X_HI - X_LO) / cfg.particles as f64;
        let radius = cfg.radius_in_spacings * spacing;
        let frame_dt = cfg.frame_courant * radius / p1.c0;
        let run = |seed: u64| -> Result<Simulation1d> {
            let mut sim = scene.build(seed, None)?;
            let mut frames = Vec::with_capacity(cfg.frames);
            for f in 0..cfg.skip_frames + cfg.frames {
                if f >= cfg.skip_frames {
                    let fr = sim.frame()?;
                    frames.push(Frame1d { x: fr.positions, v: fr.velocities });
                }
                sim.run_until((f + 1) as f64 * frame_dt)?;
            }
            Ok(Simulation1d { seed, frames })
        };
        let train = cfg.train_seeds.iter().map(|&s| run(s)).collect::<Result<Vec<_>>>()?;
        let test = cfg.test_seeds.iter().map(|&s| run(s)).collect::<Result<Vec<_>>>()?;
        Ok(Dataset1d {
            config: cfg.clone(),
            train,
            test,
            // The density tasks' synthetic particle mass (the solver's own differs by the noise's mean).
            mass: rho0 * spacing,
            rho0,
            radius,
            frame_dt,
        })
    }

    fn domain(&self) -> Domain<f64, 1> {
        Domain::periodic([X_LO], [X_HI])
    }
}

/// What the network learns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Task {
    /// SPH density (even target).
    Density,
    /// SPH density gradient (odd target).
    DensityGradient,
    /// Velocity change over one frame from `[1, v]`.
    Update,
}

impl Task {
    /// Name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Task::Density => "density",
            Task::DensityGradient => "density_gradient",
            Task::Update => "update",
        }
    }
}

/// Training settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Basis functions per axis (SFBC test case I: 6).
    pub terms: usize,
    /// Hidden widths before the one-channel output (none: one convolution layer, as SFBC's
    /// test case I network; the update task uses `[32]` by default through [`TrainConfig::for_task`]).
    pub hidden: Vec<usize>,
    /// Adam updates.
    pub steps: u64,
    /// Frames per update.
    pub batch: usize,
    /// Initial learning rate; halved at 25%, 50% and 75% of the steps.
    pub lr: f64,
    /// Antisymmetric last layer (DMCF) for the update task.
    pub antisymmetric: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig { terms: 6, hidden: Vec::new(), steps: 1000, batch: 4, lr: 1e-2, antisymmetric: false }
    }
}

impl TrainConfig {
    /// The default for a task: one layer for the density tasks, `[32]` hidden for the update.
    pub fn for_task(task: Task) -> Self {
        match task {
            Task::Update => TrainConfig { hidden: vec![32], lr: 3e-3, ..Default::default() },
            _ => TrainConfig::default(),
        }
    }
}

/// One frame ready for the network.
struct Sample {
    graph: Arc<PairGraph>,
    positions: Tensor,
    features: Tensor,
    target: Tensor,
}

/// The standardisation of inputs and targets (from the training set).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Scales {
    /// Velocity scale of the input feature.
    pub velocity: f64,
    /// Target scale.
    pub target: f64,
}

/// Result of one trained network.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CaseResult {
    /// The task.
    pub task: Task,
    /// The basis.
    pub basis: Basis,
    /// Training seed.
    pub seed: u64,
    /// Final training loss (standardised MSE, mean of the last 10% of steps).
    pub train_loss: f64,
    /// Test relative MSE over all held-out frames.
    pub test_rel_mse: f64,
    /// Update task only: mean |x - x_solver| over particles after `rollout_frames` frames,
    /// in particle spacings, averaged over the test simulations.
    pub rollout_error: Option<f64>,
    /// Frames in the rollout.
    pub rollout_frames: usize,
    /// Update task only: largest |Σ m v| drift relative to Σ m |v| over the rollout.
    pub momentum_drift: Option<f64>,
    /// Update task only: the rollout error of keeping every velocity constant (no update), for
    /// scale.
    pub frozen_rollout_error: Option<f64>,
    /// Training wall time in seconds.
    pub train_seconds: f64,
    /// The step training started from (0, or the checkpoint a resumed run continued from).
    pub start_step: u64,
    /// Median wall time of one network evaluation on a test frame (graph offsets included,
    /// graph search excluded), seconds.
    pub forward_seconds: f64,
}

fn sph_targets(data: &Dataset1d, task: Task, x: &[f64], graph: &PairGraph) -> Result<Vec<f64>> {
    // Wendland C2 with support = radius (h = R/2).
    let kernel = Kernel::new(KernelKind::WendlandC2, 1, data.radius / 2.0)?;
    let d = graph
        .offsets_f64::<1>(&x.iter().map(|&v| [v]).collect::<Vec<_>>(), &x.iter().map(|&v| [v]).collect::<Vec<_>>());
    let mut out = vec![0.0; x.len()];
    if task == Task::Density {
        for o in out.iter_mut() {
            *o = data.mass * kernel.w(0.0);
        }
    }
    for p in 0..graph.num_pairs() {
        let i = graph.receivers()[p] as usize;
        let r = d[p].abs();
        out[i] += match task {
            Task::Density => data.mass * kernel.w(r),
            // ∇_i W(x_i - x_j) = W'(r) (x_i - x_j) / r, and x_i - x_j = -d.
            _ => {
                if r > 0.0 {
                    data.mass * kernel.dw_dr(r) * (-d[p]) / r
                } else {
                    0.0
                }
            }
        };
    }
    let scale = match task {
        Task::Density => 1.0 / data.rho0,
        _ => data.radius / data.rho0,
    };
    Ok(out.into_iter().map(|v| v * scale).collect())
}

fn make_sample(
    data: &Dataset1d,
    task: Task,
    frame: &Frame1d,
    next: Option<&Frame1d>,
    scales: &Scales,
) -> Result<Sample> {
    let pts: Vec<[f64; 1]> = frame.x.iter().map(|&v| [v]).collect();
    let graph = Arc::new(PairGraph::build_self(&data.domain(), data.radius, &pts)?);
    let n = frame.x.len();
    let dev = Device::Cpu;
    let positions = Tensor::from_vec(frame.x.iter().map(|&v| v as f32).collect::<Vec<_>>(), (n, 1), &dev)?;
    let (features, target) = match task {
        Task::Density | Task::DensityGradient => {
            (Tensor::ones((n, 1), DType::F32, &dev)?, sph_targets(data, task, &frame.x, &graph)?)
        }
        Task::Update => {
            let t = match next {
                Some(next) => frame.v.iter().zip(&next.v).map(|(a, b)| b - a).collect(),
                None => vec![0.0; n],
            };
            (update_features(&frame.v, scales)?, t)
        }
    };
    let target =
        Tensor::from_vec(target.iter().map(|&v| (v / scales.target) as f32).collect::<Vec<_>>(), (n, 1), &dev)?;
    Ok(Sample { graph, positions, features, target })
}

/// `[1, v / velocity scale]` per particle.
fn update_features(v: &[f64], scales: &Scales) -> Result<Tensor> {
    let mut f = Vec::with_capacity(2 * v.len());
    for &v in v {
        f.push(1.0f32);
        f.push((v / scales.velocity) as f32);
    }
    Ok(Tensor::from_vec(f, (v.len(), 2), &Device::Cpu)?)
}

/// The frames of a split that have a successor (the update task needs one).
fn frame_pairs(sims: &[Simulation1d]) -> impl Iterator<Item = (&Frame1d, &Frame1d)> {
    sims.iter().flat_map(|s| s.frames.windows(2).map(|w| (&w[0], &w[1])))
}

fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for v in values {
        s += v * v;
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

/// Scales from the training split: RMS velocity, RMS target.
pub fn scales(data: &Dataset1d, task: Task) -> Result<Scales> {
    let velocity = rms(data.train.iter().flat_map(|s| s.frames.iter().flat_map(|f| f.v.iter().copied()))).max(1e-12);
    let target =
        match task {
            Task::Update => rms(frame_pairs(&data.train)
                .flat_map(|(a, b)| a.v.iter().zip(&b.v).map(|(x, y)| y - x).collect::<Vec<_>>())),
            _ => {
                let f = &data.train[0].frames[0];
                let pts: Vec<[f64; 1]> = f.x.iter().map(|&v| [v]).collect();
                let g = PairGraph::build_self(&data.domain(), data.radius, &pts)?;
                rms(sph_targets(data, task, &f.x, &g)?.into_iter())
            }
        };
    Ok(Scales { velocity, target: target.max(1e-12) })
}

/// The network of a task and basis.
pub fn network_config(data: &Dataset1d, task: Task, basis: Basis, train: &TrainConfig) -> NetworkConfig {
    let inputs = if task == Task::Update { 2 } else { 1 };
    let mut widths = train.hidden.clone();
    widths.push(1);
    NetworkConfig {
        antisymmetric_last: train.antisymmetric,
        // One-layer networks are a pure convolution (+ bias), as SFBC's test case I.
        dense_branch: widths.len() > 1,
        ..NetworkConfig::new(FilterSpec::sfbc(1, basis, train.terms, data.radius), inputs, widths)
    }
}

/// Trains one network on a task and evaluates it on the held-out simulations.
pub fn train_and_evaluate(
    data: &Dataset1d,
    task: Task,
    basis: Basis,
    train: &TrainConfig,
    seed: u64,
) -> Result<CaseResult> {
    train_and_evaluate_in(data, task, basis, train, seed, None)
}

/// What a run directory was started with; a resumed run must match it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct RunSettings {
    data: Case1dConfig,
    task: Task,
    basis: Basis,
    train: TrainConfig,
    seed: u64,
}

/// [`train_and_evaluate`] with a run directory: checkpoints (weights and Adam's state) every
/// tenth of the steps and `loss.csv` there, a progress bar, and resumption of a stopped run.
/// The directory's `settings.json` records the data, task, basis, training settings and seed;
/// resuming with other ones is an [`Error::Config`] naming `run_dir`.
pub fn train_and_evaluate_in(
    data: &Dataset1d,
    task: Task,
    basis: Basis,
    train: &TrainConfig,
    seed: u64,
    run_dir: Option<&std::path::Path>,
) -> Result<CaseResult> {
    if let Some(dir) = run_dir {
        let settings = RunSettings { data: data.config.clone(), task, basis, train: train.clone(), seed };
        let path = dir.join("settings.json");
        let io = |e: std::io::Error| Error::Io { path: path.display().to_string(), source: e };
        if path.exists() {
            let text = std::fs::read_to_string(&path).map_err(io)?;
            let old: RunSettings = serde_json::from_str(&text).map_err(|e| Error::Config {
                field: "run_dir",
                reason: format!("{}: unreadable settings ({e}); use a new directory", path.display()),
            })?;
            if old != settings {
                return Err(Error::Config {
                    field: "run_dir",
                    reason: format!(
                        "{} was started with other settings ({old:?}); use a new directory or the same settings",
                        dir.display()
                    ),
                });
            }
        } else {
            std::fs::create_dir_all(dir).map_err(io)?;
            let json = serde_json::to_vec_pretty(&settings).expect("settings serialise");
            pbdl_core::io::write_atomic(&path, |w| w.write_all(&json))?;
        }
    }
    let scales = scales(data, task)?;
    let samples: Vec<Sample> = if task == Task::Update {
        frame_pairs(&data.train).map(|(a, b)| make_sample(data, task, a, Some(b), &scales)).collect::<Result<_>>()?
    } else {
        data.train
            .iter()
            .flat_map(|s| s.frames.iter())
            .map(|f| make_sample(data, task, f, None, &scales))
            .collect::<Result<_>>()?
    };
    let varmap = VarMap::new();
    let net = BasisNetwork::new(&varmap, network_config(data, task, basis, train), seed)?;
    let cfg = match run_dir {
        None => LoopConfig { steps: train.steps, progress: false, ..Default::default() },
        Some(dir) => LoopConfig {
            steps: train.steps,
            checkpoint_every: (train.steps / 10).max(1),
            dir: Some(dir.to_path_buf()),
            progress: true,
            ..Default::default()
        },
    };
    let adam = OptimizerConfig::Adam(AdamConfig { lr: train.lr, ..Default::default() });
    let steps = train.steps.max(1) as f64;
    let lr = |s: u64| train.lr * 0.5f64.powi(((s as f64 / steps) * 4.0).floor().min(3.0) as i32);
    let start = std::time::Instant::now();
    let train_loop = TrainLoop::resume(&varmap, cfg)?;
    let start_step = train_loop.start();
    let report = train_loop.run::<Error>(&adam, lr, CheckpointMeta::at, |step| {
        // The frames of an update drawn from the seed and the step (resumable, reproducible).
        let mut rng = pbdl_core::seed::rng(pbdl_core::noise::stream_seed(seed, step));
        let mut loss: Option<Tensor> = None;
        for _ in 0..train.batch {
            let s = &samples[rng.random_range(0..samples.len())];
            let d = s.graph.offsets(&s.positions, &s.positions)?;
            let y = net.forward(&s.graph, &s.features, &d)?;
            let l = (y - &s.target)?.sqr()?.mean_all()?;
            loss = Some(match loss {
                None => l,
                Some(acc) => (acc + l)?,
            });
        }
        Ok((loss.expect("batch >= 1") / train.batch.max(1) as f64)?)
    })?;
    let train_seconds = start.elapsed().as_secs_f64();
    let tail = (report.losses.len() / 10).max(1);
    let train_loss = if report.losses.is_empty() {
        f64::NAN
    } else {
        report.losses.iter().rev().take(tail).map(|l| l.1).sum::<f64>() / tail as f64
    };

    // Test: relative MSE over all held-out frames.
    let (mut se, mut sum, mut sum2, mut count) = (0.0, 0.0, 0.0, 0usize);
    let test_samples: Vec<Sample> = if task == Task::Update {
        frame_pairs(&data.test).map(|(a, b)| make_sample(data, task, a, Some(b), &scales)).collect::<Result<_>>()?
    } else {
        data.test
            .iter()
            .flat_map(|s| s.frames.iter())
            .map(|f| make_sample(data, task, f, None, &scales))
            .collect::<Result<_>>()?
    };
    let mut forward_times = Vec::with_capacity(test_samples.len());
    for s in &test_samples {
        let t0 = std::time::Instant::now();
        let y = net.forward(&s.graph, &s.features, &s.graph.offsets(&s.positions, &s.positions)?)?;
        forward_times.push(t0.elapsed().as_secs_f64());
        let y = y.flatten_all()?.to_vec1::<f32>()?;
        let t = s.target.flatten_all()?.to_vec1::<f32>()?;
        for (a, b) in y.iter().zip(&t) {
            let (a, b) = (*a as f64, *b as f64);
            se += (a - b) * (a - b);
            sum += b;
            sum2 += b * b;
            count += 1;
        }
    }
    forward_times.sort_by(f64::total_cmp);
    let forward_seconds = forward_times[forward_times.len() / 2];
    let n = count.max(1) as f64;
    let var = (sum2 / n - (sum / n).powi(2)).max(1e-30);
    let test_rel_mse = se / n / var;
    if !test_rel_mse.is_finite() {
        return Err(Error::NonFinite {
            what: "test error",
            detail: format!("{} / {} seed {seed}", task.name(), basis.name()),
        });
    }

    let rollout_frames = data.config.frames - 1;
    let (rollout_error, momentum_drift, frozen_rollout_error) = if task == Task::Update {
        let (e, m) = rollout(data, Some(&net), &scales, rollout_frames)?;
        let (frozen, _) = rollout(data, None, &scales, rollout_frames)?;
        (Some(e), Some(m), Some(frozen))
    } else {
        (None, None, None)
    };
    Ok(CaseResult {
        task,
        basis,
        seed,
        train_loss,
        test_rel_mse,
        rollout_error,
        rollout_frames,
        momentum_drift,
        frozen_rollout_error,
        train_seconds,
        start_step,
        forward_seconds,
    })
}

/// Rolls the update network (or, with `None`, constant velocities) out from the first frame of
/// each test simulation; returns the mean position error after `frames` frames (in particle
/// spacings) and the largest relative momentum drift along the way.
fn rollout(data: &Dataset1d, net: Option<&BasisNetwork>, scales: &Scales, frames: usize) -> Result<(f64, f64)> {
    let spacing = (X_HI - X_LO) / data.config.particles as f64;
    let dt = data.frame_dt;
    let (mut err_sum, mut drift_max) = (0.0, 0.0f64);
    for sim in &data.test {
        let mut x = sim.frames[0].x.clone();
        let mut v = sim.frames[0].v.clone();
        let p0: f64 = v.iter().sum::<f64>();
        let scale: f64 = v.iter().map(|a| a.abs()).sum::<f64>().max(1e-300);
        for _ in 0..frames {
            let dv = match net {
                Some(net) => {
                    let s = make_sample(data, Task::Update, &Frame1d { x: x.clone(), v: v.clone() }, None, scales)?;
                    let dv = net.forward(&s.graph, &s.features, &s.graph.offsets(&s.positions, &s.positions)?)?;
                    dv.flatten_all()?.to_vec1::<f32>()?
                }
                None => vec![0.0; x.len()],
            };
            for i in 0..x.len() {
                let v_new = v[i] + dv[i] as f64 * scales.target;
                let mut xn = x[i] + dt * 0.5 * (v[i] + v_new);
                // Wrap into the periodic box.
                let l = X_HI - X_LO;
                xn = X_LO + (xn - X_LO).rem_euclid(l);
                x[i] = xn;
                v[i] = v_new;
            }
            let p: f64 = v.iter().sum();
            drift_max = drift_max.max((p - p0).abs() / scale);
            if x.iter().chain(&v).any(|a| !a.is_finite()) {
                return Err(Error::NonFinite { what: "rollout state", detail: format!("test seed {}", sim.seed) });
            }
        }
        let reference = &sim.frames[frames].x;
        let l = X_HI - X_LO;
        let e: f64 = x
            .iter()
            .zip(reference)
            .map(|(a, b)| {
                let d = (a - b).rem_euclid(l);
                d.min(l - d)
            })
            .sum::<f64>()
            / x.len() as f64;
        err_sum += e / spacing;
    }
    Ok((err_sum / data.test.len() as f64, drift_max))
}
