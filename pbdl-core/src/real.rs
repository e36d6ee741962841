//! The float types that pbdl's kernels are written for.

/// A float type a kernel can run in: `f32` (default) or `f64` (accuracy tests).
///
/// Kernels are written once, generic over `Real`; [`crate::op`] dispatches on the dtype.
pub trait Real:
    candle_core::WithDType
    + num_traits::Float
    + Default
    + std::iter::Sum
    + std::fmt::Debug
    + Send
    + Sync
    + crate::vmath::Elementary
{
    /// Converts an `f64` constant into this type.
    fn c(v: f64) -> Self {
        <Self as candle_core::WithDType>::from_f64(v)
    }

    /// This value as `f64` (exact for `f32` and `f64`), e.g. for sums and diagnostics.
    #[inline]
    fn wide(self) -> f64 {
        <Self as candle_core::WithDType>::to_f64(self)
    }

    /// The larger of `self` and `other`, the other one where one is NaN (as `f64::max`).
    /// (`a.max(b)` on a `Real` does not compile: candle's `VecOps` and num-traits' `Float`
    /// both define `max`.)
    #[inline]
    fn fmax(self, other: Self) -> Self {
        if other > self || self.is_nan() {
            other
        } else {
            self
        }
    }

    /// The smaller of `self` and `other`, the other one where one is NaN (as `f64::min`).
    #[inline]
    fn fmin(self, other: Self) -> Self {
        if other < self || self.is_nan() {
            other
        } else {
            self
        }
    }
}

impl Real for f32 {}
impl Real for f64 {}
