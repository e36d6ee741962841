//! The forward convolution: im2col per tile, then one matrix product per channel group (or the
//! depthwise kernels, or for stride 1 and one group the opt-in implicit path of `implicit.rs`).

use super::backward::{grad_input_tensor, grad_weight_tensor};
use super::depthwise;
use super::epilogue::Epilogue;
use super::geometry::{expect_shape, Geometry};
use super::im2col::Plan;
use super::implicit;
use crate::matmul::{matmul, split, Mat};
use crate::op::{apply2, grad_if_tracked, Kernel2, Op2};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// `y = conv(x, w)` on dense buffers; `y` is overwritten.
///
/// Work is split into (image, group) units; each unit writes its own contiguous block of `y`,
/// so units run in parallel.
pub(crate) fn conv_forward<T: Real>(g: &Geometry, x: &[T], w: &[T], y: &mut [T]) {
    conv_forward_epilogue(g, x, w, None, y)
}

/// [`conv_forward`] followed, tile by tile while the tile is in cache, by adding a bias per
/// output channel and an activation (`epilogue`).
pub(crate) fn conv_forward_epilogue<T: Real>(
    g: &Geometry,
    x: &[T],
    w: &[T],
    epilogue: Option<(&[T], Epilogue)>,
    y: &mut [T],
) {
    if depthwise::handles(g) {
        depthwise::forward(g, x, w, None, y);
        if let (Some((bias, e)), true) = (epilogue, g.out_len() > 0) {
            let out_len = g.out_len();
            let run = |(i, plane): (usize, &mut [T])| e.apply(plane, bias[i % g.c_out]);
            if crate::threads::parallel(y.len()) {
                y.par_chunks_mut(out_len).enumerate().for_each(run);
            } else {
                y.chunks_mut(out_len).enumerate().for_each(run);
            }
        }
        return;
    }
    if implicit::handles(g) {
        return implicit::forward(g, x, w, epilogue, y);
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
            matmul(&mut yu[off..], out_len, false, wg, cols, (cout_g, n, kg), T::one(), par);
            if let Some((bias, e)) = epilogue {
                for (o, row) in yu.chunks_mut(out_len).enumerate() {
                    e.apply(&mut row[off..off + n], bias[grp * cout_g + o]);
                }
            }
        }
    });
}

/// Defines `$op(Geometry)`, the two-input kernel `$name` of a convolution geometry: its inputs
/// must have the geometry's shapes `$a_shape` and `$b_shape` (called `$a` and `$b` in errors),
/// its output has the shape `$out_shape`, and `$kernel(geometry, a, b, out)` fills the output.
macro_rules! conv_kernel2 {
    ($(#[$doc:meta])* $op:ident, $name:literal, $kernel:path, ($a:literal: $a_shape:ident, $b:literal: $b_shape:ident) -> $out_shape:ident) => {
        $(#[$doc])*
        pub(crate) struct $op(pub Geometry);

        impl Kernel2 for $op {
            fn name(&self) -> &'static str {
                $name
            }

            fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
                expect_shape($name, $a, a.dims(), &self.0.$a_shape())?;
                expect_shape($name, $b, b.dims(), &self.0.$b_shape())?;
                Ok(Shape::from(self.0.$out_shape()))
            }

            fn forward<T: Real>(&self, a: &[T], _: &Shape, b: &[T], _: &Shape, out: &mut [T]) -> candle_core::Result<()> {
                $kernel(&self.0, a, b, out);
                Ok(())
            }
        }
    };
}
pub(super) use conv_kernel2;

conv_kernel2! {
    /// The differentiable op `y = conv(x, w)` on tensors.
    ConvForward, "conv", conv_forward, ("input": x_shape, "weight": w_shape) -> y_shape
}

impl Op2 for ConvForward {
    fn backward(&self, x: &Tensor, w: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let gx = grad_if_tracked(x, || grad_input_tensor(&self.0, gy, w))?;
        let gw = grad_if_tracked(w, || grad_weight_tensor(&self.0, x, gy))?;
        Ok((gx, gw))
    }
}

/// `conv(x, w)` on tensors of geometry `g`, differentiable to any order.
pub(crate) fn conv_tensor(g: &Geometry, x: &Tensor, w: &Tensor) -> candle_core::Result<Tensor> {
    apply2(x, w, ConvForward(*g))
}
