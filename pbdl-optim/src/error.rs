//! The crate's error type: bad input is a typed error that says what to change.

/// Errors of `pbdl-optim`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A Jacobian, gradient or state holds NaN or an infinity.
    #[error(
        "{what} has a non-finite entry {value} at row {row}, column {col}; the network or the physics overflowed: \
         lower the learning rate (eta), raise the truncation tau, or check the inputs"
    )]
    NonFinite {
        /// Which array (e.g. `"Jacobian"`, `"loss gradient"`).
        what: &'static str,
        /// Row of the entry.
        row: usize,
        /// Column of the entry (0 for vectors).
        col: usize,
        /// The value found.
        value: f64,
    },
    /// The relative truncation threshold is not a finite positive number.
    #[error("truncation tau = {tau} must be finite and > 0 (relative to the largest singular value; typical 1e-6)")]
    InvalidTau {
        /// The value given.
        tau: f64,
    },
    /// Arrays whose sizes do not fit together.
    #[error("{what}: expected {expected}, got {got}")]
    ShapeMismatch {
        /// What was checked, e.g. `"loss gradient length"`.
        what: String,
        /// The size that fits.
        expected: String,
        /// The size given.
        got: String,
    },
    /// A setting outside its valid range.
    #[error("{name} = {value} is invalid: {hint}")]
    InvalidConfig {
        /// Name of the setting.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What to use instead.
        hint: &'static str,
    },
    /// faer's SVD did not converge.
    #[error("the SVD of the {rows}x{cols} Jacobian did not converge; check it for huge or tiny entries")]
    SvdNoConvergence {
        /// Rows of the Jacobian.
        rows: usize,
        /// Columns of the Jacobian.
        cols: usize,
    },
    /// A loss became NaN or infinite during training.
    #[error("training diverged at step {step}: loss = {loss}; the parameters of step {last_good} are kept (lower eta or raise tau)")]
    Diverged {
        /// The step whose loss was not finite.
        step: u64,
        /// The loss value.
        loss: f64,
        /// The last step whose loss was finite; the model still holds its parameters.
        last_good: u64,
    },
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    /// An error from pbdl-core.
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
}

/// Result type of `pbdl-optim`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A [`Error::ShapeMismatch`] from displayable sizes.
    pub fn shape(what: impl Into<String>, expected: impl std::fmt::Display, got: impl std::fmt::Display) -> Self {
        Error::ShapeMismatch { what: what.into(), expected: expected.to_string(), got: got.to_string() }
    }
}

/// Checks that `len` equals `expected`.
pub(crate) fn check_len(what: &str, expected: usize, len: usize) -> Result<()> {
    if expected != len {
        return Err(Error::shape(what, expected, len));
    }
    Ok(())
}

/// Checks that every entry of a row-major `rows x cols` array is finite.
pub(crate) fn check_finite(what: &'static str, data: &[f64], cols: usize) -> Result<()> {
    match data.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => {
            let cols = cols.max(1);
            Err(Error::NonFinite { what, row: i / cols, col: i % cols, value: data[i] })
        }
    }
}
