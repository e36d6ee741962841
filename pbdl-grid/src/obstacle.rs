//! Obstacles: solid cells inside the domain.
//!
//! An [`Obstacle`] (cylinder or box) marks the cells whose centres it covers as solid; an
//! [`ObstacleMask`] is the union over a list. Solid cells leave the pressure solve (the masked
//! Laplacian is factored once, [`crate::pressure::MaskedPressureSolver`]) and every face that
//! touches a solid cell carries zero normal velocity after projection (static obstacles).

use crate::boundary::Boundaries;
use crate::{Bc, Error, Grid, Result};
use candle_core::{DType, Device, Tensor};
use serde::{Deserialize, Serialize};

/// A static solid shape, in domain coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Obstacle {
    /// A disc of radius `radius` around `center`.
    Cylinder {
        /// Centre `[x, y]`.
        center: [f64; 2],
        /// Radius (> 0).
        radius: f64,
    },
    /// An axis-aligned box `[lo, hi]`.
    Box {
        /// Lower corner `[x, y]`.
        lo: [f64; 2],
        /// Upper corner `[x, y]`.
        hi: [f64; 2],
    },
}

impl Obstacle {
    /// `true` when the point `(x, y)` is inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match *self {
            Obstacle::Cylinder { center, radius } => {
                (x - center[0]).powi(2) + (y - center[1]).powi(2) <= radius * radius
            }
            Obstacle::Box { lo, hi } => x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1],
        }
    }

    /// Checks that the shape is finite, non-empty and inside the domain of `grid`.
    pub fn validate(&self, grid: &Grid) -> Result<()> {
        let bad = |reason: String| Err(Error::Invalid { field: "obstacles", reason });
        let (lo, hi) = match *self {
            Obstacle::Cylinder { center, radius } => {
                if !(radius > 0.0 && radius.is_finite()) {
                    return bad(format!("cylinder radius must be positive and finite, got {radius}"));
                }
                ([center[0] - radius, center[1] - radius], [center[0] + radius, center[1] + radius])
            }
            Obstacle::Box { lo, hi } => {
                if !(lo[0] < hi[0] && lo[1] < hi[1]) {
                    return bad(format!("box needs lo < hi on both axes, got lo {lo:?} hi {hi:?}"));
                }
                (lo, hi)
            }
        };
        if !lo.iter().chain(&hi).all(|v| v.is_finite())
            || lo[0] < 0.0
            || lo[1] < 0.0
            || hi[0] > grid.lx
            || hi[1] > grid.ly
        {
            return bad(format!(
                "{self:?} reaches outside the domain [0, {}] x [0, {}]; move or shrink it",
                grid.lx, grid.ly
            ));
        }
        Ok(())
    }
}

/// Which cells of a grid are solid.
#[derive(Clone, Debug, PartialEq)]
pub struct ObstacleMask {
    grid: Grid,
    solid: Vec<bool>,
}

impl ObstacleMask {
    /// The cells whose centres lie inside any of `obstacles` (each validated against the grid).
    /// At least one cell must be solid and one fluid.
    pub fn new(grid: Grid, obstacles: &[Obstacle]) -> Result<Self> {
        grid.validate()?;
        for o in obstacles {
            o.validate(&grid)?;
        }
        let (dx, dy) = (grid.dx(), grid.dy());
        let mut solid = vec![false; grid.cells()];
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = ((i as f64 + 0.5) * dx, (j as f64 + 0.5) * dy);
                solid[j * grid.nx + i] = obstacles.iter().any(|o| o.contains(x, y));
            }
        }
        Self::from_cells(grid, solid)
    }

    /// A mask from per-cell flags (`true` = solid), row-major `ny x nx`.
    pub fn from_cells(grid: Grid, solid: Vec<bool>) -> Result<Self> {
        if solid.len() != grid.cells() {
            return Err(Error::Invalid {
                field: "obstacles",
                reason: format!("mask has {} cells, the grid {}", solid.len(), grid.cells()),
            });
        }
        let count = solid.iter().filter(|s| **s).count();
        if count == 0 || count == solid.len() {
            return Err(Error::Invalid {
                field: "obstacles",
                reason: format!(
                    "the obstacles cover {count} of {} cells; they must cover at least one cell and leave fluid",
                    solid.len()
                ),
            });
        }
        Ok(Self { grid, solid })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// `true` when cell `(j, i)` is solid.
    pub fn is_solid(&self, j: usize, i: usize) -> bool {
        self.solid[j * self.grid.nx + i]
    }

    /// Number of solid cells.
    pub fn solid_cells(&self) -> usize {
        self.solid.iter().filter(|s| **s).count()
    }

    /// `1` in fluid cells and `0` in solid ones, `[1, 1, ny, nx]`.
    pub fn fluid_tensor(&self, dtype: DType) -> Result<Tensor> {
        let v: Vec<f64> = self.solid.iter().map(|&s| if s { 0.0 } else { 1.0 }).collect();
        Ok(Tensor::from_vec(v, (1, 1, self.grid.ny, self.grid.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }

    /// Open-face masks `(u faces, v faces)` of a MAC velocity with boundaries `bc`: 0 on every
    /// face that touches a solid cell (across a periodic edge too), 1 elsewhere.
    pub(crate) fn face_masks(&self, bc: &Boundaries) -> (Vec<f64>, Vec<f64>) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (px, py) = (bc.x_lo == Bc::Periodic, bc.y_lo == Bc::Periodic);
        let mut mu = vec![1.0; nx * ny];
        let mut mv = vec![1.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let me = self.is_solid(j, i);
                let east = if i + 1 < nx { self.is_solid(j, i + 1) } else { px && self.is_solid(j, 0) };
                let north = if j + 1 < ny { self.is_solid(j + 1, i) } else { py && self.is_solid(0, i) };
                if me || east {
                    mu[j * nx + i] = 0.0;
                }
                if me || north {
                    mv[j * nx + i] = 0.0;
                }
            }
        }
        (mu, mv)
    }

    /// The open-face masks as a `[1, 2, ny, nx]` tensor (for multiplying a velocity).
    pub fn face_tensor(&self, bc: &Boundaries, dtype: DType) -> Result<Tensor> {
        let (mut mu, mv) = self.face_masks(bc);
        mu.extend(mv);
        Ok(Tensor::from_vec(mu, (1, 2, self.grid.ny, self.grid.nx), &Device::Cpu)?.to_dtype(dtype)?)
    }
}
