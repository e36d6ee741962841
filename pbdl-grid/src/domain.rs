//! The computational domain: a uniform 2D grid of cells.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// A uniform grid of `nx` x `ny` cells covering `[0, lx] x [0, ly]`.
///
/// Cell `(j, i)` has its centre at `((i + 1/2) dx, (j + 1/2) dy)`. Tensors on the grid are laid
/// out `[batch, channel, ny, nx]`, x fastest.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid {
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
    /// Domain length along x.
    pub lx: f64,
    /// Domain length along y.
    pub ly: f64,
}

impl Grid {
    /// A validated grid: at least 2 cells per axis, positive finite lengths.
    pub fn new(nx: usize, ny: usize, lx: f64, ly: f64) -> Result<Self> {
        let g = Self { nx, ny, lx, ly };
        g.validate()?;
        Ok(g)
    }

    /// A square grid of `n` x `n` cells on `[0, l]^2`.
    pub fn square(n: usize, l: f64) -> Result<Self> {
        Self::new(n, n, l, l)
    }

    /// Checks the grid's fields; errors name the bad one.
    pub fn validate(&self) -> Result<()> {
        for (field, n) in [("grid.nx", self.nx), ("grid.ny", self.ny)] {
            if n < 2 {
                return Err(Error::Invalid { field, reason: format!("need at least 2 cells, got {n}") });
            }
        }
        for (field, l) in [("grid.lx", self.lx), ("grid.ly", self.ly)] {
            if !(l > 0.0 && l.is_finite()) {
                return Err(Error::Invalid { field, reason: format!("must be a positive finite length, got {l}") });
            }
        }
        Ok(())
    }

    /// Cell width along x.
    pub fn dx(&self) -> f64 {
        self.lx / self.nx as f64
    }

    /// Cell width along y.
    pub fn dy(&self) -> f64 {
        self.ly / self.ny as f64
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// The shape `[batch, channels, ny, nx]` of a tensor on this grid.
    pub fn shape(&self, batch: usize, channels: usize) -> [usize; 4] {
        [batch, channels, self.ny, self.nx]
    }
}
