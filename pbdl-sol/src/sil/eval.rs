//! Rollouts of the source solver with and without a corrector, and their mean absolute error
//! against the downsampled reference.

use super::data::ReferenceSim;
use super::net::Corrector;
use super::scene::{SilScene, SourceSolver};
use crate::{Error, Result};
use candle_core::Tensor;

/// `steps` steps of `source` from `start` `[1, C, ny, nx]`, corrected after every step when a
/// corrector is given. Returns the states after steps `1..=steps` (detached: no graph is kept).
pub fn rollout(
    source: &SourceSolver,
    start: &Tensor,
    steps: usize,
    corrector: Option<&Corrector>,
) -> Result<Vec<Tensor>> {
    source.check(start)?;
    let mut s = start.detach();
    let mut out = Vec::with_capacity(steps);
    for t in 0..steps {
        let mut next = source.step(&s)?;
        if let Some(c) = corrector {
            next = c.apply(&next, source.re)?;
        }
        s = next.detach();
        let m = s.abs()?.max_all()?.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?;
        if !m.is_finite() {
            return Err(Error::NonFinite { context: "rollout", step: t + 1 });
        }
        out.push(s.clone());
    }
    Ok(out)
}

/// Mean absolute error of the velocity (all MAC faces, both components; channels 0 and 1) of
/// each state of a rollout against `reference.frames[first + 1 + i]`.
pub fn mae_per_step(states: &[Tensor], reference: &ReferenceSim, first: usize) -> Result<Vec<f64>> {
    mae_channels(states, reference, first, 0, 2)
}

/// Mean absolute error of the scalar channels (`2..`, the plume's density) of each state of a
/// rollout against `reference.frames[first + 1 + i]`; empty for velocity-only states.
pub fn scalar_mae_per_step(states: &[Tensor], reference: &ReferenceSim, first: usize) -> Result<Vec<f64>> {
    let c = reference.frames.dim(1)?;
    if c <= 2 {
        return Ok(Vec::new());
    }
    mae_channels(states, reference, first, 2, c - 2)
}

fn mae_channels(states: &[Tensor], reference: &ReferenceSim, first: usize, from: usize, n: usize) -> Result<Vec<f64>> {
    if first + states.len() >= reference.len() {
        return Err(Error::invalid(
            "mae_per_step",
            "steps",
            format!(
                "{} steps from frame {first} need {} frames, the reference has {}",
                states.len(),
                first + states.len() + 1,
                reference.len()
            ),
        ));
    }
    states
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let r = reference.frames.narrow(0, first + 1 + i, 1)?.narrow(1, from, n)?;
            let s = s.narrow(1, from, n)?;
            Ok((s - r)?.abs()?.mean_all()?.to_dtype(candle_core::DType::F64)?.to_scalar::<f64>()?)
        })
        .collect()
}

/// The MAE curves of rollouts from the first frame of every simulation in `sims`, `steps`
/// long, averaged over the simulations (one value per step), and the per-simulation means.
#[derive(Clone, Debug)]
pub struct Evaluation {
    /// Mean over the simulations of the MAE after each step.
    pub mae_per_step: Vec<f64>,
    /// `(Re, MAE averaged over all steps)` per simulation (the scene's parameter: the plume's
    /// buoyancy factor).
    pub per_sim: Vec<(f64, f64)>,
    /// Mean over the simulations of the scalar channels' MAE (the plume's density) after each
    /// step; empty for the wake.
    pub scalar_mae_per_step: Vec<f64>,
}

impl Evaluation {
    /// The MAE averaged over steps `from..to` (of the per-step curve).
    pub fn mean_over(&self, from: usize, to: usize) -> f64 {
        let to = to.min(self.mae_per_step.len());
        let from = from.min(to);
        if to == from {
            return f64::NAN;
        }
        self.mae_per_step[from..to].iter().sum::<f64>() / (to - from) as f64
    }

    /// [`Evaluation::mean_over`] of the scalar channels' curve (NaN for the wake).
    pub fn scalar_mean_over(&self, from: usize, to: usize) -> f64 {
        let to = to.min(self.scalar_mae_per_step.len());
        let from = from.min(to);
        if to == from {
            return f64::NAN;
        }
        self.scalar_mae_per_step[from..to].iter().sum::<f64>() / (to - from) as f64
    }
}

/// Rolls out the source of `scene` (optionally corrected) from frame 0 of each simulation for
/// `steps` steps and compares with the reference.
pub fn evaluate<S: SilScene>(
    scene: &S,
    sims: &[ReferenceSim],
    steps: usize,
    corrector: Option<&Corrector>,
) -> Result<Evaluation> {
    if sims.is_empty() || steps == 0 {
        return Err(Error::invalid("evaluate", "sims / steps", "give at least one simulation and one step"));
    }
    let mut sum = vec![0.0; steps];
    let mut scalar_sum = vec![0.0; if scene.scalars() > 0 { steps } else { 0 }];
    let mut per_sim = Vec::new();
    for sim in sims {
        let source = scene.source_solver(sim.re)?;
        let states = rollout(&source, &sim.frames.narrow(0, 0, 1)?, steps, corrector)?;
        let mae = mae_per_step(&states, sim, 0)?;
        for (a, b) in sum.iter_mut().zip(&mae) {
            *a += b;
        }
        for (a, b) in scalar_sum.iter_mut().zip(&scalar_mae_per_step(&states, sim, 0)?) {
            *a += b;
        }
        per_sim.push((sim.re, mae.iter().sum::<f64>() / steps as f64));
    }
    let n = sims.len() as f64;
    Ok(Evaluation {
        mae_per_step: sum.into_iter().map(|s| s / n).collect(),
        per_sim,
        scalar_mae_per_step: scalar_sum.into_iter().map(|s| s / n).collect(),
    })
}
