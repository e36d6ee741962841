//! Convolution + bias + activation as one op: the bias and a ReLU or LeakyReLU are applied to
//! each output tile right after its matrix product, while it is still in cache.
//!
//! Unfused, a conv layer with bias and activation is three nodes of candle's graph (conv,
//! broadcast add, activation), each with its own output buffer, its own backward pass and, in
//! candle's backward, its own zero-filled gradient accumulator; the bias gradient is a strided
//! reduction over batch and space. Fused it is one node: the backward turns the output
//! gradient into the pre-activation gradient with one pass over the *output* (the activation's
//! derivative is read off `y`, so no pre-activation buffer is kept), sums it per channel for
//! the bias, and hands it to the two convolution adjoints.
//!
//! The derivative at a pre-activation of exactly 0 is described in `crate::nn::epilogue`.

use super::backward::{grad_input_tensor, grad_weight_tensor};
use super::forward::conv_forward_epilogue;
use super::geometry::{expect_shape, Geometry};
pub(crate) use crate::nn::epilogue::Epilogue;
use crate::op::{apply1, apply2, apply3, grad_if_tracked, Kernel1, Kernel2, Kernel3, Op1, Op2, Op3};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// The op `y = act(conv(x, w) + b)`.
struct ConvBiasAct {
    geo: Geometry,
    epilogue: Epilogue,
}

impl Kernel3 for ConvBiasAct {
    fn name(&self) -> &'static str {
        "conv_bias_act"
    }

    fn output_shape(&self, x: &Shape, w: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        expect_shape("conv_bias_act", "input", x.dims(), &self.geo.x_shape())?;
        expect_shape("conv_bias_act", "weight", w.dims(), &self.geo.w_shape())?;
        expect_shape("conv_bias_act", "bias", b.dims(), &[self.geo.c_out])?;
        Ok(Shape::from(self.geo.y_shape()))
    }

    #[allow(clippy::too_many_arguments)]
    fn forward<T: Real>(
        &self,
        x: &[T],
        _: &Shape,
        w: &[T],
        _: &Shape,
        b: &[T],
        _: &Shape,
        y: &mut [T],
    ) -> candle_core::Result<()> {
        conv_forward_epilogue(&self.geo, x, w, Some((b, self.epilogue)), y);
        Ok(())
    }
}

impl Op3 for ConvBiasAct {
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        b: &Tensor,
        y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let g_pre = self.epilogue.pre_activation_grad(y, gy)?;
        let gx = grad_if_tracked(x, || grad_input_tensor(&self.geo, &g_pre, w))?;
        let gw = grad_if_tracked(w, || grad_weight_tensor(&self.geo, x, &g_pre))?;
        let gb = grad_if_tracked(b, || apply1(&g_pre, ChannelSum))?;
        Ok((gx, gw, gb))
    }
}

/// Per-channel sums of `[batch, channel, spatial...]`: the bias gradient. Each channel is
/// summed by one thread in a fixed order, so the result does not depend on scheduling.
struct ChannelSum;

impl Kernel1 for ChannelSum {
    fn name(&self) -> &'static str {
        "conv_bias_grad"
    }

    fn output_shape(&self, g: &Shape) -> candle_core::Result<Shape> {
        if g.rank() < 2 {
            candle_core::bail!("conv_bias_grad: expected [batch, channel, ...], got {:?}", g.dims());
        }
        Ok(Shape::from(g.dims()[1]))
    }

    fn forward<T: Real>(&self, g: &[T], shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let dims = shape.dims();
        let (batch, channels) = (dims[0], dims[1]);
        let spatial: usize = dims[2..].iter().product();
        let sum = |(c, o): (usize, &mut T)| {
            let mut acc = T::zero();
            for b in 0..batch {
                acc += g[(b * channels + c) * spatial..][..spatial].iter().copied().sum::<T>();
            }
            *o = acc;
        };
        if crate::threads::parallel(g.len()) {
            out.par_iter_mut().enumerate().for_each(sum);
        } else {
            out.iter_mut().enumerate().for_each(sum);
        }
        Ok(())
    }
}

impl Op1 for ChannelSum {
    fn backward(&self, g: &Tensor, _out: &Tensor, gg: &Tensor) -> candle_core::Result<Tensor> {
        let mut shape = vec![1; g.rank()];
        shape[1] = g.dim(1)?;
        gg.reshape(shape)?.broadcast_as(g.shape())?.contiguous()
    }
}

/// The op `y = act(z + b)` for `z` `[batch, channel, spatial...]` and `b` `[channel]`: the
/// epilogue on its own, for outputs that are not made by [`ConvBiasAct`] (transposed
/// convolutions).
struct BiasAct(Epilogue);

impl Kernel2 for BiasAct {
    fn name(&self) -> &'static str {
        "bias_act"
    }

    fn output_shape(&self, z: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        if z.rank() < 2 {
            candle_core::bail!("bias_act: expected [batch, channel, ...], got {:?}", z.dims());
        }
        expect_shape("bias_act", "bias", b.dims(), &[z.dims()[1]])?;
        Ok(z.clone())
    }

    fn forward<T: Real>(&self, z: &[T], shape: &Shape, b: &[T], _: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        let spatial: usize = shape.dims()[2..].iter().product();
        let channels = b.len();
        y.copy_from_slice(z);
        let e = self.0;
        let run = |(i, plane): (usize, &mut [T])| e.apply(plane, b[i % channels]);
        if spatial > 0 && crate::threads::parallel(y.len()) {
            y.par_chunks_mut(spatial).enumerate().for_each(run);
        } else if spatial > 0 {
            y.chunks_mut(spatial).enumerate().for_each(run);
        }
        Ok(())
    }
}

impl Op2 for BiasAct {
    fn backward(&self, _z: &Tensor, b: &Tensor, y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let g_pre = self.0.pre_activation_grad(y, gy)?;
        let gb = grad_if_tracked(b, || apply1(&g_pre, ChannelSum))?;
        Ok((g_pre, gb))
    }
}

/// `act(z + b)` per channel as one op (CPU, `f32`/`f64`, checked by the caller).
pub(crate) fn bias_act_tensor(z: &Tensor, bias: &Tensor, epilogue: Epilogue) -> candle_core::Result<Tensor> {
    apply2(z, bias, BiasAct(epilogue))
}

/// `act(conv(x, w) + b)` as one op on tensors of geometry `geo` (CPU, `f32`/`f64`, checked by
/// the caller). `bias` `None` adds nothing (a constant zero bias, which gets no gradient).
pub(crate) fn conv_bias_act_tensor(
    geo: &Geometry,
    x: &Tensor,
    w: &Tensor,
    bias: Option<&Tensor>,
    epilogue: Epilogue,
) -> candle_core::Result<Tensor> {
    let zeros;
    let b = match bias {
        Some(b) => b,
        None => {
            zeros = Tensor::zeros(geo.c_out, x.dtype(), x.device())?;
            &zeros
        }
    };
    apply3(x, w, b, ConvBiasAct { geo: *geo, epilogue })
}
