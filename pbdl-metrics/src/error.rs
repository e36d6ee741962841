//! The one error type of `pbdl-metrics`.
//!
//! Every message names the metric, the argument and what to change: mismatched shapes name both
//! shapes, a weight file with a missing or wrongly shaped tensor names the tensor and the file.

use candle_core::DType;
use std::path::PathBuf;

/// Errors raised by `pbdl-metrics`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A tensor had the wrong shape (rank, channels, a spatial size too small).
    #[error("{op}: `{arg}` has shape {got:?}, expected {expected}")]
    Shape {
        /// The metric that rejected the input.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// What the metric expects.
        expected: String,
        /// The shape it got.
        got: Vec<usize>,
    },
    /// Two inputs that must have one shape do not.
    #[error("{op}: inputs have different shapes {a:?} and {b:?}; compare fields of one shape (resize one first)")]
    ShapeMismatch {
        /// The metric.
        op: &'static str,
        /// Shape of the first input.
        a: Vec<usize>,
        /// Shape of the second input.
        b: Vec<usize>,
    },
    /// An input has no elements.
    #[error("{op}: `{arg}` is empty (shape {shape:?}); give at least one element per sample")]
    Empty {
        /// The metric.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// Its shape.
        shape: Vec<usize>,
    },
    /// A dtype the metric cannot read.
    #[error("{op}: `{arg}` has dtype {got:?}, expected {expected}")]
    DType {
        /// The metric.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// The dtypes it accepts.
        expected: &'static str,
        /// The dtype it got.
        got: DType,
    },
    /// An input contains NaN or an infinity.
    #[error("{op}: `{arg}` has the non-finite value {value} at flat index {index}; metrics need finite inputs")]
    NonFinite {
        /// The metric.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// Flat index of the first bad value.
        index: usize,
        /// The bad value.
        value: f64,
    },
    /// An argument out of its valid range, or a quantity the metric cannot define for this input.
    #[error("{op}: invalid `{arg}`: {reason}")]
    Invalid {
        /// The metric.
        op: &'static str,
        /// The argument's name.
        arg: &'static str,
        /// Why, and what to use instead.
        reason: String,
    },
    /// A weight file that does not fit the model: missing tensors, wrong shapes, bad metadata.
    #[error("{path}: {reason}")]
    Weights {
        /// The weight file.
        path: PathBuf,
        /// What is wrong, naming the tensor or metadata key.
        reason: String,
    },
    /// A pickle stream (a PyTorch checkpoint) that is malformed or ends early.
    #[error("pickle at byte {offset}: {reason}")]
    Pickle {
        /// Byte offset of the opcode (or field) that failed, from the start of the file.
        offset: usize,
        /// What is wrong.
        reason: String,
    },
    /// A pickle opcode the reader does not implement (it reads what legacy PyTorch checkpoints use).
    #[error(
        "pickle at byte {offset}: unsupported opcode 0x{opcode:02x} ({name}); this reader handles the opcodes of legacy (pre-1.6) PyTorch checkpoints, protocol 2"
    )]
    UnsupportedOpcode {
        /// The opcode byte.
        opcode: u8,
        /// Its name in Python's `pickletools`, or `unknown`.
        name: &'static str,
        /// Byte offset of the opcode from the start of the file.
        offset: usize,
    },
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// An error from pbdl-core (convolution, resize, ...).
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Result type of `pbdl-metrics`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Converts a metrics error into a candle error, e.g. inside closures given to
/// [`pbdl_core::check_grad`].
impl From<Error> for candle_core::Error {
    fn from(e: Error) -> Self {
        candle_core::Error::wrap(e)
    }
}

impl Error {
    /// Shortcut for [`Error::Invalid`].
    pub fn invalid(op: &'static str, arg: &'static str, reason: impl Into<String>) -> Self {
        Error::Invalid { op, arg, reason: reason.into() }
    }
}
