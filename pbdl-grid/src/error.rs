//! The one error type of `pbdl-grid`.
//!
//! Every message names what was wrong and what to change: a bad grid names the field, an unstable
//! time step names the limit and the largest stable step.

/// Errors raised by `pbdl-grid`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A grid or physical parameter is out of range.
    #[error("invalid `{field}`: {reason}")]
    Invalid {
        /// The parameter, e.g. `"grid.nx"` or `"nu"`.
        field: &'static str,
        /// Why, and what to use instead.
        reason: String,
    },
    /// Boundary conditions that cannot work together.
    #[error("boundary `{face}`: {reason}")]
    Boundary {
        /// The face, e.g. `"x_lo"`.
        face: &'static str,
        /// Why, and what to use instead.
        reason: String,
    },
    /// A tensor does not match the grid or the staggering.
    #[error("{op}: `{arg}` has shape {got:?}, expected {expected}")]
    Shape {
        /// The op that rejected it.
        op: &'static str,
        /// The argument.
        arg: &'static str,
        /// What the op expects.
        expected: String,
        /// What it got.
        got: Vec<usize>,
    },
    /// A time step beyond the stability limit of an explicit scheme.
    #[error("{what} {value:.3} exceeds the limit {limit:.3} of {scheme} at dt = {dt:.3e}; use dt <= {stable_dt:.3e}")]
    Unstable {
        /// The number that is too large, e.g. `"advective CFL number"`.
        what: &'static str,
        /// Its value at this `dt`.
        value: f64,
        /// The scheme's limit for it.
        limit: f64,
        /// The scheme, e.g. `"rk4"`.
        scheme: String,
        /// The time step that was asked for.
        dt: f64,
        /// The largest stable time step.
        stable_dt: f64,
    },
    /// A linear solver failed (e.g. the pressure matrix could not be factored).
    #[error("{solver}: {reason}")]
    Solver {
        /// Which solver.
        solver: &'static str,
        /// What failed.
        reason: String,
    },
    /// A value became NaN or infinite.
    #[error("{what} is not finite ({value}); reduce the time step or check the initial state")]
    NonFinite {
        /// What was checked.
        what: &'static str,
        /// The first bad value.
        value: f64,
    },
    /// An error from pbdl-core.
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Result type of `pbdl-grid`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Converts a grid error into a candle error, for use inside custom ops.
impl From<Error> for candle_core::Error {
    fn from(e: Error) -> Self {
        candle_core::Error::wrap(e)
    }
}
