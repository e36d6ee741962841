//! A trainable LSiM: the LSiM base network (five conv layers, every ReLU output a feature
//! layer), built from seeded random weights as candle `Var`s, with per-layer feature
//! normalisation from calibrated statistics and learned non-negative channel weights.
//!
//! Differences to the published model ([`crate::Lsim`]), all deliberate for CPU-sized training
//! on scalar fields: one input channel (the published net repeats a scalar to three), an
//! optional channel-width multiplier ([`MetricNetConfig::width`], 1.0 = the published widths
//! 32/96/192/128/128), inputs at their own size (no resize to 224; the statistics are computed
//! at that size), and one min/max mapping to [0, 255] per sequence (all frames of a sequence
//! jointly). Training can apply the published dropout (p = 0.5 on the weighted squared feature
//! differences, [`MetricNet::pair_distances_dropout`]).
//!
//! The distance of a pair is the published one: `d = sqrt( sum_l mean_(h,w) sum_c w_(l,c)
//! (n_l(b) - n_l(a))^2 )`, `n = (phi - mu) / (sqrt(M2 / (count - 1)) + 1e-10) / (sqrt(C) - 1)`,
//! with `mu`, `M2` per pixel and averaged over channels, accumulated with Welford's update one
//! frame at a time by [`MetricNet::calibrate`] (the calibration epoch of the paper).

use crate::learned::{layer_distance, stats as norm_stats};
use crate::pool::max_pool2d;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::conv::{conv2d, Conv2dParams};
use pbdl_core::io::{load_checkpoint, save_checkpoint, CheckpointMeta};
use pbdl_core::sample::Resize;
use std::path::Path;

/// One conv layer of the base network: `(c_out at width 1, kernel, stride, padding, pool before)`.
const BASE: [(usize, usize, usize, usize, bool); 5] =
    [(32, 12, 4, 2, false), (96, 5, 1, 2, true), (192, 3, 1, 1, true), (128, 3, 1, 1, false), (128, 3, 1, 1, false)];

/// Max-pool (kernel, stride) before layers 2 and 3.
const POOL: (usize, usize) = (4, 2);

/// Architecture and initialisation of a [`MetricNet`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetricNetConfig {
    /// Channel-width multiplier of every layer (1.0: LSiM's 32/96/192/128/128). Default 1.0.
    pub width: f64,
    /// Input channels. Default 1 (scalar fields).
    pub in_channels: usize,
    /// Initial value of every channel weight (LSiM 0.1). Default 0.1.
    pub lin_init: f64,
    /// Seed of the conv initialisation. Default 0.
    pub seed: u64,
    /// Integer factor by which the frames are upsampled (bilinear) before the first conv, so
    /// that the deepest feature maps of small frames are larger than 1 x 1 (the published model
    /// resizes to 224). 1: none. Default 1.
    pub input_scale: usize,
    /// Max-pool before the third conv layer (the published architecture). `false` keeps the
    /// last three feature maps at the size of the second. Default true.
    pub second_pool: bool,
}

impl Default for MetricNetConfig {
    fn default() -> Self {
        Self { width: 1.0, in_channels: 1, lin_init: 0.1, seed: 0, input_scale: 1, second_pool: true }
    }
}

impl MetricNetConfig {
    /// Output channels of each layer.
    pub fn channels(&self) -> Vec<usize> {
        BASE.iter().map(|&(c, ..)| ((c as f64 * self.width).round() as usize).max(2)).collect()
    }
}

/// Calibrated normalisation statistics of one feature layer.
#[derive(Clone, Debug)]
pub struct LayerStats {
    /// Per-pixel mean `[1, 1, h, w]`.
    pub mean: Tensor,
    /// Per-pixel Welford M2 `[1, 1, h, w]`.
    pub m2: Tensor,
    /// Number of frames accumulated.
    pub count: f64,
}

/// The trainable metric network.
///
/// Not `Clone`: a candle `Var` clone shares its storage, so a derived clone would train along
/// with the original. Use [`MetricNet::deep_copy`] for an independent copy.
#[derive(Debug)]
pub struct MetricNet {
    cfg: MetricNetConfig,
    convs: Vec<(Var, Var)>,
    lin: Vec<Var>,
    stats: Option<Vec<LayerStats>>,
}

impl MetricNet {
    /// A network with seeded PyTorch-default initialisation (uniform in `+-1/sqrt(fan_in)` for
    /// weights and biases) and channel weights `lin_init`, `f32`, uncalibrated.
    pub fn new(cfg: MetricNetConfig) -> Result<Self> {
        if !(cfg.width > 0.0 && cfg.width.is_finite())
            || cfg.in_channels == 0
            || cfg.lin_init < 0.0
            || cfg.input_scale == 0
        {
            return Err(Error::invalid(
                "MetricNet::new",
                "cfg",
                format!("need width > 0, in_channels >= 1, lin_init >= 0, input_scale >= 1; got {cfg:?}"),
            ));
        }
        let dev = Device::Cpu;
        let mut c_in = cfg.in_channels;
        let mut convs = Vec::new();
        let mut lin = Vec::new();
        for (l, (&(_, k, ..), c_out)) in BASE.iter().zip(cfg.channels()).enumerate() {
            let bound = 1.0 / ((c_in * k * k) as f64).sqrt();
            let s = cfg.seed.wrapping_mul(31).wrapping_add(2 * l as u64);
            let w = pbdl_core::seed::rand_uniform((c_out, c_in, k, k), -bound, bound, DType::F32, &dev, s)?;
            let b = pbdl_core::seed::rand_uniform(c_out, -bound, bound, DType::F32, &dev, s + 1)?;
            convs.push((Var::from_tensor(&w)?, Var::from_tensor(&b)?));
            lin.push(Var::from_tensor(&(Tensor::ones((1, c_out, 1, 1), DType::F32, &dev)? * cfg.lin_init)?)?);
            c_in = c_out;
        }
        Ok(Self { cfg, convs, lin, stats: None })
    }

    /// The configuration.
    pub fn config(&self) -> &MetricNetConfig {
        &self.cfg
    }

    /// Every trainable variable (conv weights and biases, then the channel weights).
    pub fn vars(&self) -> Vec<Var> {
        self.convs.iter().flat_map(|(w, b)| [w.clone(), b.clone()]).chain(self.lin.iter().cloned()).collect()
    }

    /// The channel weights only (one `[1, C, 1, 1]` variable per feature layer).
    pub fn channel_weights(&self) -> Vec<Var> {
        self.lin.clone()
    }

    /// Number of trainable parameters.
    pub fn parameter_count(&self) -> usize {
        self.vars().iter().map(|v| v.elem_count()).sum()
    }

    /// The calibrated statistics, if [`MetricNet::calibrate`] ran.
    pub fn stats(&self) -> Option<&[LayerStats]> {
        self.stats.as_deref()
    }

    /// Replaces the statistics (a resumed training run restores those of its checkpoint).
    pub(crate) fn set_stats(&mut self, stats: Vec<LayerStats>) -> Result<()> {
        if stats.len() != BASE.len() {
            return Err(Error::invalid(
                "MetricNet::set_stats",
                "stats",
                format!("expected {} layers, got {}", BASE.len(), stats.len()),
            ));
        }
        self.stats = Some(stats);
        Ok(())
    }

    /// Sets the channel weights to `max(w, 0)` (the published model clamps before every forward
    /// pass; here after every optimiser step, which gives the same forward passes).
    pub fn clamp_weights(&self) -> Result<()> {
        for w in &self.lin {
            w.set(&w.as_tensor().relu()?)?;
        }
        Ok(())
    }

    /// The float dtype of the weights (`f32` after [`MetricNet::new`]).
    pub fn dtype(&self) -> DType {
        self.convs[0].0.dtype()
    }

    /// An independent copy: the same weights and statistics in new variables, so that training
    /// or changing one leaves the other as it was.
    pub fn deep_copy(&self) -> Result<Self> {
        self.to_dtype(self.dtype())
    }

    /// The same network (weights and statistics) in another float dtype, as new variables
    /// (`f64` for gradient checks; the same dtype gives [`MetricNet::deep_copy`]).
    pub fn to_dtype(&self, dtype: DType) -> Result<Self> {
        // `detach` first: `Var::from_tensor` of a variable tensor (and `to_dtype` to the same
        // dtype) would reuse its storage instead of copying it.
        let var = |v: &Var| -> Result<Var> { Ok(Var::from_tensor(&v.as_tensor().detach().to_dtype(dtype)?)?) };
        Ok(Self {
            cfg: self.cfg,
            convs: self.convs.iter().map(|(w, b)| Ok((var(w)?, var(b)?))).collect::<Result<_>>()?,
            lin: self.lin.iter().map(var).collect::<Result<_>>()?,
            stats: self.stats.clone(),
        })
    }

    /// The five ReLU feature maps of `x` `[n, in_channels, h, w]` (already mapped to [0, 255]).
    pub fn features(&self, x: &Tensor) -> Result<Vec<Tensor>> {
        let params: Vec<Tensor> = self.vars().iter().map(|v| v.as_tensor().clone()).collect();
        self.features_with(x, &params)
    }

    /// [`MetricNet::features`] with the parameters given as tensors in [`MetricNet::vars`]
    /// order (for gradient checks with respect to the weights).
    pub fn features_with(&self, x: &Tensor, params: &[Tensor]) -> Result<Vec<Tensor>> {
        if x.rank() != 4 || x.dim(1)? != self.cfg.in_channels {
            return Err(Error::Shape {
                op: "MetricNet::features",
                arg: "x",
                expected: format!("[n, {}, h, w]", self.cfg.in_channels),
                got: x.dims().to_vec(),
            });
        }
        self.check_params(params)?;
        let mut h = x.to_dtype(params[0].dtype())?;
        if self.cfg.input_scale > 1 {
            let (y, w) = (h.dim(2)? * self.cfg.input_scale, h.dim(3)? * self.cfg.input_scale);
            h = pbdl_core::sample::resize2d(&h, (y, w), Resize::Bilinear { align_corners: false })?;
        }
        let mut out = Vec::with_capacity(BASE.len());
        for (l, &(_, _, stride, padding, pool)) in BASE.iter().enumerate() {
            if pool && (l < 2 || self.cfg.second_pool) {
                h = max_pool2d(&h, POOL.0, POOL.1)?;
            }
            let p = Conv2dParams::default().stride(stride).padding(padding);
            h = conv2d(&h, &params[2 * l], Some(&params[2 * l + 1]), &p)?.relu()?;
            out.push(h.clone());
        }
        Ok(out)
    }

    fn check_params(&self, params: &[Tensor]) -> Result<()> {
        let vars = self.vars();
        if params.len() != vars.len() || params.iter().zip(&vars).any(|(p, v)| p.dims() != v.dims()) {
            return Err(Error::invalid(
                "MetricNet",
                "params",
                format!("expected {} tensors shaped like MetricNet::vars(), got {}", vars.len(), params.len()),
            ));
        }
        Ok(())
    }

    /// One calibration pass: per-layer, per-pixel mean and M2 of the channel-averaged Welford
    /// update over every frame of `batches` (each `[n, in_channels, h, w]`, mapped to [0, 255]),
    /// one frame at a time, as the official `normDist` accumulation. Replaces earlier statistics.
    pub fn calibrate<'a>(&mut self, batches: impl IntoIterator<Item = &'a Tensor>) -> Result<()> {
        let mut acc: Option<Vec<(Tensor, Tensor)>> = None;
        let mut count = 0.0;
        for x in batches {
            let feats = self.features(x)?;
            let feats: Vec<Tensor> =
                feats.iter().map(|f| f.detach().to_dtype(DType::F64)).collect::<candle_core::Result<_>>()?;
            for n in 0..x.dim(0)? {
                count += 1.0;
                let frame: Vec<Tensor> = feats.iter().map(|f| f.get(n)).collect::<candle_core::Result<_>>()?;
                let a = acc.get_or_insert_with(|| {
                    frame
                        .iter()
                        .map(|f| {
                            let z = Tensor::zeros(&f.dims()[1..], DType::F64, &Device::Cpu).expect("cpu zeros");
                            (z.clone(), z)
                        })
                        .collect()
                });
                for ((mean, m2), f) in a.iter_mut().zip(&frame) {
                    let delta = f.broadcast_sub(mean)?;
                    *mean = (&*mean + (delta.mean(0)? / count)?)?;
                    *m2 = (&*m2 + (delta * f.broadcast_sub(mean)?)?.mean(0)?)?;
                }
            }
        }
        let acc = acc.ok_or_else(|| Error::invalid("MetricNet::calibrate", "batches", "no frames given"))?;
        if count < 2.0 {
            return Err(Error::invalid("MetricNet::calibrate", "batches", "need at least two frames for a variance"));
        }
        self.stats = Some(
            acc.into_iter()
                .map(|(mean, m2)| -> Result<LayerStats> {
                    let (h, w) = mean.dims2()?;
                    Ok(LayerStats {
                        mean: mean.reshape((1, 1, h, w))?.to_dtype(DType::F32)?,
                        m2: m2.reshape((1, 1, h, w))?.to_dtype(DType::F32)?,
                        count,
                    })
                })
                .collect::<Result<_>>()?,
        );
        Ok(())
    }

    /// Distances of the index pairs `(i, j)` between frames whose features are `feats`
    /// (from [`MetricNet::features`]); `[pairs.len()]`, differentiable.
    pub fn pair_distances(&self, feats: &[Tensor], pairs: &[(usize, usize)]) -> Result<Tensor> {
        let lin: Vec<Tensor> = self.lin.iter().map(|v| v.as_tensor().clone()).collect();
        self.pair_distances_with(feats, &lin, pairs)
    }

    /// [`MetricNet::pair_distances`] with the channel weights given as tensors.
    pub fn pair_distances_with(&self, feats: &[Tensor], lin: &[Tensor], pairs: &[(usize, usize)]) -> Result<Tensor> {
        let stats = self.stats.as_ref().ok_or_else(|| {
            Error::invalid(
                "MetricNet::pair_distances",
                "stats",
                "run MetricNet::calibrate (or load a calibrated model) first",
            )
        })?;
        if feats.len() != BASE.len() || lin.len() != BASE.len() {
            return Err(Error::invalid(
                "MetricNet::pair_distances",
                "feats",
                format!(
                    "expected {} feature maps and channel weights, got {} and {}",
                    BASE.len(),
                    feats.len(),
                    lin.len()
                ),
            ));
        }
        let n = feats[0].dim(0)?;
        if pairs.is_empty() || pairs.iter().any(|&(i, j)| i >= n || j >= n) {
            return Err(Error::invalid(
                "MetricNet::pair_distances",
                "pairs",
                format!("need at least one pair, every index below the {n} frames"),
            ));
        }
        let dev = Device::Cpu;
        let ia = Tensor::from_vec(pairs.iter().map(|p| p.0 as u32).collect::<Vec<_>>(), pairs.len(), &dev)?;
        let ib = Tensor::from_vec(pairs.iter().map(|p| p.1 as u32).collect::<Vec<_>>(), pairs.len(), &dev)?;
        let mut total: Option<Tensor> = None;
        for ((f, st), lin) in feats.iter().zip(stats).zip(lin) {
            let dt = f.dtype();
            let (mean, std) = norm_stats(&st.mean.to_dtype(dt)?, &st.m2.to_dtype(dt)?, st.count, &f.dims()[2..])?;
            let layer = layer_distance(&f.index_select(&ia, 0)?, &f.index_select(&ib, 0)?, &mean, &std, lin)?;
            total = Some(match total {
                None => layer,
                Some(t) => (t + layer)?,
            });
        }
        Ok(total.expect("five layers").sqrt()?)
    }

    /// [`MetricNet::pair_distances`] with dropout as in the published training: every element of
    /// each layer's squared normalised difference `(n_l(b) - n_l(a))^2` is zeroed with
    /// probability `p` and the rest scaled by `1 / (1 - p)` before the channel weights (PyTorch's
    /// `Dropout` in front of the 1x1 weighting conv). `p = 0` gives [`MetricNet::pair_distances`].
    pub fn pair_distances_dropout(
        &self,
        feats: &[Tensor],
        pairs: &[(usize, usize)],
        p: f64,
        seed: u64,
    ) -> Result<Tensor> {
        if !(0.0..1.0).contains(&p) {
            return Err(Error::invalid("MetricNet::pair_distances_dropout", "p", format!("need 0 <= p < 1, got {p}")));
        }
        if p == 0.0 {
            return self.pair_distances(feats, pairs);
        }
        // Checks shapes and statistics the same way as the plain path (on the first pair only).
        self.pair_distances(feats, &pairs[..pairs.len().min(1)])?;
        let stats = self.stats.as_ref().expect("checked above");
        let dev = Device::Cpu;
        let ia = Tensor::from_vec(pairs.iter().map(|q| q.0 as u32).collect::<Vec<_>>(), pairs.len(), &dev)?;
        let ib = Tensor::from_vec(pairs.iter().map(|q| q.1 as u32).collect::<Vec<_>>(), pairs.len(), &dev)?;
        let mut total: Option<Tensor> = None;
        for (l, ((f, st), lin)) in feats.iter().zip(stats).zip(&self.lin).enumerate() {
            let dt = f.dtype();
            let (mean, std) = norm_stats(&st.mean.to_dtype(dt)?, &st.m2.to_dtype(dt)?, st.count, &f.dims()[2..])?;
            let den = (std + 1e-10)?;
            let scale = 1.0 / ((f.dim(1)? as f64).sqrt() - 1.0);
            let norm = |x: &Tensor| -> Result<Tensor> { Ok((x.broadcast_sub(&mean)?.broadcast_div(&den)? * scale)?) };
            let diff = (norm(&f.index_select(&ib, 0)?)? - norm(&f.index_select(&ia, 0)?)?)?.sqr()?;
            let keep =
                pbdl_core::seed::rand_uniform(diff.shape(), 0.0, 1.0, DType::F64, &dev, seed.wrapping_add(l as u64))?
                    .ge(p)?
                    .to_dtype(dt)?;
            let diff = (diff * keep)? * (1.0 / (1.0 - p));
            let layer = diff?.broadcast_mul(lin.as_tensor())?.sum(1)?.flatten_from(1)?.mean(1)?;
            total = Some(match total {
                None => layer,
                Some(t) => (t + layer)?,
            });
        }
        Ok(total.expect("five layers").sqrt()?)
    }

    /// Distances of `pairs` within one sequence of frames `[n, in_channels, h, w]` (any range;
    /// mapped jointly to [0, 255] first, see [`to_byte_range`]).
    pub fn sequence_distances(&self, frames: &Tensor, pairs: &[(usize, usize)]) -> Result<Tensor> {
        let feats = self.features(&to_byte_range(frames)?)?;
        self.pair_distances(&feats, pairs)
    }

    /// [`MetricNet::sequence_distances`] with all parameters given as tensors in
    /// [`MetricNet::vars`] order (for gradient checks with respect to the weights).
    pub fn sequence_distances_with(
        &self,
        frames: &Tensor,
        params: &[Tensor],
        pairs: &[(usize, usize)],
    ) -> Result<Tensor> {
        let feats = self.features_with(&to_byte_range(frames)?, params)?;
        self.pair_distances_with(&feats, &params[2 * BASE.len()..], pairs)
    }

    /// Saves weights and statistics as a pbdl checkpoint (`path.safetensors` + `path.json`).
    pub fn save(&self, path: impl AsRef<Path>, step: u64) -> Result<()> {
        let stats =
            self.stats.as_ref().ok_or_else(|| Error::invalid("MetricNet::save", "stats", "calibrate before saving"))?;
        let mut named: Vec<(String, Tensor)> = Vec::new();
        for (l, (w, b)) in self.convs.iter().enumerate() {
            named.push((format!("conv{l}.weight"), w.as_tensor().clone()));
            named.push((format!("conv{l}.bias"), b.as_tensor().clone()));
            named.push((format!("lin{l}.weight"), self.lin[l].as_tensor().clone()));
            named.push((format!("norm.mean.{l}"), stats[l].mean.clone()));
            named.push((format!("norm.m2.{l}"), stats[l].m2.clone()));
            named.push((format!("norm.count.{l}"), Tensor::new(&[stats[l].count], &Device::Cpu)?));
        }
        let config = serde_json::json!({
            "width": self.cfg.width, "in_channels": self.cfg.in_channels,
            "lin_init": self.cfg.lin_init, "seed": self.cfg.seed,
            "input_scale": self.cfg.input_scale, "second_pool": self.cfg.second_pool,
        });
        save_checkpoint(path, named, &CheckpointMeta { step, seed: Some(self.cfg.seed), config })?;
        Ok(())
    }

    /// Loads a checkpoint written by [`MetricNet::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let (t, info) = load_checkpoint(&path, &Device::Cpu)?;
        let c = &info.config;
        let num = |k: &str| c.get(k).and_then(|v| v.as_f64());
        let cfg = MetricNetConfig {
            width: num("width").unwrap_or(1.0),
            in_channels: num("in_channels").unwrap_or(1.0) as usize,
            lin_init: num("lin_init").unwrap_or(0.1),
            seed: num("seed").unwrap_or(0.0) as u64,
            input_scale: num("input_scale").unwrap_or(1.0) as usize,
            second_pool: c.get("second_pool").and_then(|v| v.as_bool()).unwrap_or(true),
        };
        let mut net = Self::new(cfg)?;
        let get = |name: String, like: &Tensor| -> Result<Tensor> {
            let v = t.get(&name).ok_or_else(|| Error::Weights {
                path: path.as_ref().to_path_buf(),
                reason: format!("missing tensor `{name}`"),
            })?;
            if v.dims() != like.dims() && !like.dims().is_empty() {
                return Err(Error::Weights {
                    path: path.as_ref().to_path_buf(),
                    reason: format!("`{name}` has shape {:?}, expected {:?}", v.dims(), like.dims()),
                });
            }
            Ok(v.to_dtype(DType::F32)?)
        };
        let mut stats = Vec::new();
        for l in 0..BASE.len() {
            net.convs[l].0.set(&get(format!("conv{l}.weight"), net.convs[l].0.as_tensor())?)?;
            net.convs[l].1.set(&get(format!("conv{l}.bias"), net.convs[l].1.as_tensor())?)?;
            net.lin[l].set(&get(format!("lin{l}.weight"), net.lin[l].as_tensor())?)?;
            let scalar = Tensor::zeros((), DType::F32, &Device::Cpu)?;
            let mean = get(format!("norm.mean.{l}"), &scalar)?;
            let m2 = get(format!("norm.m2.{l}"), &scalar)?;
            let count =
                get(format!("norm.count.{l}"), &scalar)?.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
            stats.push(LayerStats { mean, m2, count: count.first().copied().unwrap_or(0.0) });
        }
        net.stats = Some(stats);
        Ok(net)
    }
}

/// Maps a tensor jointly (all its elements) to [0, 255] (a constant tensor is only shifted),
/// the input normalisation of the published metric applied to a whole sequence; `f64`. The
/// min/max are constants (not differentiated), as in the published code, which normalises in NumPy.
pub fn to_byte_range(x: &Tensor) -> Result<Tensor> {
    let x64 = x.to_dtype(DType::F64)?;
    let lo = x64.min_all()?.to_scalar::<f64>()?;
    let hi = x64.max_all()?.to_scalar::<f64>()?;
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(Error::invalid("to_byte_range", "x", "input contains NaN or infinity"));
    }
    let scale = if hi > lo { 255.0 / (hi - lo) } else { 1.0 };
    Ok(((x64 - lo)? * scale)?)
}
