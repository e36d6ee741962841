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

use super::{train_step, ClipConfig, NanGuard, OptimizerConfig, Progress, ScalarLog, StepInfo};
use crate::io::{latest_checkpoint, load_varmap, save_varmap, CheckpointMeta};
use crate::Result;
use candle_core::{Tensor, Var};
use candle_nn::{Optimizer, VarMap};
use std::path::PathBuf;
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
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self { steps: 0, checkpoint_every: 0, dir: None, clip: ClipConfig::None, progress: true }
    }
}

/// What a [`TrainLoop`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoopReport {
    /// `(step, loss)` of every update of this call.
    pub losses: Vec<(u64, f64)>,
    /// The step the run resumed from (0 for a fresh run).
    pub resumed_from: u64,
    /// Wall-clock seconds of the updates.
    pub seconds: f64,
    /// Seconds per update.
    pub seconds_per_step: f64,
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

/// A training run over the variables of one `VarMap`, resumed from its run directory; `H` is
/// the [`TrainLoop::after_step`] hook ([`NoHook`] by default).
pub struct TrainLoop<'a, H = NoHook> {
    /// `None` for [`TrainLoop::in_memory`].
    varmap: Option<&'a VarMap>,
    cfg: LoopConfig,
    start: u64,
    /// `Some` for [`TrainLoop::in_memory`]; otherwise the `VarMap`'s variables.
    vars: Option<Vec<Var>>,
    hook: H,
}

impl<H> std::fmt::Debug for TrainLoop<'_, H> {
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
    /// `varmap` (the weights; optimiser moments restart) and continues after its step.
    pub fn resume(varmap: &'a VarMap, cfg: LoopConfig) -> Result<Self> {
        let mut start = 0;
        if let Some(dir) = &cfg.dir {
            if let Some(path) = latest_checkpoint(dir)? {
                start = load_varmap(&path, varmap)?.step;
            }
        }
        Ok(Self { varmap: Some(varmap), cfg, start, vars: None, hook: NoHook })
    }

    /// Opens an in-memory run over `vars`, variables kept outside any `VarMap` (a hand-built
    /// network, a frozen part left out), trained in this order (the order the gradient norm
    /// sums in; `VarMap::all_vars` has no fixed one). It starts at step 0, writes no files and
    /// no checkpoints: `cfg.dir` must be `None`.
    pub fn in_memory(vars: Vec<Var>, cfg: LoopConfig) -> Result<Self> {
        if let Some(dir) = &cfg.dir {
            return Err(crate::Error::invalid(
                "TrainLoop::in_memory",
                "cfg.dir",
                format!("an in-memory run writes no files; got {}, use TrainLoop::resume with a VarMap", dir.display()),
            ));
        }
        Ok(Self { varmap: None, cfg, start: 0, vars: Some(vars), hook: NoHook })
    }
}

impl<'a, H> TrainLoop<'a, H> {
    /// The first step this run will take (the resumed checkpoint's step, or 0). Seed per-run
    /// random streams from it so that a resumed run does not replay the same batches.
    pub fn start(&self) -> u64 {
        self.start
    }

    /// Calls `hook(step, &info)` after each update (after its `loss.csv` row, before the
    /// progress bar and the checkpoint of that step, which so holds the hooked weights): clamp
    /// or project weights, recalibrate, collect [`StepInfo::grad_norm`]. An error from the hook
    /// stops the run with that error. Replaces an earlier hook.
    pub fn after_step<E, F>(self, hook: F) -> TrainLoop<'a, F>
    where
        F: FnMut(u64, &StepInfo) -> std::result::Result<(), E>,
    {
        TrainLoop { varmap: self.varmap, cfg: self.cfg, start: self.start, vars: self.vars, hook }
    }

    /// Runs the updates `start..steps`: at each, sets the learning rate `lr_at(step)`, asks
    /// `loss_at(step)` for the loss, and takes one [`train_step`] with the configured clipping
    /// and a [`NanGuard`] (a non-finite loss or gradient stops the run with
    /// [`crate::Error::Diverged`], the last checkpoint kept). Logs `loss`, `grad_norm` and
    /// `seconds` per step to `dir/loss.csv`, calls the [`TrainLoop::after_step`] hook, and
    /// checkpoints `dir/step-<n>` with `meta(n)`.
    pub fn run<E: From<crate::Error>>(
        mut self,
        optimizer: &OptimizerConfig,
        lr_at: impl Fn(u64) -> f64,
        meta: impl Fn(u64) -> CheckpointMeta,
        mut loss_at: impl FnMut(u64) -> std::result::Result<Tensor, E>,
    ) -> std::result::Result<LoopReport, E>
    where
        H: AfterStep<E>,
    {
        let vars = match (self.vars.take(), self.varmap) {
            (Some(vars), _) => vars,
            (None, Some(varmap)) => varmap.all_vars(),
            (None, None) => Vec::new(),
        };
        let mut opt = optimizer.build(vars.clone())?;
        let mut guard = NanGuard::new();
        let mut log = None;
        if let Some(dir) = &self.cfg.dir {
            guard = guard.with_checkpoint(dir.display().to_string());
            std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
            log = Some(ScalarLog::open(dir.join("loss.csv"))?);
        }
        let progress = if self.cfg.progress { Progress::new(self.cfg.steps) } else { Progress::hidden(self.cfg.steps) };
        let t0 = Instant::now();
        let mut losses = Vec::new();
        for step in self.start..self.cfg.steps {
            opt.set_learning_rate(lr_at(step));
            let l = loss_at(step)?;
            let info = train_step(step, &l, &mut opt, &vars, &self.cfg.clip, &mut guard)?;
            losses.push((step, info.loss));
            if let Some(log) = log.as_mut() {
                log.log(
                    step,
                    &[("loss", info.loss), ("grad_norm", info.grad_norm), ("seconds", t0.elapsed().as_secs_f64())],
                )?;
            }
            self.hook.after_step(step, &info)?;
            progress.update(step, info.loss);
            let done = step + 1 == self.cfg.steps;
            if let (Some(dir), Some(varmap)) = (&self.cfg.dir, self.varmap) {
                let every = self.cfg.checkpoint_every;
                if done || (every > 0 && (step + 1) % every == 0) {
                    save_varmap(dir.join(format!("step-{}", step + 1)), varmap, &meta(step + 1))?;
                }
            }
        }
        progress.finish();
        let seconds = t0.elapsed().as_secs_f64();
        let n = losses.len().max(1) as f64;
        Ok(LoopReport { losses, resumed_from: self.start, seconds, seconds_per_step: seconds / n })
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
    /// from step 10 to the end; the log holds every step taken.
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
        assert_eq!(log.column("loss").len(), 12 + 10, "12 rows before the NaN, 10 after resuming");
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
}
