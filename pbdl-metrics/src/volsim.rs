//! VolSiM, the learned similarity metric for 3D fields (Kohl, Chen, Thuerey, AAAI 2023),
//! evaluated from a converted weight file (`VolSiM_MS_3scales.safetensors`, see
//! [`crate::weights`]).
//!
//! **Network** (`multiScaleSkip`): resolution blocks `k = 0 .. S-1`, as many as the weight file
//! has (the shipped 3-scale ablation: 3 blocks, 12 feature layers). Block `k` reads the raw input
//! average-pooled by `2^k`, concatenated (from block 1 on, if the file's channel counts say so)
//! with the last feature map of block `k - 1`; it applies conv 5^3 (stride 1), conv 5^3
//! (stride 2), conv 3^3, conv 3^3, each followed by a ReLU whose output is a feature layer.
//! Features are normalised per voxel with the stored statistics as in LSiM (maps resized
//! trilinearly with aligned corners for other sizes), weighted per channel with the clamped
//! learned weights, averaged over space, summed over the layers; the distance is the square root.
//!
//! **Preprocessing**: one min/max over all values of both volumes (all channels) maps the data to
//! [-1, 1] (a constant input is only shifted by -min, to 0); one channel is repeated to three.
//! [`NormScope::PerPair`] (default) takes the min/max per pair, [`NormScope::JointBatch`] over the
//! whole call, as the official `computeDistance`. Volumes run at their native size by default;
//! every side must then be a multiple of `2^(S-1)` (so pooled inputs and skipped features line
//! up) and at least that. [`Volsim::with_resize`]`(Some(64))` is the official `interpolate=True`
//! option: after the normalisation and the channel repeat, every volume is resized to 64^3 with
//! cubic B-spline interpolation as `scipy.ndimage.zoom(order=3)`
//! ([`pbdl_core::sample::spline_zoom`]; like the official code it may overshoot [-1, 1]).
//!
//! Unlike the official code, 1-channel and constant volumes work (the official preprocessing
//! loops over three channels of a one-channel array and raises an IndexError on constant data).

pub use crate::learned::NormScope;
use crate::learned::{layer_distance, stats};
use crate::weights::{weights_dir, WeightFile, VOLSIM_FILE, WEIGHTS_DIR_ENV};
use crate::{check, Error, Result};
use candle_core::{DType, Tensor};
use pbdl_core::conv::{conv3d, Conv3dParams};
use pbdl_core::sample::spline_zoom;
use std::path::Path;

/// Options of [`Volsim::distance_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct VolsimOptions {
    /// Per-pair (default) or whole-call min/max normalisation.
    pub norm: NormScope,
}

/// One feature layer: a 3D convolution and a ReLU.
#[derive(Clone)]
struct Layer {
    weight: Tensor,
    bias: Tensor,
    stride: usize,
    padding: usize,
}

/// The VolSiM metric with its weights.
#[derive(Clone)]
pub struct Volsim {
    layers: Vec<Layer>,
    /// Whether block `k > 0` also reads the last features of block `k - 1`.
    skip: bool,
    lin: Vec<Tensor>,
    mean: Vec<Tensor>,
    m2: Vec<Tensor>,
    count: Vec<f64>,
    /// Cubic-spline resize of every side to this size before the network (`None`: native size).
    resize: Option<usize>,
}

/// The side length the official VolSiM resizes to with `interpolate=True` (its
/// `dataScaleInference`).
pub const VOLSIM_RESIZE: usize = 64;

impl Volsim {
    /// Loads a converted VolSiM weight file (any number of scales).
    ///
    /// Errors: [`Error::Io`] for an unreadable file; [`Error::Weights`] naming a missing or
    /// wrongly shaped tensor, a layer count that is not a multiple of 4, or bad metadata.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(&WeightFile::read(path)?)
    }

    /// Loads `VolSiM_MS_3scales.safetensors` from [`weights_dir`].
    pub fn load_default() -> Result<Self> {
        let dir = weights_dir().ok_or_else(|| {
            Error::invalid(
                "Volsim::load_default",
                "weights",
                format!("no weight directory: set {WEIGHTS_DIR_ENV} or pass the file's path to Volsim::load"),
            )
        })?;
        Self::load(dir.join(VOLSIM_FILE))
    }

    /// Builds the model from an opened weight file.
    pub fn from_weights(w: &WeightFile) -> Result<Self> {
        let bad = |reason: String| Error::Weights { path: w.path().to_path_buf(), reason };
        let n = (0..).take_while(|i| w.contains(&format!("model.basenet.slice{i}.0.weight"))).count();
        if n == 0 || n % 4 != 0 {
            return Err(bad(format!(
                "found {n} layers `model.basenet.slice<i>.0.weight`; a VolSiM network has 4 per scale"
            )));
        }
        let mut layers = Vec::with_capacity(n);
        let mut lin = Vec::with_capacity(n);
        let mut mean = Vec::with_capacity(n);
        let mut m2 = Vec::with_capacity(n);
        let mut skip = false;
        let mut prev_out = 0;
        for i in 0..n {
            let name = format!("model.basenet.slice{i}.0.weight");
            let any = w.get_any(&name)?;
            let d = any.dims().to_vec();
            let k = if i % 4 < 2 { 5 } else { 3 };
            if d.len() != 5 || d[2..] != [k, k, k] {
                return Err(bad(format!("tensor `{name}` has shape {d:?}, expected [out, in, {k}, {k}, {k}]")));
            }
            let (c_out, c_in) = (d[0], d[1]);
            let expected_in: Vec<usize> = match i {
                0 => vec![3],
                i if i % 4 == 0 => vec![3, 3 + prev_out],
                _ => vec![prev_out],
            };
            if !expected_in.contains(&c_in) {
                return Err(bad(format!("tensor `{name}` has {c_in} input channels, expected one of {expected_in:?}")));
            }
            if i == 4 {
                skip = c_in == 3 + prev_out;
            } else if i % 4 == 0 && i > 0 && skip != (c_in == 3 + prev_out) {
                return Err(bad(format!("tensor `{name}`: blocks disagree on skip connections")));
            }
            let weight = w.get(&name, &d)?;
            let bias = w.get(&format!("model.basenet.slice{i}.0.bias"), &[c_out])?;
            let (stride, padding) = match i % 4 {
                0 => (1, 2),
                1 => (2, 2),
                _ => (1, 1),
            };
            layers.push(Layer { weight, bias, stride, padding });
            lin.push(w.get(&format!("model.avg{i}.1.weight"), &[1, c_out, 1, 1, 1])?.clamp(0f32, f32::INFINITY)?);
            let mu = w.get_any(&format!("norm.mean.{i}"))?;
            if mu.rank() != 3 {
                return Err(bad(format!("tensor `norm.mean.{i}` has shape {:?}, expected [d, h, w]", mu.dims())));
            }
            let sd = mu.dims().to_vec();
            let mm = w.get(&format!("norm.m2.{i}"), &sd)?;
            mean.push(mu.reshape((1, 1, sd[0], sd[1], sd[2]))?);
            m2.push(mm.reshape((1, 1, sd[0], sd[1], sd[2]))?);
            prev_out = c_out;
        }
        let count = w.norm_counts(n)?;
        Ok(Self { layers, skip, lin, mean, m2, count, resize: None })
    }

    /// The same model in another float dtype (`f64` for gradient checks).
    pub fn to_dtype(&self, dtype: DType) -> Result<Self> {
        let cv = |v: &[Tensor]| -> Result<Vec<Tensor>> {
            Ok(v.iter().map(|t| t.to_dtype(dtype)).collect::<candle_core::Result<_>>()?)
        };
        let layers = self
            .layers
            .iter()
            .map(|l| Ok(Layer { weight: l.weight.to_dtype(dtype)?, bias: l.bias.to_dtype(dtype)?, ..l.clone() }))
            .collect::<Result<_>>()?;
        Ok(Self {
            layers,
            skip: self.skip,
            lin: cv(&self.lin)?,
            mean: cv(&self.mean)?,
            m2: cv(&self.m2)?,
            count: self.count.clone(),
            resize: self.resize,
        })
    }

    /// The same model, resizing every input volume to `size`^3 (cubic B-spline, as the official
    /// `interpolate=True` with [`VOLSIM_RESIZE`] = 64) after normalisation, or at native size
    /// with `None` (the default). Errors: a size of 0 or not a multiple of `2^(scales - 1)`.
    pub fn with_resize(mut self, size: Option<usize>) -> Result<Self> {
        let m = 1usize << (self.scales() - 1);
        if let Some(s) = size.filter(|&s| s == 0 || s % m != 0) {
            return Err(Error::invalid(
                "Volsim::with_resize",
                "size",
                format!("{s} is not a positive multiple of {m} (2^(scales - 1)); use 64 as the official code"),
            ));
        }
        self.resize = size;
        Ok(self)
    }

    /// The resize set with [`Volsim::with_resize`].
    pub fn resize(&self) -> Option<usize> {
        self.resize
    }

    /// The dtype the network runs in (`f32` after loading).
    pub fn dtype(&self) -> DType {
        self.layers[0].weight.dtype()
    }

    /// Number of resolution blocks (scales).
    pub fn scales(&self) -> usize {
        self.layers.len() / 4
    }

    /// Number of feature layers (4 per scale).
    pub fn feature_layers(&self) -> usize {
        self.layers.len()
    }

    /// Distances of the pairs `(a[i], b[i])` with the default options.
    ///
    /// `a`, `b`: `[batch, channel, z, y, x]`, 1 or 3 channels, `u8`/`f32`/`f64`, one shape.
    pub fn distance(&self, a: &Tensor, b: &Tensor) -> Result<Vec<f64>> {
        Ok(self.distance_with(a, b, &VolsimOptions::default())?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
    }

    /// Distances `[batch]` in the model's dtype, differentiable in float inputs.
    ///
    /// Errors: ranks other than 5, channel counts other than 1 or 3, different shapes, empty or
    /// non-finite input, unsupported dtypes, sides that are not multiples of `2^(scales - 1)`.
    pub fn distance_with(&self, a: &Tensor, b: &Tensor, opts: &VolsimOptions) -> Result<Tensor> {
        let (pa, pb) = self.preprocess(a, b, opts)?;
        let n = pa.dim(0)?;
        let feats = self.features(&Tensor::cat(&[&pa, &pb], 0)?)?;
        let mut total: Option<Tensor> = None;
        for (l, f) in feats.iter().enumerate() {
            let (fa, fb) = (f.narrow(0, 0, n)?, f.narrow(0, n, n)?);
            let (mean, std) = stats(&self.mean[l], &self.m2[l], self.count[l], &f.dims()[2..])?;
            let d = layer_distance(&fa, &fb, &mean, &std, &self.lin[l])?;
            total = Some(match total {
                None => d,
                Some(t) => (t + d)?,
            });
        }
        Ok(total.expect("at least 4 layers").sqrt()?)
    }

    /// Both inputs as `[batch, 3, z, y, x]` in the model's dtype, mapped to [-1, 1].
    pub fn preprocess(&self, a: &Tensor, b: &Tensor, opts: &VolsimOptions) -> Result<(Tensor, Tensor)> {
        const OP: &str = "volsim";
        for (arg, t) in [("a", a), ("b", b)] {
            if t.rank() != 5 || !matches!(t.dim(1)?, 1 | 3) {
                return Err(Error::Shape {
                    op: OP,
                    arg,
                    expected: "[batch, channel, z, y, x] with 1 or 3 channels".into(),
                    got: t.dims().to_vec(),
                });
            }
            if !matches!(t.dtype(), DType::U8 | DType::U32 | DType::I64 | DType::F32 | DType::F64) {
                return Err(Error::DType { op: OP, arg, expected: "u8, u32, i64, f32 or f64", got: t.dtype() });
            }
            check::non_empty(OP, arg, t)?;
        }
        if a.dims() != b.dims() {
            return Err(Error::ShapeMismatch { op: OP, a: a.dims().to_vec(), b: b.dims().to_vec() });
        }
        let m = 1usize << (self.scales() - 1);
        if self.resize.is_none() && a.dims()[2..].iter().any(|&s| s % m != 0) {
            return Err(Error::Shape {
                op: OP,
                arg: "a",
                expected: format!(
                    "spatial sizes that are multiples of {m} (2^(scales - 1) for {} scales), or resize with \
                     `Volsim::with_resize(Some(64))`",
                    self.scales()
                ),
                got: a.dims().to_vec(),
            });
        }
        check::finite(OP, "a", a)?;
        check::finite(OP, "b", b)?;
        let (a, b) = (a.to_dtype(DType::F64)?, b.to_dtype(DType::F64)?);
        let reduce = |t: &Tensor, max: bool| -> candle_core::Result<Tensor> {
            let f = t.flatten_from(1)?;
            if max {
                f.max_keepdim(1)
            } else {
                f.min_keepdim(1)
            }
        };
        // [batch, 1] per pair, or [1, 1] over the call.
        let mut lo = reduce(&a, false)?.minimum(&reduce(&b, false)?)?;
        let mut hi = reduce(&a, true)?.maximum(&reduce(&b, true)?)?;
        if opts.norm == NormScope::JointBatch {
            lo = lo.min_keepdim(0)?;
            hi = hi.max_keepdim(0)?;
        }
        let range = (&hi - &lo)?;
        let constant = range.eq(0.0)?.to_dtype(DType::F64)?;
        let den = (&range + &constant)?;
        // 2 (x - lo) / range - 1, or x - lo for a constant input.
        let scale = ((&constant * -1.0)? + 2.0)?;
        let shift = ((&constant * -1.0)? + 1.0)?;
        let lo = lo.reshape((lo.dim(0)?, 1, 1, 1, 1))?;
        let (den, scale, shift) = (den.reshape(lo.shape())?, scale.reshape(lo.shape())?, shift.reshape(lo.shape())?);
        let map = |t: &Tensor| -> Result<Tensor> {
            let mut t = t.broadcast_sub(&lo)?.broadcast_div(&den)?.broadcast_mul(&scale)?.broadcast_sub(&shift)?;
            // Resized before the channel repeat: the same result, a third of the work.
            if let Some(s) = self.resize {
                t = spline_zoom(&t, &[s, s, s])?;
            }
            if t.dim(1)? == 1 {
                t = t.repeat((1, 3, 1, 1, 1))?;
            }
            Ok(t.to_dtype(self.dtype())?)
        };
        Ok((map(&a)?, map(&b)?))
    }

    /// The feature maps of a preprocessed batch `[n, 3, z, y, x]`, 4 per scale.
    pub fn features(&self, x: &Tensor) -> Result<Vec<Tensor>> {
        let mut out: Vec<Tensor> = Vec::with_capacity(self.layers.len());
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            if i % 4 == 0 && i > 0 {
                let pooled = avg_pool3d(x, 1 << (i / 4))?;
                h = if self.skip { Tensor::cat(&[&pooled, out.last().expect("previous block")], 1)? } else { pooled };
            }
            let p = Conv3dParams::default().stride(layer.stride).padding(layer.padding);
            h = conv3d(&h, &layer.weight, Some(&layer.bias), &p)?.relu()?;
            out.push(h.clone());
        }
        Ok(out)
    }
}

/// Average pooling with kernel = stride = `f` (floor mode, as PyTorch's `AvgPool3d(f, f)`).
fn avg_pool3d(x: &Tensor, f: usize) -> Result<Tensor> {
    let (n, c, d, h, w) = x.dims5()?;
    let (d2, h2, w2) = (d / f, h / f, w / f);
    let x = x.narrow(2, 0, d2 * f)?.narrow(3, 0, h2 * f)?.narrow(4, 0, w2 * f)?;
    let x = x.contiguous()?.reshape(vec![n * c, d2, f, h2, f, w2, f])?;
    Ok(x.mean(6)?.mean(4)?.mean(2)?.reshape((n, c, d2, h2, w2))?)
}
