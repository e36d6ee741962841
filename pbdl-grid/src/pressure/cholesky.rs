//! Poisson solve by a sparse Cholesky factor (faer), factored once per grid and boundaries.
//!
//! The matrix is `-L` assembled from the pressure ghost rules (so it is exactly the `D M G` of
//! the projection). Without a Dirichlet face `L` is singular; cell 0 is then pinned and the
//! pseudo-inverse solution recovered by removing means.

use crate::boundary::Ghosts;
use crate::{Error, Grid, Result};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::Llt;
use faer::sparse::{SparseColMat, Triplet};
use faer::{MatMut, Side};

/// A factored Poisson matrix.
pub(crate) struct CholeskyPoisson {
    n: usize,
    pinned: bool,
    llt: Llt<usize, f64>,
}

impl CholeskyPoisson {
    pub(crate) fn new(grid: &Grid, ghosts: &Ghosts, singular: bool) -> Result<Self> {
        let (nx, ny) = (grid.nx, grid.ny);
        let n = nx * ny;
        let (ax, ay) = (1.0 / (grid.dx() * grid.dx()), 1.0 / (grid.dy() * grid.dy()));
        // Row-wise accumulation of -L: each row has at most five distinct columns.
        let mut trip = Vec::with_capacity(5 * n);
        let off = usize::from(singular);
        let mut row: Vec<(usize, f64)> = Vec::with_capacity(6);
        for j in 0..ny {
            for i in 0..nx {
                let me = j * nx + i;
                row.clear();
                let mut add = |col: usize, v: f64| match row.iter_mut().find(|(c, _)| *c == col) {
                    Some(e) => e.1 += v,
                    None => row.push((col, v)),
                };
                // Each neighbour contributes (neighbour - me) * a; a ghost is s * p[src].
                let nb = [
                    (i == 0, ghosts.x_lo, (me.wrapping_sub(1)), ax, true),
                    (i == nx - 1, ghosts.x_hi, me + 1, ax, true),
                    (j == 0, ghosts.y_lo, me.wrapping_sub(nx), ay, false),
                    (j == ny - 1, ghosts.y_hi, me + nx, ay, false),
                ];
                for (at_edge, g, inner, a, along_x) in nb {
                    add(me, a);
                    if at_edge {
                        let src = if along_x { j * nx + g.src - 1 } else { (g.src - 1) * nx + i };
                        add(src, -g.s * a);
                    } else {
                        add(inner, -a);
                    }
                }
                if singular && me == 0 {
                    continue;
                }
                for &(c, v) in &row {
                    if c >= off && v != 0.0 {
                        trip.push(Triplet::new(me - off, c - off, v));
                    }
                }
            }
        }
        let m = n - off;
        let mat = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &trip).map_err(|e| Error::Solver {
            solver: "pressure cholesky",
            reason: format!("assembling the {m}x{m} matrix: {e:?}"),
        })?;
        let llt = mat.sp_cholesky(Side::Lower).map_err(|e| Error::Solver {
            solver: "pressure cholesky",
            reason: format!("factorisation failed: {e:?}"),
        })?;
        Ok(Self { n, pinned: singular, llt })
    }

    /// `x = L^+ b` in place (`b` has `nx * ny` entries).
    pub(crate) fn solve(&self, b: &mut [f64]) {
        debug_assert_eq!(b.len(), self.n);
        if self.pinned {
            let mean = b.iter().sum::<f64>() / self.n as f64;
            b.iter_mut().for_each(|x| *x = mean - *x);
            b[0] = 0.0;
            let m = self.n - 1;
            self.llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut b[1..], m, 1));
            let mean = b.iter().sum::<f64>() / self.n as f64;
            b.iter_mut().for_each(|x| *x -= mean);
        } else {
            b.iter_mut().for_each(|x| *x = -*x);
            self.llt.solve_in_place(MatMut::from_column_major_slice_mut(b, self.n, 1));
        }
    }
}
