//! The crate's error type.

/// Errors of pbdl-latent; each message says what to change.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration field is out of range.
    #[error("latent config: `{field}` = {reason}")]
    Config {
        /// The field to change.
        field: &'static str,
        /// Why it is rejected.
        reason: String,
    },
    /// Tensors do not fit together (expected vs given shape).
    #[error("latent shapes: {what}: expected {expected}, got {got:?}")]
    Shape {
        /// What was checked.
        what: &'static str,
        /// The expected layout.
        expected: String,
        /// The given dimensions.
        got: Vec<usize>,
    },
    /// A non-finite value where finite data is required.
    #[error("latent: {what} is not finite ({detail})")]
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
}
