//! Typed errors: each names the file and the variable involved and says what to change.

use std::path::PathBuf;

/// What can go wrong reading, checking or scoring weather fields.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be opened or parsed as NetCDF.
    #[error("{file}: not a readable NetCDF file ({reason})")]
    NetCdf {
        /// The file.
        file: PathBuf,
        /// The reader's message.
        reason: String,
    },
    /// The `.npy` file could not be read as a float array.
    #[error("{file}: not a readable .npy float array ({reason}); write it with numpy.save as float32 or float64")]
    Npy {
        /// The file.
        file: PathBuf,
        /// The reader's message.
        reason: String,
    },
    /// A variable the caller asked for is not in the file.
    #[error("{file}: variable '{var}' not found; the file has {available:?} (pass --var with one of them)")]
    MissingVariable {
        /// The file.
        file: PathBuf,
        /// The missing variable.
        var: String,
        /// The data variables that are there.
        available: Vec<String>,
    },
    /// No variable was named and the file does not have exactly one data variable.
    #[error("{file}: {count} data variables {available:?}; name the one to score with --var")]
    AmbiguousVariable {
        /// The file.
        file: PathBuf,
        /// How many candidates there are.
        count: usize,
        /// The candidates.
        available: Vec<String>,
    },
    /// The variable's dimensions are not in the order WeatherBench writes them.
    #[error("{file}: variable '{var}' has dimensions {found:?}; expected {expected} (nothing is transposed silently: reorder the file, e.g. with xarray's transpose)")]
    DimensionOrder {
        /// The file.
        file: PathBuf,
        /// The variable.
        var: String,
        /// The dimension names found.
        found: Vec<String>,
        /// The accepted order.
        expected: String,
    },
    /// A coordinate is missing, not monotonic or otherwise unusable.
    #[error("{file}: coordinate '{coord}' of variable '{var}': {problem}")]
    Coordinate {
        /// The file.
        file: PathBuf,
        /// The variable.
        var: String,
        /// The coordinate.
        coord: String,
        /// What is wrong and what to change.
        problem: String,
    },
    /// The field holds NaN or infinite values where none are allowed (the truth, or a fill value).
    #[error("{file}: variable '{var}' holds {count} non-finite values (NaN, Inf or _FillValue/missing_value) where the truth must be complete; remove those times or fill them")]
    NonFinite {
        /// The file.
        file: PathBuf,
        /// The variable.
        var: String,
        /// How many values are not finite.
        count: usize,
    },
    /// Two fields do not fit together.
    #[error("forecast and truth do not match: {0}")]
    Mismatch(String),
    /// Building or running a network failed (shape or tensor errors from candle).
    #[error("model: {0}")]
    Model(String),
    /// An argument is out of its domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Reading or writing a file failed.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
