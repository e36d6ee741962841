//! A periodic 3D MAC velocity: `[batch, 3, nz, ny, nx]`, `u` on x-faces at
//! `((i + 1) dx, (j + 1/2) dy, (k + 1/2) dz)`, `v` on y-faces at `((i + 1/2) dx, (j + 1) dy,
//! (k + 1/2) dz)`, `w` on z-faces at `((i + 1/2) dx, (j + 1/2) dy, (k + 1) dz)`.
//!
//! Every face of the box is periodic, so each stored face is an unknown (no boundary faces).

use super::Grid3d;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};

/// A staggered velocity on a periodic [`Grid3d`].
#[derive(Clone, Debug)]
pub struct MacField3d {
    values: Tensor,
    grid: Grid3d,
}

impl MacField3d {
    /// Refuses a field that lives on another grid than the stepper's (`grid`).
    pub(crate) fn check_stepper_grid(&self, grid: &Grid3d) -> Result<()> {
        if &self.grid != grid {
            return Err(Error::Invalid {
                field: "u",
                reason: format!("the field lives on {:?}; the stepper was built for {grid:?}", self.grid),
            });
        }
        Ok(())
    }

    /// Wraps `values` (`[batch, 3, nz, ny, nx]`, f32 or f64) after checking it against `grid`.
    pub fn new(values: Tensor, grid: Grid3d) -> Result<Self> {
        grid.validate()?;
        check_values("MacField3d::new", "values", &values, &grid, Some(3))?;
        Ok(Self { values, grid })
    }

    /// Builds from already-checked parts (internal: ops whose output shape equals their input's).
    pub(crate) fn from_parts(values: Tensor, grid: Grid3d) -> Self {
        Self { values, grid }
    }

    /// Samples `f(x, y, z) -> [u, v, w]` at each component's own faces (batch 1).
    pub fn from_fn(grid: Grid3d, dtype: DType, f: impl Fn(f64, f64, f64) -> [f64; 3]) -> Result<Self> {
        grid.validate()?;
        if !matches!(dtype, DType::F32 | DType::F64) {
            return Err(Error::Invalid { field: "dtype", reason: format!("use f32 or f64, got {dtype:?}") });
        }
        let [dx, dy, dz] = grid.spacing();
        let n = grid.cells();
        let mut data = vec![0.0f64; 3 * n];
        for c in 0..3 {
            // Face centres: shifted by half a cell along the component's own axis.
            let shift = [(c == 0) as usize as f64, (c == 1) as usize as f64, (c == 2) as usize as f64];
            for k in 0..grid.nz {
                for j in 0..grid.ny {
                    for i in 0..grid.nx {
                        let x = (i as f64 + 0.5 + 0.5 * shift[0]) * dx;
                        let y = (j as f64 + 0.5 + 0.5 * shift[1]) * dy;
                        let z = (k as f64 + 0.5 + 0.5 * shift[2]) * dz;
                        data[c * n + (k * grid.ny + j) * grid.nx + i] = f(x, y, z)[c];
                    }
                }
            }
        }
        let t = Tensor::from_vec(data, grid.shape(1, 3).to_vec(), &Device::Cpu)?.to_dtype(dtype)?;
        Ok(Self { values: t, grid })
    }

    /// Zero velocity, `batch` samples.
    pub fn zeros(grid: Grid3d, batch: usize, dtype: DType) -> Result<Self> {
        Self::new(Tensor::zeros(grid.shape(batch, 3).to_vec(), dtype, &Device::Cpu)?, grid)
    }

    /// The same grid with other values (checked).
    pub fn with_values(&self, values: Tensor) -> Result<Self> {
        Self::new(values, self.grid)
    }

    /// The values `[batch, 3, nz, ny, nx]`.
    pub fn values(&self) -> &Tensor {
        &self.values
    }

    /// The values, consuming the field.
    pub fn into_values(self) -> Tensor {
        self.values
    }

    /// The grid.
    pub fn grid(&self) -> &Grid3d {
        &self.grid
    }

    /// Batch size.
    pub fn batch(&self) -> usize {
        self.values.dims()[0]
    }

    /// `[max |u|, max |v|, max |w|]` over the batch; a typed error when a value is not finite.
    pub fn max_abs_components(&self) -> Result<[f64; 3]> {
        let a = self.values.abs()?;
        // A max skips NaN (comparisons with NaN are false); a sum propagates NaN and Inf.
        let total = a.sum_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        if !total.is_finite() {
            return Err(Error::NonFinite { what: "velocity", value: total });
        }
        let m = a.max_keepdim(4)?.max_keepdim(3)?.max_keepdim(2)?.max_keepdim(0)?;
        let m = m.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
        Ok([m[0], m[1], m[2]])
    }
}

/// Checks a tensor on `grid`: rank 5, `[batch, channels, nz, ny, nx]`, f32/f64, CPU.
pub(crate) fn check_values(
    op: &'static str,
    arg: &'static str,
    t: &Tensor,
    grid: &Grid3d,
    channels: Option<usize>,
) -> Result<()> {
    let d = t.dims();
    let ok_rank = d.len() == 5 && d[0] >= 1 && d[2] == grid.nz && d[3] == grid.ny && d[4] == grid.nx;
    let ok_ch = d.len() == 5 && channels.is_none_or(|c| d[1] == c);
    if !(ok_rank && ok_ch) {
        let ch = channels.map_or("channels".to_string(), |c| c.to_string());
        return Err(Error::Shape {
            op,
            arg,
            expected: format!("[batch, {ch}, {}, {}, {}] (nz, ny, nx of the grid)", grid.nz, grid.ny, grid.nx),
            got: d.to_vec(),
        });
    }
    if !matches!(t.dtype(), DType::F32 | DType::F64) {
        return Err(Error::Invalid { field: arg, reason: format!("use f32 or f64, got {:?}", t.dtype()) });
    }
    if !t.device().is_cpu() {
        return Err(Error::Invalid { field: arg, reason: "pbdl-grid kernels run on the CPU; move it there".into() });
    }
    Ok(())
}
