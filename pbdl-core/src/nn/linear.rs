//! The affine map `y = x W^T + b` as one op with a hand-written backward.
//!
//! Composed from candle ops (`x.matmul(&w.t())` and `broadcast_add`), the backward of the
//! transposed weight goes through a strided view: its gradient is accumulated element by element
//! through candle's strided binary map, and with the transposes and the bias sum the input
//! projection of a 1024-unit LSTM took 35 ms forward + backward where its three matrix products
//! take 16 ms. Here the forward is one product; the backward is one kernel that writes `dW` in
//! `W`'s own layout, the bias gradient and (only when the input tracks gradients) `dx` into one
//! buffer, of which the three gradients are views.
//!
//! First derivatives only: differentiating the gradients again is an error; inside
//! [`crate::nn::with_composed`] the composed candle ops run instead (second derivatives, A/B
//! comparisons).

use crate::matmul::{matmul, threads_for, Mat};
use crate::op::{apply2, apply3, apply_kernel3, Kernel2, Kernel3, Op2, Op3};
use crate::Real;
use candle_core::{Shape, Tensor};

/// Sizes: `rows` input rows (all leading dims flattened), `inputs` and `outputs` features.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Dims {
    rows: usize,
    inputs: usize,
    outputs: usize,
}

impl Dims {
    fn of(x: &Shape, w: &Shape) -> candle_core::Result<Self> {
        let (xd, wd) = (x.dims(), w.dims());
        match (xd.last(), wd) {
            (Some(&inputs), &[outputs, w_in]) if inputs == w_in => {
                Ok(Dims { rows: x.elem_count() / inputs.max(1), inputs, outputs })
            }
            _ => candle_core::bail!(
                "linear: input {xd:?} and weight {wd:?} do not fit: the weight must be [outputs, inputs] with inputs = the input's last dim"
            ),
        }
    }

    fn output_shape(&self, x: &Shape) -> Shape {
        let mut dims = x.dims().to_vec();
        *dims.last_mut().expect("rank >= 1, checked in Dims::of") = self.outputs;
        Shape::from(dims)
    }

    /// `y = x W^T` (overwrites `y`).
    fn product<T: Real>(&self, x: &[T], w: &[T], y: &mut [T]) {
        let Dims { rows, inputs, outputs } = *self;
        let wt = Mat { data: w, rs: 1, cs: inputs };
        matmul(
            y,
            outputs,
            false,
            Mat::row_major(x, inputs),
            wt,
            (rows, outputs, inputs),
            T::one(),
            threads_for(rows, outputs, inputs),
        );
    }
}

/// `x W^T + b`.
struct LinearBias(Dims);

impl Kernel3 for LinearBias {
    fn name(&self) -> &'static str {
        "linear"
    }

    fn output_shape(&self, x: &Shape, w: &Shape, b: &Shape) -> candle_core::Result<Shape> {
        let d = Dims::of(x, w)?;
        if b.dims() != [d.outputs] {
            candle_core::bail!("linear: bias {:?}, expected [{}]", b.dims(), d.outputs);
        }
        Ok(d.output_shape(x))
    }

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
        self.0.product(x, w, y);
        // `max(1)`: no rows to add to when there are no outputs (chunks_exact(0) panics).
        for row in y.chunks_exact_mut(self.0.outputs.max(1)) {
            row.iter_mut().zip(b).for_each(|(v, &bj)| *v += bj);
        }
        Ok(())
    }
}

impl Op3 for LinearBias {
    fn backward(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let (dx, dw, db) = grads(self.0, x, w, gy, true)?;
        Ok((dx, dw, db.expect("bias gradient requested")))
    }
}

/// `x W^T`.
struct LinearNoBias(Dims);

impl Kernel2 for LinearNoBias {
    fn name(&self) -> &'static str {
        "linear"
    }

    fn output_shape(&self, x: &Shape, w: &Shape) -> candle_core::Result<Shape> {
        Ok(Dims::of(x, w)?.output_shape(x))
    }

    fn forward<T: Real>(&self, x: &[T], _: &Shape, w: &[T], _: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        self.0.product(x, w, y);
        Ok(())
    }
}

impl Op2 for LinearNoBias {
    fn backward(&self, x: &Tensor, w: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let (dx, dw, _) = grads(self.0, x, w, gy, false)?;
        Ok((dx, dw))
    }
}

/// The gradients `(dx, dW, db)` from one kernel call; `db` only `with_bias`.
fn grads(
    d: Dims,
    x: &Tensor,
    w: &Tensor,
    gy: &Tensor,
    with_bias: bool,
) -> candle_core::Result<(Tensor, Tensor, Option<Tensor>)> {
    // An input that tracks no gradient (data fed to the first layer) gets no dx product.
    let with_dx = x.track_op();
    let packed = apply_kernel3(gy, x, w, LinearGrads { dims: d, with_bias, with_dx })?;
    let n_x = if with_dx { d.rows * d.inputs } else { 0 };
    let n_w = d.outputs * d.inputs;
    let dx = if with_dx { packed.narrow(0, 0, n_x)?.reshape(x.shape())? } else { crate::op::zeros_like(x)? };
    let dw = packed.narrow(0, n_x, n_w)?.reshape(w.shape())?;
    let db = with_bias.then(|| packed.narrow(0, n_x + n_w, d.outputs)).transpose()?;
    Ok((dx, dw, db))
}

/// Backward kernel (forward-only itself): from `gy`, `x` and `W`, writes `[dx | dW | db]` flat,
/// one buffer that the three gradients are views of.
struct LinearGrads {
    dims: Dims,
    with_bias: bool,
    /// Whether `dx` is computed (else the buffer starts with `dW`).
    with_dx: bool,
}

impl Kernel3 for LinearGrads {
    fn name(&self) -> &'static str {
        "linear_backward"
    }

    fn output_shape(&self, _gy: &Shape, _x: &Shape, _w: &Shape) -> candle_core::Result<Shape> {
        let Dims { rows, inputs, outputs } = self.dims;
        let n_x = if self.with_dx { rows * inputs } else { 0 };
        Ok(Shape::from(n_x + outputs * inputs + if self.with_bias { outputs } else { 0 }))
    }

    fn forward<T: Real>(
        &self,
        gy: &[T],
        _: &Shape,
        x: &[T],
        _: &Shape,
        w: &[T],
        _: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let Dims { rows, inputs, outputs } = self.dims;
        let (dx, rest) = out.split_at_mut(if self.with_dx { rows * inputs } else { 0 });
        let (dw, db) = rest.split_at_mut(outputs * inputs);
        if self.with_dx {
            // dx = gy W
            let gy_rows = Mat::row_major(gy, outputs);
            matmul(
                dx,
                inputs,
                false,
                gy_rows,
                Mat::row_major(w, inputs),
                (rows, inputs, outputs),
                T::one(),
                threads_for(rows, inputs, outputs),
            );
        }
        // dW = gy^T x, in W's layout
        let gy_t = Mat { data: gy, rs: 1, cs: outputs };
        matmul(
            dw,
            inputs,
            false,
            gy_t,
            Mat::row_major(x, inputs),
            (outputs, inputs, rows),
            T::one(),
            threads_for(outputs, inputs, rows),
        );
        if self.with_bias {
            for row in gy.chunks_exact(outputs.max(1)) {
                db.iter_mut().zip(row).for_each(|(s, &g)| *s += g);
            }
        }
        Ok(())
    }
}

/// `y = x W^T + b` for `x` `[..., inputs]`, `w` `[outputs, inputs]` (PyTorch's layout), `b`
/// `[outputs]`; one op with a hand-written backward on the CPU in `f32`/`f64`, the composed
/// candle ops otherwise (other devices or dtypes, or inside [`crate::nn::with_composed`]).
///
/// ```
/// use candle_core::{Device, Tensor};
/// use pbdl_core::nn::linear;
///
/// let x = Tensor::new(&[[1.0f32, 2.0], [3.0, 4.0]], &Device::Cpu)?;
/// let w = Tensor::new(&[[1.0f32, 0.0], [1.0, -1.0], [0.5, 0.5]], &Device::Cpu)?;
/// let b = Tensor::new(&[0.0f32, 1.0, -1.0], &Device::Cpu)?;
/// let y = linear(&x, &w, Some(&b))?;
/// assert_eq!(y.to_vec2::<f32>()?, [[1.0, 0.0, 0.5], [3.0, 0.0, 2.5]]);
/// # Ok::<(), pbdl_core::Error>(())
/// ```
pub fn linear(x: &Tensor, w: &Tensor, b: Option<&Tensor>) -> crate::Result<Tensor> {
    let fused = super::fusion_enabled()
        && x.device().is_cpu()
        && matches!(x.dtype(), candle_core::DType::F32 | candle_core::DType::F64)
        && x.rank() >= 1;
    if !fused {
        return linear_composed(x, w, b);
    }
    let d = Dims::of(x.shape(), w.shape())?;
    Ok(match b {
        Some(b) => apply3(x, w, b, LinearBias(d))?,
        None => apply2(x, w, LinearNoBias(d))?,
    })
}

/// [`linear`] composed from candle ops (differentiable to any order).
pub fn linear_composed(x: &Tensor, w: &Tensor, b: Option<&Tensor>) -> crate::Result<Tensor> {
    // candle's matmul needs rank >= 2: a single vector is one row.
    let y = if x.rank() == 1 { x.unsqueeze(0)?.matmul(&w.t()?)?.squeeze(0)? } else { x.broadcast_matmul(&w.t()?)? };
    Ok(match b {
        Some(b) => y.broadcast_add(b)?,
        None => y,
    })
}
