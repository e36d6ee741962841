//! Training the toy's score network on simulated paths, and measuring it against the analytic
//! score of the affine case.

use super::analytic::AffineMixture;
use super::loss::{graded_one_step_loss, multi_step_loss, one_step_loss, LossWorkspace};
use super::mlp::{paper_adam, ScoreMlp};
use super::sampler::CoarseSteps;
use super::sde::{chunk_rng, two_point_starts, Paths, ToySde};
use crate::{Error, Result};
use pbdl_core::io::CheckpointMeta;
use pbdl_core::train::{LoopConfig, TrainLoop, Update};
use rand::Rng;
use std::time::Instant;

/// Which loss a training stage uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToyLoss {
    /// The 1-step loss with the `(1/4) dt^2 ||s||^2` regulariser.
    OneStep,
    /// The multi-step loss over a window of this many steps (no regulariser), backpropagated
    /// through the whole rollout.
    MultiStep(usize),
    /// The 1-step loss over `stride` data steps (step `h = stride dt`; the official code's
    /// "subsample"), at the official time grid `k = steps - stride j`. `bidirectional: false`
    /// adds the `(1/4) h^2 ||s||^2` regulariser; `true` instead follows the official
    /// `bidirectional` option: one Adam step on the backward window `x_k -> x_{k-stride}`, then
    /// one on the reversed window `x_{k-stride} -> x_k` (step `-h`, score at `t_{k-stride}`), no
    /// regulariser. Both directions count as one update, as in the official code.
    Strided {
        /// Data steps per training step (5 in the official first stage, then 1).
        stride: usize,
        /// Train both time directions instead of adding the regulariser.
        bidirectional: bool,
    },
    /// The regularised 1-step loss on the graded time grid of
    /// [`super::sampler::CoarseSteps`]: transitions over `stride` data steps wherever such a step
    /// ends at or above `fine_below`, over single data steps below
    /// ([`super::loss::graded_one_step_loss`]). Training times start at the first step.
    Graded {
        /// Data steps per coarse step.
        stride: usize,
        /// Coarse steps end at or above this time.
        fine_below: f64,
        /// Loss weight of a single-step sample relative to a coarse one (`stride^2` weighs both
        /// alike in units of the score; 1 keeps the plain loss's `h^2` scaling).
        fine_weight: f64,
    },
}

impl ToyLoss {
    /// How many data steps a sample spans (the largest `m` in `x_{k-m}` that it reads).
    fn span(&self) -> usize {
        match *self {
            ToyLoss::OneStep => 1,
            ToyLoss::MultiStep(w) => w,
            ToyLoss::Strided { stride, .. } | ToyLoss::Graded { stride, .. } => stride,
        }
    }

    /// The earliest step index a training sample can start from.
    fn first_index(&self) -> usize {
        match *self {
            ToyLoss::Graded { .. } => 1,
            _ => self.span(),
        }
    }
}

/// One stage of training: a loss, a learning rate, a number of Adam updates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToyStage {
    /// The loss.
    pub loss: ToyLoss,
    /// Adam's learning rate.
    pub lr: f64,
    /// Number of updates.
    pub updates: usize,
}

/// How training times are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimeSampling {
    /// Every step index equally often (what iterating over whole paths does).
    Uniform,
    /// Step indices log-uniform: small `t`, where the score is large and changes fast, is
    /// visited as often per decade of `t` as large `t`.
    LogUniform,
}

/// How to train the toy score network.
#[derive(Clone, Debug, PartialEq)]
pub struct ToyTrainConfig {
    /// Number of simulated training paths (2500 in the paper), half from `+1`, half from `-1`.
    pub n_paths: usize,
    /// Batch size (256).
    pub batch: usize,
    /// Stages, run in order with one Adam state each.
    pub stages: Vec<ToyStage>,
    /// Seed of the training paths and of the batches.
    pub seed: u64,
    /// Record the mean loss every this many updates.
    pub log_every: usize,
    /// How training times are drawn.
    pub time_sampling: TimeSampling,
    /// Euler-Maruyama sub-steps per stored data step (1: the data chain has step `dt`; the
    /// official data set integrates with `dt / 2` and stores every `dt`, i.e. 2).
    pub sim_substeps: usize,
    /// Training samples start at times in `[lo, hi]` (an expert for one time interval, see
    /// [`super::experts::SplitExpertRecipe`]); `(0, inf)`: everywhere.
    pub time_range: (f64, f64),
}

impl ToyTrainConfig {
    /// The 1-step (regularised) schedule: `updates_hi` at lr 1e-3, then `updates_lo` at 1e-4.
    pub fn one_step(updates_hi: usize, updates_lo: usize) -> Self {
        ToyTrainConfig {
            n_paths: 2500,
            batch: 256,
            stages: vec![
                ToyStage { loss: ToyLoss::OneStep, lr: 1e-3, updates: updates_hi },
                ToyStage { loss: ToyLoss::OneStep, lr: 1e-4, updates: updates_lo },
            ],
            seed: 0,
            log_every: 1000,
            time_sampling: TimeSampling::Uniform,
            sim_substeps: 1,
            time_range: (0.0, f64::INFINITY),
        }
    }

    /// The growing-window schedule: windows `start, start + inc, ...` (`stages` of them), each
    /// for `updates` updates at `lr`.
    pub fn sliding_window(start: usize, inc: usize, stages: usize, updates: usize, lr: f64) -> Self {
        ToyTrainConfig {
            n_paths: 2500,
            batch: 256,
            stages: (0..stages).map(|i| ToyStage { loss: ToyLoss::MultiStep(start + i * inc), lr, updates }).collect(),
            seed: 0,
            log_every: 1000,
            time_sampling: TimeSampling::Uniform,
            sim_substeps: 1,
            time_range: (0.0, f64::INFINITY),
        }
    }

    /// The official toy notebook's recipe (`training_and_inference.ipynb`): the 1-step loss
    /// trained in both time directions, `updates_hi` updates at lr 1e-3 on every 5th data point
    /// (step `5 dt`), then `updates_lo` at lr 1e-4 on every point; data integrated at `dt / 2`.
    /// The notebook runs 250k + 250k updates (of batches of its 250 paths; here 2500 paths,
    /// batch 256, as in the paper's 100% data set).
    pub fn official(updates_hi: usize, updates_lo: usize) -> Self {
        let stage =
            |stride, lr, updates| ToyStage { loss: ToyLoss::Strided { stride, bidirectional: true }, lr, updates };
        ToyTrainConfig {
            stages: vec![stage(5, 1e-3, updates_hi), stage(1, 1e-4, updates_lo)],
            sim_substeps: 2,
            ..Self::one_step(0, 0)
        }
    }

    fn validate(&self, steps: usize) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.n_paths == 0 || self.batch == 0 || self.log_every == 0 || self.sim_substeps == 0 {
            return bad(
                "n_paths/batch/log_every/sim_substeps",
                format!("{}/{}/{}/{}", self.n_paths, self.batch, self.log_every, self.sim_substeps),
                "use positive counts (2500 paths, batch 256, 1 or 2 sub-steps)",
            );
        }
        let (lo, hi) = self.time_range;
        if !(lo >= 0.0 && hi > lo && lo.is_finite()) {
            return bad("time_range", format!("{lo}..{hi}"), "use 0 <= lo < hi (hi may be infinite)");
        }
        for s in &self.stages {
            let w = s.loss.span();
            if w == 0 || w > steps {
                return bad(
                    "window/stride",
                    w.to_string(),
                    "use a window or stride between 1 and the number of SDE steps",
                );
            }
            if let ToyLoss::Graded { fine_below, fine_weight, .. } = s.loss {
                if !(fine_below.is_finite() && fine_below >= 0.0 && fine_weight.is_finite() && fine_weight > 0.0) {
                    return bad(
                        "fine_below/fine_weight",
                        format!("{fine_below}/{fine_weight}"),
                        "use a finite, non-negative time and a positive weight",
                    );
                }
            }
            if !(s.lr.is_finite() && s.lr > 0.0) {
                return bad("lr", s.lr.to_string(), "use a positive learning rate (1e-3, then 1e-4)");
            }
        }
        Ok(())
    }
}

/// What a training run did.
#[derive(Clone, Debug, Default)]
pub struct ToyTrainReport {
    /// `(update, mean loss over the last log_every updates, stage)`.
    pub losses: Vec<(usize, f64, usize)>,
    /// Wall-clock seconds of the whole run (simulation included).
    pub seconds: f64,
    /// Seconds spent simulating the training paths.
    pub simulate_seconds: f64,
}

/// Simulates the training paths of `cfg` (half from `+1`, half from `-1`): integrated with step
/// `dt / sim_substeps`, stored every `dt`.
pub fn training_paths(sde: &ToySde, cfg: &ToyTrainConfig) -> Result<Paths> {
    let sub = cfg.sim_substeps.max(1);
    let fine = ToySde { dt: sde.dt / sub as f64, ..*sde };
    let paths = fine.simulate(&two_point_starts(cfg.n_paths), cfg.seed)?;
    if sub == 1 {
        return Ok(paths);
    }
    let steps = sde.steps();
    let mut data = Vec::with_capacity(cfg.n_paths * (steps + 1));
    for p in 0..paths.n_paths {
        data.extend(paths.path(p).iter().step_by(sub).take(steps + 1));
    }
    if data.len() != cfg.n_paths * (steps + 1) {
        return Err(Error::InvalidConfig {
            name: "sim_substeps",
            value: sub.to_string(),
            hint: "use sub-steps that divide the time step evenly (t_end / dt must stay an integer)",
        });
    }
    Ok(Paths { n_paths: cfg.n_paths, steps, dt: sde.dt, data })
}

/// Trains `net` on `sde`'s paths following `cfg`.
///
/// Each stage is one in-memory [`TrainLoop`] run ([`TrainLoop::run_custom`], no progress bar)
/// whose update draws the batch, computes the loss and its hand-written gradient and takes the
/// stage's own Adam step ([`paper_adam`], fresh per stage); the batches come from one random
/// stream over all stages. A non-finite loss stops the run with [`Error::NonFinite`] (step
/// counted over all stages) before its update is applied (a bidirectional update has then
/// applied its backward half).
pub fn train_toy(sde: &ToySde, net: &mut ScoreMlp, cfg: &ToyTrainConfig) -> Result<ToyTrainReport> {
    let start = Instant::now();
    sde.validate()?;
    let steps = sde.steps();
    cfg.validate(steps)?;
    let paths = training_paths(sde, cfg)?;
    let simulate_seconds = start.elapsed().as_secs_f64();
    let mut rng = chunk_rng(cfg.seed ^ 0xBA7C, 1);
    let b = cfg.batch;
    let (mut x, mut t, mut prev) = (vec![0.0; b], vec![0.0; b], vec![0.0; b]);
    let mut grad = vec![0.0; net.num_params()];
    let mut ws = LossWorkspace::default();
    let mut report = ToyTrainReport { simulate_seconds, ..Default::default() };
    let mut total = 0;
    for (si, stage) in cfg.stages.iter().enumerate() {
        let mut adam = paper_adam(net.num_params(), stage.lr);
        let window = stage.loss.span();
        // The step indices this stage may start from: the loss's first one and the time range.
        let (lo_t, hi_t) = cfg.time_range;
        let first = stage.loss.first_index().max((lo_t / sde.dt - 1e-9).ceil() as usize);
        let last = if hi_t.is_finite() { steps.min((hi_t / sde.dt + 1e-9).floor() as usize) } else { steps };
        if first > last {
            return Err(Error::InvalidConfig {
                name: "time_range",
                value: format!("{lo_t}..{hi_t} with {window} data steps per sample"),
                hint: "give a time range that holds at least one training step",
            });
        }
        // The official strided grid k = steps - stride j, restricted to [first, last].
        let grid_j = |stride: usize| (steps - last).div_ceil(stride)..=(steps - first) / stride;
        if let (ToyLoss::Strided { stride, .. }, TimeSampling::Uniform) = (stage.loss, cfg.time_sampling) {
            if grid_j(stride).is_empty() {
                return Err(Error::InvalidConfig {
                    name: "time_range",
                    value: format!("{lo_t}..{hi_t} with stride {stride}"),
                    hint: "give a time range that holds a point of the strided grid (or log-uniform times)",
                });
            }
        }
        let grid = match stage.loss {
            ToyLoss::Graded { stride, fine_below, fine_weight } => {
                Some((CoarseSteps { stride, above: fine_below }, fine_weight))
            }
            _ => None,
        };
        let (mut h, mut w) = (vec![sde.dt; b], vec![1.0; b]);
        let mut targets = vec![vec![0.0; b]; window];
        let run = LoopConfig { steps: stage.updates as u64, progress: false, ..Default::default() };
        // The stage's own Adam over the hand-written gradient; the loop only frames the updates.
        let done = TrainLoop::in_memory(Vec::new(), run)?.run_custom::<Error>(
            |_| stage.lr,
            CheckpointMeta::at,
            |u, _lr| {
                let u = u as usize;
                for i in 0..b {
                    let p = rng.random_range(0..paths.n_paths);
                    let k = match (stage.loss, cfg.time_sampling) {
                        // The official grid: every stride-th point counted from t = T.
                        (ToyLoss::Strided { stride, .. }, TimeSampling::Uniform) => {
                            steps - stride * rng.random_range(grid_j(stride))
                        }
                        (_, TimeSampling::Uniform) => rng.random_range(first..=last),
                        (_, TimeSampling::LogUniform) => {
                            let u: f64 = rng.random_range(0.0..1.0);
                            let (lo, hi) = ((first as f64).ln(), ((last + 1) as f64).ln());
                            ((lo + u * (hi - lo)).exp().floor() as usize).clamp(first, last)
                        }
                    };
                    let path = paths.path(p);
                    x[i] = path[k];
                    t[i] = k as f64 * sde.dt;
                    if let Some((g, fine_weight)) = grid {
                        let stride = g.stride_at(k, sde.dt);
                        h[i] = stride as f64 * sde.dt;
                        w[i] = if stride < g.stride { fine_weight } else { 1.0 };
                        prev[i] = path[k - stride];
                        continue;
                    }
                    for (m, tg) in targets.iter_mut().enumerate() {
                        tg[i] = path[k - 1 - m];
                    }
                    prev[i] = path[k - window];
                }
                grad.fill(0.0);
                let loss = match stage.loss {
                    ToyLoss::OneStep => one_step_loss(net, &sde.drift, sde.dt, &x, &t, &prev, Some(&mut grad), &mut ws),
                    ToyLoss::MultiStep(_) => {
                        multi_step_loss(net, &sde.drift, sde.dt, &x, &t, &targets, false, Some(&mut grad), &mut ws)
                    }
                    ToyLoss::Graded { .. } => {
                        graded_one_step_loss(net, &sde.drift, &h, &w, &x, &t, &prev, Some(&mut grad), &mut ws)
                    }
                    ToyLoss::Strided { stride, bidirectional: false } => {
                        let h = stride as f64 * sde.dt;
                        one_step_loss(net, &sde.drift, h, &x, &t, &prev, Some(&mut grad), &mut ws)
                    }
                    ToyLoss::Strided { stride, bidirectional: true } => {
                        let h = stride as f64 * sde.dt;
                        let back = multi_step_loss(
                            net,
                            &sde.drift,
                            h,
                            &x,
                            &t,
                            std::slice::from_ref(&prev),
                            false,
                            Some(&mut grad),
                            &mut ws,
                        );
                        adam.step(net.params_mut(), &grad)?;
                        grad.fill(0.0);
                        // The reversed window: from x_{k-stride} forward to x_k with step -h.
                        let t_prev: Vec<f64> = t.iter().map(|v| (v - h).max(0.0)).collect();
                        let fwd = multi_step_loss(
                            net,
                            &sde.drift,
                            -h,
                            &prev,
                            &t_prev,
                            std::slice::from_ref(&x),
                            false,
                            Some(&mut grad),
                            &mut ws,
                        );
                        back + fwd
                    }
                };
                if !loss.is_finite() {
                    return Err(Error::NonFinite { what: "toy training loss".into(), step: (total + u) as u64 });
                }
                adam.step(net.params_mut(), &grad)?;
                Ok(Update::loss(loss))
            },
        )?;
        // The mean of every `log_every` losses, summed in update order as before the port.
        let mut acc = 0.0;
        for &(u, loss) in &done.losses {
            let u = u as usize;
            acc += loss;
            if (u + 1) % cfg.log_every == 0 {
                report.losses.push((total + u + 1, acc / cfg.log_every as f64, si));
                acc = 0.0;
            }
        }
        total += stage.updates;
    }
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// The learned score against the analytic one of the affine case.
#[derive(Clone, Debug, PartialEq)]
pub struct ScoreErrorReport {
    /// Relative L2 error `||s - s_ref|| / ||s_ref||`, pooled over all grid points `(x, t)` where
    /// `p_t(x) > 1%` of its maximum at that `t`.
    pub pooled: f64,
    /// The same per time: `(t, error)`.
    pub per_t: Vec<(f64, f64)>,
    /// The pooled error split by density, `(lower bound of p_t / max p_t, error)` for the bands
    /// `[1%, 10%)`, `[10%, 50%)` and `[50%, 100%]`: where the error sits (tails or modes).
    pub by_band: Vec<(f64, f64)>,
}

/// Compares `net` with `g^2 law.score` at the times `ts` on `nx` points per time, spread over
/// `mu_t +- 5 sigma_t` and its mirror, keeping those with `p_t > 1%` of the maximum.
pub fn affine_score_error(net: &ScoreMlp, law: &AffineMixture, ts: &[f64], nx: usize) -> ScoreErrorReport {
    let g2 = law.g * law.g;
    score_error_against(net, law, ts, nx, |x, t| g2 * law.score(x, t))
}

/// The minimiser of the regularised 1-step loss on the affine toy's Euler chain (step `dt`),
/// trained over `stride` data steps (`h = stride dt`): `(E[x_{k-stride} | x_k] - (1 + a h) x) / h`,
/// with the exact conditional mean of the linear-Gaussian chain. This is what a network of
/// unlimited capacity converges to; it differs from `g^2 grad log p` by `O(a dt)`.
pub fn affine_one_step_target(law: &AffineMixture, dt: f64, stride: usize, x: f64, t: f64) -> f64 {
    let c1 = 1.0 - law.a * dt;
    let c = c1.powi(stride as i32);
    // Variance of the noise accumulated over `stride` steps: g^2 dt sum_j c1^(2j).
    let var = if (1.0 - c1 * c1).abs() < 1e-15 {
        law.g * law.g * dt * stride as f64
    } else {
        law.g * law.g * dt * (1.0 - c * c) / (1.0 - c1 * c1)
    };
    let h = stride as f64 * dt;
    let mean_prev = (x + var * law.score(x, t)) / c;
    (mean_prev - (1.0 + law.a * h) * x) / h
}

/// Compares `net` with a reference score `reference(x, t)` on the region of [`affine_score_error`].
pub fn score_error_against(
    net: &ScoreMlp,
    law: &AffineMixture,
    ts: &[f64],
    nx: usize,
    reference: impl Fn(f64, f64) -> f64,
) -> ScoreErrorReport {
    let (mut num, mut den) = (0.0, 0.0);
    let mut bands = [(0.01, 0.0, 0.0), (0.1, 0.0, 0.0), (0.5, 0.0, 0.0)];
    let mut per_t = vec![];
    for &t in ts {
        let (mu, s) = law.moments(t);
        let hi = mu + 5.0 * s;
        let xs: Vec<f64> = (0..nx).map(|i| -hi + 2.0 * hi * i as f64 / (nx - 1) as f64).collect();
        let p: Vec<f64> = xs.iter().map(|&x| law.density(x, t)).collect();
        let pmax = p.iter().cloned().fold(0.0, f64::max).max(law.density(mu, t));
        let keep: Vec<(f64, f64)> =
            xs.iter().zip(&p).filter(|(_, &pv)| pv > 0.01 * pmax).map(|(x, pv)| (*x, pv / pmax)).collect();
        let kx: Vec<f64> = keep.iter().map(|k| k.0).collect();
        let s_net = net.eval(&kx, &vec![t; kx.len()]);
        let (mut n_t, mut d_t) = (0.0, 0.0);
        for ((x, rel), sn) in keep.iter().zip(&s_net) {
            let sa = reference(*x, t);
            let (e2, a2) = ((sn - sa) * (sn - sa), sa * sa);
            n_t += e2;
            d_t += a2;
            if let Some(b) = bands.iter_mut().rev().find(|b| *rel >= b.0) {
                b.1 += e2;
                b.2 += a2;
            }
        }
        per_t.push((t, (n_t / d_t).sqrt()));
        num += n_t;
        den += d_t;
    }
    let by_band = bands.iter().map(|b| (b.0, (b.1 / b.2).sqrt())).collect();
    ScoreErrorReport { pooled: (num / den).sqrt(), per_t, by_band }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed-form minimiser of the 1-step loss against a Monte Carlo estimate of
    /// `E[x_{k-1} | x_k = x]` from simulated affine paths (a narrow bin around `x`).
    #[test]
    fn affine_one_step_target_matches_monte_carlo() {
        let sde = ToySde::paper_affine();
        let law = AffineMixture::euler(0.5, 0.04, sde.dt);
        let k = 50; // t = 1
        let short = ToySde { t_end: k as f64 * sde.dt, ..sde };
        let paths = short.simulate(&two_point_starts(400_000), 21).unwrap();
        let (prev, cur) = (paths.at_step(k - 1), paths.at_step(k));
        let (mu, sig) = law.moments(k as f64 * sde.dt);
        for x in [mu - sig, mu, mu + 0.5 * sig] {
            let w = 0.05 * sig;
            let sel: Vec<f64> = cur.iter().zip(&prev).filter(|(c, _)| (*c - x).abs() < w).map(|(_, p)| *p).collect();
            let mc_mean = sel.iter().sum::<f64>() / sel.len() as f64;
            let mc = (mc_mean - (1.0 + 0.5 * sde.dt) * x) / sde.dt;
            let exact = affine_one_step_target(&law, sde.dt, 1, x, k as f64 * sde.dt);
            // Standard error of the bin mean: the one-step noise g sqrt(dt) over sqrt(count), / dt.
            let se = 0.04 * sde.dt.sqrt() / (sel.len() as f64).sqrt() / sde.dt;
            assert!((mc - exact).abs() < 4.0 * se + 0.02 * exact.abs(), "x {x}: MC {mc} vs {exact} (se {se})");
        }
    }
}
