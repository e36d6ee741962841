//! Two score networks, each trained on one time interval, sampled on a graded time grid.
//!
//! Why: on the quadratic toy the samplers need the 1-step minimiser for single fine steps near
//! `t = 0` (where one coarse step's noise is as wide as the distribution; measured with the
//! exact law: a perfect model on a grid with steps of `dt / 8` below `t = 0.02..0.5` and `dt`
//! above hits 100% / 100%) and an accurate, small score at large `t` (where the posterior is
//! decided). One MLP trained on both fits one at the other's cost: weighting the fine samples up
//! spoils the large-`t` score (posterior off by 0.11-0.33), weighting them as the plain loss
//! does leaves the fine steps unlearned (ODE hits 48%). Experts per time interval (as eDiff-I's
//! expert denoisers) separate the two: the `near` network learns `t < split` on the graded
//! grid, the `far` network `t >= split` with coarse steps only.
//!
//! ```
//! use pbdl_diffusion::smdp::experts::SplitExpertRecipe;
//! use pbdl_diffusion::smdp::sampler::hit_rates_with;
//! use pbdl_diffusion::smdp::ToySde;
//!
//! let sde = ToySde::paper_quadratic();
//! // A short run (the measured recipe trains 600k updates per expert).
//! let recipe = SplitExpertRecipe { updates: [300, 100, 0], n_paths: 64, ..SplitExpertRecipe::quadratic() };
//! let (score, reports) = recipe.train(&sde, 0)?;
//! // Sample on the refined SDE with the matching graded grid.
//! let hits = hit_rates_with(&recipe.data_sde(&sde), &score, 50, 0.01, recipe.sampler_options(), 1)?;
//! println!("ODE {:.0}%, SDE {:.0}% after {:.1} s", 100.0 * hits.ode_hits, 100.0 * hits.sde_hits, reports[0].seconds);
//! assert_eq!(hits.n, 50);
//! # Ok::<(), pbdl_diffusion::Error>(())
//! ```

use super::mlp::ScoreMlp;
use super::sampler::{CoarseSteps, SamplerOptions, ScalarScore};
use super::sde::ToySde;
use super::toy::{train_toy, TimeSampling, ToyLoss, ToyStage, ToyTrainConfig, ToyTrainReport};
use crate::{Error, Result};

/// One score for `t < split`, another from `split` on.
#[derive(Clone, Debug)]
pub struct SplitScore<A, B> {
    /// The score below `split`.
    pub near: A,
    /// The score at and above `split`.
    pub far: B,
    /// The time where the two meet.
    pub split: f64,
}

impl<A: ScalarScore, B: ScalarScore> ScalarScore for SplitScore<A, B> {
    fn scores(&self, x: &[f64], t: f64, out: &mut [f64]) {
        if t < self.split {
            self.near.scores(x, t, out)
        } else {
            self.far.scores(x, t, out)
        }
    }
}

/// How to train the two experts of a [`SplitScore`] on data refined `stride` times.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitExpertRecipe {
    /// Data steps (of the refined SDE) per coarse step: the sampler's step away from `t = 0`.
    pub stride: usize,
    /// Below this time the sampler takes single data steps ([`CoarseSteps::above`]).
    pub fine_below: f64,
    /// Where the near expert hands over to the far one.
    pub split: f64,
    /// Each expert's training range reaches this far past `split` (relative), so that both
    /// are trained where they meet.
    pub overlap: f64,
    /// Updates at Adam learning rates 1e-3, 1e-4 and 1e-5 (per expert).
    pub updates: [usize; 3],
    /// Training paths (half from `+1`, half from `-1`) and batch size.
    pub n_paths: usize,
    /// Batch size.
    pub batch: usize,
    /// Make both networks odd in `x` ([`ScoreMlp::with_odd_symmetry`]): right for drifts and data
    /// symmetric under `x -> -x`, as the toy's.
    pub odd: bool,
}

impl SplitExpertRecipe {
    /// The settings measured on the quadratic toy (data at `dt / 8`, fine steps below 0.1,
    /// experts split at 0.5; 250k + 250k + 100k updates of batch 256 on 2500 paths each).
    pub fn quadratic() -> Self {
        SplitExpertRecipe {
            stride: 8,
            fine_below: 0.1,
            split: 0.5,
            overlap: 0.05,
            updates: [250_000, 250_000, 100_000],
            n_paths: 2500,
            batch: 256,
            odd: true,
        }
    }

    /// Rejects settings that cannot be trained.
    pub fn validate(&self) -> Result<()> {
        let ok = self.stride >= 1
            && self.fine_below.is_finite()
            && self.fine_below >= 0.0
            && self.split.is_finite()
            && self.split > 0.0
            && (0.0..1.0).contains(&self.overlap);
        if ok {
            return Ok(());
        }
        Err(Error::InvalidConfig {
            name: "SplitExpertRecipe",
            value: format!("{self:?}"),
            hint: "use stride >= 1, 0 <= fine_below, 0 < split and 0 <= overlap < 1",
        })
    }

    /// The SDE the experts are trained and sampled on: `sde` with step `dt / stride`.
    pub fn data_sde(&self, sde: &ToySde) -> ToySde {
        sde.refined(self.stride)
    }

    /// The sampler settings that match the training: coarse steps of `stride` data steps above
    /// `fine_below`, the paper's explicit steps.
    pub fn sampler_options(&self) -> SamplerOptions {
        SamplerOptions {
            coarse: Some(CoarseSteps { stride: self.stride, above: self.fine_below }),
            ..Default::default()
        }
    }

    fn stages(&self, loss: impl Fn(usize) -> ToyLoss) -> Vec<ToyStage> {
        [1e-3, 1e-4, 1e-5]
            .iter()
            .zip(self.updates)
            .enumerate()
            .filter(|(_, (_, u))| *u > 0)
            .map(|(i, (&lr, updates))| ToyStage { loss: loss(i), lr, updates })
            .collect()
    }

    fn config(&self, seed: u64, stages: Vec<ToyStage>, time_range: (f64, f64)) -> ToyTrainConfig {
        ToyTrainConfig {
            n_paths: self.n_paths,
            batch: self.batch,
            stages,
            seed,
            // About a dozen loss records per run.
            log_every: (self.updates.iter().sum::<usize>() / 12).clamp(1, 50_000),
            time_sampling: TimeSampling::LogUniform,
            sim_substeps: 1,
            time_range,
        }
    }

    /// The near expert: the graded 1-step loss (fine samples weighted `stride^2`, alike in
    /// units of the score) on `t <= split (1 + overlap)`.
    pub fn near_config(&self, seed: u64) -> ToyTrainConfig {
        let fine_weight = (self.stride * self.stride) as f64;
        let graded = ToyLoss::Graded { stride: self.stride, fine_below: self.fine_below, fine_weight };
        self.config(seed, self.stages(|_| graded), (0.0, self.split * (1.0 + self.overlap)))
    }

    /// The far expert: the regularised 1-step loss over 5 coarse steps at the first rate (the
    /// official pre-training stride), then over one coarse step, on `t >= split (1 - overlap)`.
    pub fn far_config(&self, seed: u64) -> ToyTrainConfig {
        let loss =
            |i: usize| ToyLoss::Strided { stride: if i == 0 { 5 } else { 1 } * self.stride, bidirectional: false };
        self.config(seed, self.stages(loss), (self.split * (1.0 - self.overlap), f64::INFINITY))
    }

    /// Trains both experts (the paper's MLP each, initialised with `seed`) on the same paths of
    /// [`data_sde`](Self::data_sde), in parallel.
    pub fn train(&self, sde: &ToySde, seed: u64) -> Result<(SplitScore<ScoreMlp, ScoreMlp>, [ToyTrainReport; 2])> {
        self.validate()?;
        let data = self.data_sde(sde);
        let net = |seed| if self.odd { ScoreMlp::paper(seed).with_odd_symmetry() } else { ScoreMlp::paper(seed) };
        let (mut near, mut far) = (net(seed), net(seed ^ 0x5EED));
        let (a, b) = rayon::join(
            || train_toy(&data, &mut near, &self.near_config(seed)),
            || train_toy(&data, &mut far, &self.far_config(seed)),
        );
        Ok((SplitScore { near, far, split: self.split }, [a?, b?]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_score_picks_the_expert_by_time() {
        struct Constant(f64);
        impl ScalarScore for Constant {
            fn scores(&self, _x: &[f64], _t: f64, out: &mut [f64]) {
                out.fill(self.0);
            }
        }
        let s = SplitScore { near: Constant(1.0), far: Constant(2.0), split: 0.5 };
        let mut out = [0.0; 2];
        s.scores(&[0.1, 0.2], 0.49, &mut out);
        assert_eq!(out, [1.0, 1.0]);
        s.scores(&[0.1, 0.2], 0.5, &mut out);
        assert_eq!(out, [2.0, 2.0]);
    }

    #[test]
    fn recipe_configs_cover_both_intervals_and_bad_settings_are_rejected() {
        let r = SplitExpertRecipe::quadratic();
        let (near, far) = (r.near_config(0), r.far_config(0));
        assert!(near.time_range.1 > r.split && far.time_range.0 < r.split);
        assert_eq!(near.stages.len(), 3);
        assert!(matches!(far.stages[0].loss, ToyLoss::Strided { stride: 40, .. }));
        assert!(matches!(far.stages[1].loss, ToyLoss::Strided { stride: 8, .. }));
        assert_eq!(r.data_sde(&ToySde::paper_quadratic()).dt, 0.0025);
        let bad = SplitExpertRecipe { split: 0.0, ..r.clone() };
        assert!(matches!(bad.validate(), Err(Error::InvalidConfig { .. })));
        let tiny = SplitExpertRecipe { updates: [20, 0, 0], n_paths: 8, ..r };
        assert!(tiny.train(&ToySde::paper_quadratic(), 0).is_ok());
    }
}
