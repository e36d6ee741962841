//! Fields: a tensor on a [`Grid`], its staggering in the type and its boundary conditions with it.
//!
//! * [`CenteredField`] (`Field<Centered>`): values at cell centres, `[batch, channels, ny, nx]`,
//!   with [`ScalarBoundaries`].
//! * [`MacField`] (`Field<Mac>`): a staggered velocity, `[batch, 2, ny, nx]`; `u` on x-faces at
//!   `((i + 1) dx, (j + 1/2) dy)`, `v` on y-faces at `((i + 1/2) dx, (j + 1) dy)`, with
//!   velocity [`Boundaries`] (see [`crate::boundary`] for how boundary faces are stored).

use crate::boundary::{Boundaries, ScalarBoundaries};
use crate::{Error, Grid, Result};
use candle_core::{DType, Device, Tensor};
use std::marker::PhantomData;

/// Where a field's values sit, and which boundary conditions it carries.
pub trait Staggering: Clone + std::fmt::Debug + Send + Sync + 'static {
    /// The boundary conditions a field of this staggering carries.
    type Bc: Clone + Copy + std::fmt::Debug + PartialEq + Send + Sync;
    /// Short name for errors.
    const NAME: &'static str;
    /// Channels required (`None`: any).
    const CHANNELS: Option<usize>;
    /// Validates the boundary conditions.
    fn validate_bc(bc: &Self::Bc) -> Result<()>;
}

/// Cell-centred values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Centered;

/// Staggered (marker-and-cell) velocity: normal components on cell faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mac;

impl Staggering for Centered {
    type Bc = ScalarBoundaries;
    const NAME: &'static str = "centered";
    const CHANNELS: Option<usize> = None;
    fn validate_bc(bc: &Self::Bc) -> Result<()> {
        bc.validate()
    }
}

impl Staggering for Mac {
    type Bc = Boundaries;
    const NAME: &'static str = "mac";
    const CHANNELS: Option<usize> = Some(2);
    fn validate_bc(bc: &Self::Bc) -> Result<()> {
        bc.validate()
    }
}

/// A tensor on a grid with its staggering `S` and boundary conditions.
#[derive(Clone, Debug)]
pub struct Field<S: Staggering> {
    values: Tensor,
    grid: Grid,
    bc: S::Bc,
    _s: PhantomData<S>,
}

/// Cell-centred field.
pub type CenteredField = Field<Centered>;
/// Staggered (MAC) velocity field.
pub type MacField = Field<Mac>;

impl<S: Staggering> Field<S> {
    /// Wraps `values` (`[batch, channels, ny, nx]`, f32 or f64) after checking it against `grid`.
    pub fn new(values: Tensor, grid: Grid, bc: S::Bc) -> Result<Self> {
        grid.validate()?;
        S::validate_bc(&bc)?;
        check_values::<S>("Field::new", &values, &grid)?;
        Ok(Self { values, grid, bc, _s: PhantomData })
    }

    /// The same grid and boundaries with other values (checked).
    pub fn with_values(&self, values: Tensor) -> Result<Self> {
        check_values::<S>("Field::with_values", &values, &self.grid)?;
        Ok(Self { values, grid: self.grid, bc: self.bc, _s: PhantomData })
    }

    /// Internal constructor for op outputs whose shape is right by construction.
    pub(crate) fn from_parts(values: Tensor, grid: Grid, bc: S::Bc) -> Self {
        Self { values, grid, bc, _s: PhantomData }
    }

    /// The values.
    pub fn values(&self) -> &Tensor {
        &self.values
    }

    /// Consumes the field, returning its values.
    pub fn into_values(self) -> Tensor {
        self.values
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The boundary conditions.
    pub fn bc(&self) -> &S::Bc {
        &self.bc
    }

    /// Batch size.
    pub fn batch(&self) -> usize {
        self.values.dims()[0]
    }
}

fn check_values<S: Staggering>(op: &'static str, values: &Tensor, grid: &Grid) -> Result<()> {
    let d = values.dims();
    let channels_ok = d.len() == 4 && S::CHANNELS.is_none_or(|c| d[1] == c);
    if !channels_ok || d[2] != grid.ny || d[3] != grid.nx {
        let ch = S::CHANNELS.map(|c| c.to_string()).unwrap_or_else(|| "C".into());
        return Err(Error::Shape {
            op,
            arg: "values",
            expected: format!("[batch, {ch}, {}, {}] ({} field on the grid)", grid.ny, grid.nx, S::NAME),
            got: d.to_vec(),
        });
    }
    pbdl_core::error::check_float(op, "values", values)?;
    Ok(())
}

impl CenteredField {
    /// Samples `f(x, y) -> [channels]` at the cell centres (batch 1).
    pub fn from_fn(
        grid: Grid,
        bc: ScalarBoundaries,
        channels: usize,
        dtype: DType,
        f: impl Fn(f64, f64) -> Vec<f64>,
    ) -> Result<Self> {
        let (dx, dy) = (grid.dx(), grid.dy());
        let mut data = vec![0.0; channels * grid.cells()];
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let v = f((i as f64 + 0.5) * dx, (j as f64 + 0.5) * dy);
                for c in 0..channels {
                    data[c * grid.cells() + j * grid.nx + i] = v[c];
                }
            }
        }
        let t = Tensor::from_vec(data, (1, channels, grid.ny, grid.nx), &Device::Cpu)?.to_dtype(dtype)?;
        Self::new(t, grid, bc)
    }
}

impl MacField {
    /// Samples a velocity `f(x, y) -> [vx, vy]` at the faces (batch 1): `u` from `f(..)[0]` at
    /// x-faces, `v` from `f(..)[1]` at y-faces. Stored boundary faces fixed by a wall or an inflow
    /// are then set to their condition's value.
    pub fn from_fn(grid: Grid, bc: Boundaries, dtype: DType, f: impl Fn(f64, f64) -> [f64; 2]) -> Result<Self> {
        let (dx, dy) = (grid.dx(), grid.dy());
        let n = grid.cells();
        let mut data = vec![0.0; 2 * n];
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                data[j * grid.nx + i] = f((i as f64 + 1.0) * dx, (j as f64 + 0.5) * dy)[0];
                data[n + j * grid.nx + i] = f((i as f64 + 0.5) * dx, (j as f64 + 1.0) * dy)[1];
            }
        }
        bc.validate()?;
        let g = bc.mac_ghosts(grid.nx, grid.ny);
        if let Some(v) = g.u_fixed {
            for j in 0..grid.ny {
                data[j * grid.nx + grid.nx - 1] = v;
            }
        }
        if let Some(v) = g.v_fixed {
            for i in 0..grid.nx {
                data[n + (grid.ny - 1) * grid.nx + i] = v;
            }
        }
        let t = Tensor::from_vec(data, (1, 2, grid.ny, grid.nx), &Device::Cpu)?.to_dtype(dtype)?;
        Self::new(t, grid, bc)
    }

    /// A velocity at rest that satisfies the boundary conditions (batch `batch`).
    pub fn zeros(grid: Grid, bc: Boundaries, batch: usize, dtype: DType) -> Result<Self> {
        let one = Self::from_fn(grid, bc, dtype, |_, _| [0.0, 0.0])?;
        let values = one.values.repeat((batch, 1, 1, 1))?;
        Ok(Self::from_parts(values, grid, bc))
    }

    /// The `u` component, `[batch, ny, nx]`.
    pub fn u(&self) -> Result<Tensor> {
        Ok(self.values.narrow(1, 0, 1)?.squeeze(1)?)
    }

    /// The `v` component, `[batch, ny, nx]`.
    pub fn v(&self) -> Result<Tensor> {
        Ok(self.values.narrow(1, 1, 1)?.squeeze(1)?)
    }

    /// Largest speed component, `max(|u|, |v|)` over all faces (for time-step control).
    pub fn max_abs(&self) -> Result<f64> {
        Ok(self.values.abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?)
    }
}
