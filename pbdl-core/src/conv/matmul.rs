//! A bounds-checked wrapper around the `gemm` crate's strided matrix product.

use crate::Real;
use gemm::Parallelism;

/// A strided matrix view: element `(i, j)` is `data[i * rs + j * cs]`.
#[derive(Clone, Copy)]
pub(crate) struct Mat<'a, T> {
    pub data: &'a [T],
    pub rs: usize,
    pub cs: usize,
}

/// Index one past the last element of a `rows x cols` matrix with strides `rs`, `cs`.
fn extent(rows: usize, cols: usize, rs: usize, cs: usize) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * rs + (cols - 1) * cs + 1
    }
}

/// `dst (m x n, strides dst_rs, 1) = [dst +] a (m x k) * b (k x n)`: accumulates into `dst`
/// when `accumulate`, overwrites it otherwise.
///
/// # Panics
/// If a view is too short for its shape and strides (a bug in the caller).
pub(crate) fn matmul<T: Real>(
    dst: &mut [T],
    dst_rs: usize,
    accumulate: bool,
    a: Mat<'_, T>,
    b: Mat<'_, T>,
    (m, n, k): (usize, usize, usize),
    par: Parallelism,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(dst.len() >= extent(m, n, dst_rs, 1), "matmul: dst too short");
    if k == 0 {
        if !accumulate {
            (0..m).for_each(|i| dst[i * dst_rs..i * dst_rs + n].fill(T::zero()));
        }
        return;
    }
    assert!(a.data.len() >= extent(m, k, a.rs, a.cs), "matmul: lhs too short");
    assert!(b.data.len() >= extent(k, n, b.rs, b.cs), "matmul: rhs too short");
    // SAFETY: the asserts above keep every accessed element inside the three slices; `dst` is
    // borrowed mutably, so it cannot alias `a` or `b`. `T` is f32 or f64, which gemm supports.
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
            T::one(),
            false,
            false,
            false,
            par,
        )
    }
}

/// How a kernel splits `units` independent blocks of work over rayon's threads: into how many
/// parallel chunks, and with which parallelism inside each matrix product (the threads left
/// over when there are fewer units than threads, e.g. a single image).
pub(crate) fn split(units: usize) -> (usize, Parallelism) {
    let threads = rayon::current_num_threads().max(1);
    let chunks = threads.min(units).max(1);
    let inner = threads / chunks;
    let par = if inner > 1 { Parallelism::Rayon(inner) } else { Parallelism::None };
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
        matmul(&mut dst, 3, false, am, bm, (2, 2, 3), Parallelism::None);
        assert_eq!(dst, [58.0, 64.0, -1.0, 139.0, 154.0, -1.0]);
        matmul(&mut dst, 3, true, am, bm, (2, 2, 3), Parallelism::None);
        assert_eq!(dst, [116.0, 128.0, -1.0, 278.0, 308.0, -1.0]);
    }
}
