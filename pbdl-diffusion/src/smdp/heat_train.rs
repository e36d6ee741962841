//! Training the heat score network with the 1-step loss, reconstructing initial states from
//! observations with the plain inverse step, the probability-flow ODE and the reverse SDE, and
//! scoring the reconstructions.

use super::heat::{mse, spectral_error, HeatProblem};
use super::heat_net::HeatScoreNet;
use super::physics::PhysicsDrift;
use super::sampler::Sampler;
use crate::{Error, Result};
use candle_core::{Device, Tensor};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{AdamConfig, LoopConfig, OptimizerConfig, TrainLoop};
use rand::Rng;
use std::time::Instant;

use super::heat::HeatPhysics;

/// How to train the heat score network.
#[derive(Clone, Debug, PartialEq)]
pub struct HeatTrainConfig {
    /// Number of training fields (2500 in the paper).
    pub n_train: usize,
    /// Batch size (transitions per update).
    pub batch: usize,
    /// Number of Adam updates.
    pub updates: usize,
    /// Learning rate.
    pub lr: f64,
    /// Seed of data, initial weights and batches.
    pub seed: u64,
    /// Record the mean loss every this many updates.
    pub log_every: usize,
}

impl Default for HeatTrainConfig {
    fn default() -> Self {
        HeatTrainConfig { n_train: 500, batch: 16, updates: 2000, lr: 1e-3, seed: 0, log_every: 100 }
    }
}

/// What a heat training run did.
#[derive(Clone, Debug, Default)]
pub struct HeatTrainReport {
    /// `(update, mean loss over the last log_every updates)`.
    pub losses: Vec<(usize, f64)>,
    /// Wall-clock seconds, data generation included.
    pub seconds: f64,
}

/// The 1-step loss (with the regulariser) of a batch: states `x_t` at times `t`, data states
/// `x_prev` one step earlier.
pub fn heat_one_step_loss(
    problem: &HeatProblem,
    net: &HeatScoreNet,
    x_t: &Tensor,
    t: &[f64],
    x_prev: &Tensor,
) -> Result<Tensor> {
    let dt = problem.dt;
    let s = net.forward(x_t, t)?;
    let pred = (HeatPhysics.inverse_step(x_t, 0.0, dt)? + s.affine(0.5 * dt, 0.0)?)?;
    Ok(((pred - x_prev)?.sqr()?.mean_all()? + s.sqr()?.mean_all()?.affine(0.25 * dt * dt, 0.0)?)?)
}

/// Trains `net` on noisy heat simulations of `cfg.n_train` random fields.
///
/// The updates run as one in-memory [`TrainLoop`] over `net.vars()` ([`TrainLoop::run`]:
/// candle's Adam with betas (0.9, 0.99) at `cfg.lr`, no clipping, no progress bar). A
/// non-finite loss or gradient stops the run with the loop's
/// [`pbdl_core::Error::Diverged`] (in [`Error::Core`]) before that update is applied; before
/// the move onto the loop a non-finite loss gave [`Error::NonFinite`] and a non-finite
/// gradient of a finite loss was applied.
pub fn train_heat(problem: &HeatProblem, net: &HeatScoreNet, cfg: &HeatTrainConfig) -> Result<HeatTrainReport> {
    let start = Instant::now();
    problem.validate()?;
    if cfg.n_train == 0 || cfg.batch == 0 || cfg.log_every == 0 {
        return Err(Error::InvalidConfig {
            name: "n_train/batch/log_every",
            value: format!("{}/{}/{}", cfg.n_train, cfg.batch, cfg.log_every),
            hint: "use positive counts",
        });
    }
    let dtype = net.vars()[0].dtype();
    let x0 = problem.random_fields(cfg.n_train, dtype, cfg.seed)?;
    let states = problem.simulate(&x0, cfg.seed ^ 0x5EED)?;
    // [(steps + 1) * n_train, 1, n, n]: state k of field i is row k * n_train + i.
    let all = Tensor::cat(&states, 0)?;
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, beta1: 0.9, beta2: 0.99, ..Default::default() });
    let mut rng = super::sde::chunk_rng(cfg.seed ^ 0xB47C, 3);
    let steps = problem.steps();
    let run = LoopConfig { steps: cfg.updates as u64, progress: false, ..Default::default() };
    let done = TrainLoop::in_memory(net.vars(), run)?.run::<Error>(
        &adam,
        |_| cfg.lr,
        CheckpointMeta::at,
        |_| {
            let mut cur = Vec::with_capacity(cfg.batch);
            let mut prev = Vec::with_capacity(cfg.batch);
            let mut t = Vec::with_capacity(cfg.batch);
            for _ in 0..cfg.batch {
                let i = rng.random_range(0..cfg.n_train);
                let k = rng.random_range(1..=steps);
                cur.push((k * cfg.n_train + i) as u32);
                prev.push(((k - 1) * cfg.n_train + i) as u32);
                t.push(k as f64 * problem.dt);
            }
            let ci = Tensor::new(cur.as_slice(), &Device::Cpu)?;
            let pi = Tensor::new(prev.as_slice(), &Device::Cpu)?;
            heat_one_step_loss(problem, net, &all.index_select(&ci, 0)?, &t, &all.index_select(&pi, 0)?)
        },
    )?;
    // The mean of every `log_every` losses, summed in update order as before the port.
    let mut report = HeatTrainReport::default();
    let mut acc = 0.0;
    for &(u, loss) in &done.losses {
        let u = u as usize;
        acc += loss;
        if (u + 1) % cfg.log_every == 0 {
            report.losses.push((u + 1, acc / cfg.log_every as f64));
            acc = 0.0;
        }
    }
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Reconstructs the initial states from observations `obs` at `t1`: `net = None` runs the plain
/// inverse step `x - P(x)`; otherwise `sampler` adds the learned correction (weight 1/2 for the
/// ODE, 1 plus noise for the SDE, no noise on the last step).
pub fn reconstruct(
    problem: &HeatProblem,
    net: Option<&HeatScoreNet>,
    obs: &Tensor,
    sampler: Sampler,
    seed: u64,
) -> Result<Tensor> {
    problem.validate()?;
    let dt = problem.dt;
    let steps = problem.steps();
    let b = obs.dim(0)?;
    let mut x = obs.clone();
    for k in (1..=steps).rev() {
        let mut next = HeatPhysics.inverse_step(&x, 0.0, dt)?;
        if let Some(net) = net {
            let s = net.forward(&x, &vec![k as f64 * dt; b])?.detach();
            let w = if sampler == Sampler::ReverseSde { 1.0 } else { 0.5 };
            next = (next + s.affine(w * dt, 0.0)?)?;
            if sampler == Sampler::ReverseSde && k > 1 {
                let xi = pbdl_core::seed::randn(
                    x.shape(),
                    0.0,
                    problem.g * dt.sqrt(),
                    x.dtype(),
                    x.device(),
                    seed.wrapping_add(k as u64),
                )?;
                next = (next + xi)?;
            }
        }
        x = next.detach();
    }
    Ok(x)
}

/// MSE (re-simulated reconstruction vs observation) and spectral error (reconstruction vs the
/// true initial state, k = 1..10) of one reconstruction method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatScores {
    /// `mean (heat_{t1}(x_rec) - obs)^2`.
    pub mse: f64,
    /// Mean `|log P_rec(k) - log P_true(k)|` over k = 1..10.
    pub spectral: f64,
}

/// The reconstruction methods compared on held-out fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatEvalReport {
    /// The true initial states themselves (the noise floor of the MSE).
    pub truth: HeatScores,
    /// The plain inverse step.
    pub plain: HeatScores,
    /// The probability-flow ODE with the learned correction.
    pub ode: HeatScores,
    /// The reverse SDE with the learned correction.
    pub sde: HeatScores,
}

/// Scores the plain, ODE and SDE reconstructions of `count` held-out fields (seeded apart from
/// the training data by `seed`).
pub fn evaluate_heat(problem: &HeatProblem, net: &HeatScoreNet, count: usize, seed: u64) -> Result<HeatEvalReport> {
    let dtype = net.vars()[0].dtype();
    let x0 = problem.random_fields(count, dtype, seed)?;
    let obs = problem.simulate(&x0, seed ^ 0x0B5)?.pop().ok_or_else(|| Error::shape("simulation", "states", "none"))?;
    let score = |rec: &Tensor| -> Result<HeatScores> {
        Ok(HeatScores { mse: mse(&problem.forward_clean(rec)?, &obs)?, spectral: spectral_error(rec, &x0, 10)? })
    };
    Ok(HeatEvalReport {
        truth: score(&x0)?,
        plain: score(&reconstruct(problem, None, &obs, Sampler::ProbabilityFlow, 0)?)?,
        ode: score(&reconstruct(problem, Some(net), &obs, Sampler::ProbabilityFlow, 0)?)?,
        sde: score(&reconstruct(problem, Some(net), &obs, Sampler::ReverseSde, seed ^ 0x5DE)?)?,
    })
}

/// The official evaluation protocol (`heat-diffusion/evaluation`, `Optimizer::eval_reconstruction`):
/// the observation is the noise-free forward simulation of the true state plus Gaussian noise of
/// standard deviation `obs_noise` (0.01 there), and the MSE compares the noise-free forward
/// simulations of the reconstruction and of the true state (so the truth scores 0). The spectral
/// error is the same as in [`evaluate_heat`].
pub fn evaluate_heat_clean_obs(
    problem: &HeatProblem,
    net: &HeatScoreNet,
    count: usize,
    seed: u64,
    obs_noise: f64,
) -> Result<HeatEvalReport> {
    if !(obs_noise >= 0.0 && obs_noise.is_finite()) {
        return Err(Error::InvalidConfig {
            name: "obs_noise",
            value: obs_noise.to_string(),
            hint: "use a finite, non-negative observation noise (0.01 in the official evaluation)",
        });
    }
    let dtype = net.vars()[0].dtype();
    let x0 = problem.random_fields(count, dtype, seed)?;
    let clean = problem.forward_clean(&x0)?;
    let xi = pbdl_core::seed::randn(clean.shape(), 0.0, obs_noise, dtype, clean.device(), seed ^ 0x0B5)?;
    let obs = (&clean + xi)?;
    let score = |rec: &Tensor| -> Result<HeatScores> {
        Ok(HeatScores { mse: mse(&problem.forward_clean(rec)?, &clean)?, spectral: spectral_error(rec, &x0, 10)? })
    };
    Ok(HeatEvalReport {
        truth: score(&x0)?,
        plain: score(&reconstruct(problem, None, &obs, Sampler::ProbabilityFlow, 0)?)?,
        ode: score(&reconstruct(problem, Some(net), &obs, Sampler::ProbabilityFlow, 0)?)?,
        sde: score(&reconstruct(problem, Some(net), &obs, Sampler::ReverseSde, seed ^ 0x5DE)?)?,
    })
}
