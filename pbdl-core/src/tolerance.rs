//! Named tolerances for tests and checks, so that a bar is written once, with its reason.
//!
//! ```
//! use pbdl_core::tolerance::GRAD_CHECK_F64;
//! let report_error = 3e-9; // e.g. `check_grad(..)?.max_rel_error`
//! assert!(report_error <= GRAD_CHECK_F64);
//! ```

/// Finite-difference gradient checks in f64 ([`crate::check_grad`] with its default step
/// `1e-6`): the central difference's truncation error is `O(eps^2) ~ 1e-12` and its round-off
/// `~1e-16 / eps ~ 1e-10` relative, so a correct adjoint lands near `1e-9`; a wrong one at `1e-2`
/// or above.
pub const GRAD_CHECK_F64: f64 = 1e-6;

/// Two f32 evaluations of the same quantity by different kernels (ours against candle's, a fused
/// path against a composed one): `max |a - b| / max |b|`. Accumulating sums of a few thousand
/// terms in different orders gives `~1e-6`.
pub const F32_AGREEMENT: f64 = 1e-5;

/// Two f64 evaluations by different kernels (or against a direct loop): `max |a - b| / max |b|`.
pub const F64_AGREEMENT: f64 = 1e-12;
