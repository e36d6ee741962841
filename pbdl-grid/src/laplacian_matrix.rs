//! The five-point Laplacian as a sparse matrix over a subset of cells, and its Cholesky factor.
//!
//! One assembly serves every direct solve: the pressure Poisson matrix `-L` (with and without
//! obstacles) and backward-Euler diffusion `I - nu dt L`. Neighbours beyond the domain edge come
//! from the field's ghost rules (`ghost = s * q[src]`); a neighbour that is not an unknown is
//! either a closed face (obstacle: no flux, no entry) or a known value (fixed boundary face: the
//! caller moves it to the right-hand side).

use crate::boundary::Ghosts;
use crate::{Error, Grid, Result};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::Llt;
use faer::sparse::{SparseColMat, Triplet};
use faer::{MatMut, Side};

/// Marks a cell that is not an unknown in an index map.
pub(crate) const NOT_UNKNOWN: usize = usize::MAX;

/// How a row treats a neighbour that is not an unknown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Excluded {
    /// The face between them is closed (obstacle): no flux, so no entry at all.
    ClosedFace,
    /// The neighbour has a known value: the diagonal keeps its share, the off-diagonal entry
    /// goes to the right-hand side (the caller's job).
    KnownValue,
}

/// What to assemble: `shift I - scale L` on the unknowns of `index`.
pub(crate) struct Laplacian<'a> {
    /// The grid (cell sizes).
    pub grid: &'a Grid,
    /// Ghost rules of the field at the domain edges.
    pub ghosts: Ghosts,
    /// Unknown number of each cell (row-major), [`NOT_UNKNOWN`] for the others.
    pub index: &'a [usize],
    /// Treatment of neighbours that are not unknowns.
    pub excluded: Excluded,
    /// Factor on `-L` (1 for the Poisson matrix, `nu dt` for implicit diffusion).
    pub scale: f64,
    /// Identity shift (0 for the Poisson matrix, 1 for implicit diffusion).
    pub shift: f64,
    /// Drop unknown 0 (its row and column) to make a singular `-L` definite.
    pub pin_first: bool,
}

/// Numbers the cells for which `is_unknown` holds (row-major); returns the index map and the
/// number of unknowns.
pub(crate) fn unknown_index(cells: usize, is_unknown: impl Fn(usize) -> bool) -> (Vec<usize>, usize) {
    let mut index = vec![NOT_UNKNOWN; cells];
    let mut n = 0;
    for (k, ix) in index.iter_mut().enumerate() {
        if is_unknown(k) {
            *ix = n;
            n += 1;
        }
    }
    (index, n)
}

impl Laplacian<'_> {
    /// The matrix (`unknowns - pin_first` square), symmetric when the ghost rules are.
    pub(crate) fn assemble(&self, solver: &'static str) -> Result<SparseColMat<usize, f64>> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (g, index) = (&self.ghosts, self.index);
        let unknowns = index.iter().filter(|&&ix| ix != NOT_UNKNOWN).count();
        let (ax, ay) = (self.scale / (self.grid.dx() * self.grid.dx()), self.scale / (self.grid.dy() * self.grid.dy()));
        let off = usize::from(self.pin_first);
        if unknowns < off {
            return Err(Error::Solver {
                solver,
                reason: format!("no unknowns to solve for ({unknowns} cells, pinned: {})", self.pin_first),
            });
        }
        let mut trip = Vec::with_capacity(5 * unknowns);
        // Row-wise accumulation: each row has at most five distinct columns.
        let mut row: Vec<(usize, f64)> = Vec::with_capacity(6);
        for j in 0..ny {
            for i in 0..nx {
                let me = j * nx + i;
                if index[me] == NOT_UNKNOWN {
                    continue;
                }
                row.clear();
                let mut add = |cell: usize, v: f64| match row.iter_mut().find(|(c, _)| *c == cell) {
                    Some(e) => e.1 += v,
                    None => row.push((cell, v)),
                };
                if self.shift != 0.0 {
                    add(me, self.shift);
                }
                // Each neighbour contributes (neighbour - me) * a; a ghost is s * q[src].
                let nb = [
                    (i == 0, g.x_lo, me.wrapping_sub(1), ax, true),
                    (i == nx - 1, g.x_hi, me + 1, ax, true),
                    (j == 0, g.y_lo, me.wrapping_sub(nx), ay, false),
                    (j == ny - 1, g.y_hi, me + nx, ay, false),
                ];
                for (at_edge, gh, inner, a, along_x) in nb {
                    let (other, s) = if at_edge {
                        (if along_x { j * nx + gh.src - 1 } else { (gh.src - 1) * nx + i }, gh.s)
                    } else {
                        (inner, 1.0)
                    };
                    let known = index[other] == NOT_UNKNOWN;
                    if known && self.excluded == Excluded::ClosedFace {
                        continue;
                    }
                    add(me, a);
                    if !known {
                        add(other, -s * a);
                    }
                }
                if self.pin_first && index[me] == 0 {
                    continue;
                }
                for &(c, v) in &row {
                    let ci = index[c];
                    if ci >= off && v != 0.0 {
                        trip.push(Triplet::new(index[me] - off, ci - off, v));
                    }
                }
            }
        }
        let m = unknowns - off;
        SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &trip)
            .map_err(|e| Error::Solver { solver, reason: format!("assembling the {m}x{m} matrix: {e:?}") })
    }
}

/// A sparse Cholesky factor of an assembled matrix, with the solve that undoes `pin_first`.
pub(crate) struct Factored {
    /// Unknowns, pinned one included.
    n: usize,
    pinned: bool,
    /// The matrix is `-A` for the `A x = b` callers solve (the Poisson matrix `-L`).
    negated: bool,
    llt: Llt<usize, f64>,
}

impl Factored {
    /// Assembles and factors `spec`. `negated`: [`Self::solve`] solves `-M x = b` (callers of
    /// the Poisson matrix `M = -L` pass `L x = b`); `hint` ends the error message of a failed
    /// factorisation (what to check).
    pub(crate) fn new(spec: &Laplacian<'_>, negated: bool, solver: &'static str, hint: &str) -> Result<Self> {
        let mat = spec.assemble(solver)?;
        let llt = mat
            .sp_cholesky(Side::Lower)
            .map_err(|e| Error::Solver { solver, reason: format!("factorisation failed: {e:?}{hint}") })?;
        Ok(Self { n: mat.nrows() + usize::from(spec.pin_first), pinned: spec.pin_first, negated, llt })
    }

    /// Solves in place (`b` has one entry per unknown). Pinned: the zero-mean (pseudo-inverse)
    /// solution for the zero-mean part of `b`.
    pub(crate) fn solve(&self, b: &mut [f64]) {
        debug_assert_eq!(b.len(), self.n);
        if self.pinned {
            let mean = b.iter().sum::<f64>() / self.n as f64;
            if self.negated {
                b.iter_mut().for_each(|x| *x = mean - *x);
            } else {
                b.iter_mut().for_each(|x| *x -= mean);
            }
            b[0] = 0.0;
            self.llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut b[1..], self.n - 1, 1));
            let mean = b.iter().sum::<f64>() / self.n as f64;
            b.iter_mut().for_each(|x| *x -= mean);
        } else {
            if self.negated {
                b.iter_mut().for_each(|x| *x = -*x);
            }
            self.llt.solve_in_place(MatMut::from_column_major_slice_mut(b, self.n, 1));
        }
    }
}
