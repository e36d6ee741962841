//! LSiM, the learned similarity metric for 2D physical fields (Kohl, Um, Thuerey, ICML 2020),
//! evaluated from its published weights (`LSiM.safetensors`, see [`crate::weights`]).
//!
//! **Pipeline** (as the official `DistanceModel.computeDistance`):
//!
//! 1. Input pairs `a`, `b` of shape `[batch, channel, y, x]` with 1 or 3 channels (`u8`, `f32` or
//!    `f64`; [`hwc_to_nchw`] converts NumPy's `[H, W, C]` / `[B, H, W, C]`); one channel is
//!    repeated to three.
//! 2. [`LsimSize::Resize224`] (default): nearest-neighbour resize to 224x224 in the convention of
//!    `scipy.ndimage.zoom(order=0)` (`src = round(o (n_in - 1) / 223)`; see
//!    [`pbdl_core::sample::Resize::Nearest`], which also lists the few sizes where scipy writes a
//!    zero border row instead). Nearest selection copies values, so resizing `u8` values, as the
//!    official code does, or their float conversion gives the same result.
//!    [`LsimSize::Native`] skips the resize (inputs of at least 44x44); the normalisation maps
//!    are then resized bilinearly with aligned corners to each feature map's size.
//! 3. Per channel, the joint min/max of the pair is mapped to [0, 255]; a channel with
//!    min == max is only shifted by -min. Computed in `f64`, then cast to the model's dtype
//!    (`f32` by default), as the official code casts after normalising in NumPy.
//! 4. The base network (5 conv layers, ReLU outputs as features) runs on both inputs; each
//!    feature map is normalised with the stored per-pixel statistics,
//!    `n = (phi - mu) / (sqrt(M2 / (count - 1)) + 1e-10) / (sqrt(C) - 1)`.
//! 5. `d = sqrt( sum_l mean_(h,w) sum_c w_(l,c) (n_l(b) - n_l(a))^2 )` with the learned weights
//!    clamped to `w >= 0`.
//!
//! **Batches.** The official code maps min/max to [0, 255] jointly over the *whole batch*, so a
//! pair's distance depends on which other pairs share its call. Here each pair is normalised on
//! its own by default ([`NormScope::PerPair`]): a batched call gives the same distances as one call
//! per pair. [`NormScope::JointBatch`] reproduces the official batched behaviour. For a single pair
//! both are the same.
//!
//! **Properties** (tested): `d(a, a) = 0` exactly, `d(a, b) = d(b, a)` exactly, `d >= 0`, and
//! invariance to a common positive scale and offset of both inputs (the min/max mapping removes
//! it). The distance is differentiable in the inputs ([`Lsim::distance_with`]); at `a == b` the
//! square root makes the gradient infinite.
//!
//! One deliberate difference: with mixed constant and non-constant channels on `u8` input, the
//! official code writes the normalised floats back into the `u8` array (truncating them); here
//! every channel is normalised in floating point.
//!
//! ```no_run
//! use pbdl_metrics::{Lsim, LsimOptions};
//! let lsim = Lsim::load("../shared/weights/LSiM.safetensors")?;
//! let a = pbdl_core::io::read_npy("a.npy")?; // [H, W, C]
//! let b = pbdl_core::io::read_npy("b.npy")?;
//! let (a, b) = (pbdl_metrics::lsim::hwc_to_nchw(&a)?, pbdl_metrics::lsim::hwc_to_nchw(&b)?);
//! let d = lsim.distance(&a, &b)?; // one distance per pair
//! # Ok::<(), pbdl_metrics::Error>(())
//! ```

mod network;

pub use crate::learned::NormScope;
use crate::weights::{weights_dir, WeightFile, LSIM_FILE, WEIGHTS_DIR_ENV};
use crate::{check, Error, Result};
use candle_core::{DType, Tensor};
use network::{feature_side, Network, LAYERS};
use pbdl_core::sample::{resize2d, Resize};
use std::path::Path;

/// Input size of the default path.
pub const SIZE_224: usize = 224;

/// The smallest side a [`LsimSize::Native`] input may have (every feature map keeps >= 1 pixel).
pub const MIN_NATIVE_SIDE: usize = 44;

/// How inputs are sized for the network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum LsimSize {
    /// Nearest-neighbour resize to 224x224 (scipy `zoom(order=0)` convention). The official default.
    #[default]
    Resize224,
    /// The input's own size (at least [`MIN_NATIVE_SIDE`]); the normalisation maps are resized.
    Native,
}

/// Options of [`Lsim::distance_with`]; `Default` is the official single-pair behaviour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LsimOptions {
    /// Resize to 224 (default) or keep the native size.
    pub size: LsimSize,
    /// Per-pair (default) or whole-batch normalisation.
    pub norm: NormScope,
}

/// The LSiM metric with its published weights.
#[derive(Clone)]
pub struct Lsim {
    net: Network,
}

impl Lsim {
    /// Loads the weights from a converted `LSiM.safetensors`.
    ///
    /// Errors: [`Error::Io`] for an unreadable file, [`Error::Weights`] naming any missing or
    /// wrongly shaped tensor or bad `normCount` metadata.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(&WeightFile::read(path)?)
    }

    /// Loads `LSiM.safetensors` from [`weights_dir`] (`$PBDL_WEIGHTS_DIR` or `../shared/weights`).
    pub fn load_default() -> Result<Self> {
        let dir = weights_dir().ok_or_else(|| {
            Error::invalid(
                "Lsim::load_default",
                "weights",
                format!("no weight directory: set {WEIGHTS_DIR_ENV} or pass the file's path to Lsim::load"),
            )
        })?;
        Self::load(dir.join(LSIM_FILE))
    }

    /// Builds the model from an opened weight file.
    pub fn from_weights(w: &WeightFile) -> Result<Self> {
        Ok(Self { net: Network::from_file(w)? })
    }

    /// The same model in another float dtype (`f64` for gradient checks).
    pub fn to_dtype(&self, dtype: DType) -> Result<Self> {
        check::float("Lsim::to_dtype", "dtype", &Tensor::zeros(1, dtype, &candle_core::Device::Cpu)?)?;
        Ok(Self { net: self.net.to_dtype(dtype)? })
    }

    /// The dtype the network runs in (`f32` after loading).
    pub fn dtype(&self) -> DType {
        self.net.dtype()
    }

    /// Distances of the pairs `(a[i], b[i])` with the default options (224, per pair).
    ///
    /// `a`, `b`: `[batch, channel, y, x]`, 1 or 3 channels, `u8`/`f32`/`f64`, one shape.
    pub fn distance(&self, a: &Tensor, b: &Tensor) -> Result<Vec<f64>> {
        Ok(self.distance_with(a, b, &LsimOptions::default())?.to_dtype(DType::F64)?.to_vec1::<f64>()?)
    }

    /// Distances of the pairs `(a[i], b[i])`, `[batch]` in the model's dtype, differentiable in
    /// float inputs.
    ///
    /// Errors: ranks other than 4, channel counts other than 1 or 3, different shapes, empty or
    /// non-finite input, unsupported dtypes, a native input smaller than [`MIN_NATIVE_SIDE`].
    pub fn distance_with(&self, a: &Tensor, b: &Tensor, opts: &LsimOptions) -> Result<Tensor> {
        let (pa, pb) = self.preprocess(a, b, opts)?;
        let n = pa.dim(0)?;
        let feats = self.net.features(&Tensor::cat(&[&pa, &pb], 0)?)?;
        let fa: Vec<Tensor> = feats.iter().map(|f| f.narrow(0, 0, n)).collect::<candle_core::Result<_>>()?;
        let fb: Vec<Tensor> = feats.iter().map(|f| f.narrow(0, n, n)).collect::<candle_core::Result<_>>()?;
        self.net.feature_distance(&fa, &fb)
    }

    /// Steps 1-3 of the pipeline: both inputs as `[batch, 3, h, w]` in the model's dtype, resized
    /// (or not) and mapped to [0, 255].
    pub fn preprocess(&self, a: &Tensor, b: &Tensor, opts: &LsimOptions) -> Result<(Tensor, Tensor)> {
        const OP: &str = "lsim";
        for (arg, t) in [("a", a), ("b", b)] {
            if t.rank() != 4 || !matches!(t.dim(1)?, 1 | 3) {
                return Err(Error::Shape {
                    op: OP,
                    arg,
                    expected:
                        "[batch, channel, y, x] with 1 or 3 channels (use lsim::hwc_to_nchw for [H, W, C] arrays)"
                            .into(),
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
        check::finite(OP, "a", a)?;
        check::finite(OP, "b", b)?;
        let (h, w) = (a.dim(2)?, a.dim(3)?);
        let target = match opts.size {
            LsimSize::Resize224 => (SIZE_224, SIZE_224),
            LsimSize::Native => {
                if h < MIN_NATIVE_SIDE || w < MIN_NATIVE_SIDE {
                    return Err(Error::Shape {
                        op: OP,
                        arg: "a",
                        expected: format!(
                            "at least {MIN_NATIVE_SIDE}x{MIN_NATIVE_SIDE} for the native path (use LsimSize::Resize224)"
                        ),
                        got: a.dims().to_vec(),
                    });
                }
                debug_assert!(feature_side(MIN_NATIVE_SIDE, LAYERS.len() - 1).is_some());
                (h, w)
            }
        };
        let prep = |t: &Tensor| -> Result<Tensor> {
            let mut t = t.to_dtype(DType::F64)?;
            if t.dim(1)? == 1 {
                t = t.repeat((1, 3, 1, 1))?;
            }
            if (h, w) != target {
                t = resize2d(&t, target, Resize::Nearest)?;
            }
            Ok(t)
        };
        let (a, b) = (prep(a)?, prep(b)?);
        // Per-channel min/max of each pair: [batch, 3, 1, 1], or over the batch: [1, 3, 1, 1].
        let reduce_min = |t: &Tensor| t.min_keepdim(3)?.min_keepdim(2);
        let reduce_max = |t: &Tensor| t.max_keepdim(3)?.max_keepdim(2);
        let mut lo = reduce_min(&a)?.minimum(&reduce_min(&b)?)?;
        let mut hi = reduce_max(&a)?.maximum(&reduce_max(&b)?)?;
        if opts.norm == NormScope::JointBatch {
            lo = lo.min_keepdim(0)?;
            hi = hi.max_keepdim(0)?;
        }
        let range = (&hi - &lo)?;
        // 1 where a channel is constant (only shifted there), 0 elsewhere.
        let constant = range.eq(0.0)?.to_dtype(DType::F64)?;
        let den = (&range + &constant)?;
        let scale = ((&constant * -254.0)? + 255.0)?;
        let map = |t: &Tensor| -> Result<Tensor> {
            Ok(t.broadcast_sub(&lo)?.broadcast_div(&den)?.broadcast_mul(&scale)?.to_dtype(self.dtype())?)
        };
        Ok((map(&a)?, map(&b)?))
    }

    /// The five ReLU feature maps of a preprocessed batch `[n, 3, h, w]`.
    pub fn features(&self, x: &Tensor) -> Result<Vec<Tensor>> {
        self.net.features(x)
    }

    /// The distance between the feature maps of two preprocessed batches (step 4-5); `[n]`.
    pub fn feature_distance(&self, fa: &[Tensor], fb: &[Tensor]) -> Result<Tensor> {
        if fa.len() != LAYERS.len() || fb.len() != LAYERS.len() {
            return Err(Error::invalid(
                "Lsim::feature_distance",
                "features",
                format!("expected {} feature maps per side, got {} and {}", LAYERS.len(), fa.len(), fb.len()),
            ));
        }
        for (x, y) in fa.iter().zip(fb) {
            if x.dims() != y.dims() {
                return Err(Error::ShapeMismatch {
                    op: "Lsim::feature_distance",
                    a: x.dims().to_vec(),
                    b: y.dims().to_vec(),
                });
            }
        }
        self.net.feature_distance(fa, fb)
    }
}

/// The published LSiM distances of the official repository's plume example
/// (`lsim_example_plume{Reference,A,B}`): `[d(reference, A), d(reference, B)]`.
pub const PUBLISHED_EXAMPLE_DISTANCES: [f64; 2] = [0.3791, 0.4433];

/// Converts NumPy image layouts `[H, W, C]` or `[B, H, W, C]` into `[B, C, H, W]` (contiguous).
///
/// Errors: a rank other than 3 or 4.
pub fn hwc_to_nchw(t: &Tensor) -> Result<Tensor> {
    let t = match t.rank() {
        3 => t.unsqueeze(0)?,
        4 => t.clone(),
        _ => {
            return Err(Error::Shape {
                op: "hwc_to_nchw",
                arg: "t",
                expected: "[H, W, C] or [B, H, W, C]".into(),
                got: t.dims().to_vec(),
            })
        }
    };
    Ok(t.permute((0, 3, 1, 2))?.contiguous()?)
}
