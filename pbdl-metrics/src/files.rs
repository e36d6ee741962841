//! Distances between two fields stored in files: the library side of `cargo xtask metric`.
//!
//! [`read_field`] reads one array from a `.npy`, a single-array `.npz` or a `.png` (8-bit gray as
//! `[H, W]` u8, colour as `[H, W, 3]` u8, other depths as `f32`); [`Metric`] names a metric and
//! [`compare`] lays the two arrays out as the metric wants them and evaluates it:
//!
//! | metric | array layout | result |
//! |---|---|---|
//! | `lsim` | `[H, W]`, `[H, W, C]` (C = 1 or 3) or a batch `[B, H, W, C]` | one distance per pair |
//! | `volsim` | `[D, H, W]`, `[D, H, W, C]` or a batch `[B, D, H, W, C]` | one distance per pair |
//! | `mse`, `mae`, `rmse`, `rel_l2`, `psnr`, `pearson`, `spearman`, `spectral` | one field of 1 to 3 dimensions | one value |
//! | `ssim` | one field of 2 (SSIM 2D; also `[H, W, C]` images) or 3 (SSIM 3D) dimensions | one value |
//!
//! Classic metrics treat the whole array as one sample, read as `f64`: an image `[H, W, C]` with
//! C = 1, 3 or 4 (a trailing axis that small is taken as channels) is a 2D field with C channels,
//! any other array of 1 to 3 dimensions a single-channel field.
//!
//! ```
//! use pbdl_metrics::files::{compare, read_field, CompareOptions, Metric};
//! # let dir = tempfile::tempdir().unwrap();
//! let a = candle_core::Tensor::arange(0f32, 64.0, &candle_core::Device::Cpu)?.reshape((8, 8))?;
//! pbdl_core::io::write_npy(dir.path().join("a.npy"), &a)?;
//! let a = read_field(dir.path().join("a.npy"))?;
//! let d = compare("mse".parse::<Metric>()?, &a, &a, &CompareOptions::default())?;
//! assert_eq!(d, [0.0]);
//! # Ok::<(), pbdl_metrics::Error>(())
//! ```

use crate::classic::{mae, mse, pearson, psnr, rel_l2, rmse, spearman, spectral_error, ssim2d, ssim3d, SsimConfig};
use crate::lsim::{hwc_to_nchw, LsimOptions, LsimSize};
use crate::volsim::VolsimOptions;
use crate::weights::{weights_dir, LSIM_FILE, VOLSIM_FILE, WEIGHTS_DIR_ENV};
use crate::{Error, Lsim, NormScope, Result, Volsim};
use candle_core::{DType, Tensor};
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// The metrics [`compare`] can evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Metric {
    /// LSiM (2D, learned).
    Lsim,
    /// VolSiM (3D, learned).
    Volsim,
    /// Mean squared error.
    Mse,
    /// Mean absolute error.
    Mae,
    /// Root mean squared error.
    Rmse,
    /// Relative L2 error of the second field against the first.
    RelL2,
    /// PSNR of the second field against the first (data range from the first).
    Psnr,
    /// SSIM 2D or 3D by the array's rank (a similarity: 1 for equal fields).
    Ssim,
    /// Pearson correlation (a similarity).
    Pearson,
    /// Spearman rank correlation (a similarity).
    Spearman,
    /// Log-spectral distance of the radially averaged energy spectra.
    Spectral,
}

impl Metric {
    /// Every metric with its command-line name.
    pub const ALL: [(&'static str, Metric); 11] = [
        ("lsim", Metric::Lsim),
        ("volsim", Metric::Volsim),
        ("mse", Metric::Mse),
        ("mae", Metric::Mae),
        ("rmse", Metric::Rmse),
        ("rel_l2", Metric::RelL2),
        ("psnr", Metric::Psnr),
        ("ssim", Metric::Ssim),
        ("pearson", Metric::Pearson),
        ("spearman", Metric::Spearman),
        ("spectral", Metric::Spectral),
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        Self::ALL.iter().find(|(_, m)| *m == self).map(|(n, _)| *n).unwrap_or("?")
    }
}

impl FromStr for Metric {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        let s = s.to_ascii_lowercase().replace('-', "_");
        Self::ALL.iter().find(|(n, _)| *n == s).map(|(_, m)| *m).ok_or_else(|| {
            let names: Vec<&str> = Self::ALL.iter().map(|(n, _)| *n).collect();
            Error::invalid("metric", "metric", format!("unknown metric `{s}`; available: {}", names.join(", ")))
        })
    }
}

/// Options of [`compare`] that only the learned metrics read.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CompareOptions {
    /// The weight file; default `LSiM.safetensors` / `VolSiM_MS_3scales.safetensors` in
    /// [`weights_dir`].
    pub weights: Option<PathBuf>,
    /// LSiM at the input's own size instead of the 224 resize.
    pub native: bool,
    /// The official whole-batch normalisation instead of per pair (differs only for batches).
    pub joint_batch: bool,
    /// VolSiM: cubic-spline resize of both volumes to 64^3 first (the official option).
    pub resize64: bool,
}

/// Reads one array from `path` by its extension: `.npy`, `.npz` (exactly one array) or `.png`.
///
/// Errors: [`Error::Io`] for a missing file, [`Error::Invalid`] for an unknown extension, an
/// `.npz` with zero or several arrays, or an undecodable PNG; pbdl-core's errors for a malformed
/// `.npy` or unsupported dtype.
pub fn read_field(path: impl AsRef<Path>) -> Result<Tensor> {
    let path = path.as_ref();
    if !path.is_file() {
        return Err(Error::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    match ext.as_str() {
        "npy" => Ok(pbdl_core::io::read_npy(path)?),
        "npz" => {
            let mut arrays = pbdl_core::io::read_npz(path)?;
            if arrays.len() != 1 {
                let names: Vec<&str> = arrays.iter().map(|(n, _)| n.as_str()).collect();
                return Err(Error::invalid(
                    "read_field",
                    "path",
                    format!(
                        "{} holds {} arrays [{}]; give an .npz with exactly one array (or save it as .npy)",
                        path.display(),
                        names.len(),
                        names.join(", ")
                    ),
                ));
            }
            Ok(arrays.remove(0).1)
        }
        #[cfg(feature = "viz")]
        "png" => read_png(path),
        #[cfg(not(feature = "viz"))]
        "png" => Err(Error::invalid(
            "read_field",
            "path",
            format!("{}: reading PNG needs pbdl-metrics' `viz` feature; enable it or convert to .npy", path.display()),
        )),
        _ => Err(Error::invalid(
            "read_field",
            "path",
            format!("{}: unknown file type `.{ext}`; expected .npy, .npz or .png", path.display()),
        )),
    }
}

#[cfg(feature = "viz")]
fn read_png(path: &Path) -> Result<Tensor> {
    use image::DynamicImage as D;
    let img = image::open(path)
        .map_err(|e| Error::invalid("read_field", "path", format!("{}: not a readable PNG: {e}", path.display())))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let dev = candle_core::Device::Cpu;
    let color = img.color().has_color();
    Ok(match (&img, color) {
        (D::ImageLuma8(_) | D::ImageLumaA8(_), _) => Tensor::from_vec(img.to_luma8().into_raw(), (h, w), &dev)?,
        (D::ImageRgb8(_) | D::ImageRgba8(_), _) => Tensor::from_vec(img.to_rgb8().into_raw(), (h, w, 3), &dev)?,
        (_, false) => Tensor::from_vec(img.to_luma32f().into_raw(), (h, w), &dev)?,
        (_, true) => Tensor::from_vec(img.to_rgb32f().into_raw(), (h, w, 3), &dev)?,
    })
}

/// Lays `t` (`spatial` dims, optionally a trailing channel axis, optionally a leading batch axis)
/// out as `[B, C, spatial...]`.
fn learned_layout(op: &'static str, arg: &'static str, t: &Tensor, spatial: usize) -> Result<Tensor> {
    let r = t.rank();
    let bad = || Error::Shape {
        op,
        arg,
        expected: if spatial == 2 {
            "[H, W], [H, W, C] or [B, H, W, C] with C = 1 or 3".into()
        } else {
            "[D, H, W], [D, H, W, C] or [B, D, H, W, C] with C = 1 or 3".into()
        },
        got: t.dims().to_vec(),
    };
    let t = if r == spatial {
        t.unsqueeze(r)?
    } else if r == spatial + 1 || r == spatial + 2 {
        t.clone()
    } else {
        return Err(bad());
    };
    if !matches!(t.dims().last(), Some(1 | 3)) {
        return Err(bad());
    }
    if spatial == 2 {
        return hwc_to_nchw(&t);
    }
    let t = if t.rank() == 4 { t.unsqueeze(0)? } else { t };
    Ok(t.permute((0, 4, 1, 2, 3))?.contiguous()?)
}

fn weights_path(explicit: &Option<PathBuf>, file: &str, metric: &str) -> Result<PathBuf> {
    match explicit {
        Some(p) => Ok(p.clone()),
        None => weights_dir().map(|d| d.join(file)).ok_or_else(|| {
            Error::invalid(
                "metric",
                "weights",
                format!(
                    "no weight directory (../shared/weights does not exist and ${WEIGHTS_DIR_ENV} is unset): \
                     pass --weights PATH to {metric}'s {file}"
                ),
            )
        }),
    }
}

/// Evaluates `metric` on the arrays `a` and `b` as read by [`read_field`] (layouts in the module
/// docs): one value per pair (learned metrics on batches), else one value.
///
/// Errors: [`Error::ShapeMismatch`] for arrays of different shapes, [`Error::Shape`] for a layout
/// the metric cannot read, a missing weight directory ([`Error::Invalid`] naming `--weights`), and
/// the metric's own errors (NaN/Inf, empty arrays, weight files that do not fit).
pub fn compare(metric: Metric, a: &Tensor, b: &Tensor, opts: &CompareOptions) -> Result<Vec<f64>> {
    if a.dims() != b.dims() {
        return Err(Error::ShapeMismatch { op: metric.name(), a: a.dims().to_vec(), b: b.dims().to_vec() });
    }
    let norm = if opts.joint_batch { NormScope::JointBatch } else { NormScope::PerPair };
    match metric {
        Metric::Lsim => {
            if opts.resize64 {
                return Err(Error::invalid(
                    "lsim",
                    "resize64",
                    "--resize64 is for volsim; LSiM resizes to 224 unless --native",
                ));
            }
            let (a, b) = (learned_layout("lsim", "a", a, 2)?, learned_layout("lsim", "b", b, 2)?);
            let model = Lsim::load(weights_path(&opts.weights, LSIM_FILE, "LSiM")?)?;
            let size = if opts.native { LsimSize::Native } else { LsimSize::Resize224 };
            let d = model.distance_with(&a, &b, &LsimOptions { size, norm })?;
            Ok(d.to_dtype(DType::F64)?.to_vec1()?)
        }
        Metric::Volsim => {
            if opts.native {
                return Err(Error::invalid(
                    "volsim",
                    "native",
                    "--native is for lsim; VolSiM always runs at native size",
                ));
            }
            let (a, b) = (learned_layout("volsim", "a", a, 3)?, learned_layout("volsim", "b", b, 3)?);
            let model = Volsim::load(weights_path(&opts.weights, VOLSIM_FILE, "VolSiM")?)?
                .with_resize(opts.resize64.then_some(crate::volsim::VOLSIM_RESIZE))?;
            let d = model.distance_with(&a, &b, &VolsimOptions { norm })?;
            Ok(d.to_dtype(DType::F64)?.to_vec1()?)
        }
        _ => {
            if opts.native || opts.joint_batch || opts.resize64 || opts.weights.is_some() {
                return Err(Error::invalid(
                    metric.name(),
                    "options",
                    "--native, --joint-batch, --resize64 and --weights are for lsim/volsim",
                ));
            }
            let op = metric.name();
            let rank_ok =
                if metric == Metric::Ssim { (2..=3).contains(&a.rank()) } else { (1..=3).contains(&a.rank()) };
            if !rank_ok {
                let expected = if metric == Metric::Ssim {
                    "a field of 2 or 3 dimensions"
                } else {
                    "a field of 1 to 3 dimensions"
                };
                return Err(Error::Shape { op, arg: "a", expected: expected.into(), got: a.dims().to_vec() });
            }
            // An image [H, W, C] (C = 1, 3, 4) is one 2D field with C channels; else one channel.
            let image = a.rank() == 3 && matches!(a.dims()[2], 1 | 3 | 4);
            let field = |t: &Tensor| -> Result<Tensor> {
                let t = t.to_dtype(DType::F64)?;
                Ok(if image {
                    t.permute((2, 0, 1))?.contiguous()?.unsqueeze(0)?
                } else {
                    t.unsqueeze(0)?.unsqueeze(0)?
                })
            };
            let (a, b) = (field(a)?, field(b)?);
            let t = match metric {
                Metric::Mse => mse(&a, &b)?,
                Metric::Mae => mae(&a, &b)?,
                Metric::Rmse => rmse(&a, &b)?,
                Metric::RelL2 => rel_l2(&b, &a)?,
                Metric::Psnr => psnr(&b, &a, None)?,
                Metric::Pearson => pearson(&a, &b)?,
                Metric::Ssim if a.rank() == 4 => ssim2d(&a, &b, &SsimConfig::default())?,
                Metric::Ssim => ssim3d(&a, &b, &SsimConfig::default())?,
                Metric::Spearman => return spearman(&a, &b),
                _ => return spectral_error(&a, &b),
            };
            Ok(t.to_vec1()?)
        }
    }
}
