//! Training utilities: optimisers, learning-rate schedules, gradient clipping, scalar logs,
//! a progress bar and a divergence guard.
//!
//! | file | gives you |
//! |---|---|
//! | [`optim`] | [`OptimizerConfig`] (serde: Adam, AdamW, SGD with momentum) building an [`Optim`] |
//! | [`schedule`] | [`ScheduleConfig`] (constant, step decay, cosine + warmup, reduce-on-plateau) and [`LrScheduler`] |
//! | [`clip`] | [`clip_grad_norm`] (returns the pre-clip norm), [`clip_grad_value`], [`ClipConfig`] |
//! | [`flat`] | [`FlatAdam`] (candle-nn's Adam, bit for bit, on one `f64` vector) and [`clip_in_place`] for hand-written networks |
//! | [`log`] | [`ScalarLog`]: CSV / JSON lines / JSON array, written through without losing rows |
//! | [`progress`] | [`Progress`]: an indicatif bar, hidden in CI and when stdout is not a terminal |
//! | [`guard`] | [`NanGuard`]: `Error::Diverged` at the first non-finite loss or gradient norm |
//! | [`run`] | [`TrainLoop`]: the one training loop (resume from the latest checkpoint, lr schedule, clip, NaN guard, `loss.csv`, progress, atomic checkpoints, an after-step hook, an evaluation cadence kept out of the timings, a time budget; `TrainLoop::in_memory` for a fixed variable list); a method supplies its loss, or its whole update with `TrainLoop::run_custom` (hand-written adjoints, HIG, GANs) |
//! | [`step`] | [`train_step`]: backward, clip, guard, update in one call |
//! | [`resume`] | [`check_resume`]: refuses to resume a run directory whose newest checkpoint holds another config (naming the first differing setting) or more updates than asked; [`canonical`], [`logged_losses`] |
//! | [`state`] | [`save_train_checkpoint`] / [`load_train_checkpoint`]: weights and optimiser state in one atomic checkpoint, for exact resumes; [`remove_interrupted_writes`] |
//! | [`crash`] | a kill -9 harness: a test kills a child training run at random times and inside checkpoint writes, resumes it, and compares with an uninterrupted run |
//!
//! A complete loop (the optimiser and schedule come from serde configs, as in a run file):
//!
//! ```
//! use candle_core::{DType, Device, Module, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use pbdl_core::train::*;
//!
//! let dev = Device::Cpu;
//! let varmap = VarMap::new();
//! let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
//! // Zero-initialised (candle's random init cannot be seeded on the CPU).
//! let w = vb.get_with_hints((1, 1), "fit.weight", candle_nn::Init::Const(0.0))?;
//! let b = vb.get_with_hints(1, "fit.bias", candle_nn::Init::Const(0.0))?;
//! let model = candle_nn::Linear::new(w, Some(b));
//! let x = Tensor::new(&[[0.0f32], [1.0], [2.0], [3.0]], &dev)?;
//! let y = ((&x * 2.0)? + 1.0)?; // fit y = 2x + 1
//!
//! let opt_cfg: OptimizerConfig = serde_json::from_str(r#"{"kind": "adam", "lr": 0.1}"#).unwrap();
//! let sched_cfg: ScheduleConfig = serde_json::from_str(r#"{"kind": "cosine", "total_steps": 300}"#).unwrap();
//! let vars = varmap.all_vars();
//! let mut opt = opt_cfg.build(vars.clone())?;
//! let schedule = LrScheduler::new(sched_cfg, opt_cfg.lr())?;
//! let mut guard = NanGuard::new();
//! let mut log = ScalarLog::new();
//! let progress = Progress::new(300);
//! for step in 0..300 {
//!     let lr = schedule.apply(&mut opt, step);
//!     let loss = model.forward(&x)?.sub(&y)?.sqr()?.mean_all()?;
//!     let info = train_step(step, &loss, &mut opt, &vars, &ClipConfig::Norm { max_norm: 10.0 }, &mut guard)?;
//!     log.log(step, &[("loss", info.loss), ("grad_norm", info.grad_norm), ("lr", lr)])?;
//!     progress.update(step, info.loss);
//! }
//! progress.finish();
//! assert!(log.last("loss").unwrap() < 1e-4, "{:?}", log.last("loss"));
//! # Ok::<(), pbdl_core::Error>(())
//! ```

mod adamw_inplace;
pub mod clip;
pub mod crash;
pub mod flat;
pub mod guard;
pub mod log;
pub mod optim;
pub mod progress;
pub mod resume;
pub mod run;
pub mod schedule;
pub mod state;
pub mod step;

pub use clip::{clip_grad_norm, clip_grad_value, grad_norm, ClipConfig};
pub use flat::{clip_in_place, global_norm, FlatAdam};
pub use guard::NanGuard;
pub use log::{LogFormat, LogRow, ScalarLog};
pub use optim::{AdamConfig, AdamW, AdamWConfig, Optim, OptimState, OptimizerConfig, Sgd, SgdConfig};
pub use progress::Progress;
pub use resume::{canonical, check_resume, guarded_loop_config, logged_losses};
pub use run::{AfterStep, Evaluate, Evaluation, LoopConfig, LoopReport, NoEval, NoHook, StopReason, TrainLoop, Update};
pub use schedule::{LrScheduler, PlateauConfig, ScheduleConfig};
pub use state::{
    load_train_checkpoint, remove_checkpoint, remove_interrupted_writes, save_train_checkpoint, sorted_vars,
    TrainCheckpoint, OPTIM_PREFIX,
};
pub use step::{train_step, StepInfo};
