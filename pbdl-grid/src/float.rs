//! Dispatch from a kernel's float type `T` (`f32` or `f64`, the [`Real`] types) to code written
//! for the concrete type, e.g. an FFT plan per precision (2D and 3D Poisson solvers).

use pbdl_core::Real;
use std::any::TypeId;

/// Runs `f32` or `f64` on `x` and `out` seen as the concrete float type that `T` is.
pub(crate) fn with_concrete<T: Real>(
    x: &[T],
    out: &mut [T],
    f32: impl FnOnce(&[f32], &mut [f32]),
    f64: impl FnOnce(&[f64], &mut [f64]),
) {
    if TypeId::of::<T>() == TypeId::of::<f32>() {
        // SAFETY: T is f32 (checked by TypeId), same size and layout.
        let (r, o) = unsafe { (cast::<T, f32>(x), cast_mut::<T, f32>(out)) };
        f32(r, o);
    } else if TypeId::of::<T>() == TypeId::of::<f64>() {
        // SAFETY: T is f64 (checked by TypeId).
        let (r, o) = unsafe { (cast::<T, f64>(x), cast_mut::<T, f64>(out)) };
        f64(r, o);
    } else {
        unreachable!("Real is implemented for f32 and f64 only");
    }
}

/// Reinterprets a slice of `T` as `U`. Caller guarantees `T == U`.
unsafe fn cast<T: 'static, U: 'static>(x: &[T]) -> &[U] {
    debug_assert_eq!(TypeId::of::<T>(), TypeId::of::<U>());
    // SAFETY: the caller guarantees T and U are the same type.
    unsafe { std::slice::from_raw_parts(x.as_ptr() as *const U, x.len()) }
}

/// Mutable variant of [`cast`].
unsafe fn cast_mut<T: 'static, U: 'static>(x: &mut [T]) -> &mut [U] {
    debug_assert_eq!(TypeId::of::<T>(), TypeId::of::<U>());
    // SAFETY: the caller guarantees T and U are the same type.
    unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr() as *mut U, x.len()) }
}
