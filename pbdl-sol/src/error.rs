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
    /// A run directory holds a run started with other settings than those given to resume it
    /// (or a run of another trainer); nothing was loaded.
    #[error(
        "{}: the run in this directory was started with `{field}` = {stored}, this call has {given}; \
         resume with the run's setting, or start a new run directory",
        dir.display()
    )]
    ResumeMismatch {
        /// The run directory.
        dir: std::path::PathBuf,
        /// The differing setting, as a dotted path into the checkpoint's recorded config
        /// (e.g. `train.lr`, `data.digest`, `trainer`).
        field: String,
        /// Its value in the run directory (JSON).
        stored: String,
        /// Its value in this call (JSON).
        given: String,
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
