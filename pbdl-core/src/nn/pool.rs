//! Max pooling with any kernel and stride, with a backward.
//!
//! candle 0.11's `max_pool2d_with_stride` has no backward when the kernel differs from the stride
//! (LSiM pools with kernel 4, stride 2), and where it has one (kernel = stride = 2) the input
//! gradient is 4x too small (`tests/nn_tests.rs` asserts the gap, so a fixed candle shows up). [`max_pool2d`] follows PyTorch's `MaxPool2d` without
//! padding (floor mode): output size `(n - k) / s + 1`; within a window the first maximum in
//! row-major order wins, and the backward sends each output gradient to that element.

use crate::error::{check_float, Error, Result};
use crate::op::{apply1, apply_kernel2, Kernel1, Kernel2, Op1};
use crate::Real;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

/// 2D max pooling of `x` `[batch, channel, y, x]` with a square `kernel` and `stride`, no padding.
///
/// Differentiable in `x`. Errors: a rank other than 4, a zero kernel or stride, a kernel larger
/// than the input, a dtype other than `f32`/`f64`.
pub fn max_pool2d(x: &Tensor, kernel: usize, stride: usize) -> Result<Tensor> {
    const OP: &str = "max_pool2d";
    if x.rank() != 4 {
        return Err(Error::Shape {
            op: OP,
            arg: "x",
            expected: "[batch, channel, y, x]".into(),
            got: x.dims().to_vec(),
        });
    }
    if kernel == 0 || stride == 0 {
        return Err(Error::invalid(OP, "kernel", format!("kernel {kernel} and stride {stride} must be >= 1")));
    }
    let (h, w) = (x.dim(2)?, x.dim(3)?);
    if h < kernel || w < kernel {
        return Err(Error::Shape {
            op: OP,
            arg: "x",
            expected: format!("spatial size >= the kernel {kernel}"),
            got: x.dims().to_vec(),
        });
    }
    check_float(OP, "x", x)?;
    Ok(apply1(x, MaxPool { kernel, stride })?)
}

#[derive(Clone, Copy)]
struct MaxPool {
    kernel: usize,
    stride: usize,
}

impl MaxPool {
    fn out_size(&self, n: usize) -> usize {
        (n - self.kernel) / self.stride + 1
    }

    /// Flat index (within one `h x w` plane) of the first maximum of output `(oy, ox)`.
    fn argmax<T: Real>(&self, plane: &[T], w: usize, oy: usize, ox: usize) -> usize {
        let (y0, x0) = (oy * self.stride, ox * self.stride);
        let mut best = y0 * w + x0;
        for y in y0..y0 + self.kernel {
            for x in x0..x0 + self.kernel {
                let i = y * w + x;
                // A NaN wins, as in PyTorch.
                if plane[i] > plane[best] || plane[i].is_nan() {
                    best = i;
                }
            }
        }
        best
    }
}

impl Kernel1 for MaxPool {
    fn name(&self) -> &'static str {
        "max_pool2d"
    }

    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        let d = input.dims();
        Ok(Shape::from((d[0], d[1], self.out_size(d[2]), self.out_size(d[3]))))
    }

    fn forward<T: Real>(&self, x: &[T], x_shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let d = x_shape.dims();
        let (h, w) = (d[2], d[3]);
        let (oh, ow) = (self.out_size(h), self.out_size(w));
        out.par_chunks_mut(oh * ow).zip(x.par_chunks(h * w)).for_each(|(o, plane)| {
            for oy in 0..oh {
                for ox in 0..ow {
                    o[oy * ow + ox] = plane[self.argmax(plane, w, oy, ox)];
                }
            }
        });
        Ok(())
    }
}

impl Op1 for MaxPool {
    fn backward(&self, x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel2(x, grad_y, MaxPoolBackward(*self))
    }
}

/// Scatters the output gradient onto the argmax of each window (forward-only kernel).
struct MaxPoolBackward(MaxPool);

impl Kernel2 for MaxPoolBackward {
    fn name(&self) -> &'static str {
        "max_pool2d_backward"
    }

    fn output_shape(&self, x: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        Ok(x.clone())
    }

    fn forward<T: Real>(
        &self,
        x: &[T],
        x_shape: &Shape,
        g: &[T],
        _gs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let p = self.0;
        let d = x_shape.dims();
        let (h, w) = (d[2], d[3]);
        let (oh, ow) = (p.out_size(h), p.out_size(w));
        out.par_chunks_mut(h * w).zip(x.par_chunks(h * w)).zip(g.par_chunks(oh * ow)).for_each(|((dx, plane), g)| {
            for oy in 0..oh {
                for ox in 0..ow {
                    dx[p.argmax(plane, w, oy, ox)] += g[oy * ow + ox];
                }
            }
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{check_grad, seed, GradCheckOptions};
    use candle_core::{DType, Device};

    #[test]
    fn matches_candle_where_candle_works_and_has_a_gradient_where_it_does_not() {
        let x = seed::randn((2, 3, 9, 9), 0.0, 1.0, DType::F64, &Device::Cpu, 3).unwrap();
        let ours = max_pool2d(&x, 3, 3).unwrap();
        let theirs = x.max_pool2d_with_stride(3, 3).unwrap();
        assert_eq!(
            ours.flatten_all().unwrap().to_vec1::<f64>().unwrap(),
            theirs.flatten_all().unwrap().to_vec1::<f64>().unwrap()
        );
        let ours = max_pool2d(&x, 4, 2).unwrap();
        let theirs = x.max_pool2d_with_stride(4, 2).unwrap();
        assert_eq!(ours.dims(), &[2, 3, 3, 3]);
        assert_eq!(
            ours.flatten_all().unwrap().to_vec1::<f64>().unwrap(),
            theirs.flatten_all().unwrap().to_vec1::<f64>().unwrap()
        );
        let r = check_grad(|xs| Ok(max_pool2d(&xs[0], 4, 2)?), &[x], &GradCheckOptions::default()).unwrap();
        assert!(r.max_rel_error < 1e-8, "{r:?}");
    }

    #[test]
    fn a_kernel_larger_than_the_input_is_an_error() {
        let x = Tensor::zeros((1, 1, 3, 3), DType::F32, &Device::Cpu).unwrap();
        assert!(max_pool2d(&x, 4, 2).unwrap_err().to_string().contains("kernel"));
    }
}
