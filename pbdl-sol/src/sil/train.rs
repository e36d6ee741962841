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

use super::data::ReferenceSet;
use super::net::{Corrector, CorrectorConfig, Normalisation};
use super::scene::SourceSolver;
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::train::{train_step, AdamConfig, ClipConfig, NanGuard, OptimizerConfig, Progress};
use rand::Rng;
use serde::{Deserialize, Serialize};

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
        }
    }

    /// Checks the settings against the data (typed [`Error::InvalidConfig`]).
    pub fn validate(&self, data: &ReferenceSet) -> Result<()> {
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
        let grid = data.wake.coarse_grid()?;
        for r in data.train.iter().chain(&data.test) {
            let d = r.frames.dims();
            if d.len() != 4 || d[1] != 2 || d[2] != grid.ny || d[3] != grid.nx {
                return Err(Error::Shape {
                    context: "TrainConfig::validate",
                    expected: format!("frames [T, 2, {}, {}] on the source grid", grid.ny, grid.nx),
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
    let sigma = corrector.normalisation().sigma;
    Ok(Tensor::new(&[1.0 / sigma[0], 1.0 / sigma[1]], like.device())?.to_dtype(like.dtype())?.reshape((1, 2, 1, 1))?)
}

fn scaled_half_mse(s: &Tensor, target: &Tensor, inv: &Tensor) -> Result<Tensor> {
    Ok((s - target)?.broadcast_mul(inv)?.sqr()?.mean_all()?.affine(0.5, 0.0)?)
}

/// The precomputed one-step inputs of PRE (`P_s(T r_t)`) and NON (`P_s(s^src_t) =
/// s^src_{t+1}`), `t = 0..frames-1`, one tensor per training simulation, paired with the targets
/// `T r_{t+1}`; `None` for SOL-m.
fn one_step_inputs(data: &ReferenceSet, sources: &[SourceSolver], variant: Variant) -> Result<Option<Vec<Tensor>>> {
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
pub fn training_inputs(data: &ReferenceSet, variant: Variant) -> Result<Option<Vec<Tensor>>> {
    TrainConfig::new(variant, 1, 0).validate(data)?;
    let sources: Vec<SourceSolver> = data.train.iter().map(|r| data.wake.source(r.re)).collect::<Result<_>>()?;
    one_step_inputs(data, &sources, variant)
}

/// A trained corrector and its loss curve.
#[derive(Debug)]
pub struct Trained {
    /// The network.
    pub corrector: Corrector,
    /// Loss of every update.
    pub losses: Vec<f64>,
    /// Wall time of the training, seconds.
    pub seconds: f64,
}

/// Trains a corrector on `data` as `config` says. The source solvers (one per training
/// Reynolds number) are built from `data.wake`.
pub fn train(data: &ReferenceSet, config: &TrainConfig) -> Result<Trained> {
    config.validate(data)?;
    let t0 = std::time::Instant::now();
    let dtype = data.train[0].frames.dtype();
    let norm = Normalisation::from_data(data)?;
    let corrector = Corrector::new(config.corrector, norm, dtype, config.seed)?;
    let sources: Vec<SourceSolver> = data.train.iter().map(|r| data.wake.source(r.re)).collect::<Result<_>>()?;
    // PRE and NON: the one-step inputs, computed once.
    let pre: Option<Vec<Tensor>> = one_step_inputs(data, &sources, config.variant)?;
    let m = config.variant.unroll();
    let opt_cfg = OptimizerConfig::Adam(AdamConfig { lr: config.lr, ..AdamConfig::default() });
    let vars = corrector.varmap().all_vars();
    let mut opt = opt_cfg.build(vars.clone())?;
    let mut guard = NanGuard::new();
    let mut rng = pbdl_core::seed::rng(config.seed ^ 0x5011_5eed);
    let progress = if config.progress {
        Progress::new(config.iterations as u64)
    } else {
        Progress::hidden(config.iterations as u64)
    };
    progress.set_message(config.variant.name());
    let mut losses = Vec::with_capacity(config.iterations);
    for it in 0..config.iterations {
        let k = rng.random_range(0..data.train.len());
        let sim = &data.train[k];
        let starts: Vec<u32> = (0..config.batch).map(|_| rng.random_range(0..(sim.len() - m) as u32)).collect();
        let idx =
            |off: u32| Tensor::new(starts.iter().map(|s| s + off).collect::<Vec<u32>>(), &candle_core::Device::Cpu);
        let loss = match &pre {
            Some(pre) => {
                let x = pre[k].index_select(&idx(0)?, 0)?;
                let y = sim.frames.index_select(&idx(1)?, 0)?;
                scaled_half_mse(&corrector.apply(&x, sim.re)?, &y, &inverse_sigma(&corrector, &x)?)?
            }
            None => {
                let start = sim.frames.index_select(&idx(0)?, 0)?;
                let targets: Vec<Tensor> =
                    (1..=m as u32).map(|i| sim.frames.index_select(&idx(i)?, 0)).collect::<candle_core::Result<_>>()?;
                unrolled_loss(&corrector, &sources[k], &start, &targets)?
            }
        };
        let info = train_step(it as u64, &loss, &mut opt, &vars, &config.clip, &mut guard)?;
        losses.push(info.loss);
        progress.update(it as u64, info.loss);
    }
    progress.finish();
    Ok(Trained { corrector, losses, seconds: t0.elapsed().as_secs_f64() })
}
