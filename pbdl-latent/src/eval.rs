//! Scores of a trained model on held-out scenes: the autoencoder's reconstruction error, the
//! one-step prediction error against the autoencoder's own floor, and hybrid rollouts against
//! the pure solver.

use crate::data::{PlumeScene, Sequence};
use crate::hybrid::{HybridSmoke, HybridState, PressureSource, Schedule};
use crate::model::LatentModel;
use crate::train::encode_sequence;
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_core::stepper::Stepper;
use pbdl_grid::{fd, FluidState};
use serde::{Deserialize, Serialize};
use std::time::Instant;

fn sum_sq(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(candle_core::DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()?)
}

/// Relative L2 error `||a - b|| / ||b||` over whole tensors.
pub fn relative_l2(a: &Tensor, b: &Tensor) -> Result<f64> {
    let den = sum_sq(b)?;
    Ok((sum_sq(&(a - b)?)? / den.max(f64::MIN_POSITIVE)).sqrt())
}

/// The autoencoder's relative L2 reconstruction error of the pressure over all frames of
/// `seqs` but the first (at rest, zero pressure): `sqrt(sum |AE(p) - p|^2 / sum |p|^2)`.
pub fn autoencoder_error(model: &LatentModel, seqs: &[Sequence]) -> Result<f64> {
    let (mut err, mut den) = (0.0, 0.0);
    for s in seqs {
        let p = s.pressure.narrow(0, 1, s.frames() - 1)?;
        let r = model.decode_pressure(&model.encode_pressure(&p)?)?;
        err += sum_sq(&(r - &p)?)?;
        den += sum_sq(&p)?;
    }
    Ok((err / den.max(f64::MIN_POSITIVE)).sqrt())
}

/// One-step prediction scores over every window of the held-out scenes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PredictionScore {
    /// Relative L2 error of the decoded prediction against the solver's pressure.
    pub predicted: f64,
    /// Relative L2 error of the autoencoder's reconstruction of the same frames (its floor).
    pub floor: f64,
    /// `predicted / floor`.
    pub ratio: f64,
    /// Mean absolute error of the predicted normalised code against the encoded one.
    pub latent_mae: f64,
    /// The same for persistence (the last code repeated): what the LSTM must beat.
    pub persistence_latent_mae: f64,
}

/// [`PredictionScore`] of `model` on `seqs`: from the encoded pressures of frames
/// `t - window .. t`, the prediction of frame `t`'s, for every `t >= window`.
pub fn prediction_error(model: &LatentModel, seqs: &[Sequence]) -> Result<PredictionScore> {
    let w = model.predictor.config().window;
    let (mut e_pred, mut e_floor, mut den, mut mae, mut mae_p, mut count) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    for s in seqs {
        let codes = (encode_sequence(&model.autoencoder, model.scales.pressure, s)? / model.scales.code as f64)?;
        let t = s.frames();
        if t <= w {
            return Err(Error::config("frames", format!("{t} frames leave no window of {w}; simulate more")));
        }
        let hist: Vec<Tensor> = (w..t).map(|k| codes.narrow(0, k - w, w)).collect::<candle_core::Result<_>>()?;
        let target = codes.narrow(0, w, t - w)?;
        let pred = model.predict(&Tensor::stack(&hist, 0)?)?;
        let p = s.pressure.narrow(0, w, t - w)?;
        e_pred += sum_sq(&(model.decode_pressure(&pred)? - &p)?)?;
        e_floor += sum_sq(&(model.decode_pressure(&target)? - &p)?)?;
        den += sum_sq(&p)?;
        let n = target.elem_count();
        mae += (&pred - &target)?.abs()?.sum_all()?.to_scalar::<f32>()? as f64;
        mae_p += (codes.narrow(0, w - 1, t - w)? - &target)?.abs()?.sum_all()?.to_scalar::<f32>()? as f64;
        count += n;
    }
    let predicted = (e_pred / den).sqrt();
    let floor = (e_floor / den).sqrt();
    Ok(PredictionScore {
        predicted,
        floor,
        ratio: predicted / floor,
        latent_mae: mae / count as f64,
        persistence_latent_mae: mae_p / count as f64,
    })
}

/// A hybrid rollout against the pure solver from the same start.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RolloutScore {
    /// The schedule.
    pub warmup: usize,
    /// Solver every `interval`-th step after the warm-up.
    pub interval: usize,
    /// Steps of both runs.
    pub steps: usize,
    /// Steps that used a predicted pressure.
    pub predicted_steps: usize,
    /// Whether every state of the hybrid run is finite.
    pub finite: bool,
    /// Relative L2 error of the hybrid density against the solver's, at the last step.
    pub density_error_final: f64,
    /// Its largest value over the run.
    pub density_error_max: f64,
    /// Over the predicted steps, the largest `max |div u|` after the correction divided by
    /// `max |div u|` before it (the solver's projection gives round-off).
    pub divergence_ratio_max: f64,
    /// Wall-clock seconds per step of the hybrid run (after the warm-up).
    pub hybrid_seconds_per_step: f64,
    /// Wall-clock seconds per step of the solver run (after the warm-up).
    pub solver_seconds_per_step: f64,
}

impl RolloutScore {
    /// The header of [`RolloutScore::markdown_row`]'s table.
    pub const MARKDOWN_HEADER: &'static str = "| scene x | interval | predicted steps | finite | density rel L2 final | max | div ratio max | hybrid ms/step | solver ms/step |\n|---|---|---|---|---|---|---|---|---|";

    /// One markdown table row: the scene parameter, `interval` as given (e.g. `"2"` or
    /// `"2 (autoencoder only)"`) and the scores.
    pub fn markdown_row(&self, scene_x: f64, interval: &str) -> String {
        format!(
            "| {scene_x:.3} | {interval} | {} | {} | {:.4} | {:.4} | {:.3} | {:.3} | {:.3} |",
            self.predicted_steps,
            self.finite,
            self.density_error_final,
            self.density_error_max,
            self.divergence_ratio_max,
            self.hybrid_seconds_per_step * 1e3,
            self.solver_seconds_per_step * 1e3
        )
    }
}

fn max_div(u: &pbdl_grid::MacField) -> Result<f64> {
    Ok(fd::divergence(u)?
        .values()
        .abs()?
        .flatten_all()?
        .max(0)?
        .to_dtype(candle_core::DType::F64)?
        .to_scalar::<f64>()?)
}

/// Runs `scene` `steps` steps with the solver and with the hybrid loop of `schedule`, and
/// compares the densities after every step.
pub fn rollout(model: &LatentModel, scene: &PlumeScene, schedule: Schedule, steps: usize) -> Result<RolloutScore> {
    rollout_with(model, scene, schedule, steps, false)
}

/// [`rollout`] of the diagnostic [`HybridSmoke::autoencoder_only`] loop (a perfect LSTM): the
/// error floor the autoencoder sets.
pub fn rollout_autoencoder_only(
    model: &LatentModel,
    scene: &PlumeScene,
    schedule: Schedule,
    steps: usize,
) -> Result<RolloutScore> {
    rollout_with(model, scene, schedule, steps, true)
}

fn rollout_with(
    model: &LatentModel,
    scene: &PlumeScene,
    schedule: Schedule,
    steps: usize,
    autoencoder_only: bool,
) -> Result<RolloutScore> {
    let fluid = scene.fluid()?;
    let rate = scene.rate()?;
    let start = scene.start(&fluid)?;
    let mut hybrid = HybridSmoke::new(scene.fluid()?, rate.clone(), model, schedule)?;
    if autoencoder_only {
        hybrid = hybrid.autoencoder_only();
    }
    let mut solver_state: FluidState = start.clone();
    let mut state = HybridState::new(start);
    let (mut t_solver, mut t_hybrid) = (0.0, 0.0);
    let (mut err_max, mut err_last, mut div_ratio, mut predicted, mut finite) = (0.0f64, 0.0, 0.0f64, 0, true);
    for k in 0..steps {
        let t0 = Instant::now();
        solver_state = fluid.step(&solver_state, Some(&rate))?;
        let t1 = Instant::now();
        let next = hybrid.step(&state)?;
        let t2 = Instant::now();
        if k >= schedule.warmup {
            t_solver += (t1 - t0).as_secs_f64();
            t_hybrid += (t2 - t1).as_secs_f64();
        }
        if next.last == Some(PressureSource::Predicted) {
            predicted += 1;
            let before = fluid.step_unprojected(&state.fluid, Some(&rate))?;
            let (a, b) = (max_div(&next.fluid.velocity)?, max_div(&before.velocity)?);
            div_ratio = div_ratio.max(a / b.max(f64::MIN_POSITIVE));
        }
        state = next;
        let rho_h = state.fluid.density.as_ref().expect("plume density").values();
        let rho_s = solver_state.density.as_ref().expect("plume density").values();
        let ok = rho_h.abs()?.max_all()?.to_scalar::<f32>()?.is_finite()
            && state.fluid.velocity.values().abs()?.max_all()?.to_scalar::<f32>()?.is_finite();
        if !ok {
            finite = false;
            err_last = f64::INFINITY;
            err_max = f64::INFINITY;
            break;
        }
        err_last = relative_l2(rho_h, rho_s)?;
        err_max = err_max.max(err_last);
    }
    let measured = steps.saturating_sub(schedule.warmup).max(1) as f64;
    Ok(RolloutScore {
        warmup: schedule.warmup,
        interval: schedule.interval,
        steps,
        predicted_steps: predicted,
        finite,
        density_error_final: err_last,
        density_error_max: err_max,
        divergence_ratio_max: div_ratio,
        hybrid_seconds_per_step: t_hybrid / measured,
        solver_seconds_per_step: t_solver / measured,
    })
}
