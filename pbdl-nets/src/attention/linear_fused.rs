//! The linear-attention layer (bias-free 1x1 projection to queries, keys and values, linear
//! attention, bias-free 1x1 output projection) as one fused, differentiable op.
//!
//! Composed from candle ops, the layer materialises a `[batch, 3 heads dim_head, pixels]`
//! tensor, runs two softmaxes and batched products over it and back, one allocation and one
//! memory pass each. At the top level of a small U-Net that tensor is far larger than the
//! feature map (384 channels against 16 at dim 16). Here each image is processed head by head
//! in cache-sized blocks with `gemm` products, and only the feature maps touch memory.
//!
//! Per head `h`, with `x` `[c, n]`, projections `W_q, W_k, W_v` (`[d, c]` row blocks of
//! `w_qkv`), `W_o` (`[c, d]` column block of `w_out`) and `s = 1/sqrt(d)`:
//! `q = W_q x`, `P = softmax_d(q)`, `K = softmax_n(W_k x)`, `v = W_v x`, `C = K v^T`,
//! `o = s C^T P`, and `y = sum_h W_o o`.
//! Backward from `G = dy`: `do = W_o^T G`, `dW_o += G o^T`, `dC = s P do^T`, `dP = s C do`,
//! `dK = dC v`, `dv = dC^T K`, `dq = P (dP - sum_d P dP)`, `dk = K (dK - sum_n K dK)`, then
//! `dW_{q,k,v} += d{q,k,v} x^T` and `dx += W_q^T dq + W_k^T dk + W_v^T dv`.

use crate::Result;
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply2, apply_kernel3, Kernel2, Kernel3, Op2};
use pbdl_core::Real;
use rayon::prelude::*;

/// Sizes of the layer.
#[derive(Clone, Copy, Debug)]
struct Dims {
    heads: usize,
    d: usize,
    c: usize,
}

impl Dims {
    fn hid(&self) -> usize {
        self.heads * self.d
    }

    /// Length of the packed weights `[w_qkv (3 hid x c), w_out (c x hid)]`.
    fn w_len(&self) -> usize {
        4 * self.hid() * self.c
    }

    /// `(batch, pixels)` of an input `[batch, c, spatial..]` and packed weights.
    fn check(&self, op: &'static str, x: &Shape, w: &Shape) -> candle_core::Result<(usize, usize)> {
        let dims = x.dims();
        if dims.len() < 3 || dims[1] != self.c || w.dims() != [self.w_len()] {
            return Err(candle_core::Error::Msg(format!(
                "{op}: input {dims:?} and packed weights {:?} do not fit [batch, {}, spatial..] and [{}]",
                w.dims(),
                self.c,
                self.w_len()
            )));
        }
        Ok((dims[0], dims[2..].iter().product()))
    }
}

/// A strided matrix view `(data, row stride, column stride)`.
type View<'a, T> = (&'a [T], usize, usize);

/// `dst (m x n, row-major) = [dst +] beta * a (m x k) b (k x n)`.
fn mm<T: Real>(dst: &mut [T], a: View<T>, b: View<T>, (m, n, k): (usize, usize, usize), beta: T, accumulate: bool) {
    gemm_checked(dst, n, a, b, (m, n, k), beta, accumulate, "mm");
}

/// `dst (m x n, row stride ld) = [dst +] beta * a (m x k) b (k x n)`: pbdl-core's checked
/// product behind [`mm`] and [`mm_into_block`], serial (heads already run in parallel); `what`
/// names the caller in the panic on an empty product.
fn gemm_checked<T: Real>(
    dst: &mut [T],
    ld: usize,
    a: View<T>,
    b: View<T>,
    (m, n, k): (usize, usize, usize),
    beta: T,
    accumulate: bool,
    what: &str,
) {
    use pbdl_core::matmul::{matmul, Mat, Threads};
    assert!(m > 0 && n > 0 && k > 0, "{what}: empty product");
    matmul(dst, ld, accumulate, Mat::new(a.0, a.1, a.2), Mat::new(b.0, b.1, b.2), (m, n, k), beta, Threads::Serial);
}

/// The larger of two values (`Float::max`; `Real` also sees candle's `WithDType::max`).
fn num_max<T: Real>(a: T, b: T) -> T {
    if b > a {
        b
    } else {
        a
    }
}

/// Per-head scratch: projections, softmaxes, context and head output, all `[d, n]` or `[d, d]`.
struct Head<T> {
    q: Vec<T>,
    k: Vec<T>,
    v: Vec<T>,
    p: Vec<T>,
    ks: Vec<T>,
    ctx: Vec<T>,
    o: Vec<T>,
    col: Vec<T>,
}

impl<T: Real> Head<T> {
    fn new(dims: Dims, n: usize) -> Self {
        let dn = vec![T::zero(); dims.d * n];
        Self {
            q: dn.clone(),
            k: dn.clone(),
            v: dn.clone(),
            p: dn.clone(),
            ks: dn.clone(),
            ctx: vec![T::zero(); dims.d * dims.d],
            o: dn,
            col: vec![T::zero(); n],
        }
    }

    /// Projections, softmaxes, context and output of head `h` for the image `x` `[c, n]`.
    fn forward(&mut self, dims: Dims, w: &[T], x: &[T], h: usize, n: usize) {
        let Dims { d, c, .. } = dims;
        let hid = dims.hid();
        let rows = |part: usize| (&w[(part * hid + h * d) * c..][..d * c], c, 1);
        let xv = (x, n, 1);
        mm(&mut self.q, rows(0), xv, (d, n, c), T::one(), false);
        mm(&mut self.k, rows(1), xv, (d, n, c), T::one(), false);
        mm(&mut self.v, rows(2), xv, (d, n, c), T::one(), false);
        // P: softmax over d of each column.
        let m = &mut self.col;
        m.fill(T::neg_infinity());
        for row in self.q.chunks_exact(n) {
            m.iter_mut().zip(row).for_each(|(m, &x)| *m = num_max(*m, x));
        }
        // Vectorised exp (libm's scalar expf was 7.5% of an ACDM sampling step).
        pbdl_core::vmath::with_simd(
            #[inline(always)]
            || {
                for (prow, qrow) in self.p.chunks_exact_mut(n).zip(self.q.chunks_exact(n)) {
                    prow.iter_mut()
                        .zip(qrow.iter().zip(m.iter()))
                        .for_each(|(p, (&q, &m))| *p = pbdl_core::vmath::exp(q - m));
                }
            },
        );
        m.fill(T::zero());
        for prow in self.p.chunks_exact(n) {
            m.iter_mut().zip(prow).for_each(|(s, &p)| *s += p);
        }
        for prow in self.p.chunks_exact_mut(n) {
            prow.iter_mut().zip(m.iter()).for_each(|(p, &s)| *p /= s);
        }
        // K: softmax over n of each row.
        for (out, row) in self.ks.chunks_exact_mut(n).zip(self.k.chunks_exact(n)) {
            let mx = row.iter().fold(T::neg_infinity(), |a, &b| num_max(a, b));
            pbdl_core::vmath::with_simd(
                #[inline(always)]
                || out.iter_mut().zip(row).for_each(|(o, &x)| *o = pbdl_core::vmath::exp(x - mx)),
            );
            let mut sum = T::zero();
            for &o in out.iter() {
                sum += o;
            }
            out.iter_mut().for_each(|o| *o /= sum);
        }
        // C[d, e] = sum_n K[d, n] v[e, n]; o[e, n] = s sum_d C[d, e] P[d, n].
        mm(&mut self.ctx, (&self.ks, n, 1), (&self.v, 1, n), (d, d, n), T::one(), false);
        let s = T::c(1.0 / (d as f64).sqrt());
        mm(&mut self.o, (&self.ctx, 1, d), (&self.p, n, 1), (d, n, d), s, false);
    }
}

/// The forward op `(x, packed weights) -> y`.
struct LinearAttentionLayer(Dims);

impl Kernel2 for LinearAttentionLayer {
    fn name(&self) -> &'static str {
        "linear_attention_layer"
    }

    fn output_shape(&self, x: &Shape, w: &Shape) -> candle_core::Result<Shape> {
        self.0.check("linear_attention_layer", x, w)?;
        Ok(x.clone())
    }

    fn forward<T: Real>(&self, x: &[T], xs: &Shape, w: &[T], ws: &Shape, y: &mut [T]) -> candle_core::Result<()> {
        let dims = self.0;
        let (_, n) = dims.check("linear_attention_layer", xs, ws)?;
        let (c, d, hid) = (dims.c, dims.d, dims.hid());
        let w_out = &w[3 * hid * c..];
        y.par_chunks_mut(c * n).enumerate().for_each_init(
            || Head::new(dims, n),
            |head, (b, yb)| {
                let xb = &x[b * c * n..][..c * n];
                for h in 0..dims.heads {
                    head.forward(dims, w, xb, h, n);
                    // y += W_o[:, h d..(h + 1) d] o
                    mm(yb, (&w_out[h * d..], hid, 1), (&head.o, n, 1), (c, n, d), T::one(), h > 0);
                }
            },
        );
        Ok(())
    }
}

impl Op2 for LinearAttentionLayer {
    fn backward(&self, x: &Tensor, w: &Tensor, _y: &Tensor, g: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        // One kernel computes both gradients, packed as [dx (x.len()), dw (w.len())].
        let packed = apply_kernel3(x, w, g, LinearAttentionLayerGrad(self.0))?;
        let nx = x.elem_count();
        let dx = packed.narrow(0, 0, nx)?.reshape(x.shape())?;
        let dw = packed.narrow(0, nx, self.0.w_len())?;
        Ok((dx, dw))
    }
}

/// The backward kernel `(x, packed weights, dy) -> [dx, dw]` (forward-only: no second
/// derivatives).
struct LinearAttentionLayerGrad(Dims);

impl Kernel3 for LinearAttentionLayerGrad {
    fn name(&self) -> &'static str {
        "linear_attention_layer_grad"
    }

    fn output_shape(&self, x: &Shape, w: &Shape, _g: &Shape) -> candle_core::Result<Shape> {
        self.0.check("linear_attention_layer_grad", x, w)?;
        Ok(Shape::from(x.elem_count() + self.0.w_len()))
    }

    fn forward<T: Real>(
        &self,
        x: &[T],
        xs: &Shape,
        w: &[T],
        ws: &Shape,
        g: &[T],
        _: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let dims = self.0;
        let (batch, n) = dims.check("linear_attention_layer_grad", xs, ws)?;
        let (c, d, hid) = (dims.c, dims.d, dims.hid());
        let s = T::c(1.0 / (d as f64).sqrt());
        let (dx, dw_total) = out.split_at_mut(batch * c * n);
        let w_out = &w[3 * hid * c..];
        // Each image writes its own dx block and returns its weight-gradient partial; the
        // partials are summed in image order, so the result does not depend on scheduling.
        let partials: Vec<Vec<T>> = dx
            .par_chunks_mut(c * n)
            .enumerate()
            .map_init(
                || (Head::new(dims, n), vec![T::zero(); d * n], vec![T::zero(); d * d]),
                |(head, dout, dctx), (b, dxb)| {
                    let xb = &x[b * c * n..][..c * n];
                    let gb = &g[b * c * n..][..c * n];
                    let mut dw = vec![T::zero(); dims.w_len()];
                    for h in 0..dims.heads {
                        head.forward(dims, w, xb, h, n);
                        // do = W_o_h^T G; dW_o[:, h block] += G o^T.
                        mm(dout, (&w_out[h * d..], 1, hid), (gb, n, 1), (d, n, c), T::one(), false);
                        let (dw_qkv, dw_o) = dw.split_at_mut(3 * hid * c);
                        mm_into_block(dw_o, hid, h * d, (gb, n, 1), (&head.o, 1, n), (c, d, n));
                        // dC = s P do^T; dP = s C do (into q); dK = dC v (into k); dv = dC^T K (into v).
                        mm(dctx, (&head.p, n, 1), (dout, 1, n), (d, d, n), s, false);
                        mm(&mut head.q, (&head.ctx, d, 1), (dout, n, 1), (d, n, d), s, false);
                        mm(&mut head.k, (dctx, d, 1), (&head.v, n, 1), (d, n, d), T::one(), false);
                        mm(&mut head.v, (dctx, 1, d), (&head.ks, n, 1), (d, n, d), T::one(), false);
                        // Softmax backward, in place: dq = P (dP - sum_d P dP), dk = K (dK - sum_n K dK).
                        let dot = &mut head.col;
                        dot.fill(T::zero());
                        for (prow, dprow) in head.p.chunks_exact(n).zip(head.q.chunks_exact(n)) {
                            dot.iter_mut().zip(prow.iter().zip(dprow)).for_each(|(a, (&p, &dp))| *a += p * dp);
                        }
                        for (prow, dprow) in head.p.chunks_exact(n).zip(head.q.chunks_exact_mut(n)) {
                            dprow
                                .iter_mut()
                                .zip(prow.iter().zip(dot.iter()))
                                .for_each(|(dp, (&p, &a))| *dp = p * (*dp - a));
                        }
                        for (krow, dkrow) in head.ks.chunks_exact(n).zip(head.k.chunks_exact_mut(n)) {
                            let a = krow.iter().zip(dkrow.iter()).fold(T::zero(), |a, (&k, &dk)| a + k * dk);
                            krow.iter().zip(dkrow.iter_mut()).for_each(|(&k, dk)| *dk = k * (*dk - a));
                        }
                        // dW_{q,k,v} rows += d{q,k,v} x^T; dx += W^T d{q,k,v}.
                        for (part, grad) in [(0, &head.q), (1, &head.k), (2, &head.v)] {
                            let r0 = (part * hid + h * d) * c;
                            mm(&mut dw_qkv[r0..r0 + d * c], (grad, n, 1), (xb, 1, n), (d, c, n), T::one(), true);
                            let first = part == 0 && h == 0;
                            mm(dxb, (&w[r0..r0 + d * c], 1, c), (grad, n, 1), (c, n, d), T::one(), !first);
                        }
                    }
                    dw
                },
            )
            .collect();
        dw_total.fill(T::zero());
        for p in partials {
            dw_total.iter_mut().zip(&p).for_each(|(a, &b)| *a += b);
        }
        Ok(())
    }
}

/// `dst[:, col0..col0 + n] += a (m x k) b (k x n)` for a row-major `dst` with `ld` columns.
fn mm_into_block<T: Real>(
    dst: &mut [T],
    ld: usize,
    col0: usize,
    a: View<T>,
    b: View<T>,
    (m, n, k): (usize, usize, usize),
) {
    assert!(col0 + n <= ld && dst.len() >= m * ld, "mm_into_block: block outside dst");
    gemm_checked(&mut dst[col0..], ld, a, b, (m, n, k), T::one(), true, "mm_into_block");
}

/// The layer `y = W_out linear_attention(W_qkv x)` on `x` `[batch, c, y, x]`, with
/// `w_qkv` `[3 heads d, c, 1, 1]` and `w_out` `[c, heads d, 1, 1]` (1x1 conv weights, no
/// biases); see the module docs. CPU, f32/f64; gradients to all three (first order only).
pub(crate) fn linear_attention_layer(
    x: &Tensor,
    w_qkv: &Tensor,
    w_out: &Tensor,
    heads: usize,
    d: usize,
) -> Result<Tensor> {
    let c = x.dim(1)?;
    let w = Tensor::cat(&[w_qkv.flatten_all()?, w_out.flatten_all()?], 0)?;
    Ok(apply2(x, &w, LinearAttentionLayer(Dims { heads, d, c }))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device, Var};
    use pbdl_core::conv::{conv2d, Conv2dParams};
    use pbdl_core::nn::softmax;
    use pbdl_core::{check_grad, seed, GradCheckOptions};

    /// The same layer composed from candle ops (1x1 convs, softmax, matmul).
    fn composed(x: &Tensor, w_qkv: &Tensor, w_out: &Tensor, heads: usize, d: usize) -> candle_core::Result<Tensor> {
        let p = Conv2dParams::default();
        let qkv = conv2d(x, w_qkv, None, &p).map_err(candle_core::Error::wrap)?;
        let (b, _, h, w) = qkv.dims4()?;
        let qkv = qkv.reshape((b, 3, heads, d, h * w))?;
        let part = |i: usize| qkv.narrow(1, i, 1).and_then(|t| t.squeeze(1)).and_then(|t| t.contiguous());
        let q = (softmax(&part(0)?, 2).map_err(candle_core::Error::wrap)? / (d as f64).sqrt())?;
        let k = softmax(&part(1)?, 3).map_err(candle_core::Error::wrap)?;
        let ctx = k.matmul(&part(2)?.t()?)?;
        let o = ctx.t()?.matmul(&q)?.reshape((b, heads * d, h, w))?;
        conv2d(&o, w_out, None, &p).map_err(candle_core::Error::wrap)
    }

    fn randn(shape: &[usize], std: f64, s: u64) -> Tensor {
        seed::randn(shape, 0.0, std, DType::F64, &Device::Cpu, s).unwrap()
    }

    fn max_abs(t: &Tensor) -> f64 {
        t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
    }

    #[test]
    fn forward_and_gradients_match_the_composed_layer() {
        let (heads, d, c) = (3, 5, 4);
        let x = Var::from_tensor(&randn(&[2, c, 4, 3], 1.0, 1)).unwrap();
        let wq = Var::from_tensor(&randn(&[3 * heads * d, c, 1, 1], 0.7, 2)).unwrap();
        let wo = Var::from_tensor(&randn(&[c, heads * d, 1, 1], 0.3, 3)).unwrap();
        let r = randn(&[2, c, 4, 3], 1.0, 4);
        let ours = linear_attention_layer(x.as_tensor(), wq.as_tensor(), wo.as_tensor(), heads, d).unwrap();
        let theirs = composed(x.as_tensor(), wq.as_tensor(), wo.as_tensor(), heads, d).unwrap();
        let err = max_abs(&(&ours - &theirs).unwrap()) / max_abs(&theirs);
        assert!(err < 1e-13, "forward {err:.2e}");
        let g1 = (ours * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let g2 = (theirs * &r).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, v) in [("x", &x), ("w_qkv", &wq), ("w_out", &wo)] {
            let (a, b) = (g1.get(v.as_tensor()).unwrap(), g2.get(v.as_tensor()).unwrap());
            let err = max_abs(&(a - b).unwrap()) / max_abs(b);
            assert!(err < 1e-12, "gradient of {name}: {err:.2e}");
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let inputs = [randn(&[2, 3, 3, 3], 1.0, 5), randn(&[24, 3, 1, 1], 0.7, 6), randn(&[3, 8, 1, 1], 0.5, 7)];
        let f = |t: &[Tensor]| linear_attention_layer(&t[0], &t[1], &t[2], 2, 4).map_err(candle_core::Error::wrap);
        let report = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
        println!("fused linear attention FD: max rel error {:.2e}", report.max_rel_error);
        assert!(report.max_rel_error < 1e-7, "{report:?}");
    }

    #[test]
    fn f32_agrees_with_f64() {
        let (x, wq, wo) = (randn(&[2, 8, 8, 4], 1.0, 8), randn(&[96, 8, 1, 1], 0.3, 9), randn(&[8, 32, 1, 1], 0.2, 10));
        let y64 = linear_attention_layer(&x, &wq, &wo, 4, 8).unwrap();
        let f = |t: &Tensor| t.to_dtype(DType::F32).unwrap();
        let y32 = linear_attention_layer(&f(&x), &f(&wq), &f(&wo), 4, 8).unwrap().to_dtype(DType::F64).unwrap();
        assert!(max_abs(&(y32 - &y64).unwrap()) / max_abs(&y64) < 1e-5);
    }

    #[test]
    fn mismatched_weights_are_an_error() {
        let x = randn(&[1, 4, 2, 2], 1.0, 11);
        assert!(
            linear_attention_layer(&x, &randn(&[24, 4, 1, 1], 1.0, 12), &randn(&[4, 6, 1, 1], 1.0, 13), 2, 4).is_err()
        );
    }
}
