//! The two adjoints of a convolution, each a differentiable op itself:
//!
//! * `grad_input(gy, w)`: the gradient with respect to the input, a transposed convolution
//!   (`W^T gy` per tile, then col2im; without col2im on the implicit path, `implicit.rs`);
//! * `grad_weight(x, gy)`: the gradient with respect to the weight, `sum_b gy_b col(x_b)^T`.
//!
//! Both are bilinear, and with `conv` they form a closed family under differentiation:
//! `<ggx, grad_input(gy, w)> = <conv(ggx, w), gy>` and
//! `<ggw, grad_weight(x, gy)> = <conv(x, ggw), gy>`, so second derivatives come for free.

use super::depthwise;
use super::forward::{conv_kernel2, conv_tensor};
use super::geometry::{expect_shape, Geometry};
use super::im2col::Plan;
use super::implicit;
use crate::matmul::{matmul, split, Mat};
use crate::op::{apply2, grad_if_tracked, Kernel2, Op2};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// `gx = grad_input(gy, w)` on dense buffers; `gx` must be zero on entry.
///
/// Each (image, group) unit owns a contiguous block of `gx`, so units run in parallel; the
/// tiles of one unit overlap in `gx` and run one after the other.
pub(crate) fn conv_grad_input<T: Real>(g: &Geometry, gy: &[T], w: &[T], gx: &mut [T]) {
    if depthwise::handles(g) {
        return depthwise::grad_input(g, gy, w, gx);
    }
    if implicit::handles(g) {
        return implicit::grad_input(g, gy, w, gx);
    }
    let (cin_g, cout_g, kg) = (g.cin_g(), g.cout_g(), g.k_len());
    let (in_len, out_len, ow) = (g.in_len(), g.out_len(), g.output[2]);
    let units = g.batch * g.groups;
    let unit_len = cin_g * in_len;
    if units == 0 || unit_len == 0 {
        return;
    }
    let plan = Plan::new::<T>(g);
    let pointwise = g.pointwise();
    let (_, par) = split(units);
    let scratch = || if pointwise { Vec::new() } else { vec![T::zero(); plan.tile_len()] };
    gx.par_chunks_mut(unit_len).enumerate().for_each_init(scratch, |col, (u, gxu)| {
        let (b, grp) = (u / g.groups, u % g.groups);
        let gyg = &gy[(b * g.c_out + grp * cout_g) * out_len..][..cout_g * out_len];
        // W_g^T: element (tap, o) of the group's [cout_g, kg] block.
        let wt = Mat { data: &w[grp * cout_g * kg..][..cout_g * kg], rs: 1, cs: kg };
        for lines in plan.tiles() {
            let (off, n) = (lines.start * ow, lines.len() * ow);
            let gy_tile = Mat { data: &gyg[off..], rs: out_len, cs: 1 };
            if pointwise {
                matmul(&mut gxu[off..], in_len, false, wt, gy_tile, (kg, n, cout_g), T::one(), par);
            } else {
                matmul(col, n, false, wt, gy_tile, (kg, n, cout_g), T::one(), par);
                plan.col2im(col, &lines, gxu);
            }
        }
    });
}

/// `gw = grad_weight(x, gy)` on dense buffers; `gw` is overwritten.
///
/// Units are split into one contiguous range per thread; each range sums into its own
/// accumulator and the accumulators are added in order, so the result does not depend on
/// scheduling.
pub(crate) fn conv_grad_weight<T: Real>(g: &Geometry, x: &[T], gy: &[T], gw: &mut [T]) {
    if depthwise::handles(g) {
        return depthwise::grad_weight(g, x, gy, gw);
    }
    if implicit::handles(g) {
        return implicit::grad_weight(g, x, gy, gw);
    }
    let (cin_g, cout_g, kg) = (g.cin_g(), g.cout_g(), g.k_len());
    let (in_len, out_len, ow) = (g.in_len(), g.out_len(), g.output[2]);
    let units = g.batch * g.groups;
    gw.fill(T::zero());
    if units == 0 || gw.is_empty() {
        return;
    }
    let plan = Plan::new::<T>(g);
    let pointwise = g.pointwise();
    let (chunks, par) = split(units);
    let per = units.div_ceil(chunks);
    let partials: Vec<Vec<T>> = (0..chunks)
        .into_par_iter()
        .map(|ci| {
            let mut acc = vec![T::zero(); gw.len()];
            let mut col = if pointwise { Vec::new() } else { vec![T::zero(); plan.tile_len()] };
            for u in ci * per..((ci + 1) * per).min(units) {
                let (b, grp) = (u / g.groups, u % g.groups);
                let xg = &x[(b * g.c_in + grp * cin_g) * in_len..][..cin_g * in_len];
                let gyg = &gy[(b * g.c_out + grp * cout_g) * out_len..][..cout_g * out_len];
                let gwg = &mut acc[grp * cout_g * kg..][..cout_g * kg];
                for lines in plan.tiles() {
                    let (off, n) = (lines.start * ow, lines.len() * ow);
                    // col^T: element (position, tap).
                    let col_t = if pointwise {
                        Mat { data: &xg[off..], rs: 1, cs: in_len }
                    } else {
                        plan.im2col(xg, &lines, &mut col);
                        Mat { data: &col, rs: 1, cs: n }
                    };
                    let gy_tile = Mat { data: &gyg[off..], rs: out_len, cs: 1 };
                    matmul(gwg, kg, true, gy_tile, col_t, (cout_g, kg, n), T::one(), par);
                }
            }
            acc
        })
        .collect();
    for p in partials {
        gw.iter_mut().zip(&p).for_each(|(a, &b)| *a += b);
    }
}

conv_kernel2! {
    /// The differentiable op `gx = grad_input(gy, w)` on tensors.
    ConvGradInput, "conv_grad_input", conv_grad_input, ("grad_output": y_shape, "weight": w_shape) -> x_shape
}

impl Op2 for ConvGradInput {
    fn backward(&self, gy: &Tensor, w: &Tensor, _gx: &Tensor, ggx: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let d_gy = grad_if_tracked(gy, || conv_tensor(&self.0, ggx, w))?;
        let d_w = grad_if_tracked(w, || grad_weight_tensor(&self.0, ggx, gy))?;
        Ok((d_gy, d_w))
    }
}

conv_kernel2! {
    /// The differentiable op `gw = grad_weight(x, gy)` on tensors.
    ConvGradWeight, "conv_grad_weight", conv_grad_weight, ("input": x_shape, "grad_output": y_shape) -> w_shape
}

impl Op2 for ConvGradWeight {
    fn backward(&self, x: &Tensor, gy: &Tensor, _gw: &Tensor, ggw: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let d_x = grad_if_tracked(x, || grad_input_tensor(&self.0, gy, ggw))?;
        let d_gy = grad_if_tracked(gy, || conv_tensor(&self.0, x, ggw))?;
        Ok((d_x, d_gy))
    }
}

/// `grad_input(gy, w)` on tensors of geometry `g`.
pub(crate) fn grad_input_tensor(g: &Geometry, gy: &Tensor, w: &Tensor) -> candle_core::Result<Tensor> {
    apply2(gy, w, ConvGradInput(*g))
}

/// `grad_weight(x, gy)` on tensors of geometry `g`.
pub(crate) fn grad_weight_tensor(g: &Geometry, x: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
    apply2(x, gy, ConvGradWeight(*g))
}
