//! Periodic index arithmetic shared by the 3D kernels, and the difference stencils
//! (divergence, gradient) on raw slices.
//!
//! Rows are `(k, j)` pairs, `r = k ny + j`, each `nx` long; neighbours wrap around.

use super::Grid3d;
use pbdl_core::Real;

/// Wrapped neighbour tables of one grid.
#[derive(Clone, Debug)]
pub(crate) struct Periodic {
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    /// `i + 1` and `i - 1`, wrapped.
    ip: Vec<usize>,
    im: Vec<usize>,
}

impl Periodic {
    pub(crate) fn new(g: &Grid3d) -> Self {
        let (nx, ny, nz) = (g.nx, g.ny, g.nz);
        Self {
            nx,
            ny,
            nz,
            ip: (0..nx).map(|i| (i + 1) % nx).collect(),
            im: (0..nx).map(|i| (i + nx - 1) % nx).collect(),
        }
    }

    /// Cells per component.
    pub(crate) fn cells(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// Rows per component.
    pub(crate) fn rows(&self) -> usize {
        self.ny * self.nz
    }

    /// The row `(k + dk, j + dj)` for row `r = (k, j)`, wrapped (`|dk|, |dj| <= 1`).
    #[inline]
    pub(crate) fn row(&self, r: usize, dk: isize, dj: isize) -> usize {
        let (k, j) = (r / self.ny, r % self.ny);
        let k = (k as isize + dk).rem_euclid(self.nz as isize) as usize;
        let j = (j as isize + dj).rem_euclid(self.ny as isize) as usize;
        k * self.ny + j
    }

    /// The column `i + di`, wrapped (`|di| <= 1`).
    #[inline(always)]
    pub(crate) fn col(&self, i: usize, di: isize) -> usize {
        match di {
            0 => i,
            1 => self.ip[i],
            _ => self.im[i],
        }
    }
}

/// Unit offsets `(dk, dj, di)` of the axes x, y, z.
pub(crate) const E: [[isize; 3]; 3] = [[0, 0, 1], [0, 1, 0], [1, 0, 0]];

/// `out = D q`: `(u - u[i-1]) / dx + (v - v[j-1]) / dy + (w - w[k-1]) / dz` at cell centres, for
/// one sample (`q` holds `u, v, w`, `out` one scalar).
pub(crate) fn divergence<T: Real>(p: &Periodic, q: &[T], inv_h: [T; 3], out: &mut [T]) {
    let (n, nx) = (p.cells(), p.nx);
    let (u, v, w) = (&q[..n], &q[n..2 * n], &q[2 * n..3 * n]);
    for (r, o) in out.chunks_mut(nx).enumerate() {
        let (c, s, b) = (r * nx, p.row(r, 0, -1) * nx, p.row(r, -1, 0) * nx);
        for i in 0..nx {
            o[i] = (u[c + i] - u[c + p.col(i, -1)]) * inv_h[0]
                + (v[c + i] - v[s + i]) * inv_h[1]
                + (w[c + i] - w[b + i]) * inv_h[2];
        }
    }
}

/// `out = G s`: forward differences of the cell-centred `s` onto the faces (`out` holds 3 components).
pub(crate) fn gradient<T: Real>(p: &Periodic, s: &[T], inv_h: [T; 3], out: &mut [T]) {
    let (n, nx) = (p.cells(), p.nx);
    let (gu, rest) = out.split_at_mut(n);
    let (gv, gw) = rest.split_at_mut(n);
    for r in 0..p.rows() {
        let (c, nn, t) = (r * nx, p.row(r, 0, 1) * nx, p.row(r, 1, 0) * nx);
        for i in 0..nx {
            let s0 = s[c + i];
            gu[c + i] = (s[c + p.col(i, 1)] - s0) * inv_h[0];
            gv[c + i] = (s[nn + i] - s0) * inv_h[1];
            gw[c + i] = (s[t + i] - s0) * inv_h[2];
        }
    }
}

/// `[1/dx, 1/dy, 1/dz]` in the kernel's float type.
pub(crate) fn inv_spacing<T: Real>(g: &Grid3d) -> [T; 3] {
    g.spacing().map(|h| T::c(1.0 / h))
}
