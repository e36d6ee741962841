//! The crate's error type.

/// Errors of pbdl-temporal; each message says what to change.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration field is out of range.
    #[error("temporal config: `{field}` = {reason}")]
    Config {
        /// The field to change.
        field: &'static str,
        /// Why it is rejected.
        reason: String,
    },
    /// An input array is missing, has the wrong shape or holds non-finite values.
    #[error("temporal input: array `{array}`: {reason}")]
    Input {
        /// The array (e.g. `density`, `velocity`).
        array: String,
        /// What is wrong and what to change.
        reason: String,
    },
    /// A training run diverged or produced non-finite values.
    #[error("temporal: {what} is not finite ({detail})")]
    NonFinite {
        /// What was checked.
        what: &'static str,
        /// Where.
        detail: String,
    },
    /// From pbdl-core (IO, checkpoints, training loop).
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// From pbdl-grid (the solver).
    #[error(transparent)]
    Grid(#[from] pbdl_grid::Error),
    /// From pbdl-nets (network layers).
    #[error(transparent)]
    Nets(#[from] pbdl_nets::Error),
    /// From pbdl-metrics (scores).
    #[error(transparent)]
    Metrics(#[from] pbdl_metrics::Error),
    /// From candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Result with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A [`Error::Config`].
    pub(crate) fn config(field: &'static str, reason: impl Into<String>) -> Self {
        Self::Config { field, reason: reason.into() }
    }

    /// An [`Error::Input`] for `array`.
    pub(crate) fn input(array: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Input { array: array.into(), reason: reason.into() }
    }
}
