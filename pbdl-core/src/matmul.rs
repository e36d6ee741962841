//! One strided matrix product for every hand-written kernel: a bounds-checked wrapper around
//! the `gemm` crate (runtime CPU dispatch: AVX2/AVX-512/NEON, f32 and f64).
//!
//! Convolutions (im2col), fused attention and hand-written MLPs all reduce to
//! `dst = [dst +] scale * a b` on slices with arbitrary row and column strides; this is the only
//! place in pbdl that calls into `gemm` with raw pointers.
//!
//! ```
//! use pbdl_core::matmul::{matmul, Mat, Threads};
//!
//! // [1 2 3; 4 5 6] * [7 8; 9 10; 11 12], the right factor given transposed (column-major).
//! let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
//! let bt = [7.0, 9.0, 11.0, 8.0, 10.0, 12.0];
//! let mut c = [0.0; 4];
//! matmul(&mut c, 2, false, Mat::row_major(&a, 3), Mat::new(&bt, 1, 3), (2, 2, 3), 1.0, Threads::Serial);
//! assert_eq!(c, [58.0, 64.0, 139.0, 154.0]);
//! ```

use crate::Real;
use gemm::Parallelism;

/// A strided matrix view: element `(i, j)` is `data[i * rs + j * cs]`.
#[derive(Clone, Copy, Debug)]
pub struct Mat<'a, T> {
    /// The elements.
    pub data: &'a [T],
    /// Row stride.
    pub rs: usize,
    /// Column stride.
    pub cs: usize,
}

impl<'a, T> Mat<'a, T> {
    /// A view with row stride `rs` and column stride `cs`.
    pub fn new(data: &'a [T], rs: usize, cs: usize) -> Self {
        Self { data, rs, cs }
    }

    /// A row-major view with `cols` columns.
    pub fn row_major(data: &'a [T], cols: usize) -> Self {
        Self { data, rs: cols, cs: 1 }
    }

    /// The transpose of a row-major matrix with `cols` columns, without copying.
    pub fn transposed(data: &'a [T], cols: usize) -> Self {
        Self { data, rs: 1, cs: cols }
    }
}

/// How many threads one product may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Threads {
    /// On the calling thread (callers that already run in parallel over images or heads).
    Serial,
    /// Up to this many rayon threads.
    Rayon(usize),
}

impl From<Threads> for Parallelism {
    fn from(t: Threads) -> Self {
        match t {
            Threads::Serial | Threads::Rayon(0 | 1) => Parallelism::None,
            Threads::Rayon(n) => Parallelism::Rayon(n),
        }
    }
}

/// Index one past the last element of a `rows x cols` matrix with strides `rs`, `cs`.
fn extent(rows: usize, cols: usize, rs: usize, cs: usize) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * rs + (cols - 1) * cs + 1
    }
}

/// `dst (m x n, row stride dst_rs, column stride 1) = [dst +] scale * a (m x k) * b (k x n)`:
/// accumulates into `dst` when `accumulate`, overwrites it otherwise.
///
/// # Panics
/// If a view is too short for its shape and strides, or `n > dst_rs` (a bug in the caller).
pub fn matmul<T: Real>(
    dst: &mut [T],
    dst_rs: usize,
    accumulate: bool,
    a: Mat<'_, T>,
    b: Mat<'_, T>,
    (m, n, k): (usize, usize, usize),
    scale: T,
    threads: Threads,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(m == 1 || n <= dst_rs, "matmul: dst row stride {dst_rs} shorter than a row of {n}");
    assert!(dst.len() >= extent(m, n, dst_rs, 1), "matmul: dst too short");
    if k == 0 {
        if !accumulate {
            (0..m).for_each(|i| dst[i * dst_rs..i * dst_rs + n].fill(T::zero()));
        }
        return;
    }
    assert!(a.data.len() >= extent(m, k, a.rs, a.cs), "matmul: lhs too short");
    assert!(b.data.len() >= extent(k, n, b.rs, b.cs), "matmul: rhs too short");
    // SAFETY: the asserts above keep every accessed element inside the three slices (rows of
    // length n <= dst_rs do not overlap); `dst` is borrowed mutably, so it cannot alias `a` or
    // `b`. `T` is f32 or f64, which gemm supports.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            dst_rs as isize,
            accumulate,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            T::one(),
            scale,
            false,
            false,
            false,
            threads.into(),
        )
    }
}

/// Threads for one product of `m x n x k`: all of the policy's for large ones, none for small
/// ones (below [`crate::threads::parallel`]'s threshold for `m n k / 64` elements).
pub fn threads_for(m: usize, n: usize, k: usize) -> Threads {
    if crate::threads::parallel(m * n * k / 64) {
        Threads::Rayon(crate::threads::count())
    } else {
        Threads::Serial
    }
}

/// How a kernel splits `units` independent blocks of work over rayon's threads: into how many
/// parallel chunks, and with which parallelism inside each matrix product (the threads left
/// over when there are fewer units than threads, e.g. a single image).
pub(crate) fn split(units: usize) -> (usize, Threads) {
    let threads = crate::threads::count();
    let chunks = threads.min(units).max(1);
    let inner = threads / chunks;
    let par = if inner > 1 { Threads::Rayon(inner) } else { Threads::Serial };
    (chunks, par)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strided_product_matches_a_loop() {
        // a: 2x3 row-major, b: 3x2 given column-major (transposed view), dst with padded rows.
        let a = [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0];
        let bt = [7.0f64, 9.0, 11.0, 8.0, 10.0, 12.0];
        let mut dst = [100.0f64, 100.0, -1.0, 100.0, 100.0, -1.0];
        let am = Mat { data: &a, rs: 3, cs: 1 };
        let bm = Mat { data: &bt, rs: 1, cs: 3 };
        matmul(&mut dst, 3, false, am, bm, (2, 2, 3), 1.0, Threads::Serial);
        assert_eq!(dst, [58.0, 64.0, -1.0, 139.0, 154.0, -1.0]);
        matmul(&mut dst, 3, true, am, bm, (2, 2, 3), 1.0, Threads::Serial);
        assert_eq!(dst, [116.0, 128.0, -1.0, 278.0, 308.0, -1.0]);
    }
}
