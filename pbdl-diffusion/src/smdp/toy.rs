//! Training the toy's score network on simulated paths, and measuring it against the analytic
//! score of the affine case.

use super::analytic::AffineMixture;
use super::loss::{multi_step_loss, one_step_loss, LossWorkspace};
use super::mlp::{Adam, ScoreMlp};
use super::sde::{chunk_rng, two_point_starts, Paths, ToySde};
use crate::{Error, Result};
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
        }
    }

    fn validate(&self, steps: usize) -> Result<()> {
        let bad = |name, value: String, hint| Err(Error::InvalidConfig { name, value, hint });
        if self.n_paths == 0 || self.batch == 0 || self.log_every == 0 {
            return bad(
                "n_paths/batch/log_every",
                format!("{}/{}/{}", self.n_paths, self.batch, self.log_every),
                "use positive counts (2500 paths, batch 256)",
            );
        }
        for s in &self.stages {
            if let ToyLoss::MultiStep(w) = s.loss {
                if w == 0 || w > steps {
                    return bad("window", w.to_string(), "use a window between 1 and the number of SDE steps");
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

/// Simulates the training paths of `cfg` (half from `+1`, half from `-1`).
pub fn training_paths(sde: &ToySde, cfg: &ToyTrainConfig) -> Result<Paths> {
    sde.simulate(&two_point_starts(cfg.n_paths), cfg.seed)
}

/// Trains `net` on `sde`'s paths following `cfg`.
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
        let mut adam = Adam::new(net.num_params(), stage.lr);
        let window = match stage.loss {
            ToyLoss::OneStep => 1,
            ToyLoss::MultiStep(w) => w,
        };
        let mut targets = vec![vec![0.0; b]; window];
        let mut acc = 0.0;
        for u in 0..stage.updates {
            for i in 0..b {
                let p = rng.random_range(0..paths.n_paths);
                let k = match cfg.time_sampling {
                    TimeSampling::Uniform => rng.random_range(window..=steps),
                    TimeSampling::LogUniform => {
                        let u: f64 = rng.random_range(0.0..1.0);
                        let (lo, hi) = ((window as f64).ln(), ((steps + 1) as f64).ln());
                        ((lo + u * (hi - lo)).exp().floor() as usize).clamp(window, steps)
                    }
                };
                let path = paths.path(p);
                x[i] = path[k];
                t[i] = k as f64 * sde.dt;
                for (m, tg) in targets.iter_mut().enumerate() {
                    tg[i] = path[k - 1 - m];
                }
                prev[i] = path[k - 1];
            }
            grad.fill(0.0);
            let loss = match stage.loss {
                ToyLoss::OneStep => one_step_loss(net, &sde.drift, sde.dt, &x, &t, &prev, Some(&mut grad), &mut ws),
                ToyLoss::MultiStep(_) => {
                    multi_step_loss(net, &sde.drift, sde.dt, &x, &t, &targets, false, Some(&mut grad), &mut ws)
                }
            };
            if !loss.is_finite() {
                return Err(Error::NonFinite { what: "toy training loss".into(), step: (total + u) as u64 });
            }
            adam.step(net.params_mut(), &grad);
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
    /// Relative L2 error `||s - g^2 grad log p|| / ||g^2 grad log p||`, pooled over all grid
    /// points `(x, t)` where `p_t(x) > 1%` of its maximum at that `t`.
    pub pooled: f64,
    /// The same per time: `(t, error)`.
    pub per_t: Vec<(f64, f64)>,
}

/// Compares `net` with `g^2 law.score` at the times `ts` on `nx` points per time, spread over
/// `mu_t +- 4 sigma_t` and its mirror, keeping those with `p_t > 1%` of the maximum.
pub fn affine_score_error(net: &ScoreMlp, law: &AffineMixture, ts: &[f64], nx: usize) -> ScoreErrorReport {
    let g2 = law.g * law.g;
    let (mut num, mut den) = (0.0, 0.0);
    let mut per_t = vec![];
    for &t in ts {
        let (mu, s) = law.moments(t);
        let hi = mu + 5.0 * s;
        let xs: Vec<f64> = (0..nx).map(|i| -hi + 2.0 * hi * i as f64 / (nx - 1) as f64).collect();
        let p: Vec<f64> = xs.iter().map(|&x| law.density(x, t)).collect();
        let pmax = p.iter().cloned().fold(0.0, f64::max).max(law.density(mu, t));
        let keep: Vec<f64> = xs.iter().zip(&p).filter(|(_, &pv)| pv > 0.01 * pmax).map(|(x, _)| *x).collect();
        let s_net = net.eval(&keep, &vec![t; keep.len()]);
        let (mut n_t, mut d_t) = (0.0, 0.0);
        for (x, sn) in keep.iter().zip(&s_net) {
            let sa = g2 * law.score(*x, t);
            n_t += (sn - sa) * (sn - sa);
            d_t += sa * sa;
        }
        per_t.push((t, (n_t / d_t).sqrt()));
        num += n_t;
        den += d_t;
    }
    ScoreErrorReport { pooled: (num / den).sqrt(), per_t }
}
