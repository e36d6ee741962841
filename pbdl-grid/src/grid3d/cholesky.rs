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
//! [`CholeskyBox3d::with_topology`] assembles the same stencil over the fluid cells of a
//! [`BoxTopology`]: a periodic neighbour wraps, a solid neighbour is dropped (Neumann), an open
//! face adds its weight to the diagonal only (ghost pressure 0: the matrix is then definite and
//! nothing is pinned).
//!
//! Fill-reducing order ([`BoxOrdering`]): faer's approximate minimum degree (AMD), or geometric
//! nested dissection of the box (split the longest axis by a one-cell plane, order both halves
//! recursively, the plane last). Measured factor entries per cell (`tests/ns3d_pressure_choice.rs`):
//! 16^3 ND 138 / AMD 100, 24^3 231 / 192, 32^3 329 / 309, 48^3 536 / 688 (factor time 4.6 s /
//! 9.1 s); so [`BoxOrdering::Auto`] takes AMD up to 40^3 cells and nested dissection above.

use super::box_pressure::BoxTopology;
use super::walls::WallGeom;
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
    topology: BoxTopology,
    /// Unknown of each cell (`usize::MAX`: solid, or the pinned cell).
    unknown: Vec<usize>,
    /// Number of unknowns.
    unknowns: usize,
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
        Self::factor(grid, BoxTopology::default(), ordering, MAX_FACTOR_BYTES)
    }

    /// Assembles and factors the Laplacian of `topology` (periodic pairs wrap, open faces are
    /// Dirichlet `p = 0`, solid cells are left out: Neumann on their faces), order `Auto`.
    pub fn with_topology(grid: Grid3d, topology: BoxTopology) -> Result<Arc<Self>> {
        Self::factor(grid, topology, BoxOrdering::Auto, MAX_FACTOR_BYTES)
    }

    fn factor(grid: Grid3d, topology: BoxTopology, ordering: BoxOrdering, max_bytes: usize) -> Result<Arc<Self>> {
        grid.validate()?;
        topology.validate(&grid)?;
        let (unknown, unknowns) = unknowns(&grid, &topology);
        // `n - 1` below is the number of unknowns (the closed box pins one cell).
        let n = unknowns + 1;
        let mat = assemble(&grid, &topology, &unknown, unknowns)?;
        let ordering = match ordering {
            BoxOrdering::Auto if n > AUTO_ND_CELLS => BoxOrdering::NestedDissection,
            BoxOrdering::Auto => BoxOrdering::Amd,
            o => o,
        };
        let order = (ordering == BoxOrdering::NestedDissection).then(|| pinned_order(&grid, &unknown));
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
        Ok(Arc::new(Self { grid, topology, unknown, unknowns, ordering, symbolic, values }))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// The topology (faces, solids) the matrix was assembled for.
    pub fn topology(&self) -> &BoxTopology {
        &self.topology
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
        if self.topology.is_plain() {
            // The closed (or free-slip) box: exactly the historical path.
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
            return Ok(());
        }
        let singular = !self.topology.faces.any_open();
        let fluid = |m: usize| self.topology.fluid(m);
        if singular {
            remove_mean_where(b, fluid);
        }
        let mut rhs = vec![0.0; self.unknowns];
        for (m, &u) in self.unknown.iter().enumerate() {
            if u != usize::MAX {
                rhs[u] = b[m];
            }
        }
        let par = faer::get_global_parallelism();
        let mut mem = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(1, par));
        LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut rhs, self.unknowns, 1),
            par,
            MemStack::new(&mut mem),
        );
        for (m, (xm, &u)) in x.iter_mut().zip(&self.unknown).enumerate() {
            // Solid cells and the pinned cell hold 0.
            *xm = if u == usize::MAX || !fluid(m) { 0.0 } else { rhs[u] };
        }
        if singular {
            remove_mean_where(x, fluid);
        }
        Ok(())
    }
}

fn remove_mean(x: &mut [f64]) {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter_mut().for_each(|v| *v -= m);
}

/// Removes the mean over the cells where `keep` holds (the others are left alone).
fn remove_mean_where(x: &mut [f64], keep: impl Fn(usize) -> bool) {
    let (mut s, mut c) = (0.0, 0usize);
    for (m, v) in x.iter().enumerate() {
        if keep(m) {
            s += v;
            c += 1;
        }
    }
    let mean = s / c.max(1) as f64;
    for (m, v) in x.iter_mut().enumerate() {
        if keep(m) {
            *v -= mean;
        }
    }
}

/// The unknown of each cell and their number: fluid cells in order, without the first fluid
/// cell when the problem is singular (no open face: it is pinned, as cell 0 of the closed box).
fn unknowns(grid: &Grid3d, topo: &BoxTopology) -> (Vec<usize>, usize) {
    let mut pinned = topo.faces.any_open();
    let mut next = 0;
    let map = (0..grid.cells())
        .map(|m| {
            if !topo.fluid(m) {
                return usize::MAX;
            }
            if !pinned {
                pinned = true;
                return usize::MAX;
            }
            next += 1;
            next - 1
        })
        .collect();
    (map, next)
}

/// The lower triangle of `A` over the unknowns (the closed box: cell 0 pinned, unknown `m - 1`
/// is cell `m`). Per cell and axis the upper neighbour then the lower one: a fluid neighbour
/// (wrapped across periodic faces) adds `w` to the diagonal and `-w` off it, an open face `w` to
/// the diagonal only (the ghost pressure is 0), a wall or a solid cell nothing (Neumann).
fn assemble(grid: &Grid3d, topo: &BoxTopology, unknown: &[usize], unknowns: usize) -> Result<SparseColMat<usize, f64>> {
    let geo = WallGeom::with_faces(grid, topo.faces);
    let w = grid.spacing().map(|h| 1.0 / (h * h));
    let mut trip = Vec::with_capacity(4 * grid.cells());
    for (m, &um) in unknown.iter().enumerate() {
        if um == usize::MAX {
            continue;
        }
        let mut diag = 0.0;
        for a in 0..3 {
            for up in [true, false] {
                match geo.neighbour(m, a, up) {
                    Some(nb) if topo.fluid(nb) => {
                        diag += w[a];
                        let un = unknown[nb];
                        if un != usize::MAX && un < um {
                            trip.push(Triplet::new(um, un, -w[a]));
                        }
                    }
                    Some(_) => {}
                    None if up && topo.faces.open_hi(a) => diag += w[a],
                    None => {}
                }
            }
        }
        trip.push(Triplet::new(um, um, diag));
    }
    SparseColMat::<usize, f64>::try_new_from_triplets(unknowns, unknowns, &trip).map_err(|e| Error::Solver {
        solver: SOLVER,
        reason: format!("assembling the {0}x{0} matrix: {e:?}", unknowns),
    })
}

/// Nested-dissection order of the unknowns: `(forward, inverse)` with `forward[i]` the unknown
/// eliminated `i`-th.
fn pinned_order(grid: &Grid3d, unknown: &[usize]) -> (Vec<usize>, Vec<usize>) {
    let n = [grid.nx, grid.ny, grid.nz];
    let mut cells = Vec::with_capacity(grid.cells());
    dissect([0; 3], n, n, &mut cells);
    let fwd: Vec<usize> = cells.into_iter().map(|c| unknown[c]).filter(|&u| u != usize::MAX).collect();
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
        let ok = CholeskyBox3d::factor(g, BoxTopology::default(), BoxOrdering::Amd, MAX_FACTOR_BYTES).unwrap();
        let limit = ok.factor_entries() * 8 - 1;
        match CholeskyBox3d::factor(g, BoxTopology::default(), BoxOrdering::Amd, limit) {
            Err(Error::Solver { reason, .. }) => assert!(reason.contains("BoxPressure::Cg"), "{reason}"),
            other => panic!("expected a solver error, got {other:?}"),
        }
    }

    #[test]
    fn nested_dissection_is_a_permutation() {
        let g = Grid3d::new(7, 5, 6, 1.0, 1.0, 1.0).unwrap();
        let (unknown, _) = unknowns(&g, &BoxTopology::default());
        let (fwd, inv) = pinned_order(&g, &unknown);
        assert_eq!(fwd.len(), g.cells() - 1);
        for (i, &u) in fwd.iter().enumerate() {
            assert_eq!(inv[u], i);
        }
    }
}
