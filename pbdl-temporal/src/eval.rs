//! Scores of trained models on held-out clips: per-frame PSNR, SSIM and LSiM to the truth and
//! the temporal scores tOF and tLSiM (pbdl-metrics' `temporal` module), for every model and
//! for bicubic upsampling, with the time per generated frame next to the solver's time per
//! step at the high resolution.
//!
//! tLSiM is TecoGAN's tLP with LSiM in place of LPIPS (whose backbone weights are not
//! available offline): `100 * mean_t |LSiM(gt_{t-1}, gt_t) - LSiM(out_{t-1}, out_t)|`.

use crate::data::{simulate, Clip, SmokeData};
use crate::model::TemporalModel;
use crate::Result;
use candle_core::Tensor;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_metrics::temporal::{Crop, TemporalOptions, TemporalScores, TofOptions};
use pbdl_metrics::Lsim;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// One method's scores, means over the held-out clips.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MethodScores {
    /// `bicubic`, or the model kind's name.
    pub method: String,
    /// PSNR in dB (data range 1).
    pub psnr: f64,
    /// SSIM (data range 1).
    pub ssim: f64,
    /// LSiM distance to the truth (lower is better); `None` without the LSiM weights.
    pub lsim: Option<f64>,
    /// tOF in high-resolution pixels (lower is better).
    pub tof: f64,
    /// tLSiM (lower is better); `None` without the LSiM weights.
    pub tlsim: Option<f64>,
    /// Wall-clock milliseconds per upscaled frame (batches of 8 frames).
    pub ms_per_frame: f64,
}

/// The evaluation of a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalReport {
    /// The data settings (the held-out clips are re-simulated from them).
    pub data: SmokeData,
    /// Bicubic first, then the models.
    pub rows: Vec<MethodScores>,
    /// Wall-clock milliseconds per solver step at the high resolution (with the inflow noise).
    pub solver_ms_per_step: f64,
}

/// Bicubic `factor`-times upsampling of `lr` `[T, 1, y, x]`.
pub fn bicubic(lr: &Tensor, factor: usize) -> Result<Tensor> {
    let d = lr.dims();
    if d.len() != 4 || factor == 0 {
        return Err(crate::Error::input("density", format!("{d:?}: expected [T, 1, y, x] (and a factor >= 1)")));
    }
    Ok(resize2d(lr, (d[2] * factor, d[3] * factor), Resize::Bicubic { align_corners: false })?)
}

/// Scores of `output` against a clip's truth. tOF uses TecoGAN's centre crop (the middle half
/// of a 64-pixel side) where the frames are large enough (sides >= 48), else the whole frame;
/// the flow is estimated on the whole frame and averaged over the crop (TecoGAN crops first),
/// and every frame pair counts (TecoGAN's script drops the first and last two frames).
fn score(output: &Tensor, clip: &Clip, lsim: Option<&Lsim>) -> Result<TemporalScores> {
    let d = output.dims();
    let crop = if d[2].min(d[3]) >= 48 { Crop::TecoGan } else { Crop::None };
    let tof = TofOptions { crop, ..Default::default() };
    let opts = TemporalOptions { data_range: Some(1.0), tof };
    Ok(TemporalScores::compute(output, &clip.hr_density, lsim, &opts)?)
}

fn mean_row(method: &str, scores: &[TemporalScores], ms_per_frame: f64) -> MethodScores {
    let n = scores.len().max(1) as f64;
    let avg = |f: &dyn Fn(&TemporalScores) -> f64| scores.iter().map(f).sum::<f64>() / n;
    MethodScores {
        method: method.to_string(),
        psnr: avg(&|s| s.psnr),
        ssim: avg(&|s| s.ssim),
        lsim: scores.iter().all(|s| s.lsim.is_some()).then(|| avg(&|s| s.lsim.unwrap_or(f64::NAN))),
        tof: avg(&|s| s.tof),
        tlsim: scores.iter().all(|s| s.tlsim.is_some()).then(|| avg(&|s| s.tlsim.unwrap_or(f64::NAN))),
        ms_per_frame,
    }
}

/// The published LSiM network if its weights are found (`pbdl_metrics::weights::weights_dir`:
/// `PBDL_WEIGHTS_DIR` or `../shared/weights`), `None` if there are none; a weight file that is
/// there but does not load is an error.
pub fn default_lsim() -> Result<Option<Lsim>> {
    match pbdl_metrics::weights::weights_dir() {
        Some(dir) if dir.join(pbdl_metrics::weights::LSIM_FILE).is_file() => Ok(Some(Lsim::load_default()?)),
        _ => Ok(None),
    }
}

/// Scores bicubic upsampling and every model on `clips`; the LSiM-based scores only with
/// `lsim`.
pub fn evaluate(models: &[TemporalModel], clips: &[Clip], lsim: Option<&Lsim>) -> Result<Vec<MethodScores>> {
    // The clips' own factor (high over low resolution); a model of another factor is refused.
    let factor = match clips.first() {
        Some(c) => c.hr_density.dim(3)? / c.lr_density.dim(3)?.max(1),
        None => return Ok(Vec::new()),
    };
    if let Some(m) = models.iter().find(|m| m.factor() != factor) {
        return Err(crate::Error::config(
            "model factor",
            format!("{} model upscales {}x but the clips are {factor}x apart", m.info.kind.name(), m.factor()),
        ));
    }
    let frames: usize = clips.iter().map(|c| c.frames()).sum();
    let mut rows = Vec::with_capacity(models.len() + 1);
    let (mut scores, mut seconds) = (Vec::new(), 0.0);
    for c in clips {
        let t = Instant::now();
        let out = bicubic(&c.lr_density, factor)?;
        seconds += t.elapsed().as_secs_f64();
        scores.push(score(&out, c, lsim)?);
    }
    rows.push(mean_row("bicubic", &scores, seconds * 1e3 / frames as f64));
    for m in models {
        let (mut scores, mut seconds) = (Vec::new(), 0.0);
        for c in clips {
            let t = Instant::now();
            let out = m.upscale(&c.lr_density, Some(&c.lr_velocity))?;
            seconds += t.elapsed().as_secs_f64();
            scores.push(score(&out, c, lsim)?);
        }
        rows.push(mean_row(m.info.kind.name(), &scores, seconds * 1e3 / frames as f64));
    }
    Ok(rows)
}

/// Re-simulates the held-out scenes of `data` (timing the solver) and scores `models` on them,
/// with LSiM and tLSiM when the published LSiM weights are found ([`default_lsim`]).
pub fn evaluate_run(data: &SmokeData, models: &[TemporalModel]) -> Result<EvalReport> {
    data.validate()?;
    let (_, test) = data.scenes();
    let t = Instant::now();
    let clips: Vec<Clip> = test.iter().map(|s| simulate(data, s)).collect::<Result<_>>()?;
    let steps = test.len() * (data.warmup + data.frames) * data.steps_per_frame;
    let solver_ms_per_step = t.elapsed().as_secs_f64() * 1e3 / steps as f64;
    let lsim = default_lsim()?;
    Ok(EvalReport { data: data.clone(), rows: evaluate(models, &clips, lsim.as_ref())?, solver_ms_per_step })
}

/// The header of a Markdown table of [`MethodScores::markdown_row`]s, with its separator.
pub const MARKDOWN_HEADER: &str =
    "| method | PSNR (dB) | SSIM | LSiM | tOF (px) | tLSiM | ms / frame |\n|---|---|---|---|---|---|---|";

impl MethodScores {
    /// `| method | psnr | ssim | lsim | tof | tlsim | ms |`; LSiM scores not computed show `-`.
    pub fn markdown_row(&self) -> String {
        let opt = |v: Option<f64>, digits: usize| v.map_or_else(|| "-".to_string(), |v| format!("{v:.digits$}"));
        format!(
            "| {} | {:.2} | {:.4} | {} | {:.4} | {} | {:.2} |",
            self.method,
            self.psnr,
            self.ssim,
            opt(self.lsim, 4),
            self.tof,
            opt(self.tlsim, 3),
            self.ms_per_frame
        )
    }
}

impl EvalReport {
    /// The row of `method`.
    pub fn row(&self, method: &str) -> Option<&MethodScores> {
        self.rows.iter().find(|r| r.method == method)
    }

    /// A Markdown table with the ratios the acceptance asks for.
    pub fn markdown(&self) -> String {
        let d = &self.data;
        let mut md = format!(
            "# temporal eval: {0}^2 -> {1}^2 smoke, {2} held-out scenes x {3} frames (seed {4})\n\n{MARKDOWN_HEADER}\n",
            d.lr_resolution,
            d.hr_resolution(),
            d.test_scenes,
            d.frames,
            d.seed
        );
        for r in &self.rows {
            md.push_str(&r.markdown_row());
            md.push('\n');
        }
        md.push_str(&format!("\nSolver at {0}^2: {1:.2} ms per step.\n", d.hr_resolution(), self.solver_ms_per_step));
        if let (Some(t), Some(p)) = (self.row("temporal"), self.row("per_frame")) {
            let tlsim = match (t.tlsim, p.tlsim) {
                (Some(a), Some(b)) => format!("{:.3}x", a / b),
                _ => "- (no LSiM weights)".into(),
            };
            md.push_str(&format!(
                "Temporal / per-frame GAN: tOF {:.3}x, tLSiM {tlsim} (bar <= 0.7x each).\n",
                t.tof / p.tof
            ));
        }
        if let (Some(t), Some(b)) = (self.row("temporal"), self.row("bicubic")) {
            if let (Some(a), Some(c)) = (t.lsim, b.lsim) {
                md.push_str(&format!("Temporal GAN LSiM {a:.4} vs bicubic {c:.4} (bar: lower).\n"));
            }
        }
        md
    }
}
