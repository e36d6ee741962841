//! The exact law of the toy's Euler-Maruyama chain, its score and the 1-step loss minimiser,
//! tabulated on a fine grid (any odd drift, two-point start `x0 in {+1, -1}`).
//!
//! The training data follow the chain `x_k = F(x_{k-1}) + sigma xi`, `F(x) = x + dt P(x)`,
//! `sigma = g sqrt(dt)`, not the continuous SDE. Its law is propagated exactly (up to quadrature
//! error) by the Chapman-Kolmogorov step
//!
//! `p_k(y) = sum_i h p_{k-1}(x_i) N(y; F(x_i), sigma^2)`
//!
//! on a uniform grid of spacing `h`: the trapezoid rule on the whole line, whose error for an
//! integrand that is smooth on the scale `sigma` falls like `exp(-2 pi^2 (sigma / h)^2)`
//! (negligible at `h = sigma / 4`). The first step starts from the point masses at `+-1`, so
//! no initial width is invented. With the same sums the chain gives, at each node `y`,
//!
//! * the score (Tweedie's formula for the Gaussian step, exact):
//!   `g^2 d/dy log p_k(y) = (E[F(x_{k-1}) | x_k = y] - y) / dt`,
//! * the minimiser of the regularised 1-step loss (what a network of unlimited capacity learns,
//!   see [`super::loss`]): `s*(y) = (E[x_{k-1} | x_k = y] - y + dt P(y)) / dt`,
//! * the posterior `P(x0 = +1 | x_k = y)`.
//!
//! The drift must be odd (`P(-x) = -P(x)`; both toy drifts are), so only the law from `+1` is
//! propagated and the mixture is formed by mirroring on a symmetric grid.

use super::physics::ScalarDrift;
use super::sampler::ScalarScore;
use super::sde::ToySde;
use super::toy::ScoreErrorReport;
use crate::{Error, Result};

/// Gaussian kernels are cut where `exp(-z^2 / 2)` drops below `1e-300`.
const CUT_SIGMAS: f64 = 37.0;

/// The tabulated law of the toy's Euler chain from `x0 in {+1, -1}` (equal weights).
#[derive(Clone, Debug)]
pub struct EulerChainLaw {
    /// The chain (drift, `g`, `dt`, `T`).
    pub sde: ToySde,
    /// Grid spacing.
    pub h: f64,
    /// The grid is `[-half_width, half_width]`, `n` nodes, symmetric about 0.
    pub half_width: f64,
    n: usize,
    steps: usize,
    substeps: usize,
    /// Per step `k = 1..=steps` (row `k - 1`): the mixture density at the nodes.
    density: Vec<f64>,
    /// Per fine step `j = 1..=steps * substeps`: `g^2 d/dx log p` at the nodes (NaN where `p`
    /// underflows).
    score: Vec<f64>,
    /// The 1-step loss minimiser at the nodes (NaN where `p_k` underflows).
    target: Vec<f64>,
    /// `P(x0 = +1 | x_k)` at the nodes (NaN where `p_k` underflows).
    posterior: Vec<f64>,
    /// Per fine step: the first and last node where the score is finite.
    finite: Vec<(usize, usize)>,
    /// The law of `x_T` from `+1` alone (density at the nodes).
    from_plus_end: Vec<f64>,
}

/// Which tabulated function a [`GridScore`] returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridScoreKind {
    /// The exact score `g^2 d/dx log p_k`.
    Score,
    /// The minimiser of the regularised 1-step loss (the score plus the Euler step's correction).
    OneStepTarget,
}

/// A tabulated function of an [`EulerChainLaw`] as a sampler score: linear interpolation in `x`
/// between nodes; at a time between two chain steps, linear interpolation between the two
/// steps' tables (times below `dt` use step 1, above `T` step `T / dt`). Outside the region where
/// `p_k` is representable the value of the nearest finite node is used.
#[derive(Clone, Copy, Debug)]
pub struct GridScore<'a> {
    /// The law.
    pub law: &'a EulerChainLaw,
    /// What to return.
    pub kind: GridScoreKind,
}

impl EulerChainLaw {
    /// Propagates the chain of `sde` from `+-1` on a grid over `[-half_width, half_width]` with
    /// `cells_per_sigma` nodes per `sigma = g sqrt(dt)` (4 or more: the quadrature error is then
    /// below `1e-30`). Costs about `steps * n * 75 cells_per_sigma` multiply-adds.
    pub fn new(sde: &ToySde, cells_per_sigma: f64, half_width: f64) -> Result<Self> {
        Self::with_substeps(sde, 1, cells_per_sigma, half_width)
    }

    /// The chain integrated with the finer step `dt / substeps` and observed every `dt` (the
    /// official data set integrates at `dt / 2`; many sub-steps approach the continuous SDE).
    /// The score is tabulated at every fine step (time `j dt / substeps`); the 1-step loss
    /// minimiser (for the data step `dt`), the density and the posterior at the data steps.
    /// `cells_per_sigma` counts nodes per fine-step `sigma = g sqrt(dt / substeps)`.
    pub fn with_substeps(sde: &ToySde, substeps: usize, cells_per_sigma: f64, half_width: f64) -> Result<Self> {
        sde.validate()?;
        let bad = |name, v: f64, hint| Err(Error::InvalidConfig { name, value: v.to_string(), hint });
        if !(cells_per_sigma.is_finite() && cells_per_sigma >= 2.0) {
            return bad("cells_per_sigma", cells_per_sigma, "use at least 2 grid nodes per sigma (4 or more)");
        }
        if !(half_width.is_finite() && half_width > 1.0) {
            return bad("half_width", half_width, "use a grid wider than the start points +-1 (e.g. 1.2)");
        }
        if substeps == 0 || substeps > 64 {
            return bad("substeps", substeps as f64, "use 1 to 64 chain sub-steps per data step");
        }
        let dt = sde.dt;
        let dtf = dt / substeps as f64;
        let sigma = sde.g * dtf.sqrt();
        if sigma.is_nan() || sigma <= 0.0 {
            return bad("g", sde.g, "the exact law needs noise: use g > 0");
        }
        let cells = (2.0 * half_width * cells_per_sigma / sigma).ceil() as usize;
        let steps = sde.steps();
        if cells > 200_000 || (cells as f64) * (steps * substeps) as f64 > 5e7 {
            return bad(
                "cells_per_sigma",
                cells_per_sigma,
                "the score table would exceed 5e7 entries: use fewer nodes per sigma or sub-steps",
            );
        }
        let n = cells + 1;
        let h = 2.0 * half_width / cells as f64;
        let node = |j: usize| -half_width + j as f64 * h;
        let drift = sde.drift;
        let norm = 1.0 / (sigma * (2.0 * std::f64::consts::PI).sqrt());
        let inv2s2 = 0.5 / (sigma * sigma);
        let q_step = (-h * h / (sigma * sigma)).exp();
        let reach = (CUT_SIGMAS * sigma / h).ceil() as isize;
        let fine_steps = steps * substeps;

        let mut law = EulerChainLaw {
            sde: *sde,
            h,
            half_width,
            n,
            steps,
            substeps,
            density: vec![0.0; steps * n],
            score: vec![f64::NAN; fine_steps * n],
            target: vec![f64::NAN; steps * n],
            posterior: vec![f64::NAN; steps * n],
            finite: vec![(0, 0); fine_steps],
            from_plus_end: vec![],
        };
        // Sources of the fine step, for the law from +1: (position, h p, h b) where
        // b(x) = p(x) E[x at the last data step | x] carries the 1-step target's conditional mean.
        let mut sources: Vec<(f64, f64, f64)> = vec![(1.0, 1.0, 1.0)];
        let (mut qd, mut qa, mut qb) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for jf in 1..=fine_steps {
            qd.fill(0.0);
            qa.fill(0.0);
            qb.fill(0.0);
            if (jf - 1) % substeps == 0 {
                // A data step starts: the conditional mean is of the current position.
                for src in sources.iter_mut() {
                    src.2 = src.0 * src.1;
                }
            }
            for &(x, w, wb) in &sources {
                let f = x + dtf * drift.drift(x);
                let (wn, wbn) = (w * norm, wb * norm);
                let c = ((f + half_width) / h).round() as isize;
                let lo = (c - reach).max(0);
                let hi = (c + reach).min(n as isize - 1);
                if lo > hi {
                    continue;
                }
                // Upward from c (or from lo if c is below the grid), then downward from
                // start - 1: e_{j+-1} = e_j r_j, r_{j+-1} = r_j q (the ratio's sign of 2 d h
                // follows the direction), with e and r recomputed exactly every 32 nodes.
                let start = c.clamp(lo, hi);
                for (mut j, step) in [(start, 1isize), (start - 1, -1)] {
                    while (lo..=hi).contains(&j) {
                        let d = node(j as usize) - f;
                        let mut e = (-d * d * inv2s2).exp();
                        let mut r = (-(2.0 * d * h * step as f64 + h * h) * inv2s2).exp();
                        let end = if step > 0 { (j + 32).min(hi + 1) } else { (j - 32).max(lo - 1) };
                        while j != end {
                            let ju = j as usize;
                            let we = wn * e;
                            qd[ju] += we;
                            qa[ju] += we * (f - node(ju));
                            qb[ju] += wbn * e;
                            e *= r;
                            r *= q_step;
                            j += step;
                        }
                    }
                }
            }
            // Mixture tables by mirroring: the law from -1 at y is the law from +1 at -y.
            let row = (jf - 1) * n;
            let (mut first, mut last) = (usize::MAX, 0);
            let data_step = (jf % substeps == 0).then_some(jf / substeps);
            for j in 0..n {
                let m = n - 1 - j;
                let den = qd[j] + qd[m];
                if den > 0.0 && den.is_finite() {
                    law.score[row + j] = (qa[j] - qa[m]) / (dtf * den);
                    first = first.min(j);
                    last = last.max(j);
                }
                if let Some(k) = data_step {
                    let rk = (k - 1) * n;
                    law.density[rk + j] = 0.5 * den;
                    if den > 0.0 && den.is_finite() {
                        let y = node(j);
                        law.target[rk + j] = ((qb[j] - qb[m]) / den - y + dt * drift.drift(y)) / dt;
                        law.posterior[rk + j] = qd[j] / den;
                    }
                }
            }
            if first == usize::MAX {
                return Err(Error::NonFinite {
                    what: "Euler-chain density (underflow everywhere)".into(),
                    step: jf as u64,
                });
            }
            law.finite[jf - 1] = (first, last);
            sources.clear();
            sources.extend((0..n).filter(|&j| qd[j] > 0.0).map(|j| (node(j), h * qd[j], h * qb[j])));
        }
        law.from_plus_end = qd;
        Ok(law)
    }

    /// The paper's quadratic chain (`dt = 0.02`) on `[-1.2, 1.2]` with 5 nodes per sigma.
    pub fn paper_quadratic() -> Result<Self> {
        Self::new(&ToySde::paper_quadratic(), 5.0, 1.2)
    }

    /// Number of grid nodes.
    pub fn nodes(&self) -> usize {
        self.n
    }

    /// Node `j`'s position.
    pub fn node(&self, j: usize) -> f64 {
        -self.half_width + j as f64 * self.h
    }

    /// Number of chain steps (`T / dt`).
    pub fn steps(&self) -> usize {
        self.steps
    }

    fn table(&self, which: Table) -> &[f64] {
        match which {
            Table::Score => &self.score,
            Table::Target => &self.target,
            Table::Posterior => &self.posterior,
        }
    }

    /// Linear interpolation of a table at data step `k` (1..=steps), or fine step `k` for the
    /// score, clamped to the region where the score is finite.
    fn interp(&self, which: Table, k: usize, x: f64) -> f64 {
        let (k, fine) = match which {
            Table::Score => {
                let k = k.clamp(1, self.steps * self.substeps);
                (k, k)
            }
            _ => {
                let k = k.clamp(1, self.steps);
                (k, k * self.substeps)
            }
        };
        let row = &self.table(which)[(k - 1) * self.n..k * self.n];
        let (first, last) = self.finite[fine - 1];
        let u = ((x + self.half_width) / self.h).clamp(first as f64, last as f64);
        let j = (u.floor() as usize).min(last);
        if j == last {
            return row[last];
        }
        let a = u - j as f64;
        let (v0, v1) = (row[j], row[j + 1]);
        match (v0.is_finite(), v1.is_finite()) {
            (true, true) => (1.0 - a) * v0 + a * v1,
            (true, false) => v0,
            (false, true) => v1,
            (false, false) => f64::NAN,
        }
    }

    /// The mixture density `p_k(x)` at chain step `k` (time `k dt`); geometric interpolation
    /// between nodes (exact for an exponential, error `(h / sigma_k)^2 / 8` in `log p` for a
    /// Gaussian of width `sigma_k`).
    pub fn density(&self, k: usize, x: f64) -> f64 {
        let k = k.clamp(1, self.steps);
        let row = &self.density[(k - 1) * self.n..k * self.n];
        let u = ((x + self.half_width) / self.h).clamp(0.0, (self.n - 1) as f64);
        let j = (u.floor() as usize).min(self.n - 2);
        let a = u - j as f64;
        let (p0, p1) = (row[j], row[j + 1]);
        if p0 > 0.0 && p1 > 0.0 {
            (p0.ln() * (1.0 - a) + p1.ln() * a).exp()
        } else {
            (1.0 - a) * p0 + a * p1
        }
    }

    /// The exact score times `g^2` at data step `k` (time `k dt`).
    pub fn score(&self, k: usize, x: f64) -> f64 {
        self.interp(Table::Score, k * self.substeps, x)
    }

    /// The exact score times `g^2` at fine step `j` (time `j dt / substeps`).
    pub fn score_fine(&self, j: usize, x: f64) -> f64 {
        self.interp(Table::Score, j, x)
    }

    /// Chain sub-steps per data step.
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// The minimiser of the regularised 1-step loss at chain step `k`.
    pub fn one_step_target(&self, k: usize, x: f64) -> f64 {
        self.interp(Table::Target, k, x)
    }

    /// `P(x0 = +1 | x_k = y)`.
    pub fn posterior_plus(&self, k: usize, y: f64) -> f64 {
        self.interp(Table::Posterior, k, y)
    }

    /// `P(x0 = +1 | x_T in [y - half, y + half])` (the Monte Carlo tables' binned estimate),
    /// by the trapezoid rule over the bin.
    pub fn posterior_plus_bin(&self, y: f64, half: f64) -> f64 {
        let m = 400;
        let k = self.steps;
        let (mut plus, mut all) = (0.0, 0.0);
        for i in 0..=m {
            let x = y - half + 2.0 * half * i as f64 / m as f64;
            let w = if i == 0 || i == m { 0.5 } else { 1.0 };
            let p = self.density(k, x);
            plus += w * p * self.posterior_plus(k, x);
            all += w * p;
        }
        plus / all
    }

    /// Mean, standard deviation and `P(x_T < 0)` of `x_T` for paths from `+1`.
    pub fn end_stats_from_plus(&self) -> (f64, f64, f64) {
        let q = &self.from_plus_end;
        let (mut m0, mut m1, mut neg) = (0.0, 0.0, 0.0);
        for (j, &v) in q.iter().enumerate() {
            let x = self.node(j);
            m0 += v;
            m1 += v * x;
            // Trapezoid weight: the node at 0 counts half.
            if x < -0.5 * self.h {
                neg += v;
            } else if x.abs() <= 0.5 * self.h {
                neg += 0.5 * v;
            }
        }
        let mean = m1 / m0;
        let var = q.iter().enumerate().map(|(j, &v)| v * (self.node(j) - mean).powi(2)).sum::<f64>() / m0;
        (mean, var.sqrt(), neg / m0)
    }

    /// The mass of the mixture at step `k` (1 up to the cut tails): a check of the quadrature.
    pub fn mass(&self, k: usize) -> f64 {
        let k = k.clamp(1, self.steps);
        self.h * self.density[(k - 1) * self.n..k * self.n].iter().sum::<f64>()
    }
}

impl EulerChainLaw {
    /// Compares `f` with the table `kind` at chain steps `ks` on every grid node where
    /// `p_k > 1%` of its maximum (as [`super::toy::affine_score_error`] does for the affine law):
    /// relative L2 error pooled, per step (reported as time `k dt`), and by density band.
    pub fn compare(&self, f: &impl ScalarScore, kind: GridScoreKind, ks: &[usize]) -> ScoreErrorReport {
        let (mut num, mut den) = (0.0, 0.0);
        let mut bands = [(0.01, 0.0, 0.0), (0.1, 0.0, 0.0), (0.5, 0.0, 0.0)];
        let mut per_t = vec![];
        for &k in ks {
            let k = k.clamp(1, self.steps);
            let row = (k - 1) * self.n;
            let p = &self.density[row..row + self.n];
            let pmax = p.iter().cloned().fold(0.0, f64::max);
            let fine_row = (k * self.substeps - 1) * self.n;
            let reference = match kind {
                GridScoreKind::Score => &self.score[fine_row..fine_row + self.n],
                GridScoreKind::OneStepTarget => &self.target[row..row + self.n],
            };
            let keep: Vec<usize> = (0..self.n).filter(|&j| p[j] > 0.01 * pmax && reference[j].is_finite()).collect();
            let xs: Vec<f64> = keep.iter().map(|&j| self.node(j)).collect();
            let mut out = vec![0.0; xs.len()];
            f.scores(&xs, k as f64 * self.sde.dt, &mut out);
            let (mut n_t, mut d_t) = (0.0, 0.0);
            for (&j, o) in keep.iter().zip(&out) {
                let (e2, a2) = ((o - reference[j]).powi(2), reference[j].powi(2));
                n_t += e2;
                d_t += a2;
                if let Some(b) = bands.iter_mut().rev().find(|b| p[j] / pmax >= b.0) {
                    b.1 += e2;
                    b.2 += a2;
                }
            }
            per_t.push((k as f64 * self.sde.dt, (n_t / d_t).sqrt()));
            num += n_t;
            den += d_t;
        }
        let by_band = bands.iter().map(|b| (b.0, (b.1 / b.2).sqrt())).collect();
        ScoreErrorReport { pooled: (num / den).sqrt(), per_t, by_band }
    }
}

#[derive(Clone, Copy)]
enum Table {
    Score,
    Target,
    Posterior,
}

impl GridScore<'_> {
    /// The value at `(x, t)`.
    pub fn value(&self, x: f64, t: f64) -> f64 {
        let law = self.law;
        let (per, last) = match self.kind {
            GridScoreKind::Score => (law.sde.dt / law.substeps as f64, law.steps * law.substeps),
            GridScoreKind::OneStepTarget => (law.sde.dt, law.steps),
        };
        let u = (t / per).clamp(1.0, last as f64);
        let k0 = u.floor() as usize;
        let a = u - k0 as f64;
        let f = |k| match self.kind {
            GridScoreKind::Score => law.score_fine(k, x),
            GridScoreKind::OneStepTarget => law.one_step_target(k, x),
        };
        if a < 1e-9 || k0 >= last {
            f(k0)
        } else if a > 1.0 - 1e-9 {
            f(k0 + 1)
        } else {
            (1.0 - a) * f(k0) + a * f(k0 + 1)
        }
    }
}

impl ScalarScore for GridScore<'_> {
    fn scores(&self, x: &[f64], t: f64, out: &mut [f64]) {
        for (o, &v) in out.iter_mut().zip(x) {
            *o = self.value(v, t);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::analytic::AffineMixture;
    use super::*;

    /// The affine chain has a closed-form law: the grid's density, score, 1-step target and
    /// posterior must match it.
    #[test]
    fn affine_chain_matches_its_closed_form() {
        let sde = ToySde { t_end: 2.0, ..ToySde::paper_affine() };
        let law = EulerChainLaw::new(&sde, 4.0, 1.2).unwrap();
        let exact = AffineMixture::euler(0.5, 0.04, 0.02);
        for k in [1usize, 5, 50, 100] {
            let t = k as f64 * sde.dt;
            let (mu, s) = exact.moments(t);
            assert!((law.mass(k) - 1.0).abs() < 1e-12, "mass {}", law.mass(k));
            for z in [-2.0, -0.5, 0.0, 1.0, 3.0] {
                let x = mu + z * s;
                let (p, pe) = (law.density(k, x), exact.density(x, t));
                // Linear interpolation between nodes: relative error ~ (h/s)^2 / 8.
                assert!((p / pe - 1.0).abs() < 0.02, "k {k} z {z}: density {p} vs {pe}");
                let (sc, se) = (law.score(k, x), 0.04 * 0.04 * exact.score(x, t));
                assert!((sc - se).abs() < 1e-3 * (0.04f64.powi(2) / s), "k {k} z {z}: score {sc} vs {se}");
                let tg = law.one_step_target(k, x);
                let te = super::super::toy::affine_one_step_target(&exact, 0.02, 1, x, t);
                assert!((tg - te).abs() < 1e-3 * (0.04f64.powi(2) / s), "k {k} z {z}: target {tg} vs {te}");
                let (pp, ppe) = (law.posterior_plus(k, x), exact.posterior_plus(x, t));
                assert!((pp - ppe).abs() < 1e-3, "k {k} z {z}: posterior {pp} vs {ppe}");
            }
        }
    }

    /// Two chain sub-steps per data step: the law and the fine-step score follow the closed form
    /// of the chain with step `dt / 2`, and the 1-step target is the one over two fine steps.
    #[test]
    fn affine_chain_with_substeps_matches_its_closed_form() {
        let sde = ToySde { t_end: 1.0, ..ToySde::paper_affine() };
        let law = EulerChainLaw::with_substeps(&sde, 2, 4.0, 1.2).unwrap();
        let exact = AffineMixture::euler(0.5, 0.04, 0.01);
        for k in [1usize, 10, 50] {
            let t = k as f64 * sde.dt;
            let (mu, s) = exact.moments(t);
            for z in [-2.0, 0.0, 1.5] {
                let x = mu + z * s;
                let scale = 0.04f64.powi(2) / s;
                let (sc, se) = (law.score(k, x), 0.04 * 0.04 * exact.score(x, t));
                assert!((sc - se).abs() < 1e-3 * scale, "k {k} z {z}: score {sc} vs {se}");
                // The fine step in between (time t - dt / 2).
                let (tf, sf) = (t - 0.01, law.score_fine(2 * k - 1, x));
                if k > 1 {
                    let sfe = 0.04 * 0.04 * exact.score(x, tf);
                    assert!(
                        (sf - sfe).abs() < 1e-3 * scale.max(0.04f64.powi(2) / exact.moments(tf).1),
                        "{sf} vs {sfe}"
                    );
                }
                let tg = law.one_step_target(k, x);
                let te = super::super::toy::affine_one_step_target(&exact, 0.01, 2, x, t);
                assert!((tg - te).abs() < 1e-3 * scale, "k {k} z {z}: target {tg} vs {te}");
            }
        }
    }

    #[test]
    fn bad_settings_are_typed_errors() {
        let sde = ToySde::paper_quadratic();
        assert!(EulerChainLaw::new(&sde, 1.0, 1.2).unwrap_err().to_string().contains("cells_per_sigma"));
        assert!(EulerChainLaw::new(&sde, 4.0, 0.5).unwrap_err().to_string().contains("half_width"));
        assert!(EulerChainLaw::new(&ToySde { g: 0.0, ..sde }, 4.0, 1.2).is_err());
    }
}
