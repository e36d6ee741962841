//! Typed errors: each says which setting or input is wrong and what to change.

/// What can go wrong configuring, training or evaluating a learned solver component.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration value is out of its valid range.
    #[error("{context}: `{field}` {reason}")]
    InvalidConfig {
        /// Where the value was read (function or scene section).
        context: &'static str,
        /// The setting.
        field: &'static str,
        /// What is wrong and what to use instead.
        reason: String,
    },
    /// Tensors of the wrong shape were passed.
    #[error("{context}: expected shape {expected}, got {got:?}")]
    Shape {
        /// Where.
        context: &'static str,
        /// The expected shape, in words.
        expected: String,
        /// The shape that was passed.
        got: Vec<usize>,
    },
    /// A rollout or training run produced NaN or infinity.
    #[error("{context}: non-finite values at step {step} (lower the learning rate or the time step)")]
    NonFinite {
        /// Where.
        context: &'static str,
        /// The step at which it was first seen.
        step: usize,
    },
    /// An error of pbdl-core (IO, checkpoints, tensor ops).
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// An error of pbdl-grid (scenes, solvers).
    #[error(transparent)]
    Grid(#[from] pbdl_grid::Error),
    /// An error of pbdl-nets (network construction).
    #[error(transparent)]
    Nets(#[from] pbdl_nets::Error),
    /// A tensor operation failed.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

impl Error {
    /// An [`Error::InvalidConfig`].
    pub fn invalid(context: &'static str, field: &'static str, reason: impl Into<String>) -> Self {
        Self::InvalidConfig { context, field, reason: reason.into() }
    }
}

/// `Result` with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
