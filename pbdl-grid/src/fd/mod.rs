//! Finite differences on the staggered grid: [`divergence`], [`gradient`], [`laplacian`].
//!
//! Each is a custom op with a hand-written adjoint (finite-difference checked in the tests).
//! The slice kernels here are shared with the pressure projection.

mod divergence;
mod gradient;
mod laplacian;

pub use divergence::divergence;
pub use gradient::gradient;
pub use laplacian::laplacian;

use pbdl_core::Real;

/// Batch, channels, ny, nx of a rank-4 shape.
pub(crate) fn dims4(shape: &candle_core::Shape) -> candle_core::Result<(usize, usize, usize, usize)> {
    shape.dims4()
}

/// `out[j, i] = (U[J, I] - U[J, I-1]) / dx + (V[J, I] - V[J-1, I]) / dy` on padded `U`, `V`.
pub(crate) fn div_padded<T: Real>(up: &[T], vp: &[T], nx: usize, ny: usize, idx: T, idy: T, out: &mut [T]) {
    let w = nx + 2;
    for j in 0..ny {
        let r = (j + 1) * w;
        let (u0, v0, vs) = (&up[r..r + w], &vp[r..r + w], &vp[r - w..r]);
        let o = &mut out[j * nx..(j + 1) * nx];
        for i in 0..nx {
            o[i] = (u0[i + 1] - u0[i]) * idx + (v0[i + 1] - vs[i + 1]) * idy;
        }
    }
}

/// Adjoint of [`div_padded`]: accumulates into padded `gu`, `gv` (which must start at zero).
pub(crate) fn div_padded_adjoint<T: Real>(g: &[T], nx: usize, ny: usize, idx: T, idy: T, gu: &mut [T], gv: &mut [T]) {
    let w = nx + 2;
    for j in 0..ny {
        let r = (j + 1) * w;
        for i in 0..nx {
            let a = g[j * nx + i];
            gu[r + i + 1] += a * idx;
            gu[r + i] -= a * idx;
            gv[r + i + 1] += a * idy;
            gv[r - w + i + 1] -= a * idy;
        }
    }
}

/// Face gradient of a padded centred `P`: `u`-faces `(P[J, I+1] - P[J, I]) / dx`, `v`-faces
/// `(P[J+1, I] - P[J, I]) / dy`; fixed boundary faces get 0.
pub(crate) fn grad_padded<T: Real>(
    pp: &[T],
    nx: usize,
    ny: usize,
    idx: T,
    idy: T,
    fixed: (bool, bool),
    gu: &mut [T],
    gv: &mut [T],
) {
    let w = nx + 2;
    for j in 0..ny {
        let r = (j + 1) * w;
        let (p0, pn) = (&pp[r..r + w], &pp[r + w..r + 2 * w]);
        let (ou, ov) = (&mut gu[j * nx..(j + 1) * nx], &mut gv[j * nx..(j + 1) * nx]);
        for i in 0..nx {
            ou[i] = (p0[i + 2] - p0[i + 1]) * idx;
            ov[i] = (pn[i + 1] - p0[i + 1]) * idy;
        }
        if fixed.0 {
            ou[nx - 1] = T::zero();
        }
    }
    if fixed.1 {
        gv[(ny - 1) * nx..].iter_mut().for_each(|x| *x = T::zero());
    }
}

/// Adjoint of [`grad_padded`]: accumulates into padded `gp` (which must start at zero).
pub(crate) fn grad_padded_adjoint<T: Real>(
    gu: &[T],
    gv: &[T],
    nx: usize,
    ny: usize,
    idx: T,
    idy: T,
    fixed: (bool, bool),
    gp: &mut [T],
) {
    let w = nx + 2;
    for j in 0..ny {
        let r = (j + 1) * w;
        for i in 0..nx {
            let a = if fixed.0 && i == nx - 1 { T::zero() } else { gu[j * nx + i] * idx };
            let b = if fixed.1 && j == ny - 1 { T::zero() } else { gv[j * nx + i] * idy };
            gp[r + i + 2] += a;
            gp[r + i + 1] -= a + b;
            gp[r + w + i + 1] += b;
        }
    }
}
