//! Poisson solve by a sparse Cholesky factor (faer), factored once per grid and boundaries.
//!
//! The matrix is `-L` assembled from the pressure ghost rules (so it is exactly the `D M G` of
//! the projection). Without a Dirichlet face `L` is singular; cell 0 is then pinned and the
//! pseudo-inverse solution recovered by removing means.

use crate::boundary::Ghosts;
use crate::laplacian_matrix::{unknown_index, Excluded, Factored, Laplacian};
use crate::{Grid, Result};

/// A factored Poisson matrix.
pub(crate) struct CholeskyPoisson(Factored);

impl CholeskyPoisson {
    pub(crate) fn new(grid: &Grid, ghosts: &Ghosts, singular: bool) -> Result<Self> {
        let (index, _) = unknown_index(grid.cells(), |_| true);
        let spec = Laplacian {
            grid,
            ghosts: *ghosts,
            index: &index,
            excluded: Excluded::ClosedFace,
            scale: 1.0,
            shift: 0.0,
            pin_first: singular,
        };
        Ok(Self(Factored::new(&spec, true, "pressure cholesky", "")?))
    }

    /// `x = L^+ b` in place (`b` has `nx * ny` entries).
    pub(crate) fn solve(&self, b: &mut [f64]) {
        self.0.solve(b);
    }
}
