//! The crate's error type.

/// Errors of pbdl-pconv; each message says what to change.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration field is out of range.
    #[error("pconv config: `{field}` = {reason}")]
    Config {
        /// The field to change.
        field: &'static str,
        /// Why it is rejected.
        reason: String,
    },
    /// Tensors or particle arrays do not fit together.
    #[error("pconv shapes: {0}")]
    Shape(String),
    /// A non-finite value where finite data is required.
    #[error("pconv: {what} is not finite ({detail})")]
    NonFinite {
        /// What was checked.
        what: &'static str,
        /// Where.
        detail: String,
    },
    /// From pbdl-core (IO, checkpoints, training loop, and
    /// [`pbdl_core::Error::ResumeMismatch`]: a run directory started with other settings,
    /// naming the first differing one).
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// From pbdl-particles (neighbour search, SPH data).
    #[error(transparent)]
    Particles(#[from] pbdl_particles::Error),
    /// From candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    /// File IO.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
}

/// Result with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
