//! Scores of a frame sequence against its ground truth: tOF, tLSiM and per-frame PSNR, SSIM and
//! LSiM, and [`TemporalScores`] bundling them.
//!
//! Sequences are tensors `[t, channel, y, x]` (`f32` or `f64`), output and truth of one shape;
//! frame `t` is `seq.get(t)`.

use super::flow::{optical_flow, FlowOptions};
use crate::classic::{self, SsimConfig};
use crate::{check, Error, Lsim, Result};
use candle_core::{DType, Tensor};
use rayon::prelude::*;

/// Which pixels of the flow fields tOF averages over.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Crop {
    /// TecoGAN's `crop_8x8` (default): per axis of size `n`, the largest multiple of 32 that
    /// leaves at least 16 pixels, centred (`offset = (n - kept) / 2`). A 64-pixel side keeps the
    /// middle 32, a 128-pixel side the middle 96. Sides below 48 would keep nothing and are an
    /// error: use [`Crop::Border`] there.
    #[default]
    TecoGan,
    /// Drop this many pixels at every edge.
    Border(usize),
    /// Every pixel.
    None,
}

impl Crop {
    /// The kept index range `start..end` along an axis of `n` pixels, or `None` if nothing is kept.
    pub fn range(&self, n: usize) -> Option<std::ops::Range<usize>> {
        let (start, len) = match *self {
            Crop::None => (0, n),
            Crop::Border(b) => (b, n.saturating_sub(2 * b)),
            Crop::TecoGan => {
                let mut kept = (n / 32 * 32) as i64;
                while kept > n as i64 - 16 {
                    kept -= 32;
                }
                if kept <= 0 {
                    return None;
                }
                let kept = kept as usize;
                ((n - kept) / 2, kept)
            }
        };
        (len > 0).then_some(start..start + len)
    }
}

/// Options of [`tof`] / [`tof_pairs`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TofOptions {
    /// The optical-flow estimator's parameters.
    pub flow: FlowOptions,
    /// The pixels averaged over. Default [`Crop::TecoGan`].
    pub crop: Crop,
}

/// Checks a pair of sequences `[t, c, y, x]`: rank, float, one shape, at least `min_t` frames,
/// channel count in `channels` (if given), non-empty, finite.
fn sequences(op: &'static str, out: &Tensor, truth: &Tensor, min_t: usize, rgb_or_grey: bool) -> Result<()> {
    for (arg, t) in [("output", out), ("truth", truth)] {
        if t.rank() != 4 {
            return Err(Error::Shape {
                op,
                arg,
                expected: "a frame sequence [t, channel, y, x]".into(),
                got: t.dims().to_vec(),
            });
        }
        check::float(op, arg, t)?;
        check::non_empty(op, arg, t)?;
        let d = t.dims();
        if d[0] < min_t {
            return Err(Error::Shape {
                op,
                arg,
                expected: format!("at least {min_t} frames [t >= {min_t}, channel, y, x]"),
                got: d.to_vec(),
            });
        }
        if rgb_or_grey && d[1] != 1 && d[1] != 3 {
            return Err(Error::Shape {
                op,
                arg,
                expected: "1 (grey) or 3 (RGB) channels; pick a channel with `narrow(1, c, 1)`".into(),
                got: d.to_vec(),
            });
        }
    }
    if out.dims() != truth.dims() {
        return Err(Error::ShapeMismatch { op, a: out.dims().to_vec(), b: truth.dims().to_vec() });
    }
    check::finite(op, "output", out)?;
    check::finite(op, "truth", truth)?;
    Ok(())
}

/// Grey frames of a checked `[t, c, y, x]` sequence: 1 channel as it is, 3 channels as RGB luma
/// `0.299 R + 0.587 G + 0.114 B` (ITU-R BT.601, OpenCV's `COLOR_RGB2GRAY`).
fn grey_frames(seq: &Tensor) -> Result<Vec<Vec<f32>>> {
    let (t, c, ny, nx) = seq.dims4()?;
    let data = seq.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
    let n = ny * nx;
    Ok((0..t)
        .map(|i| {
            let f = &data[i * c * n..(i + 1) * c * n];
            if c == 1 {
                f.to_vec()
            } else {
                (0..n).map(|p| 0.299 * f[p] + 0.587 * f[n + p] + 0.114 * f[2 * n + p]).collect()
            }
        })
        .collect())
}

/// TecoGAN's tOF per consecutive pair: for `t = 1..T`, the flows `OF(truth_(t-1), truth_t)` and
/// `OF(output_(t-1), output_t)` by [`optical_flow`], and the mean over the cropped pixels of
/// `|OF_truth - OF_output|_2` (pixels); `T - 1` values.
///
/// `output`, `truth`: `[t, channel, y, x]`, one shape, `t >= 2`, 1 channel (grey) or 3 (RGB,
/// converted to luma as OpenCV's `COLOR_RGB2GRAY`). TecoGAN's script also leaves out a few
/// frames at the ends of a clip; narrow the sequences first to do the same.
///
/// Errors: shapes (rank, fewer than 2 frames, other channel counts, mismatch), non-float or
/// non-finite input, a crop that keeps nothing; otherwise as [`optical_flow`].
pub fn tof_pairs(output: &Tensor, truth: &Tensor, opts: &TofOptions) -> Result<Vec<f64>> {
    const OP: &str = "tof";
    sequences(OP, output, truth, 2, true)?;
    let (_, _, ny, nx) = truth.dims4()?;
    let (Some(ry), Some(rx)) = (opts.crop.range(ny), opts.crop.range(nx)) else {
        return Err(Error::invalid(
            OP,
            "crop",
            format!("{:?} keeps no pixel of a {ny}x{nx} frame; use Crop::Border(b) or Crop::None", opts.crop),
        ));
    };
    let (go, gt) = (grey_frames(output)?, grey_frames(truth)?);
    (1..go.len())
        .into_par_iter()
        .map(|t| {
            let fo = optical_flow(&go[t - 1], &go[t], ny, nx, &opts.flow)?;
            let ft = optical_flow(&gt[t - 1], &gt[t], ny, nx, &opts.flow)?;
            let (mut sum, mut n) = (0.0f64, 0usize);
            for y in ry.clone() {
                for x in rx.clone() {
                    let i = y * nx + x;
                    let du = f64::from(fo.u[i]) - f64::from(ft.u[i]);
                    let dv = f64::from(fo.v[i]) - f64::from(ft.v[i]);
                    sum += (du * du + dv * dv).sqrt();
                    n += 1;
                }
            }
            Ok(sum / n as f64)
        })
        .collect()
}

/// TecoGAN's tOF: the mean of [`tof_pairs`] over the pairs (pixels; lower is better).
pub fn tof(output: &Tensor, truth: &Tensor, opts: &TofOptions) -> Result<f64> {
    Ok(mean(&tof_pairs(output, truth, opts)?))
}

/// tLSiM per consecutive pair: `100 |LSiM(truth_(t-1), truth_t) - LSiM(output_(t-1), output_t)|`
/// for `t = 1..T`, with LSiM's default options (resize to 224, per-pair normalisation).
///
/// tLSiM is TecoGAN's tLP with LSiM in place of LPIPS: LPIPS' backbone weights (AlexNet/VGG
/// ImageNet features) are not available offline, while LSiM's are (`LSiM.safetensors`), and LSiM
/// is a learned distance made for simulation fields. Values are therefore not comparable with
/// published tLP numbers; compare methods with each other.
///
/// `output`, `truth`: `[t, channel, y, x]`, one shape, `t >= 2`, 1 or 3 channels (LSiM repeats a
/// single channel to three).
///
/// Errors: as [`tof_pairs`] for the shapes and values; LSiM's own errors.
pub fn tlsim_pairs(output: &Tensor, truth: &Tensor, lsim: &Lsim) -> Result<Vec<f64>> {
    sequences("tlsim", output, truth, 2, true)?;
    let t = truth.dim(0)?;
    let step = |s: &Tensor| -> Result<Vec<f64>> { lsim.distance(&s.narrow(0, 0, t - 1)?, &s.narrow(0, 1, t - 1)?) };
    let (dt, doo) = (step(truth)?, step(output)?);
    Ok(dt.iter().zip(&doo).map(|(a, b)| 100.0 * (a - b).abs()).collect())
}

/// tLSiM: the mean of [`tlsim_pairs`] (lower is better).
pub fn tlsim(output: &Tensor, truth: &Tensor, lsim: &Lsim) -> Result<f64> {
    Ok(mean(&tlsim_pairs(output, truth, lsim)?))
}

/// PSNR in dB of each frame, `10 log10(R^2 / mse)` ([`classic::psnr`] per frame): `T` values.
///
/// `data_range` is `R`; `None` takes each frame's peak-to-peak range of `truth`. A frame equal
/// to its truth gives `+inf`. Errors: as [`classic::psnr`], and a rank other than 4.
pub fn psnr_frames(output: &Tensor, truth: &Tensor, data_range: Option<f64>) -> Result<Vec<f64>> {
    sequences("psnr", output, truth, 1, false)?;
    Ok(classic::psnr(output, truth, data_range)?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
}

/// Mean over the frames of [`psnr_frames`] (dB; `+inf` if any frame is exact).
pub fn psnr(output: &Tensor, truth: &Tensor, data_range: Option<f64>) -> Result<f64> {
    Ok(mean(&psnr_frames(output, truth, data_range)?))
}

/// SSIM of each frame (Wang et al. 2004: Gaussian window of 11 taps, sigma 1.5, k1 = 0.01,
/// k2 = 0.03, valid positions, mean over channels; [`classic::ssim2d`]): `T` values.
///
/// `data_range` is `R` in the constants `C1 = (k1 R)^2`, `C2 = (k2 R)^2`; `None` takes each
/// frame's joint peak-to-peak range of both inputs. Frames need at least 11x11 pixels.
/// Errors: as [`classic::ssim2d`], and a rank other than 4.
pub fn ssim_frames(output: &Tensor, truth: &Tensor, data_range: Option<f64>) -> Result<Vec<f64>> {
    sequences("ssim", output, truth, 1, false)?;
    let cfg = SsimConfig { data_range, ..SsimConfig::default() };
    Ok(classic::ssim2d(output, truth, &cfg)?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
}

/// Mean over the frames of [`ssim_frames`].
pub fn ssim(output: &Tensor, truth: &Tensor, data_range: Option<f64>) -> Result<f64> {
    Ok(mean(&ssim_frames(output, truth, data_range)?))
}

/// LSiM distance of each output frame to its truth frame (default options): `T` values.
///
/// Errors: as [`tof_pairs`] for the shapes (at least one frame); LSiM's own errors.
pub fn lsim_frames(output: &Tensor, truth: &Tensor, lsim: &Lsim) -> Result<Vec<f64>> {
    sequences("lsim_frames", output, truth, 1, true)?;
    lsim.distance(output, truth)
}

/// Mean over the frames of [`lsim_frames`] (lower is better).
pub fn lsim_mean(output: &Tensor, truth: &Tensor, lsim: &Lsim) -> Result<f64> {
    Ok(mean(&lsim_frames(output, truth, lsim)?))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Options of [`TemporalScores::compute`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TemporalOptions {
    /// The data range for PSNR and SSIM (`None`: per frame, see [`psnr_frames`], [`ssim_frames`]).
    pub data_range: Option<f64>,
    /// tOF's options.
    pub tof: TofOptions,
}

/// The per-frame and temporal scores of an output sequence against its truth, each a mean over
/// frames (PSNR, SSIM, LSiM) or consecutive pairs (tOF, tLSiM).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TemporalScores {
    /// Mean PSNR in dB (higher is better).
    pub psnr: f64,
    /// Mean SSIM (higher is better, at most 1).
    pub ssim: f64,
    /// Mean LSiM distance to the truth (lower is better); `None` without an [`Lsim`].
    pub lsim: Option<f64>,
    /// tOF in pixels (lower is better).
    pub tof: f64,
    /// tLSiM (lower is better); `None` without an [`Lsim`].
    pub tlsim: Option<f64>,
}

impl TemporalScores {
    /// All scores of `output` against `truth` (`[t, channel, y, x]`, `t >= 2`, 1 or 3 channels,
    /// frames at least 11x11 for SSIM); the LSiM-based ones only with `lsim`.
    ///
    /// Errors: as the single scores.
    pub fn compute(output: &Tensor, truth: &Tensor, lsim: Option<&Lsim>, opts: &TemporalOptions) -> Result<Self> {
        Ok(Self {
            psnr: psnr(output, truth, opts.data_range)?,
            ssim: ssim(output, truth, opts.data_range)?,
            lsim: lsim.map(|m| lsim_mean(output, truth, m)).transpose()?,
            tof: tof(output, truth, &opts.tof)?,
            tlsim: lsim.map(|m| tlsim(output, truth, m)).transpose()?,
        })
    }

    /// The header of a Markdown table whose rows are [`TemporalScores::markdown_row`], with its
    /// separator line.
    pub fn markdown_header() -> &'static str {
        "| method | PSNR (dB) | SSIM | LSiM | tOF (px) | tLSiM |\n|---|---|---|---|---|---|"
    }

    /// One Markdown table row `| label | psnr | ssim | lsim | tof | tlsim |`; scores that were
    /// not computed show as `-`.
    pub fn markdown_row(&self, label: &str) -> String {
        let opt = |v: Option<f64>, digits: usize| v.map_or_else(|| "-".to_string(), |v| format!("{v:.digits$}"));
        format!(
            "| {label} | {:.2} | {:.4} | {} | {:.4} | {} |",
            self.psnr,
            self.ssim,
            opt(self.lsim, 4),
            self.tof,
            opt(self.tlsim, 3)
        )
    }
}
