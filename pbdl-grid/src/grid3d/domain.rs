//! The 3D computational domain: a uniform periodic box of cells.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// A uniform grid of `nx` x `ny` x `nz` cells covering `[0, lx] x [0, ly] x [0, lz]`.
///
/// Cell `(k, j, i)` has its centre at `((i + 1/2) dx, (j + 1/2) dy, (k + 1/2) dz)`. Tensors on
/// the grid are laid out `[batch, channel, nz, ny, nx]`, x fastest.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid3d {
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
    /// Cells along z.
    pub nz: usize,
    /// Domain length along x.
    pub lx: f64,
    /// Domain length along y.
    pub ly: f64,
    /// Domain length along z.
    pub lz: f64,
}

impl Grid3d {
    /// A validated grid: at least 2 cells per axis, positive finite lengths.
    pub fn new(nx: usize, ny: usize, nz: usize, lx: f64, ly: f64, lz: f64) -> Result<Self> {
        let g = Self { nx, ny, nz, lx, ly, lz };
        g.validate()?;
        Ok(g)
    }

    /// A cube of `n`^3 cells on `[0, l]^3`.
    pub fn cube(n: usize, l: f64) -> Result<Self> {
        Self::new(n, n, n, l, l, l)
    }

    /// Checks the grid's fields; errors name the bad one.
    pub fn validate(&self) -> Result<()> {
        for (field, n) in [("grid.nx", self.nx), ("grid.ny", self.ny), ("grid.nz", self.nz)] {
            if n < 2 {
                return Err(Error::Invalid { field, reason: format!("need at least 2 cells, got {n}") });
            }
        }
        for (field, l) in [("grid.lx", self.lx), ("grid.ly", self.ly), ("grid.lz", self.lz)] {
            if !(l > 0.0 && l.is_finite()) {
                return Err(Error::Invalid { field, reason: format!("must be a positive finite length, got {l}") });
            }
        }
        Ok(())
    }

    /// Cell widths `[dx, dy, dz]`.
    pub fn spacing(&self) -> [f64; 3] {
        [self.lx / self.nx as f64, self.ly / self.ny as f64, self.lz / self.nz as f64]
    }

    /// Smallest cell width.
    pub fn min_spacing(&self) -> f64 {
        let [dx, dy, dz] = self.spacing();
        dx.min(dy).min(dz)
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// The shape `[batch, channels, nz, ny, nx]` of a tensor on this grid.
    pub fn shape(&self, batch: usize, channels: usize) -> [usize; 5] {
        [batch, channels, self.nz, self.ny, self.nx]
    }
}
