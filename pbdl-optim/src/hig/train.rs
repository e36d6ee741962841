//! Training a network through a physics model: HIG / Gauss-Newton steps, an Adam baseline
//! with the same exact gradients, evaluation, and loss-against-wall-clock curves.
//!
//! Conventions (the HIG paper's code and the pbdl-book): the batch loss is
//! `L = sum_s l(y_s, y*_s)` with the per-sample [`Loss`] `l` (by default `||y_s - y*_s||^2`, no
//! 1/2), the reported loss is `L / b` (mean over samples), and the HIG right-hand side is
//! `g = d(L/b)/dy` (for least squares `2 (y - y*) / b`), flattened sample after sample.

use super::loss::Loss;
use super::model::JacobianModel;
use super::solve::{HalfInverse, HigConfig, SolveInfo};
use crate::error::{check_len, Error, Result};
use crate::physics::{Batch, Dataset, Physics};
use candle_core::{Device, Tensor, Var};
use candle_nn::Optimizer;
use faer::{MatRef, Par};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, Optim, OptimizerConfig, TrainLoop, Update as LoopUpdate};
use rayon::prelude::*;
use std::any::Any;
use std::cell::RefCell;
use std::time::Instant;

/// Checks that `net`, `physics` and `batch` fit together and runs the network on the batch.
/// Returns the controls `u: [b, nu]` (held in `cache`).
fn forward_net<'c, M: JacobianModel + ?Sized>(
    net: &M,
    physics: &dyn Physics,
    batch: Batch<'_>,
    cache: &'c mut M::Cache,
) -> Result<&'c [f64]> {
    let (b, nu, ny, nx) = (batch.len, physics.control_dim(), physics.output_dim(), physics.context_dim());
    check_len("network output width vs physics control length", nu, net.out_dim())?;
    check_len("batch targets length", b * ny, batch.targets.len())?;
    check_len("batch contexts length", b * nx, batch.contexts.len())?;
    net.forward(batch.inputs, b, cache)?;
    Ok(net.output(cache))
}

/// Runs the network on a batch and the physics (with its Jacobian) on every sample, in
/// parallel. Fills `y: [b, ny]` and `jp: [b, ny, nu]`.
fn forward_with_physics_jacobian<M: JacobianModel + ?Sized>(
    net: &M,
    physics: &dyn Physics,
    batch: Batch<'_>,
    cache: &mut M::Cache,
    y: &mut Vec<f64>,
    jp: &mut Vec<f64>,
) -> Result<()> {
    let (b, nu, ny, nx) = (batch.len, physics.control_dim(), physics.output_dim(), physics.context_dim());
    let u = forward_net(net, physics, batch, cache)?;
    y.resize(b * ny, 0.0);
    jp.resize(b * ny * nu, 0.0);
    y.par_chunks_mut(ny).zip(jp.par_chunks_mut(ny * nu)).enumerate().try_for_each(|(s, (ys, js))| {
        physics.jacobian(&batch.contexts[s * nx..(s + 1) * nx], &u[s * nu..(s + 1) * nu], ys, js)
    })
}

/// Loss `sum_s l(y_s, y*_s) / b` and its gradient `g = d(L/b)/dy`, for samples of length `ny`.
fn loss_and_gradient(loss: Loss, y: &[f64], target: &[f64], b: usize, ny: usize, g: &mut Vec<f64>) -> Result<f64> {
    if ny == 0 {
        return Err(Error::shape("physics output length", "> 0", 0));
    }
    g.resize(y.len(), 0.0);
    let inv_b = 1.0 / b as f64;
    let mut total = 0.0;
    for ((gs, ys), ts) in g.chunks_exact_mut(ny).zip(y.chunks_exact(ny)).zip(target.chunks_exact(ny)) {
        total += loss.value_and_gradient(ys, ts, gs)?;
        gs.iter_mut().for_each(|v| *v *= inv_b);
    }
    Ok(total * inv_b)
}

/// The exact composed Jacobian `J = J_phys J_net` of a batch, `[b * ny, n_params]` row-major
/// (row `s * ny + k` is output component `k` of sample `s`), with the outcomes `y`.
///
/// Each row is one backward pass through the network with the physics Jacobian's row as the
/// cotangent: no finite differences anywhere. Works for any [`JacobianModel`] (`&Mlp`,
/// `&CandleModel`, ...).
pub fn composed_jacobian<M: JacobianModel + ?Sized>(
    net: &M,
    physics: &dyn Physics,
    batch: Batch<'_>,
) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut cache = M::Cache::default();
    let (mut y, mut jp) = (Vec::new(), Vec::new());
    forward_with_physics_jacobian(net, physics, batch, &mut cache, &mut y, &mut jp)?;
    let rows = batch.len * physics.output_dim();
    let mut j = vec![0.0; rows * net.n_params()];
    net.jacobian_rows(&cache, &jp, physics.output_dim(), &mut j)?;
    Ok((j, y))
}

/// Buffers kept between steps. The model's cache is stored type-erased so that the trainers
/// need no type parameter: a step with another model type starts a fresh one.
#[derive(Debug)]
struct Workspace {
    cache: Box<dyn Any + Send>,
    y: Vec<f64>,
    jp: Vec<f64>,
    g: Vec<f64>,
}

impl Default for Workspace {
    fn default() -> Self {
        Self { cache: Box::new(()), y: Vec::new(), jp: Vec::new(), g: Vec::new() }
    }
}

/// The cache of type `C` in `slot`, replacing whatever else it held by a fresh one.
fn cache_of<C: Default + Send + 'static>(slot: &mut Box<dyn Any + Send>) -> &mut C {
    if !slot.is::<C>() {
        *slot = Box::new(C::default());
    }
    match slot.downcast_mut::<C>() {
        Some(c) => c,
        None => unreachable!("the slot was just set to a C"),
    }
}

/// What a trainer's step needs from the forward pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Forward {
    /// Outcomes `y` and the physics Jacobians `jp` (HIG / Gauss-Newton).
    WithJacobian,
    /// Outcomes `y` only (Adam, which then takes the physics VJP).
    OutcomesOnly,
}

impl Workspace {
    /// Runs the network and the physics on `batch` (with `J_phys` as `forward` asks), then the
    /// loss and its gradient `g`; [`Error::Diverged`] at `step` for a non-finite loss. Returns
    /// the loss; `y`, `jp`, `g` and the model's cache hold the pass.
    fn forward_loss<M: JacobianModel + ?Sized>(
        &mut self,
        net: &M,
        physics: &dyn Physics,
        batch: Batch<'_>,
        (loss, step): (Loss, u64),
        forward: Forward,
    ) -> Result<f64> {
        let cache = cache_of::<M::Cache>(&mut self.cache);
        let (b, nu, ny, nx) = (batch.len, physics.control_dim(), physics.output_dim(), physics.context_dim());
        match forward {
            Forward::WithJacobian => {
                forward_with_physics_jacobian(net, physics, batch, cache, &mut self.y, &mut self.jp)?;
            }
            Forward::OutcomesOnly => {
                let u = forward_net(net, physics, batch, cache)?;
                self.y.resize(b * ny, 0.0);
                self.y.par_chunks_mut(ny).enumerate().try_for_each(|(s, ys)| {
                    physics.forward(&batch.contexts[s * nx..(s + 1) * nx], &u[s * nu..(s + 1) * nu], ys)
                })?;
            }
        }
        let value = loss_and_gradient(loss, &self.y, batch.targets, b, ny, &mut self.g)?;
        check_diverged(step, value)?;
        Ok(value)
    }
}

/// The update a trainer takes after [`Workspace::forward_loss`]: the SVD's numbers, if any.
type Update = Result<Option<SolveInfo>>;

/// The methods both trainers share: `with_loss`, `loss` and `step` (the forward pass and loss
/// of [`Workspace::forward_loss`], then the trainer's own `update`, counting the step). Takes
/// the doc of `step` and the [`Forward`] the trainer needs.
macro_rules! trainer_step {
    ($(#[$step_doc:meta])* forward: $forward:expr) => {
        /// The same trainer minimising `loss` (default [`Loss::SquaredError`]).
        pub fn with_loss(mut self, loss: Loss) -> Self {
            self.loss = loss;
            self
        }

        /// The per-sample loss.
        pub fn loss(&self) -> Loss {
            self.loss
        }

        $(#[$step_doc])*
        pub fn step<M: JacobianModel + ?Sized>(
            &mut self,
            net: &mut M,
            physics: &dyn Physics,
            batch: Batch<'_>,
        ) -> Result<StepInfo> {
            let loss = self.ws.forward_loss(&*net, physics, batch, (self.loss, self.step), $forward)?;
            let solve = self.update(net, physics, batch)?;
            Ok(StepInfo::next(&mut self.step, loss, solve))
        }
    };
}

/// What one training step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepInfo {
    /// Step index (0-based).
    pub step: u64,
    /// Batch loss per sample *before* the update.
    pub loss: f64,
    /// The SVD's numbers (HIG/GN only).
    pub solve: Option<SolveInfo>,
}

impl StepInfo {
    /// The info of step `*step`, counting the step.
    fn next(step: &mut u64, loss: f64, solve: Option<SolveInfo>) -> Self {
        let out = Self { step: *step, loss, solve };
        *step += 1;
        out
    }
}

/// [`Error::Diverged`] at `step` when the batch loss is not finite (checked before the update).
fn check_diverged(step: u64, loss: f64) -> Result<()> {
    if loss.is_finite() {
        Ok(())
    } else {
        Err(Error::Diverged { step, loss, last_good: step.saturating_sub(1) })
    }
}

/// HIG (or Gauss-Newton, exponent 1) training: exact composed Jacobian, half-inverse solve,
/// plain SGD step. Buffers are kept across steps.
#[derive(Debug)]
pub struct HigTrainer {
    cfg: HigConfig,
    loss: Loss,
    solver: HalfInverse,
    ws: Workspace,
    jac: Vec<f64>,
    dtheta: Vec<f64>,
    step: u64,
}

impl HigTrainer {
    /// A trainer with the given settings; faer runs on the global rayon pool.
    pub fn new(cfg: HigConfig) -> Result<Self> {
        Self::with_par(cfg, Par::rayon(0))
    }

    /// A trainer whose SVD uses `par`.
    pub fn with_par(cfg: HigConfig, par: Par) -> Result<Self> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            loss: Loss::SquaredError,
            solver: HalfInverse::new(0, 0, par),
            ws: Workspace::default(),
            jac: Vec::new(),
            dtheta: Vec::new(),
            step: 0,
        })
    }

    trainer_step! {
        /// One step on `batch`: `theta -= eta V diag(s^-kappa) U^T g`.
        ///
        /// A non-finite loss returns [`Error::Diverged`] before the update, so `net` keeps the
        /// parameters of the last good step.
        forward: Forward::WithJacobian
    }

    /// The settings.
    pub fn config(&self) -> &HigConfig {
        &self.cfg
    }

    /// The solver (singular values and vectors of the last step).
    pub fn solver(&self) -> &HalfInverse {
        &self.solver
    }

    /// `J = J_phys J_net` of the batch, the half-inverse solve, the update of `net`.
    fn update<M: JacobianModel + ?Sized>(&mut self, net: &mut M, physics: &dyn Physics, batch: Batch<'_>) -> Update {
        let cache = cache_of::<M::Cache>(&mut self.ws.cache);
        let (rows, p) = (batch.len * physics.output_dim(), net.n_params());
        self.jac.resize(rows * p, 0.0);
        net.jacobian_rows(cache, &self.ws.jp, physics.output_dim(), &mut self.jac)?;
        self.dtheta.resize(p, 0.0);
        let j = MatRef::from_row_major_slice(&self.jac, rows, p);
        let info = self.solver.solve(&self.cfg, j, &self.ws.g, &mut self.dtheta)?;
        net.apply_update(self.cfg.eta, &self.dtheta)?;
        Ok(Some(info))
    }
}

/// The Adam baseline: the exact loss gradient `sum_s J_net,s^T J_phys,s^T g_s` (ordinary
/// backprop through the same network and physics: [`Physics::vjp`], then the network's
/// backward pass), updated by pbdl-core's Adam.
pub struct AdamTrainer {
    opt: Optim,
    loss: Loss,
    theta: Var,
    ws: Workspace,
    cot: Vec<f64>,
    grad: Vec<f64>,
    step: u64,
}

impl std::fmt::Debug for AdamTrainer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AdamTrainer").field("step", &self.step).finish()
    }
}

impl AdamTrainer {
    /// Adam with learning rate `lr` (other settings at their defaults) for `net`'s parameters.
    pub fn new<M: JacobianModel + ?Sized>(net: &M, lr: f64) -> Result<Self> {
        let mut params = vec![0.0; net.n_params()];
        net.read_params(&mut params)?;
        let theta = Var::from_slice(&params, params.len(), &Device::Cpu)?;
        let opt = OptimizerConfig::Adam(AdamConfig { lr, ..Default::default() }).build(vec![theta.clone()])?;
        Ok(Self {
            opt,
            loss: Loss::SquaredError,
            theta,
            ws: Workspace::default(),
            cot: Vec::new(),
            grad: Vec::new(),
            step: 0,
        })
    }

    trainer_step! {
        /// One Adam step on `batch`. The network's parameters must not be changed elsewhere
        /// between steps (Adam keeps its own copy and its moments).
        forward: Forward::OutcomesOnly
    }

    /// The exact gradient (physics VJP, then the network's backward pass) and the Adam update.
    fn update<M: JacobianModel + ?Sized>(&mut self, net: &mut M, physics: &dyn Physics, batch: Batch<'_>) -> Update {
        let cache = cache_of::<M::Cache>(&mut self.ws.cache);
        let (b, nu, ny, nx) = (batch.len, physics.control_dim(), physics.output_dim(), physics.context_dim());
        let u = net.output(cache);
        // Physics VJP per sample: cot_s = J_phys,s^T g_s.
        self.cot.resize(b * nu, 0.0);
        let g = &self.ws.g;
        self.cot.par_chunks_mut(nu).enumerate().try_for_each(|(s, c)| {
            physics.vjp(&batch.contexts[s * nx..(s + 1) * nx], &u[s * nu..(s + 1) * nu], &g[s * ny..(s + 1) * ny], c)
        })?;
        self.grad.resize(net.n_params(), 0.0);
        net.gradient(cache, &self.cot, &mut self.grad)?;
        crate::error::check_finite("loss gradient", &self.grad, 1)?;
        // Feed the gradient to candle's optimiser: d/dtheta (theta . G) = G.
        let g = Tensor::from_slice(&self.grad, self.grad.len(), &Device::Cpu)?;
        let surrogate = (self.theta.as_tensor() * g)?.sum_all()?;
        self.opt.backward_step(&surrogate)?;
        net.write_params(&self.theta.as_tensor().to_vec1::<f64>()?)?;
        Ok(None)
    }
}

/// Mean loss per sample `sum_s ||P(x_s; f(i_s)) - y*_s||^2 / n` over a data set.
pub fn evaluate<M: JacobianModel + ?Sized>(net: &M, physics: &dyn Physics, data: &Dataset) -> Result<f64> {
    evaluate_with_loss(net, physics, Loss::SquaredError, data)
}

/// Mean loss per sample `sum_s l(P(x_s; f(i_s)), y*_s) / n` over a data set.
pub fn evaluate_with_loss<M: JacobianModel + ?Sized>(
    net: &M,
    physics: &dyn Physics,
    loss: Loss,
    data: &Dataset,
) -> Result<f64> {
    loss.check_dim(physics.output_dim())?;
    let mut cache = M::Cache::default();
    let all = data.all();
    net.forward(all.inputs, all.len, &mut cache)?;
    let (nu, ny, nx) = (physics.control_dim(), physics.output_dim(), physics.context_dim());
    check_len("network output width vs physics control length", nu, net.out_dim())?;
    let u = net.output(&cache);
    let total: f64 = (0..all.len)
        .into_par_iter()
        .map(|s| -> Result<f64> {
            let mut y = vec![0.0; ny];
            physics.forward(&all.contexts[s * nx..(s + 1) * nx], &u[s * nu..(s + 1) * nu], &mut y)?;
            loss.value(&y, &all.targets[s * ny..(s + 1) * ny])
        })
        .collect::<Result<Vec<f64>>>()?
        .into_iter()
        .sum();
    Ok(total / all.len as f64)
}

/// Which optimiser a [`run_curve`] uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// HIG or Gauss-Newton with these settings.
    Hig(HigConfig),
    /// Adam with this learning rate.
    Adam {
        /// Learning rate.
        lr: f64,
    },
}

/// When a [`run_curve`] stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    /// Seconds of training (evaluation excluded).
    pub seconds: f64,
    /// At most this many steps.
    pub max_steps: u64,
}

/// Loss against training wall-clock time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Curve {
    /// Training seconds at each evaluation (evaluation time excluded).
    pub seconds: Vec<f64>,
    /// Steps done at each evaluation.
    pub steps: Vec<u64>,
    /// Evaluation loss at each evaluation.
    pub loss: Vec<f64>,
    /// Wall-clock seconds of every training step.
    pub step_seconds: Vec<f64>,
    /// `Some(step)` when the loss became NaN/Inf at `step` and the run stopped there; the
    /// curve holds the evaluations before it.
    pub diverged_at: Option<u64>,
}

impl Curve {
    /// The last evaluation loss.
    pub fn final_loss(&self) -> f64 {
        self.loss.last().copied().unwrap_or(f64::NAN)
    }

    /// Median wall-clock seconds of one training step (NaN without steps).
    pub fn median_step_seconds(&self) -> f64 {
        let mut t = self.step_seconds.clone();
        if t.is_empty() {
            return f64::NAN;
        }
        t.sort_by(|a, b| a.total_cmp(b));
        let n = t.len();
        if n % 2 == 1 {
            t[n / 2]
        } else {
            0.5 * (t[n / 2 - 1] + t[n / 2])
        }
    }
}

/// Trains `net` with `method` and batch size `batch` over `train` (cycling through it in order),
/// evaluating on `eval` every `eval_every` steps, until the budget is spent.
///
/// A non-finite training loss stops the run: the curve is returned with
/// [`Curve::diverged_at`] set and `net` keeps the parameters of the last good step. A
/// non-finite evaluation loss (after an update) also stops it; that point is not recorded.
pub fn run_curve<M: JacobianModel + ?Sized>(
    net: &mut M,
    physics: &dyn Physics,
    method: Method,
    train: &Dataset,
    eval: &Dataset,
    batch: usize,
    budget: Budget,
    eval_every: u64,
) -> Result<Curve> {
    run_curve_with_loss(net, physics, Loss::SquaredError, method, train, eval, batch, budget, eval_every)
}

/// [`run_curve`] minimising (and evaluating) the per-sample `loss`.
pub fn run_curve_with_loss<M: JacobianModel + ?Sized>(
    net: &mut M,
    physics: &dyn Physics,
    loss: Loss,
    method: Method,
    train: &Dataset,
    eval: &Dataset,
    batch: usize,
    budget: Budget,
    eval_every: u64,
) -> Result<Curve> {
    if batch == 0 || batch > train.len {
        return Err(Error::shape("batch size", format!("1..={}", train.len), batch));
    }
    let mut hig = match method {
        Method::Hig(cfg) => Some(HigTrainer::new(cfg)?.with_loss(loss)),
        Method::Adam { .. } => None,
    };
    let mut adam = match method {
        Method::Adam { lr } => Some(AdamTrainer::new(&*net, lr)?.with_loss(loss)),
        Method::Hig(_) => None,
    };
    let n_batches = train.len / batch;
    // The curve is filled as the run goes, so that a diverged run keeps what came before.
    let curve = RefCell::new(Curve::default());
    let net = RefCell::new(net);
    let cfg = LoopConfig {
        steps: budget.max_steps,
        progress: false,
        time_budget_seconds: budget.seconds.is_finite().then_some(budget.seconds),
        ..Default::default()
    };
    let result = TrainLoop::in_memory(Vec::new(), cfg)?
        .evaluate_every(eval_every.max(1), |done| -> Result<f64> {
            let value = evaluate_with_loss(&**net.borrow(), physics, loss, eval)?;
            if value.is_finite() {
                let mut c = curve.borrow_mut();
                let elapsed = c.step_seconds.iter().sum();
                c.seconds.push(elapsed);
                c.steps.push(done);
                c.loss.push(value);
            }
            Ok(value)
        })
        .run_custom::<Error>(
            |_| 0.0,
            CheckpointMeta::at,
            |step, _| {
                let b = train.batch((step as usize % n_batches) * batch, batch);
                let net = &mut **net.borrow_mut();
                let t = Instant::now();
                let info = match (&mut hig, &mut adam) {
                    (Some(h), _) => h.step(net, physics, b)?,
                    (_, Some(a)) => a.step(net, physics, b)?,
                    _ => unreachable!("one trainer is set"),
                };
                curve.borrow_mut().step_seconds.push(t.elapsed().as_secs_f64());
                Ok(LoopUpdate::loss(info.loss))
            },
        );
    let mut curve = curve.into_inner();
    match result {
        Ok(_) => Ok(curve),
        // A non-finite training loss (before its update) or evaluation loss (after one).
        Err(Error::Diverged { step, .. }) | Err(Error::Core(pbdl_core::Error::Diverged { step, .. })) => {
            curve.diverged_at = Some(step);
            Ok(curve)
        }
        Err(e) => Err(e),
    }
}
