//! The one error type of `pbdl-core`, and the checks that produce it.
//!
//! Every message says what to change, not only what went wrong: a shape error names the op,
//! the argument, the shape it expected and the shape it got.

use candle_core::{DType, Tensor};
use std::path::PathBuf;

/// Errors raised by `pbdl-core`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A tensor had the wrong shape for an op.
    #[error("{op}: `{arg}` has shape {got:?}, expected {expected}")]
    Shape {
        /// The op that rejected the input.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// A description of the shape the op expects.
        expected: String,
        /// The shape it got.
        got: Vec<usize>,
    },
    /// A tensor had a dtype the op does not support.
    #[error("{op}: `{arg}` has dtype {got:?}, expected {expected} (convert with `.to_dtype(..)`)")]
    DType {
        /// The op that rejected the input.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// The dtypes the op supports.
        expected: &'static str,
        /// The dtype it got.
        got: DType,
    },
    /// A value was NaN or infinite where a finite value is required.
    #[error("{what}: non-finite value {value} at flat index {index} (of {len}); check the inputs, the time step or the learning rate")]
    NonFinite {
        /// What was checked.
        what: String,
        /// Flat index of the first bad value.
        index: usize,
        /// The bad value.
        value: f64,
        /// Number of elements checked.
        len: usize,
    },
    /// An argument was out of its valid range.
    #[error("{op}: invalid `{arg}`: {reason}")]
    InvalidArgument {
        /// The op or function that rejected it.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// Why, and what to use instead.
        reason: String,
    },
    /// A trainable variable or an op input received no gradient.
    #[error("no gradient reached {names:?}: an op on its path has no backward, or it is not used by the loss")]
    MissingGradient {
        /// Names of the variables without a gradient.
        names: Vec<String>,
    },
    /// A finite-difference gradient check failed.
    #[error("gradient check failed: max relative error {max_rel_error:.3e} > tolerance {tolerance:.1e} (input {input}, flat index {index}: analytic {analytic:.6e}, finite difference {numeric:.6e})")]
    GradCheck {
        /// The worst relative error.
        max_rel_error: f64,
        /// The tolerance it was checked against.
        tolerance: f64,
        /// Which input had the worst error.
        input: usize,
        /// Flat index of the worst element.
        index: usize,
        /// The analytic gradient there.
        analytic: f64,
        /// The finite-difference gradient there.
        numeric: f64,
    },
    /// Training produced a non-finite loss or gradient and was stopped.
    #[error("training diverged at step {step}: {quantity} is {value}; the last good checkpoint is kept{hint}")]
    Diverged {
        /// The step at which it happened.
        step: u64,
        /// Which quantity (loss, gradient norm, ...).
        quantity: String,
        /// Its value.
        value: f64,
        /// Extra advice, e.g. where the checkpoint is.
        hint: String,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its content is not what was expected.
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A file lacks tensors that the caller needs (e.g. a checkpoint loaded into a model).
    #[error("{path}: missing tensors {missing:?} (the file has {available:?})")]
    MissingTensors {
        /// The file.
        path: PathBuf,
        /// The names asked for but not in the file.
        missing: Vec<String>,
        /// The names the file does have.
        available: Vec<String>,
    },
    /// A stored tensor's shape differs from the shape the caller expects.
    #[error("{path}: tensor `{name}` has shape {stored:?} in the file but {expected:?} in the model")]
    TensorShape {
        /// The file.
        path: PathBuf,
        /// The tensor's name.
        name: String,
        /// Its shape in the file.
        stored: Vec<usize>,
        /// The shape the caller expects.
        expected: Vec<usize>,
    },
    /// A run directory holds a run started with other settings than those given to resume it
    /// (see [`crate::train::check_resume`]); nothing was loaded.
    #[error(
        "{}: the run in this directory was started with `{field}` = {stored}, this call has {given}; \
         use a new run directory, or resume with the same settings as the run",
        dir.display()
    )]
    ResumeMismatch {
        /// The run directory (boxed so that the variant stays smaller than
        /// [`Error::TensorShape`] and `Error` keeps its size; `.into()` gives a `PathBuf`).
        dir: Box<std::path::Path>,
        /// The first differing setting, as a dotted path into the checkpoint's recorded config
        /// (e.g. `train.lr`, `data.re[1]`, `trainer`).
        field: String,
        /// Its value in the run directory (JSON).
        stored: String,
        /// Its value in this call (JSON).
        given: String,
    },
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Result type of `pbdl-core`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Shortcut for [`Error::InvalidArgument`].
    pub fn invalid(op: &'static str, arg: &'static str, reason: impl Into<String>) -> Self {
        Error::InvalidArgument { op, arg, reason: reason.into() }
    }

    /// Wraps an IO error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
}

/// Converts a pbdl error into a candle error, for use inside candle custom ops.
impl From<Error> for candle_core::Error {
    fn from(e: Error) -> Self {
        candle_core::Error::wrap(e)
    }
}

/// Checks that `t` has exactly the shape `expected`.
pub fn check_shape(op: &'static str, arg: &'static str, t: &Tensor, expected: &[usize]) -> Result<()> {
    if t.dims() != expected {
        return Err(Error::Shape { op, arg, expected: format!("{expected:?}"), got: t.dims().to_vec() });
    }
    Ok(())
}

/// Checks that `t` has rank `rank`; `layout` describes the axes, e.g. `"[batch, channel, y, x]"`.
pub fn check_rank(op: &'static str, arg: &'static str, t: &Tensor, rank: usize, layout: &str) -> Result<()> {
    if t.rank() != rank {
        return Err(Error::Shape { op, arg, expected: format!("rank {rank} {layout}"), got: t.dims().to_vec() });
    }
    Ok(())
}

/// Checks that `t` is `f32` or `f64`, the dtypes that pbdl's kernels support.
pub fn check_float(op: &'static str, arg: &'static str, t: &Tensor) -> Result<()> {
    match t.dtype() {
        DType::F32 | DType::F64 => Ok(()),
        got => Err(Error::DType { op, arg, expected: "f32 or f64", got }),
    }
}

/// Checks that every value of `t` is finite; reports the first bad one.
pub fn check_finite(what: &str, t: &Tensor) -> Result<()> {
    let flat = t.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
    if let Some((index, &value)) = flat.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Error::NonFinite { what: what.to_string(), index, value, len: flat.len() });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn shape_error_names_op_argument_and_shapes() {
        let t = Tensor::zeros((2, 3), DType::F32, &Device::Cpu).unwrap();
        let err = check_shape("conv2d", "weight", &t, &[2, 4]).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("conv2d") && msg.contains("weight") && msg.contains("[2, 3]") && msg.contains("[2, 4]"),
            "{msg}"
        );
    }

    #[test]
    fn finiteness_check_reports_first_nan() {
        let t = Tensor::new(&[1.0f32, 2.0, f32::NAN, f32::INFINITY], &Device::Cpu).unwrap();
        match check_finite("density", &t) {
            Err(Error::NonFinite { index, len, .. }) => {
                assert_eq!(index, 2);
                assert_eq!(len, 4);
            }
            other => panic!("expected NonFinite, got {other:?}"),
        }
        let ok = Tensor::new(&[1.0f64, -3.0], &Device::Cpu).unwrap();
        check_finite("ok", &ok).unwrap();
    }

    #[test]
    fn dtype_check_rejects_integers() {
        let t = Tensor::new(&[1u32, 2], &Device::Cpu).unwrap();
        assert!(matches!(check_float("op", "x", &t), Err(Error::DType { got: DType::U32, .. })));
    }
}
