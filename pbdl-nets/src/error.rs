//! The crate's error type: bad input is a typed error that says what to change.

/// Errors of `pbdl-nets`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A setting outside its valid range.
    #[error("{name} = {value} is invalid: {hint}")]
    InvalidConfig {
        /// Name of the setting.
        name: &'static str,
        /// The value given.
        value: String,
        /// What to use instead.
        hint: &'static str,
    },
    /// A tensor whose shape does not fit the network (channels, size, batch).
    #[error("{what}: expected {expected}, got {got}")]
    ShapeMismatch {
        /// What was checked.
        what: String,
        /// The shape that fits.
        expected: String,
        /// The shape given.
        got: String,
    },
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    /// An error from pbdl-core.
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
}

/// Result type of `pbdl-nets`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A [`Error::ShapeMismatch`] from displayable shapes.
    pub fn shape(what: impl Into<String>, expected: impl std::fmt::Debug, got: impl std::fmt::Debug) -> Self {
        Error::ShapeMismatch { what: what.into(), expected: format!("{expected:?}"), got: format!("{got:?}") }
    }
}
