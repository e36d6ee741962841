//! Sampling a field at its own grid points plus a displacement: the step of semi-Lagrangian
//! advection and of image warping.

use super::boundary::Boundaries;
use super::grid_sample::{sample_op, Kind};
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};

/// Samples `field` at `index_grid + displacement`: `out[b, c, y, x] = field[b, c](x + dx, y + dy)`
/// with `(dx, dy) = displacement[b, :, y, x]` (and likewise with z in 3D), by bilinear or
/// trilinear interpolation.
///
/// * `field`: `[batch, channel, y, x]` or `[batch, channel, z, y, x]`.
/// * `displacement`: `[batch, D, y, x]` or `[batch, D, z, y, x]` with the spatial shape of
///   `field`; component 0 is the x displacement, 1 the y and 2 the z one, in index units (cells).
/// * Returns a tensor of the shape of `field`.
///
/// Semi-Lagrangian advection of a cell-centred quantity with velocity `v` (in cells per unit
/// time) is `warp(q, &(v * -dt)?, boundary)`. Equivalent to [`grid_sample`](super::grid_sample)
/// at the points of [`index_grid`] plus `displacement` (components moved last), but one fused
/// kernel without the points tensor. Differentiable with respect to `field` and `displacement`;
/// see [`grid_sample`](super::grid_sample) for the coordinate conventions, the boundaries and the
/// gradients.
pub fn warp(field: &Tensor, displacement: &Tensor, boundary: impl Into<Boundaries>) -> Result<Tensor> {
    sample_op(Kind::Displacement, field, displacement, boundary.into())
}

/// The coordinates of every grid point of a field with spatial shape `spatial` (`[y, x]` or
/// `[z, y, x]`, as in the field's shape): a `[1, D, spatial...]` tensor whose component 0 is
/// the x index, 1 the y index and 2 the z index.
///
/// Adding a displacement and moving the component axis last gives points for
/// [`grid_sample`](super::grid_sample).
pub fn index_grid(spatial: &[usize], dtype: DType, device: &Device) -> Result<Tensor> {
    if !(spatial.len() == 2 || spatial.len() == 3) {
        return Err(Error::invalid("index_grid", "spatial", format!("expected [y, x] or [z, y, x], got {spatial:?}")));
    }
    let s = spatial.len();
    let mut comps = Vec::with_capacity(s);
    for d in 0..s {
        let axis = s - 1 - d;
        let mut view = vec![1; s];
        view[axis] = spatial[axis];
        let c = Tensor::arange(0u32, spatial[axis] as u32, device)?
            .to_dtype(dtype)?
            .reshape(view)?
            .broadcast_as(spatial)?;
        comps.push(c);
    }
    Ok(Tensor::stack(&comps, 0)?.unsqueeze(0)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_grid_components_are_x_then_y_then_z() {
        let g = index_grid(&[2, 3, 4], DType::F64, &Device::Cpu).unwrap();
        assert_eq!(g.dims(), &[1, 3, 2, 3, 4]);
        let v = g.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let at = |c: usize, z: usize, y: usize, x: usize| v[((c * 2 + z) * 3 + y) * 4 + x];
        assert_eq!((at(0, 1, 2, 3), at(1, 1, 2, 3), at(2, 1, 2, 3)), (3.0, 2.0, 1.0));
        assert_eq!((at(0, 0, 1, 0), at(1, 0, 1, 0), at(2, 0, 1, 0)), (0.0, 1.0, 0.0));
    }
}
