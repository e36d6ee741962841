//! Stabilized backpropagation through time (Schnell & Thuerey, ICLR 2024): gradient modes for
//! any differentiable rollout `s_{n+1} = P(s_n, N(s_n; theta))` written with candle tensors.
//!
//! | mode | gradient paths kept |
//! |---|---|
//! | [`GradientMode::F`] | all (regular BPTT) |
//! | [`GradientMode::P`] | the physics path only: the network sees `stop(s_n)` |
//! | [`GradientMode::S`] | neither: `P(stop(s_n), N(stop(s_n)))`, each control acts only on its own step |
//! | [`GradientMode::C`] | component-wise combination: `g = g_P` where `sign(g_P) = sign(g_F)`, else `0` (two backward passes) |
//!
//! The combined gradient can then be clipped by value or global norm
//! ([`pbdl_core::train::ClipConfig`]) before it is fed to an optimiser.
//!
//! ```
//! use candle_core::{Device, Tensor, Var};
//! use pbdl_core::train::ClipConfig;
//! use pbdl_optim::bptt::{gradients, GradientMode};
//!
//! // s_{n+1} = 0.9 s_n + u_n, u_n = w s_n, loss s_N^2.
//! let w = Var::new(&[-0.5f64], &Device::Cpu)?;
//! let s0 = Tensor::new(&[1.0f64], &Device::Cpu)?;
//! let net = |s: &Tensor| s.mul(w.as_tensor());
//! let physics = |s: &Tensor, u: &Tensor| (s * 0.9)? + u;
//! let loss = |traj: &[Tensor]| traj.last().unwrap().sqr()?.sum_all();
//! let out = gradients(GradientMode::C, std::slice::from_ref(&w), &s0, 4, &net, &physics, &loss, &ClipConfig::Norm { max_norm: 1.0 })?;
//! assert!(out.grads.get(w.as_tensor()).is_some());
//! # Ok::<(), pbdl_optim::Error>(())
//! ```

use crate::error::{check_len, Result};
use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor, Var};
use candle_nn::Optimizer;
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, ClipConfig, LoopConfig, OptimizerConfig, TrainLoop, Update};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::path::PathBuf;

/// Which gradient paths of a rollout are kept; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GradientMode {
    /// Regular BPTT.
    F,
    /// Network input stopped: feedback only along the physics path.
    P,
    /// Both paths stopped.
    S,
    /// Component-wise combination of `P` and `F` (the paper's method).
    C,
}

/// Runs `steps` steps of `s_{n+1} = physics(s_n, net(s_n))` with the stops of `mode`
/// (`C` rolls out like `P`; use [`gradients`] for its gradient). Returns `[s_0, ..., s_N]`.
pub fn rollout(
    mode: GradientMode,
    s0: &Tensor,
    steps: usize,
    net: &dyn Fn(&Tensor) -> candle_core::Result<Tensor>,
    physics: &dyn Fn(&Tensor, &Tensor) -> candle_core::Result<Tensor>,
) -> Result<Vec<Tensor>> {
    let (stop_net, stop_phys) = match mode {
        GradientMode::F => (false, false),
        GradientMode::P | GradientMode::C => (true, false),
        GradientMode::S => (true, true),
    };
    let mut traj = vec![s0.clone()];
    for _ in 0..steps {
        let s = traj.last().expect("non-empty");
        let u = if stop_net { net(&s.detach())? } else { net(s)? };
        let next = if stop_phys { physics(&s.detach(), &u)? } else { physics(s, &u)? };
        traj.push(next);
    }
    Ok(traj)
}

/// The result of [`gradients`].
#[derive(Debug)]
pub struct BpttGradients {
    /// The loss of the rollout (the same in every mode: stops do not change values).
    pub loss: f64,
    /// Gradients of the vars, combined (mode C) and clipped.
    pub grads: GradStore,
    /// Global norm before clipping.
    pub norm_before_clip: f64,
    /// Mode C only: fraction of components whose signs of `g_P` and `g_F` agreed.
    pub agreement: Option<f64>,
}

fn sign(t: &Tensor) -> candle_core::Result<Tensor> {
    t.gt(0.0)?.to_dtype(t.dtype())? - t.lt(0.0)?.to_dtype(t.dtype())?
}

/// Gradients of `loss(rollout)` with respect to `vars` in `mode`, then clipped by `clip`.
pub fn gradients(
    mode: GradientMode,
    vars: &[Var],
    s0: &Tensor,
    steps: usize,
    net: &dyn Fn(&Tensor) -> candle_core::Result<Tensor>,
    physics: &dyn Fn(&Tensor, &Tensor) -> candle_core::Result<Tensor>,
    loss: &dyn Fn(&[Tensor]) -> candle_core::Result<Tensor>,
    clip: &ClipConfig,
) -> Result<BpttGradients> {
    let run = |m: GradientMode| -> Result<(f64, GradStore)> {
        let traj = rollout(m, s0, steps, net, physics)?;
        let l = loss(&traj)?;
        let value = l.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
        Ok((value, l.backward()?))
    };
    let (value, mut grads, agreement) = match mode {
        GradientMode::C => {
            let (value, mut gp) = run(GradientMode::P)?;
            let (_, gf) = run(GradientMode::F)?;
            let (mut agree, mut total) = (0.0, 0usize);
            for v in vars {
                let t = v.as_tensor();
                let (Some(p), Some(f)) = (gp.get(t).cloned(), gf.get(t)) else { continue };
                let mask = sign(&p)?.eq(&sign(f)?)?;
                agree += mask.to_dtype(candle_core::DType::F64)?.sum_all()?.to_scalar::<f64>()?;
                total += mask.elem_count();
                let combined = mask.where_cond(&p, &p.zeros_like()?)?;
                gp.insert(t, combined);
            }
            (value, gp, Some(if total == 0 { 1.0 } else { agree / total as f64 }))
        }
        m => {
            let (value, g) = run(m)?;
            (value, g, None)
        }
    };
    if !value.is_finite() {
        return Err(crate::Error::Diverged { step: 0, loss: value, last_good: 0 });
    }
    let norm_before_clip = clip.apply(&mut grads, vars)?;
    Ok(BpttGradients { loss: value, grads, norm_before_clip, agreement })
}

/// What a stabilized-BPTT training run measured (cart-pole, guidance, quantum control).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BpttRun {
    /// Steps done at each evaluation.
    pub steps: Vec<usize>,
    /// Test loss at each evaluation (each experiment documents its loss).
    pub test_loss: Vec<f64>,
    /// Training seconds (evaluation excluded).
    pub seconds: f64,
    /// Mode C: mean fraction of gradient components whose signs agreed.
    pub agreement: Option<f64>,
}

impl BpttRun {
    /// The last test loss.
    pub fn final_loss(&self) -> f64 {
        self.test_loss.last().copied().unwrap_or(f64::NAN)
    }
}

/// The optimiser side of a stabilized-BPTT training run, shared by the experiments' configs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainSchedule {
    /// Gradient mode.
    pub mode: GradientMode,
    /// Clipping of the (combined) gradient.
    pub clip: ClipConfig,
    /// Adam learning rate.
    pub lr: f64,
    /// Batch size (at most the number of training episodes).
    pub batch: usize,
    /// Optimizer steps.
    pub iterations: usize,
    /// Evaluate the test loss every this many steps (and after the last).
    pub eval_every: usize,
}

impl TrainSchedule {
    /// The paper's optimiser settings, shared by the cart-pole, guidance and quantum-control
    /// experiments: no clipping, Adam with learning rate `1e-3`, batches of 8, and the test loss
    /// evaluated every tenth of the `iterations` steps (at least every step).
    pub fn paper(mode: GradientMode, iterations: usize) -> Self {
        Self { mode, clip: ClipConfig::None, lr: 1e-3, batch: 8, iterations, eval_every: (iterations / 10).max(1) }
    }
}

/// Declares an experiment's config struct and its paper-settings constructor.
///
/// The struct has the experiment's own leading fields as written, then the shared ones in this
/// order: `mode`, `clip`, `lr`, `batch`, `train`, `test`, `iterations`, `eval_every` (the six
/// of [`TrainSchedule`] and the episode counts), the controller `width` (documented by the given
/// string) and the `seed`. `new(own args.., mode, iterations)` sets the leading fields and the
/// width to the given expressions (which may use the own args), the schedule to
/// [`TrainSchedule::paper`]`(mode, iterations)`, 256 training and 256 test episodes and seed 42;
/// `schedule()` returns the optimiser side.
///
/// ```text
/// experiment_config! {
///     /// Settings of one run.
///     pub struct MyConfig {
///         /// The physics.
///         pub physics: MyPhysics = MyPhysics::new(size),
///     }
///     width: "Hidden width of the controller. Default `100`." = 100,
///     /// The paper's settings for `size`, `mode` and `iterations` optimizer steps.
///     new(size: usize),
/// }
/// ```
macro_rules! experiment_config {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $($(#[$field_meta:meta])* pub $field:ident: $ty:ty = $value:expr,)*
        }
        width: $width_doc:literal = $width:expr,
        $(#[$new_meta:meta])*
        new($($arg:ident: $arg_ty:ty),*) $(,)?
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
        pub struct $name {
            $($(#[$field_meta])* pub $field: $ty,)*
            /// Gradient mode.
            pub mode: $crate::bptt::GradientMode,
            /// Clipping of the (combined) gradient.
            pub clip: pbdl_core::train::ClipConfig,
            /// Adam learning rate. Default `1e-3`.
            pub lr: f64,
            /// Batch size. Default `8`.
            pub batch: usize,
            /// Training episodes. Default `256`.
            pub train: usize,
            /// Test episodes. Default `256`.
            pub test: usize,
            /// Optimizer steps.
            pub iterations: usize,
            /// Evaluate the test loss every this many steps.
            pub eval_every: usize,
            #[doc = $width_doc]
            pub width: usize,
            /// Seed of the data and the controller. Default `42`.
            pub seed: u64,
        }

        impl $name {
            $(#[$new_meta])*
            pub fn new($($arg: $arg_ty,)* mode: $crate::bptt::GradientMode, iterations: usize) -> Self {
                let schedule = $crate::bptt::TrainSchedule::paper(mode, iterations);
                Self {
                    $($field: $value,)*
                    mode: schedule.mode,
                    clip: schedule.clip,
                    lr: schedule.lr,
                    batch: schedule.batch,
                    train: 256,
                    test: 256,
                    iterations: schedule.iterations,
                    eval_every: schedule.eval_every,
                    width: $width,
                    seed: 42,
                }
            }

            /// The optimiser side of this run.
            pub fn schedule(&self) -> $crate::bptt::TrainSchedule {
                $crate::bptt::TrainSchedule {
                    mode: self.mode,
                    clip: self.clip,
                    lr: self.lr,
                    batch: self.batch,
                    iterations: self.iterations,
                    eval_every: self.eval_every,
                }
            }
        }
    };
}
pub(crate) use experiment_config;

/// A rollout and its loss, as [`gradients`] takes them.
pub struct Rollout<'a> {
    /// Steps of an episode.
    pub steps: usize,
    /// The controller `u = N(s)`.
    pub net: &'a dyn Fn(&Tensor) -> candle_core::Result<Tensor>,
    /// The physics step `s' = P(s, u)`.
    pub physics: &'a dyn Fn(&Tensor, &Tensor) -> candle_core::Result<Tensor>,
    /// The loss of a trajectory.
    pub loss: &'a dyn Fn(&[Tensor]) -> candle_core::Result<Tensor>,
}

/// Adam on the mode's gradient over the training episodes `train` (`[n, ...]`, batches taken in
/// order and cycled, as the official code does), recording `evaluate()` (the test loss) at step 0,
/// every `eval_every` steps and after the last. Training time excludes evaluation.
pub fn train(
    vars: &[Var],
    train: &Tensor,
    rollout: &Rollout<'_>,
    schedule: &TrainSchedule,
    mut evaluate: impl FnMut() -> Result<f64>,
) -> Result<BpttRun> {
    let n_train = train.dim(0)?;
    check_batch(schedule.batch, n_train)?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr: schedule.lr, ..Default::default() });
    let mut opt = adam.build(vars.to_vec())?;
    let mut step = |first: usize| -> Result<(f64, Option<f64>)> {
        let s0 = train.narrow(0, first, schedule.batch)?;
        let g = gradients(
            schedule.mode,
            vars,
            &s0,
            rollout.steps,
            rollout.net,
            rollout.physics,
            rollout.loss,
            &schedule.clip,
        )?;
        opt.step(&g.grads)?;
        Ok((g.loss, g.agreement))
    };
    let run = TrainLoop::in_memory(Vec::new(), schedule_loop(schedule, None))?;
    run_schedule(schedule, n_train, &mut (), run, |_| Ok(Vec::new()), |_, first| step(first), |_, _| evaluate())
}

/// Where a stabilized-BPTT run keeps its checkpoints, for an exact resume after it was stopped
/// or killed (`cartpole::adjoint::train_checkpointed`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RunDir {
    /// The run directory: atomic checkpoints `step-<n>` (see the trainer for what they hold)
    /// and `loss.csv` (per update: the training loss of the batch, mode C's sign `agreement`,
    /// and the test loss `eval` on the rows after an evaluation). One trainer per directory.
    pub dir: PathBuf,
    /// Write a checkpoint every this many updates, and after the last (0: only after the last).
    pub checkpoint_every: u64,
}

/// The [`TrainLoop`] settings of a stabilized-BPTT run: `iterations` updates, no progress bar,
/// a non-finite test loss recorded as a measurement (mode F may blow up) while training goes
/// on; checkpoints into `run_dir` where given.
pub(crate) fn schedule_loop(schedule: &TrainSchedule, run_dir: Option<&RunDir>) -> LoopConfig {
    LoopConfig {
        steps: schedule.iterations as u64,
        checkpoint_every: run_dir.map_or(0, |r| r.checkpoint_every),
        dir: run_dir.map(|r| r.dir.clone()),
        progress: false,
        stop_on_non_finite_eval: false,
        ..Default::default()
    }
}

/// Checkpoint names of what [`run_schedule`] itself carries across a resume: the evaluations so
/// far (steps as `i64`, test losses) and mode C's agreement sum and count (`f64` pair).
const EVAL_STEPS: &str = "bptt/eval_steps";
const EVAL_LOSS: &str = "bptt/eval_loss";
const AGREEMENT: &str = "bptt/agreement";

/// The measurements a run accumulates: the evaluations and the sign agreement of mode C.
#[derive(Default)]
struct History {
    steps: Vec<usize>,
    test_loss: Vec<f64>,
    agree_sum: f64,
    agree_n: usize,
}

impl History {
    fn from_checkpoint(ck: &pbdl_core::train::TrainCheckpoint) -> Result<Self> {
        let steps: Vec<usize> =
            ck.extra_tensor(EVAL_STEPS)?.to_vec1::<i64>()?.into_iter().map(|s| s as usize).collect();
        let test_loss: Vec<f64> = ck.extra_tensor(EVAL_LOSS)?.to_vec1::<f64>()?;
        check_len("stored evaluations (test losses vs steps)", steps.len(), test_loss.len())?;
        let agreement = ck.extra_tensor(AGREEMENT)?.to_vec1::<f64>()?;
        let (agree_sum, agree_n) = match agreement[..] {
            [sum, n] => (sum, n as usize),
            _ => return Err(crate::Error::shape(AGREEMENT, "[sum, count]", format!("{agreement:?}"))),
        };
        Ok(Self { steps, test_loss, agree_sum, agree_n })
    }

    fn tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let steps: Vec<i64> = self.steps.iter().map(|&s| s as i64).collect();
        let n = steps.len();
        Ok(vec![
            (EVAL_STEPS.into(), Tensor::from_vec(steps, n, &Device::Cpu)?),
            (EVAL_LOSS.into(), Tensor::from_slice(&self.test_loss, n, &Device::Cpu)?),
            (AGREEMENT.into(), Tensor::new(&[self.agree_sum, self.agree_n as f64], &Device::Cpu)?),
        ])
    }
}

/// The loop of a stabilized-BPTT run, written once for the candle path ([`train`]) and the
/// cart-pole hand-written adjoint path ([`crate::cartpole::adjoint`]) on
/// [`pbdl_core::train::TrainLoop`] (`run`, opened with [`schedule_loop`]'s settings: in memory,
/// or resumed from a run directory): checks the batch size against the `n_train` training
/// episodes, then calls `step(model, first)` (gradient and optimiser update on the batch of
/// episodes `first..first + batch`, cycled in order; returns the batch loss and mode C's sign
/// agreement) for the updates `run.start()..iterations`, timed by the loop, and records
/// `evaluate(model, steps_done)` at step 0, every `eval_every` steps and after the last (not
/// timed).
///
/// With a run directory each checkpoint holds, besides the `VarMap`'s variables, the
/// evaluations and agreement sums so far and the tensors of `state(model)` (the caller's
/// optimiser and whatever else its updates depend on); a resumed run picks up the first two
/// itself, the caller restores the rest from `run.resumed()` before calling this. The batches
/// follow from the step, so nothing else is needed for the resumed run to record what the
/// uninterrupted one does. The evaluation at the resume point is not repeated (it is in the
/// checkpoint if the schedule had one there), and [`BpttRun::seconds`] counts the training
/// time of this call only.
pub(crate) fn run_schedule<S>(
    schedule: &TrainSchedule,
    n_train: usize,
    model: &mut S,
    run: TrainLoop<'_>,
    mut state: impl FnMut(&S) -> Result<Vec<(String, Tensor)>>,
    mut step: impl FnMut(&mut S, usize) -> Result<(f64, Option<f64>)>,
    mut evaluate: impl FnMut(&S, usize) -> Result<f64>,
) -> Result<BpttRun> {
    check_batch(schedule.batch, n_train)?;
    let n_batches = n_train / schedule.batch;
    let start = run.start();
    let history = RefCell::new(match run.resumed() {
        Some(ck) => History::from_checkpoint(ck)?,
        None => History::default(),
    });
    // The update, the evaluation and the checkpoint writer all reach the model, one at a time.
    let model = RefCell::new(model);
    // A non-finite test loss is a measurement here (mode F may blow up), recorded while
    // training goes on (`schedule_loop`); a non-finite training loss stops the run in `step`
    // (`Diverged`).
    let report = run
        .evaluate_every(schedule.eval_every.max(1) as u64, |done| -> Result<f64> {
            if start > 0 && done == start {
                // The resume point: its evaluation, if the schedule has one there, was recorded
                // before the checkpoint; otherwise there is none (the value is not used).
                let h = history.borrow();
                return Ok(if h.steps.last() == Some(&(done as usize)) {
                    h.test_loss[h.steps.len() - 1]
                } else {
                    f64::NAN
                });
            }
            let value = evaluate(&**model.borrow(), done as usize)?;
            let mut h = history.borrow_mut();
            h.steps.push(done as usize);
            h.test_loss.push(value);
            Ok(value)
        })
        .run_custom_with_state::<crate::Error>(
            |_| schedule.lr,
            CheckpointMeta::at,
            |_| {
                let mut tensors = history.borrow().tensors()?;
                tensors.extend(state(&**model.borrow())?);
                Ok(tensors)
            },
            |it, _| {
                let (loss, agreement) = step(&mut **model.borrow_mut(), (it as usize % n_batches) * schedule.batch)?;
                let update = Update::loss(loss);
                Ok(match agreement {
                    Some(a) => {
                        let mut h = history.borrow_mut();
                        h.agree_sum += a;
                        h.agree_n += 1;
                        update.with("agreement", a)
                    }
                    None => update,
                })
            },
        )?;
    let h = history.into_inner();
    let agreement = (h.agree_n > 0).then(|| h.agree_sum / h.agree_n as f64);
    Ok(BpttRun { steps: h.steps, test_loss: h.test_loss, seconds: report.seconds, agreement })
}

/// A batch size between 1 and the number `n_train` of training episodes.
fn check_batch(batch: usize, n_train: usize) -> Result<()> {
    if batch == 0 || batch > n_train {
        return Err(crate::Error::InvalidConfig {
            name: "batch",
            value: batch as f64,
            hint: "use a batch size between 1 and the number of training episodes",
        });
    }
    Ok(())
}
