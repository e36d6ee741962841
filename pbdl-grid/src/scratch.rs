//! Reusable scratch buffers: a per-thread pool, so that kernels called every time step do not
//! allocate (large fresh allocations cost page faults that dominated a step at 128^2 and up).

use std::cell::RefCell;
use std::ops::{Deref, DerefMut};

/// Plain-data element types whose every bit pattern is valid, with alignment <= 8.
///
/// # Safety
/// Implementors must be `Copy`, have no padding and no invalid bit patterns, and align <= 8.
pub(crate) unsafe trait Pod: Copy + 'static {}
// SAFETY: floats and pairs of floats accept every bit pattern and have align <= 8.
unsafe impl Pod for f32 {}
// SAFETY: as above.
unsafe impl Pod for f64 {}
// SAFETY: `Complex<T>` is `repr(C)` of two floats.
unsafe impl Pod for realfft::num_complex::Complex<f32> {}
// SAFETY: as above.
unsafe impl Pod for realfft::num_complex::Complex<f64> {}

thread_local! {
    static POOL: RefCell<Vec<Vec<u64>>> = const { RefCell::new(Vec::new()) };
}

/// A buffer of `len` elements taken from the pool; its contents are arbitrary (callers write
/// before reading). It goes back to the pool on drop.
pub(crate) struct Buf<E: Copy + 'static> {
    store: Vec<u64>,
    len: usize,
    _e: std::marker::PhantomData<E>,
}

/// Takes a buffer of `len` elements of `E` from this thread's pool.
pub(crate) fn take<E: Pod>(len: usize) -> Buf<E> {
    take_unchecked(len)
}

/// [`take`] for a kernel's float type (`f32` or `f64`, checked at run time), filled with zeros.
pub(crate) fn zeros<T: pbdl_core::Real>(len: usize) -> Buf<T> {
    use std::any::TypeId;
    let t = TypeId::of::<T>();
    assert!(t == TypeId::of::<f32>() || t == TypeId::of::<f64>(), "scratch: f32 or f64 only");
    let mut b = take_unchecked::<T>(len);
    b.fill(T::zero());
    b
}

/// [`take`] for a kernel's float type (`f32` or `f64`, checked at run time), contents arbitrary:
/// for buffers the caller overwrites completely before reading (saves the fill of [`zeros`]).
pub(crate) fn uninit<T: pbdl_core::Real>(len: usize) -> Buf<T> {
    use std::any::TypeId;
    let t = TypeId::of::<T>();
    assert!(t == TypeId::of::<f32>() || t == TypeId::of::<f64>(), "scratch: f32 or f64 only");
    take_unchecked::<T>(len)
}

/// The pool itself; `E` must be plain data (see [`Pod`]).
fn take_unchecked<E: Copy + 'static>(len: usize) -> Buf<E> {
    assert!(std::mem::align_of::<E>() <= 8);
    let words = (len * std::mem::size_of::<E>()).div_ceil(8);
    let mut store = POOL.with(|p| {
        let mut p = p.borrow_mut();
        // Best fit: the smallest pooled buffer that is large enough, else the largest to grow.
        let pick = p
            .iter()
            .enumerate()
            .filter(|(_, v)| v.capacity() >= words)
            .min_by_key(|(_, v)| v.capacity())
            .map(|(i, _)| i);
        match pick.or_else(|| p.iter().enumerate().max_by_key(|(_, v)| v.capacity()).map(|(i, _)| i)) {
            Some(i) => p.swap_remove(i),
            None => Vec::new(),
        }
    });
    if store.len() < words {
        store.resize(words, 0);
    }
    Buf { store, len, _e: std::marker::PhantomData }
}

impl<E: Copy + 'static> Deref for Buf<E> {
    type Target = [E];
    fn deref(&self) -> &[E] {
        // SAFETY: the store holds at least len * size_of::<E>() bytes, aligned to 8 >= align_of::<E>(),
        // and E accepts every bit pattern (Pod).
        unsafe { std::slice::from_raw_parts(self.store.as_ptr() as *const E, self.len) }
    }
}

impl<E: Copy + 'static> DerefMut for Buf<E> {
    fn deref_mut(&mut self) -> &mut [E] {
        // SAFETY: as in `deref`, and we hold the store exclusively.
        unsafe { std::slice::from_raw_parts_mut(self.store.as_mut_ptr() as *mut E, self.len) }
    }
}

impl<E: Copy + 'static> Drop for Buf<E> {
    fn drop(&mut self) {
        let store = std::mem::take(&mut self.store);
        // Keep a handful per thread; more would only hold memory.
        let _ = POOL.try_with(|p| {
            if let Ok(mut p) = p.try_borrow_mut() {
                if p.len() < 16 {
                    p.push(store);
                }
            }
        });
    }
}
