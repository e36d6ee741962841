//! Samplers for the toy: the reverse SDE and the probability-flow ODE, from `t = T` to `t = 0`.
//!
//! One backward step from `t_k` (score evaluated at `t_k`, as in training):
//! * reverse SDE: `x <- x - dt [P(x) - s] + g sqrt(dt) xi` (no noise on the last step),
//! * probability-flow ODE: `x <- x - dt [P(x) - s/2]`.

use super::analytic::AffineMixture;
use super::mlp::{MlpCache, ScoreMlp};
use super::physics::ScalarDrift;
use super::sde::{chunk_rng, ToySde};
use crate::Result;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

const CHUNK: usize = 512;

/// A score `s(x, t)` (absorbing `g^2`) evaluated on a batch of states at one time.
pub trait ScalarScore: Sync {
    /// Writes `s(x[i], t)` into `out[i]`.
    fn scores(&self, x: &[f64], t: f64, out: &mut [f64]);
}

impl ScalarScore for ScoreMlp {
    fn scores(&self, x: &[f64], t: f64, out: &mut [f64]) {
        let ts = vec![t; x.len()];
        self.forward(x, &ts, out, &mut MlpCache::default());
    }
}

/// The exact score of the affine toy times `g^2` (what a perfect network would output).
#[derive(Clone, Copy, Debug)]
pub struct AnalyticScore {
    /// The law of `x_t`.
    pub law: AffineMixture,
}

impl ScalarScore for AnalyticScore {
    fn scores(&self, x: &[f64], t: f64, out: &mut [f64]) {
        let g2 = self.law.g * self.law.g;
        for (o, &v) in out.iter_mut().zip(x) {
            *o = g2 * self.law.score(v, t);
        }
    }
}

/// Which backward integrator to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampler {
    /// The reverse SDE (score weight 1, with noise).
    ReverseSde,
    /// The probability-flow ODE (score weight 1/2, no noise).
    ProbabilityFlow,
}

/// Runs `sampler` backward from states `y` at `t = T` to `t = 0`. With `record`, every state is
/// kept: `trajectory[k][i]` is sample `i` at time `(steps - k) dt`; otherwise only the end.
fn run(sde: &ToySde, score: &impl ScalarScore, y: &[f64], sampler: Sampler, seed: u64, record: bool) -> Vec<Vec<f64>> {
    let steps = sde.steps();
    let (w, noise) = match sampler {
        Sampler::ReverseSde => (1.0, sde.g * sde.dt.sqrt()),
        Sampler::ProbabilityFlow => (0.5, 0.0),
    };
    let chunks: Vec<Vec<Vec<f64>>> = y
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, y0)| {
            let mut rng = chunk_rng(seed, c);
            let mut x = y0.to_vec();
            let mut s = vec![0.0; x.len()];
            let mut traj = vec![x.clone()];
            for k in (1..=steps).rev() {
                score.scores(&x, k as f64 * sde.dt, &mut s);
                for (v, &sv) in x.iter_mut().zip(&s) {
                    *v -= sde.dt * (sde.drift.drift(*v) - w * sv);
                    if noise > 0.0 && k > 1 {
                        let xi: f64 = StandardNormal.sample(&mut rng);
                        *v += noise * xi;
                    }
                }
                if record {
                    traj.push(x.clone());
                }
            }
            if !record {
                traj = vec![x];
            }
            traj
        })
        .collect();
    let len = chunks[0].len();
    (0..len).map(|k| chunks.iter().flat_map(|c| c[k].iter().copied()).collect()).collect()
}

/// The end states `x_0` of `sampler` started at `y` (at `t = T`).
pub fn sample(sde: &ToySde, score: &impl ScalarScore, y: &[f64], sampler: Sampler, seed: u64) -> Result<Vec<f64>> {
    sde.validate()?;
    if y.is_empty() {
        return Ok(vec![]);
    }
    Ok(run(sde, score, y, sampler, seed, false).pop().unwrap_or_default())
}

/// Every state of `sampler` started at `y`: `out[k][i]` is sample `i` at time `T - k dt`.
pub fn sample_trajectories(
    sde: &ToySde,
    score: &impl ScalarScore,
    y: &[f64],
    sampler: Sampler,
    seed: u64,
) -> Result<Vec<Vec<f64>>> {
    sde.validate()?;
    if y.is_empty() {
        return Ok(vec![]);
    }
    Ok(run(sde, score, y, sampler, seed, true))
}

/// `P(x0 = +1 | x_T = y)` estimated with `n` reverse-SDE samples from each `y`: the fraction
/// that ends at `x_0 > 0`.
pub fn posterior_plus(sde: &ToySde, score: &impl ScalarScore, ys: &[f64], n: usize, seed: u64) -> Result<Vec<f64>> {
    let mut out = vec![];
    for (j, &y) in ys.iter().enumerate() {
        let end = sample(sde, score, &vec![y; n], Sampler::ReverseSde, seed.wrapping_add(j as u64 * 7919))?;
        out.push(end.iter().filter(|&&v| v > 0.0).count() as f64 / n.max(1) as f64);
    }
    Ok(out)
}

/// How often the samplers land on the data points `+-1`.
#[derive(Clone, Debug, PartialEq)]
pub struct HitReport {
    /// Number of start points (`linspace(-0.1, 0.1)` at `t = T`).
    pub n: usize,
    /// Fraction of ODE end points within `tol` (relative) of `+1` or `-1`.
    pub ode_hits: f64,
    /// Fraction of SDE end points within `tol` of `+1` or `-1`.
    pub sde_hits: f64,
    /// Fraction of ODE samples whose end point has the sign of their start point.
    pub ode_sign_kept: f64,
    /// Fraction of SDE end points at `+1`.
    pub sde_plus: f64,
}

/// The paper's evaluation: `n` start points `linspace(-0.1, 0.1)` at `t = T`, integrated to `0`
/// with both samplers; a hit lands within `tol` (0.01 = 1%) of `+-1`.
pub fn hit_rates(sde: &ToySde, score: &impl ScalarScore, n: usize, tol: f64, seed: u64) -> Result<HitReport> {
    let y: Vec<f64> = (0..n).map(|i| -0.1 + 0.2 * i as f64 / (n.max(2) - 1) as f64).collect();
    let ode = sample(sde, score, &y, Sampler::ProbabilityFlow, seed)?;
    let sd = sample(sde, score, &y, Sampler::ReverseSde, seed)?;
    let hit = |v: &f64| (v.abs() - 1.0).abs() <= tol;
    let frac = |c: usize| c as f64 / n.max(1) as f64;
    Ok(HitReport {
        n,
        ode_hits: frac(ode.iter().filter(|v| hit(v)).count()),
        sde_hits: frac(sd.iter().filter(|v| hit(v)).count()),
        ode_sign_kept: frac(ode.iter().zip(&y).filter(|(e, s)| e.signum() == s.signum() || **s == 0.0).count()),
        sde_plus: frac(sd.iter().filter(|&&v| v > 0.0).count()),
    })
}
