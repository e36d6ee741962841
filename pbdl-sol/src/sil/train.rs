//! Training the corrector: PRE, NON and SOL-m.
//!
//! * **SOL-m**: from a downsampled reference state `s~_t = T r_t`, `m` corrected source steps
//!   `s~_{t+i} = P_s(s~_{t+i-1}) + C(P_s(s~_{t+i-1}), Re)`, loss
//!   `(1/m) sum_i 1/2 mean(((s~_{t+i} - T r_{t+i}) / sigma)^2)`, backpropagated through the
//!   `m` solver steps (advection, implicit viscosity, masked pressure solve: pbdl-grid's
//!   adjoints).
//! * **NON** (non-interacting): the source solver is run once from `T r_0` without any
//!   correction, giving the source trajectory `s^src_t`
//!   ([`ReferenceSim::source`](super::data::ReferenceSim::source)); the network is trained on
//!   pairs `(P_s(s^src_t), T r_{t+1})`, i.e. on states that never saw a correction and drift
//!   away from the reference (the train/test mismatch of the paper).
//! * **PRE**: supervised on pairs `(P_s(T r_t), T r_{t+1})` computed once before training
//!   (one source step from the downsampled reference); the loss has no solver in it.
//!
//! PRE and NON share the loss `1/2 mean(((x + C(x) - T r_{t+1}) / sigma)^2)` and the batch
//! sampling; they differ in the inputs `x`.
//!
//! Every run is seeded (initial weights and batch sampling); Adam, learning rate 1e-4 by
//! default (the paper's).
//!
//! [`train_resumable`] is the same training in a run directory (pbdl-core's
//! [`TrainLoop`]): `loss.csv` and atomic checkpoints, each one commit of the weights and Adam's
//! moments and update count, every [`TrainConfig::checkpoint_every`] updates and after the
//! last. A call on a directory with checkpoints resumes from the newest and ends as the
//! uninterrupted run, bit for bit (the batches of the steps before the checkpoint are replayed
//! from the seed; none depends on the network); a directory of other settings or data is
//! refused ([`Error::ResumeMismatch`]). [`load_trained`] reads a run directory's corrector back.

use super::data::ReferenceSet;
use super::net::{scalar_sigma, Corrector, CorrectorConfig, Normalisation};
use super::scene::{SilScene, SourceSolver};
use crate::control::resume::{canonical, check_resume, digest, layout, logged_losses};
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_core::io::{latest_checkpoint, load_varmap, read_checkpoint_info, CheckpointMeta};
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::rngs::StdRng;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Which learning method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Variant {
    /// Supervised on one source step from the downsampled reference, `P_s(T r_t)`.
    Pre,
    /// Supervised on one source step from the uncorrected source trajectory, `P_s(s^src_t)`.
    Non,
    /// Through `m` unrolled solver steps.
    Sol {
        /// Unrolled steps (`>= 1`).
        m: usize,
    },
}

impl Variant {
    /// Steps unrolled in the loss (1 for PRE and NON).
    pub fn unroll(&self) -> usize {
        match *self {
            Variant::Pre | Variant::Non => 1,
            Variant::Sol { m } => m,
        }
    }

    /// `"PRE"`, `"NON"`, `"SOL-8"`.
    pub fn name(&self) -> String {
        match *self {
            Variant::Pre => "PRE".into(),
            Variant::Non => "NON".into(),
            Variant::Sol { m } => format!("SOL-{m}"),
        }
    }
}

/// Training settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// The method.
    pub variant: Variant,
    /// The network.
    #[serde(default)]
    pub corrector: CorrectorConfig,
    /// Optimiser updates.
    pub iterations: usize,
    /// Start states per update (all from one simulation). Default 1.
    #[serde(default = "one")]
    pub batch: usize,
    /// Adam learning rate. Default 1e-4.
    #[serde(default = "lr")]
    pub lr: f64,
    /// Gradient clipping. Default none.
    #[serde(default)]
    pub clip: ClipConfig,
    /// Seed of the initial weights and of the batches.
    pub seed: u64,
    /// Show a progress bar (hidden anyway when stdout is not a terminal). Default true.
    #[serde(default = "yes")]
    pub progress: bool,
    /// Updates between the checkpoints of a run directory ([`train_resumable`]), which also
    /// writes one after the last update (0: only that one). Ignored by [`train()`]. Default 100.
    #[serde(default = "checkpoint_every")]
    pub checkpoint_every: u64,
}

fn one() -> usize {
    1
}
fn lr() -> f64 {
    1e-4
}
fn yes() -> bool {
    true
}
fn checkpoint_every() -> u64 {
    100
}

impl TrainConfig {
    /// Paper defaults (Adam 1e-4, batch 1) for `variant`, `iterations` updates and `seed`.
    pub fn new(variant: Variant, iterations: usize, seed: u64) -> Self {
        Self {
            variant,
            corrector: CorrectorConfig::default(),
            iterations,
            batch: 1,
            lr: 1e-4,
            clip: ClipConfig::None,
            seed,
            progress: true,
            checkpoint_every: checkpoint_every(),
        }
    }

    /// Checks the settings against the data (typed [`Error::InvalidConfig`]).
    pub fn validate<S: SilScene>(&self, data: &ReferenceSet<S>) -> Result<()> {
        const C: &str = "TrainConfig";
        if let Variant::Sol { m: 0 } = self.variant {
            return Err(Error::invalid(C, "variant.m", "unroll at least one step (m >= 1)"));
        }
        if self.batch == 0 {
            return Err(Error::invalid(C, "batch", "use at least 1"));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(Error::invalid(C, "lr", format!("must be positive, got {}", self.lr)));
        }
        let c = &self.corrector;
        if c.width == 0 || c.kernel % 2 == 0 {
            return Err(Error::invalid(C, "corrector", "needs width >= 1 and an odd kernel"));
        }
        if data.train.is_empty() {
            return Err(Error::invalid(C, "data", "no training simulations"));
        }
        let m = self.variant.unroll();
        if let Some(r) = data.train.iter().find(|r| r.len() < m + 1) {
            return Err(Error::invalid(
                C,
                "variant.m",
                format!("m = {m} needs m + 1 frames per simulation, Re {} has {}", r.re, r.len()),
            ));
        }
        let grid = data.wake.source_grid()?;
        let ch = 2 + data.wake.scalars();
        for r in data.train.iter().chain(&data.test) {
            let d = r.frames.dims();
            if d.len() != 4 || d[1] != ch || d[2] != grid.ny || d[3] != grid.nx {
                return Err(Error::Shape {
                    context: "TrainConfig::validate",
                    expected: format!("frames [T, {ch}, {}, {}] on the source grid", grid.ny, grid.nx),
                    got: d.to_vec(),
                });
            }
        }
        if self.variant == Variant::Non {
            if let Some(r) = data.train.iter().find(|r| r.source.as_ref().map(|s| s.dims()) != Some(r.frames.dims())) {
                return Err(Error::invalid(
                    C,
                    "data.train.source",
                    format!(
                        "NON needs the uncorrected source trajectory of every training simulation (as many frames \
                         as the reference; `generate` or `source_trajectory` make it), Re {} has {:?}",
                        r.re,
                        r.source.as_ref().map(|s| s.dims().to_vec())
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The SOL-m loss from `start` `[B, 2, ny, nx]` against `targets[i] = T r_{t+i+1}` (`m =
/// targets.len()` corrected steps of `source`):
/// `(1/m) sum_i 1/2 mean(((s~_{t+i} - T r_{t+i}) / sigma)^2)`. Differentiable with respect
/// to the network and to `start`.
pub fn unrolled_loss(
    corrector: &Corrector,
    source: &SourceSolver,
    start: &Tensor,
    targets: &[Tensor],
) -> Result<Tensor> {
    if targets.is_empty() {
        return Err(Error::invalid("unrolled_loss", "targets", "give at least one target (m >= 1)"));
    }
    let inv = inverse_sigma(corrector, start)?;
    let mut s = start.clone();
    let mut total: Option<Tensor> = None;
    for target in targets {
        s = corrector.apply(&source.step(&s)?, source.re)?;
        let e = scaled_half_mse(&s, target, &inv)?;
        total = Some(match total {
            Some(t) => (t + e)?,
            None => e,
        });
    }
    Ok(total.expect("targets is not empty").affine(1.0 / targets.len() as f64, 0.0)?)
}

fn inverse_sigma(corrector: &Corrector, like: &Tensor) -> Result<Tensor> {
    let inv: Vec<f64> = corrector.channel_sigma().iter().map(|s| 1.0 / s).collect();
    let c = inv.len();
    Ok(Tensor::new(inv.as_slice(), like.device())?.to_dtype(like.dtype())?.reshape((1, c, 1, 1))?)
}

fn scaled_half_mse(s: &Tensor, target: &Tensor, inv: &Tensor) -> Result<Tensor> {
    Ok((s - target)?.broadcast_mul(inv)?.sqr()?.mean_all()?.affine(0.5, 0.0)?)
}

/// The precomputed one-step inputs of PRE (`P_s(T r_t)`) and NON (`P_s(s^src_t) =
/// s^src_{t+1}`), `t = 0..frames-1`, one tensor per training simulation, paired with the targets
/// `T r_{t+1}`; `None` for SOL-m.
fn one_step_inputs<S>(
    data: &ReferenceSet<S>,
    sources: &[SourceSolver],
    variant: Variant,
) -> Result<Option<Vec<Tensor>>> {
    Ok(match variant {
        Variant::Pre => Some(
            data.train
                .iter()
                .zip(sources)
                .map(|(r, src)| src.step(&r.frames.narrow(0, 0, r.len() - 1)?))
                .collect::<Result<_>>()?,
        ),
        Variant::Non => Some(
            data.train
                .iter()
                .map(|r| {
                    let s = r.source.as_ref().expect("validated: NON has source trajectories");
                    Ok(s.narrow(0, 1, r.len() - 1)?)
                })
                .collect::<Result<_>>()?,
        ),
        Variant::Sol { .. } => None,
    })
}

/// The one-step training inputs of `variant` for every training simulation of `data`
/// (`[frames - 1, 2, ny, nx]` each, input `t` paired with the target `T r_{t+1}`): PRE's
/// `P_s(T r_t)`, NON's `P_s(s^src_t)`; `None` for SOL-m (its inputs are the reference frames).
pub fn training_inputs<S: SilScene>(data: &ReferenceSet<S>, variant: Variant) -> Result<Option<Vec<Tensor>>> {
    TrainConfig::new(variant, 1, 0).validate(data)?;
    let sources: Vec<SourceSolver> = data.train.iter().map(|r| data.wake.source_solver(r.re)).collect::<Result<_>>()?;
    one_step_inputs(data, &sources, variant)
}

/// A trained corrector and its loss curve.
#[derive(Debug)]
pub struct Trained {
    /// The network.
    pub corrector: Corrector,
    /// Loss of every update (of a run directory: of the whole run, the updates before a resume
    /// read back from its `loss.csv`).
    pub losses: Vec<f64>,
    /// Wall time of this call, seconds.
    pub seconds: f64,
    /// The update this call started from: the resumed checkpoint's, 0 for a fresh run.
    pub resumed_from: u64,
    /// Whether Adam's moments and update count came back from the resumed checkpoint (`false`
    /// for a fresh run, and for a checkpoint without optimiser state: its moments restart and
    /// the run is close to, not equal to, the uninterrupted one).
    pub optimizer_restored: bool,
}

/// Trains a corrector on `data` as `config` says, in memory. The source solvers (one per
/// training Reynolds number) are built from `data.wake`. [`train_resumable`] is the same
/// training in a run directory.
pub fn train<S: SilScene>(data: &ReferenceSet<S>, config: &TrainConfig) -> Result<Trained> {
    fit(data, config, None)
}

/// [`train()`] in the run directory `run_dir`, crash-safe and resumable: every update is logged
/// to `run_dir/loss.csv`, and the checkpoint `run_dir/step-<n>` is written every
/// [`TrainConfig::checkpoint_every`] updates and after the last, each one atomic commit of the
/// corrector's weights, Adam's moments and update count, and the run's settings. A call on a
/// directory that holds checkpoints continues from the newest: the weights and Adam's state are
/// restored and the batches of the steps before it replayed from the seed, so a run stopped at
/// any point (`kill -9` included) and called again with the same `data` and `config` ends with
/// the same losses, weights, `loss.csv` and checkpoints, bit for bit, as one that never stopped.
/// [`TrainConfig::iterations`] may grow between calls (train 500, then continue to 1000);
/// [`TrainConfig::progress`] and [`TrainConfig::checkpoint_every`] may change.
///
/// Errors: [`Error::ResumeMismatch`] when the directory holds a run of other settings (variant,
/// network, batch, learning rate, clipping, seed) or other data (training Reynolds numbers,
/// frames, dtype, scene, the frames' digest), naming the setting; nothing is loaded then.
/// [`Error::InvalidConfig`] (`iterations`) when the directory already holds more updates than
/// asked for. One trainer per directory.
///
/// ```
/// use candle_core::DType;
/// use pbdl_sol::sil::*;
///
/// let wake = WakeConfig { coarse: [16, 8], factor: 2, radius: 14.0, reference_substeps: 1, ..Default::default() };
/// let data_cfg = DataConfig { train_re: vec![200.0], test_re: vec![], warmup: 5, train_frames: 6, test_frames: 0 };
/// let data = generate(&wake, &data_cfg, DType::F32)?;
/// let cfg = TrainConfig {
///     corrector: CorrectorConfig { width: 4, blocks: 1, kernel: 3, ..Default::default() },
///     progress: false,
///     checkpoint_every: 2,
///     ..TrainConfig::new(Variant::Sol { m: 2 }, 4, 0)
/// };
/// let dir = tempfile::tempdir().unwrap();
/// let first = train_resumable(&data, &TrainConfig { iterations: 2, ..cfg.clone() }, dir.path())?;
/// let rest = train_resumable(&data, &cfg, dir.path())?; // continues after update 2
/// assert_eq!((rest.resumed_from, rest.losses.len()), (2, 4));
/// assert_eq!(rest.losses[..2], first.losses[..]);
/// assert_eq!(rest.losses, train(&data, &cfg)?.losses); // as if it never stopped
/// # Ok::<(), pbdl_sol::Error>(())
/// ```
pub fn train_resumable<S: SilScene>(
    data: &ReferenceSet<S>,
    config: &TrainConfig,
    run_dir: impl AsRef<Path>,
) -> Result<Trained> {
    fit(data, config, Some(run_dir.as_ref()))
}

/// The name under which [`train_resumable`] records its checkpoints (the `trainer` entry).
const TRAINER: &str = "pbdl_sol::sil::train_resumable";

/// What a run's numbers depend on besides the number of updates: the sidecar `config` of
/// every checkpoint of [`train_resumable`], compared on resume.
fn run_config<S: SilScene>(
    data: &ReferenceSet<S>,
    config: &TrainConfig,
    corrector: &Corrector,
    dtype: DType,
) -> Result<serde_json::Value> {
    let frames = data.train.iter().map(|r| &r.frames);
    let sources = data.train.iter().filter_map(|r| r.source.as_ref());
    let norm = corrector.normalisation();
    let bits = [norm.sigma[0], norm.sigma[1], norm.re_mean, norm.re_std].map(f64::to_bits);
    let mut value = serde_json::json!({
        "trainer": TRAINER,
        "train": {
            "variant": config.variant,
            "corrector": config.corrector,
            "batch": config.batch,
            "lr": config.lr,
            "clip": config.clip,
            "seed": config.seed,
        },
        "network": layout(corrector.varmap()),
        "normalisation": norm,
        // Exactly (a JSON float may read back one unit in the last place off).
        "normalisation_bits": bits,
        "data": {
            "dtype": format!("{dtype:?}"),
            "wake": data.wake,
            "train_re": data.train.iter().map(|r| r.re).collect::<Vec<_>>(),
            "frames": data.train.iter().map(|r| r.len()).collect::<Vec<_>>(),
            "digest": digest(frames.chain(sources))?,
        },
    });
    // Scenes with scalars record them (a wake run's record is as before).
    if !corrector.scalar_sigma().is_empty() {
        value["data"]["scene"] = serde_json::json!(data.wake.scene_name());
        value["scalar_sigma_bits"] =
            serde_json::json!(corrector.scalar_sigma().iter().map(|s| s.to_bits()).collect::<Vec<_>>());
    }
    canonical(value)
}

/// One update's random draws: the training simulation and the batch's start frames.
fn draw<S>(rng: &mut StdRng, data: &ReferenceSet<S>, batch: usize, m: usize) -> (usize, Vec<u32>) {
    let k = rng.random_range(0..data.train.len());
    let sim = &data.train[k];
    let starts = (0..batch).map(|_| rng.random_range(0..(sim.len() - m) as u32)).collect();
    (k, starts)
}

/// [`train()`] (`dir = None`) and [`train_resumable`].
fn fit<S: SilScene>(data: &ReferenceSet<S>, config: &TrainConfig, dir: Option<&Path>) -> Result<Trained> {
    config.validate(data)?;
    let t0 = std::time::Instant::now();
    let dtype = data.train[0].frames.dtype();
    let norm = Normalisation::from_data(data)?;
    let corrector = Corrector::with_scalars(config.corrector, norm, &scalar_sigma(data)?, dtype, config.seed)?;
    let sources: Vec<SourceSolver> = data.train.iter().map(|r| data.wake.source_solver(r.re)).collect::<Result<_>>()?;
    // PRE and NON: the one-step inputs, computed once.
    let pre: Option<Vec<Tensor>> = one_step_inputs(data, &sources, config.variant)?;
    let m = config.variant.unroll();
    let run_cfg = match dir {
        Some(dir) => {
            let c = run_config(data, config, &corrector, dtype)?;
            check_resume("train_resumable", dir, &c, config.iterations)?;
            c
        }
        None => serde_json::Value::Null,
    };
    let loop_cfg = LoopConfig {
        steps: config.iterations as u64,
        checkpoint_every: config.checkpoint_every,
        dir: dir.map(Path::to_path_buf),
        clip: config.clip,
        progress: config.progress,
        ..Default::default()
    };
    let run = TrainLoop::resume(corrector.varmap(), loop_cfg)?;
    let start = run.start();
    let mut rng = pbdl_core::seed::rng(config.seed ^ 0x5011_5eed);
    // The draws of the updates before the checkpoint: none depends on the network.
    for _ in 0..start {
        draw(&mut rng, data, config.batch, m);
    }
    let meta = |step: u64| CheckpointMeta { step, seed: Some(config.seed), config: run_cfg.clone() };
    let adam = OptimizerConfig::Adam(AdamConfig { lr: config.lr, ..AdamConfig::default() });
    let report = run.run::<Error>(
        &adam,
        |_| config.lr,
        meta,
        |_| {
            let (k, starts) = draw(&mut rng, data, config.batch, m);
            let sim = &data.train[k];
            let idx =
                |off: u32| Tensor::new(starts.iter().map(|s| s + off).collect::<Vec<u32>>(), &candle_core::Device::Cpu);
            match &pre {
                Some(pre) => {
                    let x = pre[k].index_select(&idx(0)?, 0)?;
                    let y = sim.frames.index_select(&idx(1)?, 0)?;
                    scaled_half_mse(&corrector.apply(&x, sim.re)?, &y, &inverse_sigma(&corrector, &x)?)
                }
                None => {
                    let start = sim.frames.index_select(&idx(0)?, 0)?;
                    let targets: Vec<Tensor> = (1..=m as u32)
                        .map(|i| sim.frames.index_select(&idx(i)?, 0))
                        .collect::<candle_core::Result<_>>()?;
                    unrolled_loss(&corrector, &sources[k], &start, &targets)
                }
            }
        },
    )?;
    let losses = match dir {
        Some(dir) => logged_losses(dir)?,
        None => report.losses.iter().map(|&(_, l)| l).collect(),
    };
    Ok(Trained {
        corrector,
        losses,
        seconds: t0.elapsed().as_secs_f64(),
        resumed_from: start,
        optimizer_restored: report.optimizer_restored,
    })
}

/// The corrector of the newest checkpoint of a [`train_resumable`] run directory, with the
/// network settings and normalisation recorded there, and the checkpoint's step.
pub fn load_trained(run_dir: impl AsRef<Path>) -> Result<(Corrector, u64)> {
    let dir = run_dir.as_ref();
    let bad = |reason: String| Error::invalid("load_trained", "run_dir", format!("{}: {reason}", dir.display()));
    let path = latest_checkpoint(dir)?.ok_or_else(|| bad("holds no checkpoint; train into it first".into()))?;
    let info = read_checkpoint_info(&path)?;
    if info.config.get("trainer").and_then(|t| t.as_str()) != Some(TRAINER) {
        return Err(bad(format!("its checkpoints were not written by {TRAINER}")));
    }
    let field = |name: &str| info.config.pointer(name).cloned().unwrap_or_default();
    let read = |name: &str| -> Result<serde_json::Value> {
        let v = field(name);
        if v.is_null() {
            return Err(bad(format!("the checkpoint records no `{name}`")));
        }
        Ok(v)
    };
    let cfg: CorrectorConfig = serde_json::from_value(read("/train/corrector")?)
        .map_err(|e| bad(format!("unreadable corrector settings: {e}")))?;
    let bits: [u64; 4] = serde_json::from_value(read("/normalisation_bits")?)
        .map_err(|e| bad(format!("unreadable normalisation: {e}")))?;
    let [s0, s1, re_mean, re_std] = bits.map(f64::from_bits);
    let norm = Normalisation { sigma: [s0, s1], re_mean, re_std };
    let dtype = match read("/data/dtype")?.as_str() {
        Some("F64") => DType::F64,
        Some("F32") => DType::F32,
        other => return Err(bad(format!("unsupported dtype {other:?}"))),
    };
    let scalars: Vec<f64> = match info.config.get("scalar_sigma_bits") {
        Some(v) => serde_json::from_value::<Vec<u64>>(v.clone())
            .map_err(|e| bad(format!("unreadable scalar scales: {e}")))?
            .into_iter()
            .map(f64::from_bits)
            .collect(),
        None => Vec::new(),
    };
    let corrector = Corrector::with_scalars(cfg, norm, &scalars, dtype, 0)?;
    load_varmap(&path, corrector.varmap())?;
    Ok((corrector, info.step))
}
