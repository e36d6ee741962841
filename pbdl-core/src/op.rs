//! A small toolkit for writing differentiable candle custom ops.
//!
//! candle's `CustomOp1/2/3` traits hand the kernel raw storage plus a layout and make the
//! backward optional. This module puts forward and backward of an op in one place and takes
//! care of the parts that are easy to get wrong:
//!
//! * **Layouts.** Inputs are made contiguous (honouring offsets and strides) before the kernel
//!   sees them, so a kernel only ever reads a dense row-major slice.
//! * **Dtypes.** Kernels are written once, generic over [`Real`] (`f32` and `f64`); other dtypes
//!   are rejected with a typed error.
//! * **Gradients.** An [`Op1`]/[`Op2`]/[`Op3`] must implement `backward`, which returns a tensor
//!   for *every* input: a missing gradient cannot be silent. Forward-only kernels (used, e.g.,
//!   for adjoint kernels inside a backward) go through [`Kernel1`]/[`Kernel2`]/[`Kernel3`]; trying
//!   to differentiate through them is an error.
//!
//! ```
//! use candle_core::{Device, Shape, Tensor};
//! use pbdl_core::op::{apply1, Kernel1, Op1};
//! use pbdl_core::Real;
//!
//! /// y = x^3, elementwise.
//! struct Cube;
//! impl Kernel1 for Cube {
//!     fn name(&self) -> &'static str { "cube" }
//!     fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> { Ok(input.clone()) }
//!     fn forward<T: Real>(&self, x: &[T], _shape: &Shape, y: &mut [T]) -> candle_core::Result<()> {
//!         for (y, &x) in y.iter_mut().zip(x) { *y = x * x * x; }
//!         Ok(())
//!     }
//! }
//! impl Op1 for Cube {
//!     fn backward(&self, x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
//!         gy.mul(&(x.sqr()? * 3.0)?)
//!     }
//! }
//!
//! let x = Tensor::new(&[1.0f64, -2.0, 0.5], &Device::Cpu)?;
//! let report = pbdl_core::check_grad(|xs| apply1(&xs[0], Cube), &[x], &Default::default())?;
//! assert!(report.max_rel_error < 1e-8);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::Real;
use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp1, CustomOp2, CustomOp3, DType, Layout, Shape, Tensor, WithDType};
use std::borrow::Cow;

/// The forward kernel of a one-input op, generic over the float type.
pub trait Kernel1: Send + Sync + 'static {
    /// Name used in errors and in candle's graph.
    fn name(&self) -> &'static str;
    /// Shape of the output for an input of shape `input`; reject bad shapes here.
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape>;
    /// Fills `output` (zero-initialised, dense row-major) from the dense input `x`.
    fn forward<T: Real>(&self, x: &[T], x_shape: &Shape, output: &mut [T]) -> candle_core::Result<()>;
}

/// A differentiable one-input op: a [`Kernel1`] plus its vector-Jacobian product.
pub trait Op1: Kernel1 {
    /// Given the input `x`, the output `y` and the output gradient `grad_y`, returns the
    /// gradient with respect to `x`.
    fn backward(&self, x: &Tensor, y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor>;
}

/// The forward kernel of a two-input op. Both inputs share one float dtype.
pub trait Kernel2: Send + Sync + 'static {
    /// Name used in errors and in candle's graph.
    fn name(&self) -> &'static str;
    /// Shape of the output; reject bad shapes here.
    fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape>;
    /// Fills `output` from the dense inputs.
    fn forward<T: Real>(
        &self,
        a: &[T],
        a_shape: &Shape,
        b: &[T],
        b_shape: &Shape,
        output: &mut [T],
    ) -> candle_core::Result<()>;
}

/// A differentiable two-input op. `backward` returns a gradient for both inputs; an input that
/// is not differentiable (an index map, say) returns explicit zeros, which documents the choice.
pub trait Op2: Kernel2 {
    /// Gradients with respect to `a` and `b`.
    fn backward(&self, a: &Tensor, b: &Tensor, y: &Tensor, grad_y: &Tensor) -> candle_core::Result<(Tensor, Tensor)>;
}

/// The forward kernel of a three-input op. All inputs share one float dtype.
pub trait Kernel3: Send + Sync + 'static {
    /// Name used in errors and in candle's graph.
    fn name(&self) -> &'static str;
    /// Shape of the output; reject bad shapes here.
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape>;
    /// Fills `output` from the dense inputs.
    #[allow(clippy::too_many_arguments)]
    fn forward<T: Real>(
        &self,
        a: &[T],
        a_shape: &Shape,
        b: &[T],
        b_shape: &Shape,
        c: &[T],
        c_shape: &Shape,
        output: &mut [T],
    ) -> candle_core::Result<()>;
}

/// A differentiable three-input op.
pub trait Op3: Kernel3 {
    /// Gradients with respect to `a`, `b` and `c`.
    fn backward(
        &self,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        y: &Tensor,
        grad_y: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)>;
}

/// Applies a differentiable one-input op.
pub fn apply1<K: Op1>(x: &Tensor, op: K) -> candle_core::Result<Tensor> {
    x.apply_op1(WithGrad(op))
}

/// Applies a differentiable two-input op.
pub fn apply2<K: Op2>(a: &Tensor, b: &Tensor, op: K) -> candle_core::Result<Tensor> {
    a.apply_op2(b, WithGrad(op))
}

/// Applies a differentiable three-input op.
pub fn apply3<K: Op3>(a: &Tensor, b: &Tensor, c: &Tensor, op: K) -> candle_core::Result<Tensor> {
    a.apply_op3(b, c, WithGrad(op))
}

/// Applies a forward-only kernel. Differentiating through the result is an error
/// (`BackwardNotSupported`), never a silently missing gradient.
pub fn apply_kernel1<K: Kernel1>(x: &Tensor, kernel: K) -> candle_core::Result<Tensor> {
    x.apply_op1(NoGrad(kernel))
}

/// Applies a forward-only two-input kernel; see [`apply_kernel1`].
pub fn apply_kernel2<K: Kernel2>(a: &Tensor, b: &Tensor, kernel: K) -> candle_core::Result<Tensor> {
    a.apply_op2(b, NoGrad(kernel))
}

/// Applies a forward-only three-input kernel; see [`apply_kernel1`].
pub fn apply_kernel3<K: Kernel3>(a: &Tensor, b: &Tensor, c: &Tensor, kernel: K) -> candle_core::Result<Tensor> {
    a.apply_op3(b, c, NoGrad(kernel))
}

/// Returns the elements of `storage` described by `layout` as a dense row-major slice,
/// borrowing when the layout is already contiguous and copying otherwise.
pub fn dense<'a, T: WithDType>(storage: &'a CpuStorage, layout: &Layout) -> candle_core::Result<Cow<'a, [T]>> {
    let all = T::cpu_storage_as_slice(storage)?;
    Ok(match layout.contiguous_offsets() {
        Some((start, end)) => Cow::Borrowed(&all[start..end]),
        None => Cow::Owned(gather_strided(all, layout)),
    })
}

/// Copies a strided view into a dense row-major vector (odometer over the multi-index).
fn gather_strided<T: Copy>(all: &[T], layout: &Layout) -> Vec<T> {
    let dims = layout.dims();
    let stride = layout.stride();
    let n: usize = dims.iter().product();
    let mut out = Vec::with_capacity(n);
    if n == 0 {
        return out;
    }
    let mut index = vec![0usize; dims.len()];
    let mut offset = layout.start_offset();
    for _ in 0..n {
        out.push(all[offset]);
        // Advance the odometer from the fastest axis.
        for d in (0..dims.len()).rev() {
            index[d] += 1;
            offset += stride[d];
            if index[d] < dims[d] {
                break;
            }
            offset -= stride[d] * dims[d];
            index[d] = 0;
        }
    }
    out
}

fn unsupported(op: &'static str, dtype: DType) -> candle_core::Error {
    crate::Error::DType { op, arg: "input", expected: "f32 or f64 (all inputs of one op share a dtype)", got: dtype }
        .into()
}

/// The float dtype shared by all `inputs` of `op`, or the typed error naming the first input
/// whose dtype is not a float or differs from the first one.
fn common_float(op: &'static str, inputs: &[&CpuStorage]) -> candle_core::Result<DType> {
    let first = inputs[0].dtype();
    match inputs.iter().map(|s| s.dtype()).find(|d| *d != first || !matches!(d, DType::F32 | DType::F64)) {
        None => Ok(first),
        Some(bad) => Err(unsupported(op, bad)),
    }
}

/// A zero-initialised output of `shape`, filled by `fill` and handed back as candle storage.
fn output<T: Real>(
    shape: Shape,
    fill: impl FnOnce(&mut [T]) -> candle_core::Result<()>,
) -> candle_core::Result<(CpuStorage, Shape)> {
    let mut out = vec![T::zero(); shape.elem_count()];
    fill(&mut out)?;
    Ok((T::to_cpu_storage_owned(out), shape))
}

fn run1<K: Kernel1, T: Real>(k: &K, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
    let out_shape = k.output_shape(l.shape())?;
    let x = dense::<T>(s, l)?;
    output(out_shape, |out| k.forward(&x, l.shape(), out))
}

fn run2<K: Kernel2, T: Real>(
    k: &K,
    s1: &CpuStorage,
    l1: &Layout,
    s2: &CpuStorage,
    l2: &Layout,
) -> candle_core::Result<(CpuStorage, Shape)> {
    let out_shape = k.output_shape(l1.shape(), l2.shape())?;
    let (a, b) = (dense::<T>(s1, l1)?, dense::<T>(s2, l2)?);
    output(out_shape, |out| k.forward(&a, l1.shape(), &b, l2.shape(), out))
}

#[allow(clippy::too_many_arguments)]
fn run3<K: Kernel3, T: Real>(
    k: &K,
    s1: &CpuStorage,
    l1: &Layout,
    s2: &CpuStorage,
    l2: &Layout,
    s3: &CpuStorage,
    l3: &Layout,
) -> candle_core::Result<(CpuStorage, Shape)> {
    let out_shape = k.output_shape(l1.shape(), l2.shape(), l3.shape())?;
    let (a, b, c) = (dense::<T>(s1, l1)?, dense::<T>(s2, l2)?, dense::<T>(s3, l3)?);
    output(out_shape, |out| k.forward(&a, l1.shape(), &b, l2.shape(), &c, l3.shape(), out))
}

/// Adapter from an [`Op1`]/[`Op2`]/[`Op3`] to candle's custom-op traits.
struct WithGrad<K>(K);
/// Adapter from a forward-only kernel to candle's custom-op traits (backward is an error).
struct NoGrad<K>(K);

/// The `name` and `cpu_fwd` methods of a candle custom op with inputs `$s: $l`, shared by
/// [`WithGrad`] and [`NoGrad`]: the inputs' common float dtype picks the instance of `$run`.
macro_rules! forward_methods {
    ($run:ident, $($s:ident: $l:ident),+) => {
        fn name(&self) -> &'static str {
            self.0.name()
        }
        fn cpu_fwd(&self, $($s: &CpuStorage, $l: &Layout),+) -> candle_core::Result<(CpuStorage, Shape)> {
            match common_float(self.0.name(), &[$($s),+])? {
                DType::F32 => $run::<K, f32>(&self.0, $($s, $l),+),
                _ => $run::<K, f64>(&self.0, $($s, $l),+),
            }
        }
    };
}

impl<K: Op1> CustomOp1 for WithGrad<K> {
    forward_methods!(run1, s: l);
    fn bwd(&self, x: &Tensor, y: &Tensor, gy: &Tensor) -> candle_core::Result<Option<Tensor>> {
        Ok(if_tracked(x, self.0.backward(x, y, gy)?))
    }
}

impl<K: Kernel1> CustomOp1 for NoGrad<K> {
    forward_methods!(run1, s: l);
}

impl<K: Op2> CustomOp2 for WithGrad<K> {
    forward_methods!(run2, s1: l1, s2: l2);
    fn bwd(
        &self,
        a: &Tensor,
        b: &Tensor,
        y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (ga, gb) = self.0.backward(a, b, y, gy)?;
        Ok((if_tracked(a, ga), if_tracked(b, gb)))
    }
}

impl<K: Kernel2> CustomOp2 for NoGrad<K> {
    forward_methods!(run2, s1: l1, s2: l2);
}

impl<K: Op3> CustomOp3 for WithGrad<K> {
    forward_methods!(run3, s1: l1, s2: l2, s3: l3);
    fn bwd(
        &self,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (ga, gb, gc) = self.0.backward(a, b, c, y, gy)?;
        Ok((if_tracked(a, ga), if_tracked(b, gb), if_tracked(c, gc)))
    }
}

impl<K: Kernel3> CustomOp3 for NoGrad<K> {
    forward_methods!(run3, s1: l1, s2: l2, s3: l3);
}

/// The gradient `g` of input `t` for candle's gradient store, or `None` when `t` tracks no
/// gradient (a constant): candle would otherwise allocate a full-size zero buffer for `t` and
/// add `g` to it, work that nothing can read.
fn if_tracked(t: &Tensor, g: Tensor) -> Option<Tensor> {
    t.track_op().then_some(g)
}

/// An explicit zero gradient of the shape of `t`, without allocating its full size (a
/// broadcast scalar): nobody can read it, but candle expects a tensor.
pub(crate) fn zeros_like(t: &Tensor) -> candle_core::Result<Tensor> {
    Tensor::zeros((), t.dtype(), t.device())?.broadcast_as(t.shape())
}

/// The gradient `grad()` for an input `t` that tracks gradients, else [`zeros_like`]`(t)`
/// without running `grad` (nothing downstream can read that gradient).
pub(crate) fn grad_if_tracked(
    t: &Tensor,
    grad: impl FnOnce() -> candle_core::Result<Tensor>,
) -> candle_core::Result<Tensor> {
    if t.track_op() {
        grad()
    } else {
        zeros_like(t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{check_grad, GradCheckOptions};
    use candle_core::{Device, Var};

    /// y = a * sin(b), elementwise.
    struct ASinB;
    impl Kernel2 for ASinB {
        fn name(&self) -> &'static str {
            "a_sin_b"
        }
        fn output_shape(&self, a: &Shape, b: &Shape) -> candle_core::Result<Shape> {
            if a != b {
                candle_core::bail!("a_sin_b: shapes differ {a:?} vs {b:?}");
            }
            Ok(a.clone())
        }
        fn forward<T: Real>(&self, a: &[T], _: &Shape, b: &[T], _: &Shape, out: &mut [T]) -> candle_core::Result<()> {
            for i in 0..out.len() {
                out[i] = a[i] * b[i].sin();
            }
            Ok(())
        }
    }
    impl Op2 for ASinB {
        fn backward(&self, a: &Tensor, b: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
            Ok((gy.mul(&b.sin()?)?, gy.mul(&a.mul(&b.cos()?)?)?))
        }
    }

    #[test]
    fn two_input_op_passes_gradient_check() {
        let a = Tensor::new(&[[0.3f64, -1.2, 2.0], [0.7, 0.1, -0.4]], &Device::Cpu).unwrap();
        let b = Tensor::new(&[[1.3f64, 0.2, -2.0], [0.5, 3.0, 1.1]], &Device::Cpu).unwrap();
        let r = check_grad(|xs| apply2(&xs[0], &xs[1], ASinB), &[a, b], &GradCheckOptions::default()).unwrap();
        assert!(r.max_rel_error < 1e-8, "{r:?}");
    }

    #[test]
    fn strided_and_offset_inputs_are_read_correctly() {
        // A transposed, narrowed view: non-contiguous with a non-zero offset.
        let base = Tensor::arange(0f32, 24.0, &Device::Cpu).unwrap().reshape((4, 6)).unwrap();
        let view = base.t().unwrap().narrow(0, 1, 3).unwrap();
        assert!(!view.is_contiguous());
        let ones = Tensor::ones(view.shape(), DType::F32, &Device::Cpu).unwrap();
        let y = apply2(&ones, &view, ASinB).unwrap();
        let expect = view.sin().unwrap();
        let diff = (y - expect).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(diff < 1e-6);
    }

    #[test]
    fn forward_only_kernel_refuses_backward() {
        let a = Var::new(&[1.0f64, 2.0], &Device::Cpu).unwrap();
        let b = Tensor::new(&[1.0f64, 2.0], &Device::Cpu).unwrap();
        let y = apply_kernel2(a.as_tensor(), &b, ASinB).unwrap().sum_all().unwrap();
        assert!(y.backward().is_err(), "backward through a forward-only kernel must be an error");
    }

    #[test]
    fn integer_dtype_is_a_typed_error() {
        let a = Tensor::new(&[1u32, 2], &Device::Cpu).unwrap();
        let err = apply2(&a, &a, ASinB).unwrap_err().to_string();
        assert!(err.contains("f32 or f64"), "{err}");
    }
}
