//! The float types that pbdl's kernels are written for.

/// A float type a kernel can run in: `f32` (default) or `f64` (accuracy tests).
///
/// Kernels are written once, generic over `Real`; [`crate::op`] dispatches on the dtype.
pub trait Real:
    candle_core::WithDType + num_traits::Float + Default + std::iter::Sum + std::fmt::Debug + Send + Sync
{
    /// Converts an `f64` constant into this type.
    fn c(v: f64) -> Self {
        <Self as candle_core::WithDType>::from_f64(v)
    }
}

impl Real for f32 {}
impl Real for f64 {}
