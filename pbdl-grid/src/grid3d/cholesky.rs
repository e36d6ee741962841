//! Pressure solve in the closed box ([`super::walls`]) by a sparse Cholesky factor (faer), built
//! once per grid and reused every projection: the direct alternative to [`super::CgBox3d`], on the
//! very same matrix.
//!
//! `A = G^T G = -D G` is the seven-point Neumann Laplacian over all cells (a neighbour across a
//! wall is dropped), symmetric positive semi-definite with the constants as null space. As in
//! 2D ([`crate::pressure::PressureSolver`]), cell 0 is pinned (its row and column dropped), which
//! makes the rest definite; a zero-mean right-hand side then gives an exact solution with
//! `x_0 = 0`, and removing the mean gives the pseudo-inverse solution CG returns.
//!
//! Fill-reducing order ([`BoxOrdering`]): faer's approximate minimum degree (AMD), or geometric
//! nested dissection of the box (split the longest axis by a one-cell plane, order both halves
//! recursively, the plane last). Measured factor entries per cell (`tests/ns3d_pressure_choice.rs`):
//! 16^3 ND 138 / AMD 100, 24^3 231 / 192, 32^3 329 / 309, 48^3 536 / 688 (factor time 4.6 s /
//! 9.1 s); so [`BoxOrdering::Auto`] takes AMD up to 40^3 cells and nested dissection above.

use super::Grid3d;
use crate::{Error, Result};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Side};
use std::sync::Arc;

const SOLVER: &str = "grid3d box pressure cholesky";

/// Below this many cells a box is ordered lexicographically instead of being dissected further.
const LEAF_CELLS: usize = 8;

/// The fill-reducing order of the factor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BoxOrdering {
    /// AMD up to [`AUTO_ND_CELLS`] cells, nested dissection above (the measured crossover).
    #[default]
    Auto,
    /// Geometric nested dissection of the box (fewer factor entries from about 40^3 cells).
    NestedDissection,
    /// faer's approximate minimum degree (fewer factor entries on small boxes).
    Amd,
}

/// The largest factor [`CholeskyBox3d::new`] allocates (8 GiB of values). Factor entries per
/// cell grow about linearly with the box edge (309 at 32^3, 750 at 64^3), so 128^3 would need
/// ~23 GiB: such a box is refused before the numeric factorisation, pointing to CG.
pub const MAX_FACTOR_BYTES: usize = 8 << 30;

/// Above this many cells [`BoxOrdering::Auto`] uses nested dissection (40^3; measured: AMD fills
/// less at 32^3, nested dissection at 48^3).
pub const AUTO_ND_CELLS: usize = 40 * 40 * 40;

/// The Neumann pressure solve of a closed 3D box by a sparse Cholesky factor; build once, share.
pub struct CholeskyBox3d {
    grid: Grid3d,
    ordering: BoxOrdering,
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
}

impl std::fmt::Debug for CholeskyBox3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CholeskyBox3d")
            .field("grid", &self.grid)
            .field("ordering", &self.ordering)
            .field("factor_entries", &self.factor_entries())
            .finish()
    }
}

impl CholeskyBox3d {
    /// Assembles and factors the Neumann Laplacian of `grid` ([`BoxOrdering::Auto`]).
    pub fn new(grid: Grid3d) -> Result<Arc<Self>> {
        Self::with_ordering(grid, BoxOrdering::Auto)
    }

    /// Assembles and factors with the given fill-reducing order. A factor beyond
    /// [`MAX_FACTOR_BYTES`] is an [`Error::Solver`] (before anything large is allocated).
    pub fn with_ordering(grid: Grid3d, ordering: BoxOrdering) -> Result<Arc<Self>> {
        Self::factor(grid, ordering, MAX_FACTOR_BYTES)
    }

    fn factor(grid: Grid3d, ordering: BoxOrdering, max_bytes: usize) -> Result<Arc<Self>> {
        grid.validate()?;
        let n = grid.cells();
        let mat = assemble(&grid)?;
        let ordering = match ordering {
            BoxOrdering::Auto if n > AUTO_ND_CELLS => BoxOrdering::NestedDissection,
            BoxOrdering::Auto => BoxOrdering::Amd,
            o => o,
        };
        let order = (ordering == BoxOrdering::NestedDissection).then(|| pinned_order(&grid));
        let fail = |what: &str, e: &dyn std::fmt::Debug| Error::Solver {
            solver: SOLVER,
            reason: format!("{what} of the {}x{} matrix failed: {e:?}; use a smaller grid or CG", n - 1, n - 1),
        };
        let symbolic = match &order {
            Some((fwd, inv)) => factorize_symbolic_cholesky(
                mat.symbolic(),
                Side::Lower,
                SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, n - 1)),
                CholeskySymbolicParams::default(),
            ),
            None => factorize_symbolic_cholesky(
                mat.symbolic(),
                Side::Lower,
                SymmetricOrdering::Amd,
                CholeskySymbolicParams::default(),
            ),
        }
        .map_err(|e| fail("symbolic analysis", &e))?;
        let bytes = symbolic.len_val().saturating_mul(std::mem::size_of::<f64>());
        if bytes > max_bytes {
            return Err(Error::Solver {
                solver: SOLVER,
                reason: format!(
                    "the factor of the {}x{}x{} box would hold {} values ({:.1} GiB > the {:.1} GiB limit); \
                     use BoxPressure::Cg for a box this large",
                    grid.nx,
                    grid.ny,
                    grid.nz,
                    symbolic.len_val(),
                    bytes as f64 / (1u64 << 30) as f64,
                    max_bytes as f64 / (1u64 << 30) as f64
                ),
            });
        }
        let mut values = Vec::new();
        values.try_reserve_exact(symbolic.len_val()).map_err(|e| fail("allocating the factor", &e))?;
        values.resize(symbolic.len_val(), 0.0);
        let par = faer::get_global_parallelism();
        let mut mem = MemBuffer::try_new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()))
            .map_err(|e| fail("allocating the workspace", &e))?;
        symbolic
            .factorize_numeric_llt(
                &mut values,
                mat.as_ref(),
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| fail("the numeric factorisation", &e))?;
        Ok(Arc::new(Self { grid, ordering, symbolic, values }))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The fill-reducing order used (never `Auto`).
    pub fn ordering(&self) -> BoxOrdering {
        self.ordering
    }

    /// Stored values of the factor `L` (its memory is 8 bytes each, plus the index arrays;
    /// supernodal storage counts the dense supernode blocks).
    pub fn factor_entries(&self) -> usize {
        self.symbolic.len_val()
    }

    /// `x = A^+ b` (`b`'s mean is removed first; `x` has zero mean); same contract as
    /// [`super::CgBox3d::solve`], to round-off instead of a tolerance.
    pub fn solve(&self, b: &mut [f64], x: &mut [f64]) -> Result<()> {
        let n = self.grid.cells();
        if b.len() != n || x.len() != n {
            return Err(Error::Shape {
                op: "CholeskyBox3d::solve",
                arg: "b/x",
                expected: format!("{n} values each (nz * ny * nx)"),
                got: vec![b.len(), x.len()],
            });
        }
        remove_mean(b);
        x.copy_from_slice(b);
        x[0] = 0.0;
        let par = faer::get_global_parallelism();
        let mut mem = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(1, par));
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut x[1..], n - 1, 1),
            par,
            MemStack::new(&mut mem),
        );
        remove_mean(x);
        Ok(())
    }
}

fn remove_mean(x: &mut [f64]) {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter_mut().for_each(|v| *v -= m);
}

/// The lower triangle of `A` without cell 0 (unknown `m - 1` is cell `m`).
fn assemble(grid: &Grid3d) -> Result<SparseColMat<usize, f64>> {
    let n = [grid.nx, grid.ny, grid.nz];
    let cells = grid.cells();
    let w = grid.spacing().map(|h| 1.0 / (h * h));
    let stride = [1, n[0], n[0] * n[1]];
    let mut trip = Vec::with_capacity(4 * cells);
    for m in 1..cells {
        let p = [m % n[0], (m / n[0]) % n[1], m / (n[0] * n[1])];
        let mut diag = 0.0;
        for a in 0..3 {
            if p[a] + 1 < n[a] {
                diag += w[a];
            }
            if p[a] > 0 {
                diag += w[a];
                let lower = m - stride[a];
                if lower > 0 {
                    trip.push(Triplet::new(m - 1, lower - 1, -w[a]));
                }
            }
        }
        trip.push(Triplet::new(m - 1, m - 1, diag));
    }
    SparseColMat::<usize, f64>::try_new_from_triplets(cells - 1, cells - 1, &trip).map_err(|e| Error::Solver {
        solver: SOLVER,
        reason: format!("assembling the {0}x{0} matrix: {e:?}", cells - 1),
    })
}

/// Nested-dissection order of the unknowns (cells 1..): `(forward, inverse)` with `forward[i]`
/// the unknown eliminated `i`-th.
fn pinned_order(grid: &Grid3d) -> (Vec<usize>, Vec<usize>) {
    let n = [grid.nx, grid.ny, grid.nz];
    let mut cells = Vec::with_capacity(grid.cells());
    dissect([0; 3], n, n, &mut cells);
    let fwd: Vec<usize> = cells.into_iter().filter(|&c| c != 0).map(|c| c - 1).collect();
    let mut inv = vec![0; fwd.len()];
    for (i, &u) in fwd.iter().enumerate() {
        inv[u] = i;
    }
    (fwd, inv)
}

/// Appends the cells of the box `[lo, hi)` in nested-dissection order.
fn dissect(lo: [usize; 3], hi: [usize; 3], n: [usize; 3], out: &mut Vec<usize>) {
    let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let a = (0..3).max_by_key(|&a| (ext[a], 3 - a)).unwrap_or(0);
    let push_box = |lo: [usize; 3], hi: [usize; 3], out: &mut Vec<usize>| {
        for k in lo[2]..hi[2] {
            for j in lo[1]..hi[1] {
                for i in lo[0]..hi[0] {
                    out.push((k * n[1] + j) * n[0] + i);
                }
            }
        }
    };
    if ext[0] * ext[1] * ext[2] <= LEAF_CELLS || ext[a] < 3 {
        push_box(lo, hi, out);
        return;
    }
    let mid = lo[a] + ext[a] / 2;
    let (mut left_hi, mut right_lo, mut sep_lo, mut sep_hi) = (hi, lo, lo, hi);
    left_hi[a] = mid;
    right_lo[a] = mid + 1;
    sep_lo[a] = mid;
    sep_hi[a] = mid + 1;
    dissect(lo, left_hi, n, out);
    dissect(right_lo, hi, n, out);
    push_box(sep_lo, sep_hi, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_factor_beyond_the_memory_limit_is_a_typed_error() {
        let g = Grid3d::cube(8, 1.0).unwrap();
        let ok = CholeskyBox3d::factor(g, BoxOrdering::Amd, MAX_FACTOR_BYTES).unwrap();
        let limit = ok.factor_entries() * 8 - 1;
        match CholeskyBox3d::factor(g, BoxOrdering::Amd, limit) {
            Err(Error::Solver { reason, .. }) => assert!(reason.contains("BoxPressure::Cg"), "{reason}"),
            other => panic!("expected a solver error, got {other:?}"),
        }
    }

    #[test]
    fn nested_dissection_is_a_permutation() {
        let g = Grid3d::new(7, 5, 6, 1.0, 1.0, 1.0).unwrap();
        let (fwd, inv) = pinned_order(&g);
        assert_eq!(fwd.len(), g.cells() - 1);
        for (i, &u) in fwd.iter().enumerate() {
            assert_eq!(inv[u], i);
        }
    }
}
