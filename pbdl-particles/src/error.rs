//! The one error type of `pbdl-particles`.
//!
//! Every message names what was wrong and what to change: a bad parameter names the field, an
//! unstable time step names the limit and the largest stable step.

/// Errors raised by `pbdl-particles`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A parameter (smoothing length, radius, domain, state) is out of range.
    #[error("invalid `{field}`: {reason}")]
    Invalid {
        /// The parameter, e.g. `"radius"` or `"left.rho"`.
        field: &'static str,
        /// Why, and what to use instead.
        reason: String,
    },
    /// A particle lies outside a bounded domain where it must not.
    #[error("particle {index} at {position:?} lies outside the domain {lo:?}..{hi:?}")]
    OutsideDomain {
        /// Index of the first offending particle.
        index: usize,
        /// Its position.
        position: Vec<f64>,
        /// Lower corner of the domain.
        lo: Vec<f64>,
        /// Upper corner of the domain.
        hi: Vec<f64>,
    },
    /// Arrays that must have matching lengths do not.
    #[error("{op}: `{arg}` has length {got}, expected {expected}")]
    Length {
        /// The operation that rejected it.
        op: &'static str,
        /// The argument.
        arg: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// A time step beyond the stability limit of an explicit scheme.
    #[error("dt = {dt:.3e} exceeds the {criterion} limit {limit:.3e}; use dt <= {limit:.3e} (or the adaptive `run`)")]
    UnstableTimeStep {
        /// The time step that was asked for.
        dt: f64,
        /// The largest stable time step under `criterion`.
        limit: f64,
        /// Which criterion is violated: `"CFL (sound speed)"`, `"viscous"`, `"force"`.
        criterion: &'static str,
    },
    /// A value became NaN or infinite.
    #[error("{what} is not finite at particle {index} (step {step}); reduce the time step or check the initial state")]
    NonFinite {
        /// What was checked, e.g. `"density"`.
        what: &'static str,
        /// The first bad particle.
        index: usize,
        /// The step at which it was found.
        step: u64,
    },
    /// An iterative solver (pressure, divergence) missed its tolerance.
    #[error("{solver} did not converge at step {step}: residual {residual:.3e} after {iterations} iterations (tolerance {tolerance:.1e}); reduce the time step (cfl) or raise max_iterations")]
    SolverNotConverged {
        /// Which solver.
        solver: &'static str,
        /// Iterations done.
        iterations: usize,
        /// The final residual (average relative density error).
        residual: f64,
        /// The tolerance that was asked for.
        tolerance: f64,
        /// The step at which it happened.
        step: u64,
    },
    /// A scene has a bad or unknown field.
    #[error("scene `{scene}`: field `{field}`: {reason}")]
    SceneField {
        /// The scene (name or file).
        scene: String,
        /// The field's path, e.g. `dam_break.geometry.dx` or an unknown key.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A scene file could not be parsed.
    #[error("scene: {0}")]
    Scene(String),
    /// An error from pbdl-core (IO, plots).
    #[error(transparent)]
    Core(#[from] pbdl_core::Error),
    /// An error from candle.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

impl Error {
    /// An [`Error::Invalid`] for `field` with `reason`.
    pub fn invalid(field: &'static str, reason: impl Into<String>) -> Self {
        Error::Invalid { field, reason: reason.into() }
    }
}

/// Result type of `pbdl-particles`.
pub type Result<T, E = Error> = std::result::Result<T, E>;
