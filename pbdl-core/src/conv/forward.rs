//! The forward convolution: im2col per tile, then one matrix product per channel group.

use super::backward::{grad_input_tensor, grad_weight_tensor};
use super::depthwise;
use super::geometry::{expect_shape, Geometry};
use super::im2col::Plan;
use super::matmul::{matmul, split, Mat};
use crate::op::{apply2, Kernel2, Op2};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// `y = conv(x, w)` on dense buffers; `y` is overwritten.
///
/// Work is split into (image, group) units; each unit writes its own contiguous block of `y`,
/// so units run in parallel.
pub(crate) fn conv_forward<T: Real>(g: &Geometry, x: &[T], w: &[T], y: &mut [T]) {
    if depthwise::handles(g) {
        return depthwise::forward(g, x, w, None, y);
    }
    let (cin_g, cout_g, kg) = (g.cin_g(), g.cout_g(), g.k_len());
    let (in_len, out_len, ow) = (g.in_len(), g.out_len(), g.output[2]);
    let units = g.batch * g.groups;
    let unit_len = cout_g * out_len;
    if units == 0 || unit_len == 0 {
        return;
    }
    let plan = Plan::new::<T>(g);
    let pointwise = g.pointwise();
    let (_, par) = split(units);
    // One scratch tile per rayon job, reused for its units and tiles.
    let scratch = || if pointwise { Vec::new() } else { vec![T::zero(); plan.tile_len()] };
    y.par_chunks_mut(unit_len).enumerate().for_each_init(scratch, |col, (u, yu)| {
        let (b, grp) = (u / g.groups, u % g.groups);
        let xg = &x[(b * g.c_in + grp * cin_g) * in_len..][..cin_g * in_len];
        let wg = Mat { data: &w[grp * cout_g * kg..][..cout_g * kg], rs: kg, cs: 1 };
        for lines in plan.tiles() {
            let (off, n) = (lines.start * ow, lines.len() * ow);
            let cols = if pointwise {
                Mat { data: &xg[off..], rs: in_len, cs: 1 }
            } else {
                plan.im2col(xg, &lines, col);
                Mat { data: col.as_slice(), rs: n, cs: 1 }
            };
            matmul(&mut yu[off..], out_len, false, wg, cols, (cout_g, n, kg), par);
        }
    });
}

/// The differentiable op `y = conv(x, w)` on tensors.
pub(crate) struct ConvForward(pub Geometry);

impl Kernel2 for ConvForward {
    fn name(&self) -> &'static str {
        "conv"
    }

    fn output_shape(&self, x: &Shape, w: &Shape) -> candle_core::Result<Shape> {
        expect_shape("conv", "input", x.dims(), &self.0.x_shape())?;
        expect_shape("conv", "weight", w.dims(), &self.0.w_shape())?;
        Ok(Shape::from(self.0.y_shape()))
    }

    fn forward<T: Real>(&self, x: &[T], _: &Shape, w: &[T], _: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        conv_forward(&self.0, x, w, y);
        Ok(())
    }
}

impl Op2 for ConvForward {
    fn backward(&self, x: &Tensor, w: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gx = if x.track_op() { grad_input_tensor(&self.0, gy, w)? } else { zeros_like(x)? };
        let gw = if w.track_op() { grad_weight_tensor(&self.0, x, gy)? } else { zeros_like(w)? };
        Ok((gx, gw))
    }
}

/// `conv(x, w)` on tensors of geometry `g`, differentiable to any order.
pub(crate) fn conv_tensor(g: &Geometry, x: &Tensor, w: &Tensor) -> candle_core::Result<Tensor> {
    apply2(x, w, ConvForward(*g))
}

/// An explicit zero gradient for an input that does not track gradients, without allocating
/// its full size (nobody can read it, but candle expects a tensor).
pub(crate) fn zeros_like(t: &Tensor) -> candle_core::Result<Tensor> {
    Tensor::zeros((), t.dtype(), t.device())?.broadcast_as(t.shape())
}
