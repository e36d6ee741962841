//! The evaluation protocol of LSiM: per sequence the ten reference-to-variant distances are
//! min-max normalised to [0.1, 1], concatenated over a data set, and rank-correlated (Spearman)
//! with the ground truth `t = k / 10`.

use super::data::{Kind, Sequence, FRAMES};
use super::model::MetricNet;
use crate::classic::{rmse, spearman_values, ssim2d, SsimConfig};
use crate::{Error, Lsim, LsimOptions, LsimSize, NormScope, Result};
use candle_core::{DType, Tensor};

/// A metric that the evaluation can score.
#[derive(Clone, Copy)]
pub enum Scored<'a> {
    /// Root mean squared difference (the L2 norm up to a constant factor).
    L2,
    /// `1 - SSIM` (default SSIM settings; data range: each pair's joint range).
    Ssim,
    /// The published LSiM, all pairs of a sequence normalised jointly, resized as given.
    Lsim(&'a Lsim, LsimSize),
    /// A trained [`MetricNet`].
    Trained(&'a MetricNet),
}

impl Scored<'_> {
    /// Row label.
    pub fn name(&self) -> String {
        match self {
            Scored::L2 => "L2".into(),
            Scored::Ssim => "SSIM".into(),
            Scored::Lsim(_, LsimSize::Resize224) => "LSiM (published, 224)".into(),
            Scored::Lsim(_, LsimSize::Native) => "LSiM (published, native)".into(),
            Scored::Trained(_) => "trained here".into(),
        }
    }
}

/// Distances from frame 0 to frames 1..10 of a sequence `[11, 1, y, x]` under `metric`.
pub fn reference_distances(metric: Scored<'_>, frames: &Tensor) -> Result<Vec<f64>> {
    if frames.rank() != 4 || frames.dim(0)? != FRAMES {
        return Err(Error::Shape {
            op: "reference_distances",
            arg: "frames",
            expected: format!("[{FRAMES}, c, y, x]"),
            got: frames.dims().to_vec(),
        });
    }
    let n = FRAMES - 1;
    let reference = frames.narrow(0, 0, 1)?.repeat((n, 1, 1, 1))?;
    let variants = frames.narrow(0, 1, n)?;
    let d = match metric {
        Scored::L2 => rmse(&variants.to_dtype(DType::F64)?, &reference.to_dtype(DType::F64)?)?,
        Scored::Ssim => {
            (1.0 - ssim2d(&variants.to_dtype(DType::F64)?, &reference.to_dtype(DType::F64)?, &SsimConfig::default())?)?
        }
        Scored::Lsim(lsim, size) => {
            lsim.distance_with(&reference, &variants, &LsimOptions { size, norm: NormScope::JointBatch })?
        }
        Scored::Trained(net) => {
            let pairs: Vec<(usize, usize)> = (1..FRAMES).map(|j| (0, j)).collect();
            net.sequence_distances(frames, &pairs)?
        }
    };
    Ok(d.to_dtype(DType::F64)?.to_vec1::<f64>()?)
}

/// Min-max normalisation to [0.1, 1]; a constant list is shifted to 0.1 (as the official code).
pub fn normalise_01(d: &[f64]) -> Vec<f64> {
    let (lo, hi) = d.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    if hi > lo {
        d.iter().map(|v| 0.1 + 0.9 * (v - lo) / (hi - lo)).collect()
    } else {
        d.iter().map(|v| v - lo + 0.1).collect()
    }
}

/// Spearman correlation of a data set under the protocol (module docs).
pub fn spearman_protocol(metric: Scored<'_>, seqs: &[Sequence]) -> Result<f64> {
    let mut pred = Vec::with_capacity(seqs.len() * (FRAMES - 1));
    let mut truth = Vec::with_capacity(seqs.len() * (FRAMES - 1));
    for s in seqs {
        pred.extend(normalise_01(&reference_distances(metric, &s.frames)?));
        truth.extend((1..FRAMES).map(|k| k as f64 / (FRAMES - 1) as f64));
    }
    spearman_values(&pred, &truth)
}

/// One row of a results table: a metric's Spearman correlation per data set.
#[derive(Clone, Debug)]
pub struct EvalRow {
    /// The metric.
    pub metric: String,
    /// `(data set, Spearman)`.
    pub scores: Vec<(String, f64)>,
}

/// Scores every metric on every named data set.
pub fn evaluate(metrics: &[Scored<'_>], sets: &[(String, Vec<Sequence>)]) -> Result<Vec<EvalRow>> {
    metrics
        .iter()
        .map(|&m| {
            Ok(EvalRow {
                metric: m.name(),
                scores: sets
                    .iter()
                    .map(|(name, s)| Ok((name.clone(), spearman_protocol(m, s)?)))
                    .collect::<Result<_>>()?,
            })
        })
        .collect()
}

/// A markdown table of [`EvalRow`]s (three decimals, the best of each column in bold).
pub fn markdown_table(rows: &[EvalRow]) -> String {
    let Some(first) = rows.first() else { return String::new() };
    let mut s = String::from("| Metric |");
    for (name, _) in &first.scores {
        s += &format!(" {name} |");
    }
    s += "\n|---|";
    s += &"---|".repeat(first.scores.len());
    s += "\n";
    let best: Vec<f64> = (0..first.scores.len())
        .map(|c| rows.iter().filter_map(|r| r.scores.get(c).map(|x| x.1)).fold(f64::NEG_INFINITY, f64::max))
        .collect();
    for r in rows {
        s += &format!("| {} |", r.metric);
        for (c, (_, v)) in r.scores.iter().enumerate() {
            if *v == best[c] {
                s += &format!(" **{v:.3}** |");
            } else {
                s += &format!(" {v:.3} |");
            }
        }
        s += "\n";
    }
    s
}

/// Data set label: the kind's short name, with `suffix` (e.g. `" (held out)"`).
pub fn set_name(kind: Kind, suffix: &str) -> String {
    format!("{}{suffix}", kind.short())
}
