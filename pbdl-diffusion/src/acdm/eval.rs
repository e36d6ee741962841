//! Rollout evaluation against held-out ground truth: MSE, LSiM per field, temporal stability,
//! Strouhal number and posterior spread, for any [`FramePredictor`].

use super::data::{CylinderConfig, Normalization, Sequence, CHANNEL_NAMES, FIELDS};
use super::metrics::{mean, mse, sample_spread, strouhal, temporal_stability};
use super::rollout::{rollout, FramePredictor};
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_metrics::Lsim;
use serde::{Deserialize, Serialize};

/// Settings of [`evaluate`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    /// Rollout steps (frames predicted).
    pub steps: usize,
    /// Samples rolled out together (batch); the spread needs at least 2.
    pub samples: usize,
    /// Seed of the sampling noise.
    pub seed: u64,
    /// LSiM on every `lsim_every`-th frame (0: no LSiM).
    pub lsim_every: usize,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self { steps: 1000, samples: 1, seed: 0, lsim_every: 10 }
    }
}

/// The numbers of one model on one held-out sequence.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalReport {
    /// The model's name.
    pub model: String,
    /// Reynolds number of the sequence.
    pub re: f64,
    /// Steps rolled out (fewer than asked when a frame became non-finite).
    pub steps: usize,
    /// First non-finite step, if any.
    pub first_non_finite: Option<usize>,
    /// Wall-clock seconds of the rollout (all samples together).
    pub seconds: f64,
    /// Seconds per predicted frame of one sample.
    pub seconds_per_frame: f64,
    /// MSE of `[vx, vy, p]` in normalised units, over steps and samples.
    pub mse: f64,
    /// Mean LSiM distance per field `[vx, vy, p]` (NaN when not computed).
    pub lsim: [f64; 3],
    /// Mean `|ds/dt|` of the prediction (normalised fields, averaged over samples).
    pub stability: f64,
    /// The same for the ground truth over the same frames.
    pub stability_truth: f64,
    /// Strouhal number of the prediction's probe (mean over samples).
    pub strouhal: f64,
    /// Strouhal number of the ground truth over the same frames.
    pub strouhal_truth: f64,
    /// Mean standard deviation across samples (normalised fields); `None` for one sample.
    pub spread: Option<f64>,
}

impl EvalReport {
    /// `stability / stability_truth` (the acceptance band is 0.5..2).
    pub fn stability_ratio(&self) -> f64 {
        self.stability / self.stability_truth
    }

    /// `|St - St_truth| / St_truth` (acceptance: < 0.1).
    pub fn strouhal_error(&self) -> f64 {
        (self.strouhal - self.strouhal_truth).abs() / self.strouhal_truth
    }

    /// One markdown table row: model, Re, steps, finite, MSE, LSiM, stability ratio, St, spread.
    pub fn markdown_row(&self) -> String {
        format!(
            "| {} | {:.0} | {} | {} | {:.4} | {:.3} / {:.3} / {:.3} | {:.3} ({:.4} vs {:.4}) | {:.4} vs {:.4} ({:.1}%) | {} | {:.3} |",
            self.model,
            self.re,
            self.steps,
            self.first_non_finite.map_or("yes".to_string(), |s| format!("no (step {s})")),
            self.mse,
            self.lsim[0],
            self.lsim[1],
            self.lsim[2],
            self.stability_ratio(),
            self.stability,
            self.stability_truth,
            self.strouhal,
            self.strouhal_truth,
            100.0 * self.strouhal_error(),
            self.spread.map_or("-".into(), |s| format!("{s:.4}")),
            self.seconds_per_frame,
        )
    }

    /// The header of [`EvalReport::markdown_row`].
    pub fn markdown_header() -> String {
        "| model | Re | steps | finite | MSE | LSiM vx / vy / p | |ds/dt| ratio (pred vs truth) | St pred vs truth (err) | spread | s/frame |\n|---|---|---|---|---|---|---|---|---|---|".into()
    }
}

/// Rolls `model` out from the first frames of `seq` and scores it against the rest.
///
/// LSiM (`lsim`, optional) runs per field on every `lsim_every`-th frame with the metric's
/// per-pair min-max mapping to [0, 255]; the official per-sequence min-max scaling is a common
/// affine map of both fields and LSiM is invariant to it.
pub fn evaluate(
    model: &dyn FramePredictor,
    seq: &Sequence,
    norm: &Normalization,
    data: &CylinderConfig,
    cfg: &EvalConfig,
    lsim: Option<&Lsim>,
) -> Result<EvalReport> {
    let h = model.history();
    let truth = norm.normalize(seq)?;
    let (t, c, ny, nx) = truth.dims4()?;
    if t < h + cfg.steps || cfg.steps < 2 || cfg.samples == 0 {
        return Err(Error::InvalidConfig {
            name: "EvalConfig.steps",
            value: format!("{} steps, {} samples, sequence of {t} frames", cfg.steps, cfg.samples),
            hint: "use 2 <= steps <= frames - history and at least 1 sample (generate longer ground truth)",
        });
    }
    let init = truth.narrow(0, 0, h)?.unsqueeze(0)?.repeat((cfg.samples, 1, 1, 1, 1))?;
    let re = vec![norm.re_value(seq.re); cfg.samples];
    let r = rollout(model, &init, &re, cfg.steps, cfg.seed)?;
    let n = r.frames.dim(0)?;
    if n < 2 {
        return Err(Error::NonFinite { what: format!("{} rollout at Re {}", model.name(), seq.re), step: 1 });
    }
    let pred = r.frames.narrow(2, 0, FIELDS)?; // [n, S, 3, ny, nx]
    let gt = truth.narrow(0, h, n)?.narrow(1, 0, FIELDS)?; // [n, 3, ny, nx]
    let gt_b = gt.unsqueeze(1)?.broadcast_as(pred.shape())?.contiguous()?;
    let mse_v = mse(&pred, &gt_b)?;
    let dt = data.frame_dt();
    let stab_truth = mean(&temporal_stability(&gt, dt)?);
    let phys_truth = norm.denormalize(&gt)?;
    let st_truth = strouhal(&phys_truth, data)?;
    let mut stab = Vec::new();
    let mut st = Vec::new();
    for s in 0..cfg.samples {
        let p = pred.narrow(1, s, 1)?.squeeze(1)?;
        stab.push(mean(&temporal_stability(&p, dt)?));
        st.push(strouhal(&norm.denormalize(&p)?, data)?);
    }
    let spread = if cfg.samples >= 2 {
        // [S, n, 3, ny, nx]: spread per step, averaged.
        Some(sample_spread(&pred.transpose(0, 1)?.contiguous()?)?)
    } else {
        None
    };
    let mut lsim_v = [f64::NAN; FIELDS];
    if let (Some(metric), true) = (lsim, cfg.lsim_every > 0) {
        let idx: Vec<u32> = (0..n).step_by(cfg.lsim_every).map(|k| k as u32).collect();
        let idx = Tensor::new(idx.as_slice(), truth.device())?;
        let p0 = pred.narrow(1, 0, 1)?.squeeze(1)?.contiguous()?.index_select(&idx, 0)?;
        let g0 = gt.contiguous()?.index_select(&idx, 0)?;
        for (f, v) in lsim_v.iter_mut().enumerate() {
            let a = g0.narrow(1, f, 1)?.contiguous()?;
            let b = p0.narrow(1, f, 1)?.contiguous()?;
            let d = metric.distance(&a, &b).map_err(|e| Error::InvalidConfig {
                name: "lsim",
                value: format!("{} field: {e}", CHANNEL_NAMES[f]),
                hint: "LSiM needs finite [B, 1, H, W] fields",
            })?;
            *v = mean(&d);
        }
    }
    let _ = (c, ny, nx);
    Ok(EvalReport {
        model: model.name(),
        re: seq.re,
        steps: n,
        first_non_finite: r.first_non_finite,
        seconds: r.seconds,
        seconds_per_frame: r.seconds / (n * cfg.samples) as f64,
        mse: mse_v,
        lsim: lsim_v,
        stability: mean(&stab),
        stability_truth: stab_truth,
        strouhal: mean(&st),
        strouhal_truth: st_truth,
        spread,
    })
}

/// The LSiM metric from `pbdl_metrics`' default location ([`pbdl_metrics::weights::weights_dir`]);
/// `None` when the weights are nowhere (LSiM columns are then NaN).
pub fn load_lsim() -> Option<Lsim> {
    Lsim::load_default().ok()
}
