//! Activation epilogues of fused kernels: ReLU and LeakyReLU (positive slope) applied to a
//! kernel's output in place, and their backward, which reads the derivative off the output so
//! no pre-activation buffer is kept. Used by the fused convolution and the fused group norm;
//! the batch norm kernel shares the type but keeps its pre-activation (see
//! [`Epilogue::of_with_pre_activation`]).
//!
//! The derivative at a pre-activation of exactly 0: LeakyReLU (slope > 0, so the output is 0
//! only there) uses the mean of both slopes, like [`super::activation::leaky_relu`]; ReLU
//! cannot tell 0 from a negative value from its output and uses 0 (PyTorch's rule; pbdl's
//! unfused [`super::activation::relu`] uses candle's 1).

use super::Activation;
use crate::op::{apply2, zeros_like, Kernel2, Op2};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// What a fused kernel applies to its output: a bias per channel and an activation whose
/// derivative can be read off the output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Epilogue {
    /// Bias only.
    Identity,
    /// `max(v, 0)`.
    Relu,
    /// `v` for `v > 0`, `slope v` otherwise (`slope > 0` when built by [`Epilogue::of`]).
    LeakyRelu(f64),
}

impl Epilogue {
    /// The epilogue computing `act`, or `None` when `act` cannot be fused (its derivative is
    /// not a function of its output).
    pub(crate) fn of(act: Activation) -> Option<Self> {
        match act {
            Activation::Identity => Some(Self::Identity),
            Activation::Relu => Some(Self::Relu),
            // A slope that is a normal positive f32 keeps the output's sign equal to the
            // pre-activation's (no 0 * inf, no slope rounding to 0).
            Activation::LeakyRelu { negative_slope }
                if negative_slope > 0.0 && negative_slope.is_finite() && (negative_slope as f32).is_normal() =>
            {
                Some(Self::LeakyRelu(negative_slope))
            }
            _ => None,
        }
    }

    /// The epilogue computing `act` in a kernel that keeps its pre-activation and
    /// differentiates with it (batch norm): any LeakyReLU slope, or `None` for activations
    /// the kernel has no form of.
    pub(crate) fn of_with_pre_activation(act: Activation) -> Option<Self> {
        match act {
            Activation::LeakyRelu { negative_slope } => Some(Self::LeakyRelu(negative_slope)),
            a => Self::of(a),
        }
    }

    /// The gradient with respect to the pre-activation, from the kernel's output `y` and the
    /// output gradient `gy` (differentiable again).
    pub(crate) fn pre_activation_grad(self, y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Self::Identity => Ok(gy.clone()),
            e => apply2(y, gy, ActGrad(e)),
        }
    }

    /// Adds `bias` to every element of `row` and applies the activation, in place; the same
    /// operations in the same order as the unfused broadcast add and activation.
    #[inline(always)]
    pub(crate) fn apply<T: Real>(self, row: &mut [T], bias: T) {
        match self {
            Self::Identity => row.iter_mut().for_each(|v| *v += bias),
            Self::Relu => row.iter_mut().for_each(|v| {
                let u = *v + bias;
                *v = if u > T::zero() { u } else { T::zero() };
            }),
            Self::LeakyRelu(slope) => {
                let s = T::c(slope);
                row.iter_mut().for_each(|v| {
                    let u = *v + bias;
                    *v = if u > T::zero() { u } else { u * s };
                });
            }
        }
    }

    /// Applies the activation alone to every element of `row`, in place.
    #[inline(always)]
    pub(crate) fn activate<T: Real>(self, row: &mut [T]) {
        match self {
            Self::Identity => {}
            Self::Relu => row.iter_mut().for_each(|v| *v = if *v > T::zero() { *v } else { T::zero() }),
            Self::LeakyRelu(slope) => {
                let s = T::c(slope);
                row.iter_mut().for_each(|v| *v = if *v > T::zero() { *v } else { *v * s });
            }
        }
    }

    /// `gy` times the activation's derivative, read off the output `y`.
    #[inline(always)]
    pub(crate) fn grad<T: Real>(self, y: T, gy: T) -> T {
        match self {
            Self::Identity => gy,
            // A product, not a select: a NaN or infinite upstream gradient stays visible.
            Self::Relu => {
                if y > T::zero() {
                    gy
                } else {
                    gy * T::zero()
                }
            }
            Self::LeakyRelu(slope) => {
                let s = T::c(slope);
                if y > T::zero() {
                    gy
                } else if y < T::zero() {
                    gy * s
                } else {
                    let half = T::c(0.5);
                    gy * half + gy * s * half
                }
            }
        }
    }
}

/// `gy * act'(y)` elementwise. Linear in `gy`, piecewise constant in `y`, so differentiable
/// again: `d/dgy` is the same op, `d/dy` is zero.
struct ActGrad(Epilogue);

impl Kernel2 for ActGrad {
    fn name(&self) -> &'static str {
        "activation_grad"
    }

    fn output_shape(&self, y: &Shape, gy: &Shape) -> candle_core::Result<Shape> {
        if gy.dims() != y.dims() {
            candle_core::bail!("activation_grad: gradient {:?} and output {:?} differ", gy.dims(), y.dims());
        }
        Ok(y.clone())
    }

    fn forward<T: Real>(&self, y: &[T], _: &Shape, gy: &[T], _: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let e = self.0;
        let run = |((o, y), gy): ((&mut [T], &[T]), &[T])| {
            for ((o, &y), &gy) in o.iter_mut().zip(y).zip(gy) {
                *o = e.grad(y, gy);
            }
        };
        const CHUNK: usize = 1 << 15;
        if crate::threads::parallel(out.len()) {
            out.par_chunks_mut(CHUNK).zip(y.par_chunks(CHUNK)).zip(gy.par_chunks(CHUNK)).for_each(run);
        } else {
            run(((out, y), gy));
        }
        Ok(())
    }
}

impl Op2 for ActGrad {
    fn backward(&self, y: &Tensor, _gy: &Tensor, _out: &Tensor, gg: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        Ok((zeros_like(y)?, apply2(y, gg, ActGrad(self.0))?))
    }
}
