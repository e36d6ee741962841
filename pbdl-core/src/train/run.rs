//! The one training loop: resume, schedule, step, clip, guard, log, checkpoint.
//!
//! Every method's training repeats the same frame around its own loss: pick up the latest
//! checkpoint of a run directory, drive the learning rate, take [`super::train_step`] (backward,
//! clip, [`super::NanGuard`], update), append to `loss.csv`, show a [`super::Progress`] bar and
//! write atomic checkpoints every so often and at the end. [`TrainLoop`] is that frame; a method
//! supplies only the loss of step `k`.
//!
//! ```
//! use candle_core::{DType, Device, Tensor};
//! use candle_nn::{Init, VarMap};
//! use pbdl_core::io::CheckpointMeta;
//! use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
//!
//! // Fit w to 3 with loss (w - 3)^2, checkpointing into a temporary run directory.
//! let dir = std::env::temp_dir().join(format!("pbdl_train_loop_doc_{}", std::process::id()));
//! let varmap = VarMap::new();
//! let w = varmap.get(1, "w", Init::Const(0.0), DType::F64, &Device::Cpu)?;
//! let cfg = LoopConfig { steps: 300, checkpoint_every: 100, dir: Some(dir.clone()), ..Default::default() };
//! let run = TrainLoop::resume(&varmap, cfg.clone())?;
//! assert_eq!(run.start(), 0);
//! let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.1, ..Default::default() });
//! let report = run.run::<pbdl_core::Error>(&adam, |_| 0.1, |s| CheckpointMeta::at(s), |_| {
//!     Ok((&w - 3.0)?.sqr()?.sum_all()?)
//! })?;
//! assert!(report.losses.last().unwrap().1 < 1e-3);
//! // A second run over the same directory resumes at the end and has nothing left to do.
//! assert_eq!(TrainLoop::resume(&varmap, cfg)?.start(), 300);
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok::<(), pbdl_core::Error>(())
//! ```
//!
//! [`TrainLoop::after_step`] adds a hook that runs after each update (project or clamp the
//! weights, recalibrate, collect the gradient norms), and [`TrainLoop::in_memory`] trains
//! variables kept outside any `VarMap`, in a fixed order. A hook that keeps a weight at most 2:
//!
//! ```
//! use candle_core::{DType, Device, Var};
//! use candle_nn::{Init, VarMap};
//! use pbdl_core::io::CheckpointMeta;
//! use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
//!
//! // Fit w to 3, but keep it at most 2 after every update.
//! let varmap = VarMap::new();
//! let w = Var::from_tensor(&varmap.get(1, "w", Init::Const(0.0), DType::F64, &Device::Cpu)?)?;
//! let cfg = LoopConfig { steps: 200, progress: false, ..Default::default() };
//! let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.1, ..Default::default() });
//! let mut norms = Vec::new();
//! let report = TrainLoop::resume(&varmap, cfg)?
//!     .after_step(|_step, info| -> pbdl_core::Result<()> {
//!         norms.push(info.grad_norm);
//!         Ok(w.set(&w.as_tensor().minimum(2.0)?)?)
//!     })
//!     .run::<pbdl_core::Error>(&adam, |_| 0.1, CheckpointMeta::at, |_| Ok((w.as_tensor() - 3.0)?.sqr()?.sum_all()?))?;
//! assert_eq!(w.as_tensor().to_vec1::<f64>()?, [2.0]);
//! assert_eq!(norms.len(), report.losses.len());
//! assert!((norms[199] - 2.0).abs() < 1e-9); // d/dw (w - 3)^2 at w = 2
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use super::state::{
    load_train_checkpoint, remove_interrupted_writes, save_state_checkpoint, save_train_checkpoint, sorted_vars,
};
use super::{train_step, ClipConfig, NanGuard, OptimizerConfig, Progress, ScalarLog, StepInfo, TrainCheckpoint};
use crate::io::{latest_checkpoint, CheckpointMeta};
use crate::Result;
use candle_core::{Tensor, Var};
use candle_nn::{Optimizer, VarMap};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Settings of a [`TrainLoop`].
#[derive(Clone, Debug, PartialEq)]
pub struct LoopConfig {
    /// Total updates of the run (a resumed run continues up to this count).
    pub steps: u64,
    /// Write a checkpoint every this many updates (0: only at the end).
    pub checkpoint_every: u64,
    /// The run directory: checkpoints `step-<n>` (safetensors + JSON sidecar, atomic) and
    /// `loss.csv`. `None` keeps everything in memory.
    pub dir: Option<PathBuf>,
    /// Gradient clipping. Default none.
    pub clip: ClipConfig,
    /// Draw a progress bar where [`Progress::new`] would (terminal, not CI). Default `true`.
    pub progress: bool,
    /// Stop once this many seconds of updates are spent (evaluation time not counted), after
    /// the update that crossed it, which is evaluated and checkpointed like the last one.
    /// `None` (the default): no time limit. For time-vs-loss comparisons at equal budget.
    pub time_budget_seconds: Option<f64>,
    /// Stop with [`crate::Error::Diverged`] when an evaluation is not finite (the default,
    /// `true`); `false` records it as a measurement (a test loss that may blow up while
    /// training goes on).
    pub stop_on_non_finite_eval: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            steps: 0,
            checkpoint_every: 0,
            dir: None,
            clip: ClipConfig::None,
            progress: true,
            time_budget_seconds: None,
            stop_on_non_finite_eval: true,
        }
    }
}

/// Why a [`TrainLoop`] stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StopReason {
    /// All `steps` updates are done.
    #[default]
    Completed,
    /// [`LoopConfig::time_budget_seconds`] was spent first.
    TimeBudget,
}

/// What a [`TrainLoop`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoopReport {
    /// `(step, loss)` of every update of this call.
    pub losses: Vec<(u64, f64)>,
    /// The step the run resumed from (0 for a fresh run).
    pub resumed_from: u64,
    /// Wall-clock seconds of the updates (evaluation excluded).
    pub seconds: f64,
    /// Seconds per update.
    pub seconds_per_step: f64,
    /// Wall-clock seconds of each update, in order.
    pub step_seconds: Vec<f64>,
    /// `(updates done, value)` of every [`TrainLoop::evaluate_every`] evaluation, the first
    /// one before any update of this call.
    pub evaluations: Vec<(u64, f64)>,
    /// Why the run stopped.
    pub stopped: StopReason,
    /// Whether the run resumed with the optimiser state of its checkpoint ([`TrainLoop::run`]
    /// from a checkpoint that holds one). `false` for a fresh run, for a checkpoint without
    /// optimiser state (written by `save_varmap` or by pbdl before exact resume: its moments
    /// restart, so the resumed run is close to an uninterrupted one but not equal to it), and
    /// always for [`TrainLoop::run_custom`] and [`TrainLoop::run_custom_with_state`], whose
    /// method restores its own state from [`TrainLoop::resumed`].
    pub optimizer_restored: bool,
}

/// What a method's own update step ([`TrainLoop::run_custom`]) reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Update {
    /// The loss of this update (before it was applied).
    pub loss: f64,
    /// The global gradient norm, where the method computes one.
    pub grad_norm: Option<f64>,
    /// More scalars to log in `loss.csv` (e.g. a discriminator loss), by column name.
    pub extra: Vec<(&'static str, f64)>,
}

impl Update {
    /// An update with only its loss.
    pub fn loss(loss: f64) -> Self {
        Self { loss, grad_norm: None, extra: Vec::new() }
    }

    /// Adds the gradient norm.
    pub fn with_grad_norm(mut self, grad_norm: f64) -> Self {
        self.grad_norm = Some(grad_norm);
        self
    }

    /// Adds a logged scalar `name` (a `loss.csv` column).
    pub fn with(mut self, name: &'static str, value: f64) -> Self {
        self.extra.push((name, value));
        self
    }
}

/// What a [`TrainLoop`] calls after each update ([`TrainLoop::after_step`]). Implemented by
/// every `FnMut(u64, &StepInfo) -> Result<(), E>` closure and by [`NoHook`].
pub trait AfterStep<E> {
    /// Called after the update of `step` (the weights already updated, `info` its
    /// [`train_step`] result). An error stops the run with that error.
    fn after_step(&mut self, step: u64, info: &StepInfo) -> std::result::Result<(), E>;
}

/// The hook of a [`TrainLoop`] without [`TrainLoop::after_step`]: does nothing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoHook;

impl<E> AfterStep<E> for NoHook {
    fn after_step(&mut self, _step: u64, _info: &StepInfo) -> std::result::Result<(), E> {
        Ok(())
    }
}

impl<E, F: FnMut(u64, &StepInfo) -> std::result::Result<(), E>> AfterStep<E> for F {
    fn after_step(&mut self, step: u64, info: &StepInfo) -> std::result::Result<(), E> {
        self(step, info)
    }
}

/// What a [`TrainLoop`] evaluates ([`TrainLoop::evaluate_every`]): `every` and the evaluation
/// itself. Implemented by [`NoEval`] and by [`Evaluation`].
pub trait Evaluate<E> {
    /// Evaluate after this many updates done (`done` counts from 0; `last` is the run's final
    /// update, by step count or time budget). `None`: nothing to evaluate now.
    fn evaluate(&mut self, done: u64, last: bool) -> std::result::Result<Option<f64>, E>;
}

/// The evaluation of a [`TrainLoop`] without [`TrainLoop::evaluate_every`]: none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoEval;

impl<E> Evaluate<E> for NoEval {
    fn evaluate(&mut self, _done: u64, _last: bool) -> std::result::Result<Option<f64>, E> {
        Ok(None)
    }
}

/// An evaluation every `every` updates, at the start and after the last update
/// ([`TrainLoop::evaluate_every`]).
#[derive(Clone, Copy, Debug)]
pub struct Evaluation<F> {
    every: u64,
    start: u64,
    eval: F,
}

impl<E, F: FnMut(u64) -> std::result::Result<f64, E>> Evaluate<E> for Evaluation<F> {
    fn evaluate(&mut self, done: u64, last: bool) -> std::result::Result<Option<f64>, E> {
        let due = done == self.start || last || (self.every > 0 && done % self.every == 0);
        if due {
            (self.eval)(done).map(Some)
        } else {
            Ok(None)
        }
    }
}

/// A training run over the variables of one `VarMap`, resumed from its run directory; `H` is
/// the [`TrainLoop::after_step`] hook ([`NoHook`] by default), `V` the
/// [`TrainLoop::evaluate_every`] evaluation ([`NoEval`] by default).
pub struct TrainLoop<'a, H = NoHook, V = NoEval> {
    /// `None` for [`TrainLoop::in_memory`].
    varmap: Option<&'a VarMap>,
    cfg: LoopConfig,
    start: u64,
    /// `Some` for [`TrainLoop::in_memory`]; otherwise the `VarMap`'s variables.
    vars: Option<Vec<Var>>,
    /// The checkpoint the run resumed from (its optimiser state goes into [`TrainLoop::run`]'s
    /// optimiser).
    resumed: Option<TrainCheckpoint>,
    hook: H,
    eval: V,
}

impl<H, V> std::fmt::Debug for TrainLoop<'_, H, V> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrainLoop")
            .field("cfg", &self.cfg)
            .field("start", &self.start)
            .field("in_memory_vars", &self.vars.as_ref().map(Vec::len))
            .finish()
    }
}

impl<'a> TrainLoop<'a> {
    /// Opens a run: with a run directory that holds checkpoints, loads the latest into
    /// `varmap` and continues after its step. [`TrainLoop::run`] then also restores the
    /// optimiser's moments and update count from it, and `loss.csv` is cut back to the steps
    /// before it, so that a run killed at any point (`kill -9` included) and resumed gives the
    /// same loss curve and weights, bit for bit, as one that never stopped, provided the
    /// method's randomness follows from its seed and the step (see [`TrainLoop::start`]).
    /// Leftovers of a killed checkpoint write are removed first
    /// ([`super::remove_interrupted_writes`]): one trainer per run directory.
    pub fn resume(varmap: &'a VarMap, cfg: LoopConfig) -> Result<Self> {
        let mut start = 0;
        let mut resumed = None;
        if let Some(dir) = &cfg.dir {
            remove_interrupted_writes(dir)?;
            if let Some(path) = latest_checkpoint(dir)? {
                let ck = load_train_checkpoint(&path, varmap)?;
                start = ck.info.step;
                resumed = Some(ck);
            }
        }
        Ok(Self { varmap: Some(varmap), cfg, start, vars: None, resumed, hook: NoHook, eval: NoEval })
    }

    /// Opens an in-memory run over `vars`, variables kept outside any `VarMap` (a hand-built
    /// network, a frozen part left out), trained in this order (the order the gradient norm
    /// sums in; `VarMap::all_vars` has no fixed one). It starts at step 0, writes no files and
    /// no checkpoints: `cfg.dir` must be `None`. With [`TrainLoop::run_custom`] the list may be
    /// empty (the method updates its own parameters).
    pub fn in_memory(vars: Vec<Var>, cfg: LoopConfig) -> Result<Self> {
        if let Some(dir) = &cfg.dir {
            return Err(crate::Error::invalid(
                "TrainLoop::in_memory",
                "cfg.dir",
                format!("an in-memory run writes no files; got {}, use TrainLoop::resume with a VarMap", dir.display()),
            ));
        }
        Ok(Self { varmap: None, cfg, start: 0, vars: Some(vars), resumed: None, hook: NoHook, eval: NoEval })
    }
}

impl<'a, H, V> TrainLoop<'a, H, V> {
    /// The first step this run will take (the resumed checkpoint's step, or 0). For an exact
    /// resume, a method's random draws of step `k` must not depend on where the run started:
    /// derive them from `(seed, k)`, or replay the draws of steps `0..start` before training.
    pub fn start(&self) -> u64 {
        self.start
    }

    /// The checkpoint this run resumed from, if any (its sidecar and the tensors stored besides
    /// the variables and the optimiser state).
    pub fn resumed(&self) -> Option<&TrainCheckpoint> {
        self.resumed.as_ref()
    }

    /// Calls `hook(step, &info)` after each update (after its `loss.csv` row, before the
    /// progress bar and the checkpoint of that step, which so holds the hooked weights): clamp
    /// or project weights, recalibrate, collect [`StepInfo::grad_norm`]. An error from the hook
    /// stops the run with that error. Replaces an earlier hook.
    pub fn after_step<E, F>(self, hook: F) -> TrainLoop<'a, F, V>
    where
        F: FnMut(u64, &StepInfo) -> std::result::Result<(), E>,
    {
        TrainLoop {
            varmap: self.varmap,
            cfg: self.cfg,
            start: self.start,
            vars: self.vars,
            resumed: self.resumed,
            hook,
            eval: self.eval,
        }
    }

    /// Evaluates `eval(updates_done)` before the first update, every `every` updates and after
    /// the last one (`every = 0`: only first and last). The evaluation's time is not counted in
    /// the step timings or the time budget; its value goes to [`LoopReport::evaluations`] and
    /// to the `eval` column of `loss.csv`. A non-finite value stops the run with
    /// [`crate::Error::Diverged`] (at step = updates done, quantity `eval`) unless
    /// [`LoopConfig::stop_on_non_finite_eval`] is off. Replaces an earlier evaluation.
    pub fn evaluate_every<E, F>(self, every: u64, eval: F) -> TrainLoop<'a, H, Evaluation<F>>
    where
        F: FnMut(u64) -> std::result::Result<f64, E>,
    {
        let eval = Evaluation { every, start: self.start, eval };
        TrainLoop {
            varmap: self.varmap,
            cfg: self.cfg,
            start: self.start,
            vars: self.vars,
            resumed: self.resumed,
            hook: self.hook,
            eval,
        }
    }

    /// Runs the updates `start..steps`: at each, sets the learning rate `lr_at(step)`, asks
    /// `loss_at(step)` for the loss, and takes one [`train_step`] with the configured clipping
    /// and a [`NanGuard`] (a non-finite loss or gradient stops the run with
    /// [`crate::Error::Diverged`], the last checkpoint kept). Logs `loss`, `grad_norm` and
    /// `seconds` per step to `dir/loss.csv`, calls the [`TrainLoop::after_step`] hook, and
    /// checkpoints `dir/step-<n>` with `meta(n)`: the weights and the optimiser's state in one
    /// atomic commit ([`super::save_train_checkpoint`]). The `VarMap`'s variables are trained in
    /// the order of their names.
    pub fn run<E: From<crate::Error>>(
        mut self,
        optimizer: &OptimizerConfig,
        lr_at: impl Fn(u64) -> f64,
        meta: impl Fn(u64) -> CheckpointMeta,
        mut loss_at: impl FnMut(u64) -> std::result::Result<Tensor, E>,
    ) -> std::result::Result<LoopReport, E>
    where
        H: AfterStep<E>,
        V: Evaluate<E>,
    {
        let vars = match (self.vars.take(), self.varmap) {
            (Some(vars), _) => vars,
            (None, Some(varmap)) => sorted_vars(varmap).into_iter().map(|(_, v)| v).collect(),
            (None, None) => Vec::new(),
        };
        let mut opt = optimizer.build(vars.clone())?;
        let mut restored = false;
        if let (Some(ck), Some(varmap)) = (self.resumed.take(), self.varmap) {
            restored = ck.restore_optimizer(&mut opt, varmap)?;
        }
        let clip = self.cfg.clip;
        // Shared by the update and the checkpoint writer, which never run at the same time.
        let opt = RefCell::new(opt);
        let save = |_: u64, path: &Path, varmap: &VarMap, meta: &CheckpointMeta| -> std::result::Result<(), E> {
            save_train_checkpoint(path, varmap, &opt.borrow(), Vec::new(), meta)?;
            Ok(())
        };
        let mut report = self.drive(meta, save, |step, guard| {
            let mut opt = opt.borrow_mut();
            opt.set_learning_rate(lr_at(step));
            let l = loss_at(step)?;
            Ok((train_step(step, &l, &mut *opt, &vars, &clip, guard)?, Vec::new()))
        })?;
        report.optimizer_restored = restored;
        Ok(report)
    }

    /// Runs the updates `start..steps` with the method's own update: `update(step, lr_at(step))`
    /// computes the loss and its gradient and applies the update itself (hand-written adjoints,
    /// second-order updates, a generator and a discriminator step). Everything else is as in
    /// [`TrainLoop::run`]: resume, time budget, evaluation, `loss.csv` (with the update's
    /// extra columns), hook, progress and checkpoints (of the `VarMap`, where there is one).
    /// The configured clipping is not applied (the method clips its own gradient). A
    /// non-finite loss or gradient norm stops the run with [`crate::Error::Diverged`] before
    /// that step is logged or checkpointed; an update should not apply a non-finite step (its
    /// parameters are not rolled back).
    ///
    /// The checkpoints hold the `VarMap`'s variables only: a method with state of its own
    /// (optimiser moments, parameters outside the `VarMap`) restarts that state on resume, so
    /// the resumed run is not the uninterrupted one. For an exact resume use
    /// [`TrainLoop::run_custom_with_state`], which commits that state with the weights.
    ///
    /// ```
    /// use pbdl_core::train::{LoopConfig, TrainLoop, Update};
    /// use pbdl_core::io::CheckpointMeta;
    ///
    /// // Gradient descent on (w - 3)^2 by hand, evaluated every 10 updates.
    /// let mut w = 0.0f64;
    /// let cfg = LoopConfig { steps: 50, progress: false, ..Default::default() };
    /// let w_cell = std::cell::Cell::new(0.0);
    /// let report = TrainLoop::in_memory(Vec::new(), cfg)?
    ///     .evaluate_every(10, |_| -> pbdl_core::Result<f64> { Ok((w_cell.get() - 3.0f64).abs()) })
    ///     .run_custom::<pbdl_core::Error>(|_| 0.1, CheckpointMeta::at, |_, lr| {
    ///         let grad = 2.0 * (w - 3.0);
    ///         let loss = (w - 3.0) * (w - 3.0);
    ///         w -= lr * grad;
    ///         w_cell.set(w);
    ///         Ok(Update::loss(loss).with_grad_norm(grad.abs()))
    ///     })?;
    /// assert_eq!(report.losses.len(), 50);
    /// assert_eq!(report.evaluations.iter().map(|e| e.0).collect::<Vec<_>>(), [0, 10, 20, 30, 40, 50]);
    /// assert!(report.evaluations[5].1 < 1e-4);
    /// # Ok::<(), pbdl_core::Error>(())
    /// ```
    pub fn run_custom<E: From<crate::Error>>(
        self,
        lr_at: impl Fn(u64) -> f64,
        meta: impl Fn(u64) -> CheckpointMeta,
        update: impl FnMut(u64, f64) -> std::result::Result<Update, E>,
    ) -> std::result::Result<LoopReport, E>
    where
        H: AfterStep<E>,
        V: Evaluate<E>,
    {
        self.run_custom_with_state(lr_at, meta, |_| Ok(Vec::new()), update)
    }

    /// [`TrainLoop::run_custom`] whose checkpoints also hold the method's own state, in the same
    /// atomic commit as the weights: at each checkpoint after `n` updates, `state(n)` returns
    /// named tensors that are saved with the `VarMap`'s variables
    /// ([`super::state::save_state_checkpoint`]). On resume they come back in
    /// [`TrainLoop::resumed`]'s [`TrainCheckpoint::extra`] (and, for an optimiser's state,
    /// through [`TrainCheckpoint::restore_optimizer`]); the method puts them back **before**
    /// calling this.
    ///
    /// For the resumed run to equal the uninterrupted one bit for bit, the checkpoint must hold
    /// everything the remaining updates and the run's result depend on, and the method must
    /// restore all of it:
    ///
    /// * parameters kept outside the `VarMap` (a flat `Vec<f64>`, a hand-built network);
    /// * the optimiser's state: for a pbdl [`super::Optim`] over variables of the `VarMap`,
    ///   [`super::state::optimizer_state_tensors`] (moments and update count, restored by
    ///   [`TrainCheckpoint::restore_optimizer`]); for an optimiser of the method's own, its
    ///   moments, momentum buffers and update count as tensors;
    /// * anything accumulated across updates: running averages (EMA weights), best-so-far
    ///   values, schedule or plateau counters, sums a result is computed from;
    /// * the random stream: derive step `k`'s draws from `(seed, k)`, or replay the draws of
    ///   steps `0..start` before training (a generator state is not saved); data generated from
    ///   the seed before training needs nothing.
    ///
    /// Names must not collide with the `VarMap`'s variables; names under
    /// [`super::OPTIM_PREFIX`] are for [`super::state::optimizer_state_tensors`] only. `state`
    /// is called only where a checkpoint is written (a run directory and a `VarMap`); an error
    /// from it stops the run with that error, the previous checkpoints kept.
    ///
    /// ```
    /// use candle_core::{DType, Device, Tensor};
    /// use candle_nn::{Init, VarMap};
    /// use pbdl_core::io::CheckpointMeta;
    /// use pbdl_core::train::{LoopConfig, TrainLoop, Update};
    ///
    /// // Heavy-ball descent on (w - 3)^2 by hand: the velocity is the method's own state.
    /// let dir = tempfile::tempdir().unwrap();
    /// let fit = |steps: u64| -> pbdl_core::Result<f64> {
    ///     let varmap = VarMap::new();
    ///     let w = varmap.get(1, "w", Init::Const(0.0), DType::F64, &Device::Cpu)?;
    ///     let w = candle_core::Var::from_tensor(&w)?;
    ///     let cfg = LoopConfig { steps, checkpoint_every: 10, dir: Some(dir.path().into()), progress: false, ..Default::default() };
    ///     let run = TrainLoop::resume(&varmap, cfg)?;
    ///     // Restore the velocity before training (0 in a fresh run).
    ///     let vel = std::cell::Cell::new(match run.resumed() {
    ///         Some(ck) => ck.extra_tensor("velocity")?.to_vec1::<f64>()?[0],
    ///         None => 0.0,
    ///     });
    ///     run.run_custom_with_state::<pbdl_core::Error>(
    ///         |_| 0.05,
    ///         CheckpointMeta::at,
    ///         |_| Ok(vec![("velocity".to_string(), Tensor::new(&[vel.get()], &Device::Cpu)?)]),
    ///         |_, lr| {
    ///             let x = w.as_tensor().to_vec1::<f64>()?[0];
    ///             vel.set(0.9 * vel.get() - lr * 2.0 * (x - 3.0));
    ///             w.set(&Tensor::new(&[x + vel.get()], &Device::Cpu)?)?;
    ///             Ok(Update::loss((x - 3.0) * (x - 3.0)))
    ///         },
    ///     )?;
    ///     Ok(w.as_tensor().to_vec1::<f64>()?[0])
    /// };
    /// fit(25)?; // stopped after 25 updates ...
    /// let resumed = fit(60)?; // ... and resumed in a fresh call
    /// std::fs::remove_dir_all(dir.path()).unwrap();
    /// assert_eq!(resumed.to_bits(), fit(60)?.to_bits()); // the same as one uninterrupted run
    /// # Ok::<(), pbdl_core::Error>(())
    /// ```
    pub fn run_custom_with_state<E: From<crate::Error>>(
        self,
        lr_at: impl Fn(u64) -> f64,
        meta: impl Fn(u64) -> CheckpointMeta,
        mut state: impl FnMut(u64) -> std::result::Result<Vec<(String, Tensor)>, E>,
        mut update: impl FnMut(u64, f64) -> std::result::Result<Update, E>,
    ) -> std::result::Result<LoopReport, E>
    where
        H: AfterStep<E>,
        V: Evaluate<E>,
    {
        let save = |done: u64, path: &Path, varmap: &VarMap, meta: &CheckpointMeta| -> std::result::Result<(), E> {
            let tensors = state(done)?;
            save_state_checkpoint(path, varmap, tensors, meta)?;
            Ok(())
        };
        self.drive(meta, save, |step, guard| {
            let lr = lr_at(step);
            let u = update(step, lr)?;
            guard.check(step, u.loss, u.grad_norm)?;
            Ok((StepInfo { step, loss: u.loss, grad_norm: u.grad_norm.unwrap_or(f64::NAN), lr }, u.extra))
        })
    }

    /// The frame around one update `step_once(step, guard) -> (info, extra columns)`: resume point,
    /// evaluation, time budget, log row, hook, progress, checkpoint (see [`TrainLoop::run`]);
    /// `save(updates_done, path, varmap, meta)` writes one checkpoint (one atomic commit).
    fn drive<E: From<crate::Error>>(
        mut self,
        meta: impl Fn(u64) -> CheckpointMeta,
        mut save: impl FnMut(u64, &Path, &VarMap, &CheckpointMeta) -> std::result::Result<(), E>,
        mut step_once: impl FnMut(u64, &mut NanGuard) -> std::result::Result<(StepInfo, Vec<(&'static str, f64)>), E>,
    ) -> std::result::Result<LoopReport, E>
    where
        H: AfterStep<E>,
        V: Evaluate<E>,
    {
        let mut guard = NanGuard::new();
        let mut log = None;
        if let Some(dir) = &self.cfg.dir {
            guard = guard.with_checkpoint(dir.display().to_string());
            std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
            // Rows after the checkpoint are logged again by this run.
            log = Some(ScalarLog::open_resumed(dir.join("loss.csv"), self.start)?);
        }
        let mut report = LoopReport { resumed_from: self.start, ..Default::default() };
        let no_updates_left = self.start >= self.cfg.steps;
        if let Some(v) = self.eval.evaluate(self.start, no_updates_left)? {
            if self.cfg.stop_on_non_finite_eval {
                guard.check_value(self.start, "eval", v)?;
            }
            report.evaluations.push((self.start, v));
        }
        let progress = if self.cfg.progress { Progress::new(self.cfg.steps) } else { Progress::hidden(self.cfg.steps) };
        let budget = self.cfg.time_budget_seconds.unwrap_or(f64::INFINITY);
        let mut train_seconds = 0.0;
        let mut row: Vec<(&str, f64)> = Vec::new();
        for step in self.start..self.cfg.steps {
            let t = Instant::now();
            let (info, extra) = step_once(step, &mut guard)?;
            let dt = t.elapsed().as_secs_f64();
            train_seconds += dt;
            report.step_seconds.push(dt);
            report.losses.push((step, info.loss));
            let done = step + 1;
            let out_of_time = train_seconds >= budget;
            let last = done == self.cfg.steps || out_of_time;
            let evaluated = self.eval.evaluate(done, last)?;
            if let Some(v) = evaluated {
                if self.cfg.stop_on_non_finite_eval {
                    guard.check_value(done, "eval", v)?;
                }
                report.evaluations.push((done, v));
            }
            if let Some(log) = log.as_mut() {
                row.clear();
                row.push(("loss", info.loss));
                if info.grad_norm.is_finite() {
                    row.push(("grad_norm", info.grad_norm));
                }
                row.push(("seconds", train_seconds));
                row.extend(extra);
                if let Some(v) = evaluated {
                    row.push(("eval", v));
                }
                log.log(step, &row)?;
            }
            self.hook.after_step(step, &info)?;
            progress.update(step, info.loss);
            if let (Some(dir), Some(varmap)) = (&self.cfg.dir, self.varmap) {
                let every = self.cfg.checkpoint_every;
                if last || (every > 0 && done % every == 0) {
                    save(done, &dir.join(format!("step-{done}")), varmap, &meta(done))?;
                }
            }
            if out_of_time && done < self.cfg.steps {
                report.stopped = StopReason::TimeBudget;
                break;
            }
        }
        progress.finish();
        report.seconds = train_seconds;
        report.seconds_per_step = train_seconds / report.losses.len().max(1) as f64;
        Ok(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::AdamConfig;
    use candle_core::{DType, Device};
    use candle_nn::Init;

    fn quadratic_run(dir: &std::path::Path, steps: u64, fail_at: Option<u64>) -> Result<(LoopReport, f64)> {
        let varmap = VarMap::new();
        let w = varmap.get(2, "w", Init::Const(0.5), DType::F64, &Device::Cpu)?;
        let cfg = LoopConfig {
            steps,
            checkpoint_every: 5,
            dir: Some(dir.to_path_buf()),
            progress: false,
            ..Default::default()
        };
        let run = TrainLoop::resume(&varmap, cfg)?;
        let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.05, ..Default::default() });
        let report = run.run::<crate::Error>(
            &adam,
            |_| 0.05,
            CheckpointMeta::at,
            |step| {
                let l = (&w - 2.0)?.sqr()?.sum_all()?;
                Ok(if Some(step) == fail_at { (l * f64::NAN)? } else { l })
            },
        )?;
        let w0 = w.flatten_all()?.to_vec1::<f64>()?[0];
        Ok((report, w0))
    }

    /// An interrupted run (NaN at step 12) keeps its step-10 checkpoint, and resuming continues
    /// from step 10 to the end; the log holds every step once (the rows after the checkpoint
    /// are cut and logged again).
    #[test]
    fn diverged_run_keeps_its_checkpoint_and_resumes() {
        let dir = std::env::temp_dir().join(format!("pbdl_train_loop_test_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let e = quadratic_run(&dir, 20, Some(12)).unwrap_err();
        assert!(matches!(e, crate::Error::Diverged { step: 12, .. }), "{e}");
        assert_eq!(latest_checkpoint(&dir).unwrap().unwrap(), dir.join("step-10.safetensors"));
        let (report, w) = quadratic_run(&dir, 20, None).unwrap();
        assert_eq!(report.resumed_from, 10);
        assert_eq!(report.losses.first().map(|l| l.0), Some(10));
        assert_eq!(report.losses.len(), 10);
        assert!(w > 0.5 && w < 2.0, "moved towards 2: {w}");
        assert_eq!(latest_checkpoint(&dir).unwrap().unwrap(), dir.join("step-20.safetensors"));
        let log = ScalarLog::read(dir.join("loss.csv")).unwrap();
        // Rows 10 and 11 of the first run were cut on resume and logged again: every step once.
        let steps: Vec<u64> = log.column("loss").iter().map(|r| r.0).collect();
        assert_eq!(steps, (0..20).collect::<Vec<_>>(), "10 rows kept before the checkpoint, 10 after resuming");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The hook runs once after every update, sees each step's `StepInfo`, and what it does to
    /// the weights is what the next step starts from; an in-memory run trains only its variables; an error from the hook stops the run with that error.
    #[test]
    fn after_step_hook_sees_every_update_and_can_clamp() {
        let varmap = VarMap::new();
        let w = varmap.get(2, "w", Init::Const(0.0), DType::F64, &Device::Cpu).unwrap();
        let frozen = varmap.get(1, "frozen", Init::Const(1.0), DType::F64, &Device::Cpu).unwrap();
        let cfg = LoopConfig { steps: 50, progress: false, ..Default::default() };
        let adam = OptimizerConfig::Adam(AdamConfig { lr: 0.1, ..Default::default() });
        let loss = |_| -> Result<Tensor> { Ok(((&w - 2.0)?.sqr()?.sum_all()? + (&frozen - 5.0)?.sqr()?.sum_all()?)?) };
        let wv = Var::from_tensor(&w).unwrap(); // the same storage
        let mut seen = Vec::new();
        let report = TrainLoop::in_memory(vec![wv.clone()], cfg.clone())
            .unwrap()
            .after_step(|_, info: &StepInfo| -> Result<()> {
                seen.push(*info);
                Ok(wv.set(&w.minimum(1.0)?)?)
            })
            .run::<crate::Error>(&adam, |_| 0.1, CheckpointMeta::at, loss)
            .unwrap();
        assert_eq!(seen.len(), 50);
        assert!(seen.iter().enumerate().all(|(k, i)| i.step == k as u64 && i.lr == 0.1));
        assert_eq!(seen.iter().map(|i| (i.step, i.loss)).collect::<Vec<_>>(), report.losses);
        assert!(seen.iter().all(|i| i.grad_norm.is_finite() && i.grad_norm > 0.0));
        assert_eq!(w.to_vec1::<f64>().unwrap(), [1.0, 1.0], "clamped after the last update");
        assert_eq!(frozen.to_vec1::<f64>().unwrap(), [1.0], "not trained");
        // The gradient of the trained variable only: 2 (w - 2) = -2 per entry at the clamp.
        assert!((seen[49].grad_norm - 8f64.sqrt()).abs() < 1e-12, "{:?}", seen[49]);

        // A failing hook stops the run at its step.
        let mut calls = 0;
        let e = TrainLoop::resume(&varmap, cfg)
            .unwrap()
            .after_step(|step, _: &StepInfo| {
                calls += 1;
                if step == 3 {
                    Err(crate::Error::invalid("hook", "step", "stop"))
                } else {
                    Ok(())
                }
            })
            .run::<crate::Error>(&adam, |_| 0.1, CheckpointMeta::at, loss)
            .unwrap_err();
        assert!(matches!(e, crate::Error::InvalidArgument { .. }), "{e}");
        assert_eq!(calls, 4);
        // An in-memory run has nowhere to checkpoint.
        let with_dir = LoopConfig { dir: Some(std::env::temp_dir()), ..Default::default() };
        assert!(matches!(TrainLoop::in_memory(vec![wv], with_dir), Err(crate::Error::InvalidArgument { .. })));
    }

    /// A custom update: the loop logs its extra columns and the evaluations (first, every 4th,
    /// last), checkpoints the VarMap, and a time budget stops the run after the crossing update,
    /// which is evaluated and checkpointed.
    #[test]
    fn custom_update_with_evaluation_extra_columns_and_time_budget() {
        let dir = std::env::temp_dir().join(format!("pbdl_train_loop_custom_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let varmap = VarMap::new();
        let w = varmap.get(1, "w", Init::Const(0.0), DType::F64, &Device::Cpu).unwrap();
        let wv = Var::from_tensor(&w).unwrap();
        let value = || w.to_vec1::<f64>().unwrap()[0];
        let cfg = LoopConfig {
            steps: 10,
            checkpoint_every: 0,
            dir: Some(dir.clone()),
            progress: false,
            ..Default::default()
        };
        // Gradient descent on (w - 1)^2 by hand at lr 0.25: w_k = 1 - 0.5^k.
        let update = |_: u64, lr: f64| -> Result<Update> {
            let wk = value();
            let grad = 2.0 * (wk - 1.0);
            wv.set(&Tensor::new(&[wk - lr * grad], &Device::Cpu)?)?;
            Ok(Update::loss((wk - 1.0).powi(2)).with_grad_norm(grad.abs()).with("w", wk))
        };
        let report = TrainLoop::resume(&varmap, cfg.clone())
            .unwrap()
            .evaluate_every(4, |done| -> Result<f64> { Ok(done as f64 + value()) })
            .run_custom::<crate::Error>(|_| 0.25, CheckpointMeta::at, update)
            .unwrap();
        assert_eq!(report.stopped, StopReason::Completed);
        assert_eq!(report.losses.len(), 10);
        assert_eq!(report.step_seconds.len(), 10);
        assert!((value() - (1.0 - 0.5f64.powi(10))).abs() < 1e-15);
        let evals: Vec<u64> = report.evaluations.iter().map(|e| e.0).collect();
        assert_eq!(evals, [0, 4, 8, 10]);
        assert!((report.evaluations[1].1 - (4.0 + 1.0 - 0.5f64.powi(4))).abs() < 1e-15);
        let log = ScalarLog::read(dir.join("loss.csv")).unwrap();
        assert_eq!(log.column("w").len(), 10);
        assert!((log.column("w")[2].1 - 0.75).abs() < 1e-15, "w before update 2");
        assert_eq!(log.column("eval").iter().map(|e| e.0).collect::<Vec<_>>(), [3, 7, 9], "logged on the update's row");
        assert_eq!(latest_checkpoint(&dir).unwrap().unwrap(), dir.join("step-10.safetensors"));

        // A budget of zero seconds: the first update crosses it, is evaluated and checkpointed.
        std::fs::remove_dir_all(&dir).ok();
        let budget = LoopConfig { steps: 10, time_budget_seconds: Some(0.0), ..cfg.clone() };
        let report = TrainLoop::resume(&varmap, budget)
            .unwrap()
            .evaluate_every(4, |done| -> Result<f64> { Ok(done as f64) })
            .run_custom::<crate::Error>(|_| 0.25, CheckpointMeta::at, update)
            .unwrap();
        assert_eq!(report.stopped, StopReason::TimeBudget);
        assert_eq!(report.losses.len(), 1);
        assert_eq!(report.evaluations, [(0, 0.0), (1, 1.0)]);
        assert_eq!(latest_checkpoint(&dir).unwrap().unwrap(), dir.join("step-1.safetensors"));

        // A non-finite reported loss or evaluation stops the run with Diverged at that step.
        std::fs::remove_dir_all(&dir).ok();
        let e = TrainLoop::in_memory(Vec::new(), LoopConfig { steps: 10, progress: false, ..Default::default() })
            .unwrap()
            .run_custom::<crate::Error>(
                |_| 0.1,
                CheckpointMeta::at,
                |step, _| Ok(Update::loss(if step == 3 { f64::NAN } else { 1.0 })),
            )
            .unwrap_err();
        assert!(matches!(e, crate::Error::Diverged { step: 3, .. }), "{e}");
        let e = TrainLoop::in_memory(Vec::new(), LoopConfig { steps: 10, progress: false, ..Default::default() })
            .unwrap()
            .evaluate_every(2, |done| -> Result<f64> { Ok(if done == 4 { f64::INFINITY } else { 0.0 }) })
            .run_custom::<crate::Error>(|_| 0.1, CheckpointMeta::at, |_, _| Ok(Update::loss(1.0)))
            .unwrap_err();
        assert!(matches!(&e, crate::Error::Diverged { step: 4, quantity, .. } if quantity == "eval"), "{e}");
        // With the evaluation guard off, the same evaluations are recorded and the run completes.
        let cfg = LoopConfig { steps: 10, progress: false, stop_on_non_finite_eval: false, ..Default::default() };
        let report = TrainLoop::in_memory(Vec::new(), cfg)
            .unwrap()
            .evaluate_every(2, |done| -> Result<f64> { Ok(if done == 4 { f64::INFINITY } else { 0.0 }) })
            .run_custom::<crate::Error>(|_| 0.1, CheckpointMeta::at, |_, _| Ok(Update::loss(1.0)))
            .unwrap();
        assert_eq!(report.losses.len(), 10);
        assert_eq!(report.evaluations[2], (4, f64::INFINITY));
    }
}
