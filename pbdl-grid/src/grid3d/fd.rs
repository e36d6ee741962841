//! Divergence and gradient on the periodic 3D MAC grid, as differentiable custom ops.
//!
//! With periodic wrap the two are exact negative transposes of each other (`D^T = -G`, axis by
//! axis), so each one's backward is the other one, negated; `D G` is the seven-point Laplacian
//! whose eigenvalues the FFT solve divides by.

use super::field::{check_values, MacField3d};
use super::periodic::{self, inv_spacing, Periodic};
use super::Grid3d;
use crate::Result;
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, Kernel1, Op1};
use pbdl_core::Real;

/// `div u` at cell centres: `[batch, 1, nz, ny, nx]`. Differentiable.
pub fn divergence(u: &MacField3d) -> Result<Tensor> {
    Ok(apply1(u.values(), Div3d(*u.grid()))?)
}

/// `grad s` on the faces of the MAC grid (forward differences) for a cell-centred scalar
/// `s` (`[batch, 1, nz, ny, nx]`). Differentiable.
pub fn gradient(s: &Tensor, grid: &Grid3d) -> Result<MacField3d> {
    grid.validate()?;
    check_values("grid3d::gradient", "s", s, grid, Some(1))?;
    Ok(MacField3d::from_parts(apply1(s, Grad3d(*grid))?, *grid))
}

/// Divergence op; input `[b, 3, ...]`, output `[b, 1, ...]`.
#[derive(Clone, Copy)]
struct Div3d(Grid3d);

/// Gradient op; input `[b, 1, ...]`, output `[b, 3, ...]`.
#[derive(Clone, Copy)]
struct Grad3d(Grid3d);

fn with_channels(s: &Shape, from: usize, to: usize, op: &str) -> candle_core::Result<Shape> {
    let d = s.dims();
    if d.len() != 5 || d[1] != from {
        candle_core::bail!("{op}: expected [batch, {from}, nz, ny, nx], got {d:?}");
    }
    Ok(Shape::from(vec![d[0], to, d[2], d[3], d[4]]))
}

impl Kernel1 for Div3d {
    fn name(&self) -> &'static str {
        "grid3d_divergence"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        with_channels(s, 3, 1, self.name())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let p = Periodic::new(&self.0);
        let n = p.cells();
        for (xb, ob) in x.chunks(3 * n).zip(out.chunks_mut(n)) {
            periodic::divergence(&p, xb, inv_spacing(&self.0), ob);
        }
        Ok(())
    }
}

impl Op1 for Div3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply1(gy, Grad3d(self.0))?.neg()
    }
}

impl Kernel1 for Grad3d {
    fn name(&self) -> &'static str {
        "grid3d_gradient"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        with_channels(s, 1, 3, self.name())
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let p = Periodic::new(&self.0);
        let n = p.cells();
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(3 * n)) {
            periodic::gradient(&p, xb, inv_spacing(&self.0), ob);
        }
        Ok(())
    }
}

impl Op1 for Grad3d {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply1(gy, Div3d(self.0))?.neg()
    }
}
