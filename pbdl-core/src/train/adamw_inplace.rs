//! The AdamW update as three in-place passes over each variable's buffers.
//!
//! candle-nn's update is 15 tensor ops per variable, each allocating and writing a full-size
//! buffer (about 30 passes over memory). These kernels compute the same `f32`/`f64`
//! operations in the same order, element by element, so the results are bit-identical
//! (tested against the composed update), in three passes and without allocating: the first
//! moment, the second moment, then the variable.
//!
//! candle's `tensor * c` is `x * c + 0` (its affine map); the `+ 0` is kept because it turns
//! `-0` into `+0`, and dropping it would change the bits of exact zeros.

use crate::op::dense;
use crate::Real;
use candle_core::{CpuStorage, InplaceOp2, InplaceOp3, Layout, Tensor};
use rayon::prelude::*;

/// `x * c + 0` in `T`, as candle's `affine(c, 0)`.
#[inline(always)]
fn scale<T: Real>(x: T, c: T) -> T {
    x * c + T::zero()
}

/// The contiguous elements of a destination buffer, or an error for strided ones (the caller
/// then uses the composed update).
fn dst_slice<'a, T: Real>(data: &'a mut [T], layout: &Layout, op: &str) -> candle_core::Result<&'a mut [T]> {
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&mut data[start..end]),
        None => candle_core::bail!("{op}: the destination is not contiguous"),
    }
}

/// Runs `f(dst_chunk, offset)` over `dst` in parallel chunks when it is large: elementwise
/// work, so the split does not change any value.
fn for_chunks<T: Real>(dst: &mut [T], f: impl Fn(&mut [T], usize) + Sync) {
    const CHUNK: usize = 1 << 14;
    if crate::threads::parallel(dst.len()) {
        dst.par_chunks_mut(CHUNK).enumerate().for_each(|(i, c)| f(c, i * CHUNK));
    } else {
        f(dst, 0);
    }
}

/// `m = m * beta + g * (1 - beta)` (first moment) or `v = v * beta + g^2 * (1 - beta)`
/// (second moment), in place.
pub(crate) struct MomentUpdate {
    /// `beta1` or `beta2`.
    pub beta: f64,
    /// Whether the gradient is squared (second moment).
    pub squared: bool,
}

impl MomentUpdate {
    fn run<T: Real>(&self, dst: &mut [T], l1: &Layout, g: &CpuStorage, l2: &Layout) -> candle_core::Result<()> {
        let dst = dst_slice(dst, l1, "adamw_moment")?;
        let g = dense::<T>(g, l2)?;
        if g.len() != dst.len() {
            candle_core::bail!("adamw_moment: gradient has {} elements, the moment {}", g.len(), dst.len());
        }
        let (beta, rest) = (T::c(self.beta), T::c(1.0 - self.beta));
        let squared = self.squared;
        for_chunks(dst, |d, off| {
            crate::vmath::with_simd(
                #[inline(always)]
                || {
                    let g = &g[off..off + d.len()];
                    for (x, &gi) in d.iter_mut().zip(g) {
                        let gi = if squared { gi * gi } else { gi };
                        *x = scale(*x, beta) + scale(gi, rest);
                    }
                },
            )
        });
        Ok(())
    }
}

impl InplaceOp2 for MomentUpdate {
    fn name(&self) -> &'static str {
        "adamw_moment"
    }

    fn cpu_fwd(&self, s1: &mut CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> candle_core::Result<()> {
        match s1 {
            CpuStorage::F32(d) => self.run(d, l1, s2, l2),
            CpuStorage::F64(d) => self.run(d, l1, s2, l2),
            _ => candle_core::bail!("adamw_moment: f32 or f64 only"),
        }
    }
}

/// `theta = theta * (1 - lr wd) - (m * scale_m) / (sqrt(v * scale_v) + eps) * lr`, in place.
pub(crate) struct ParamUpdate {
    /// Learning rate.
    pub lr: f64,
    /// `1 - lr * weight_decay`.
    pub keep: f64,
    /// `1 / (1 - beta1^t)`.
    pub scale_m: f64,
    /// `1 / (1 - beta2^t)`.
    pub scale_v: f64,
    /// Added to the root of the second moment.
    pub eps: f64,
}

impl ParamUpdate {
    #[allow(clippy::too_many_arguments)]
    fn run<T: Real>(
        &self,
        dst: &mut [T],
        l1: &Layout,
        m: &CpuStorage,
        l2: &Layout,
        v: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<()> {
        let dst = dst_slice(dst, l1, "adamw_param")?;
        let (m, v) = (dense::<T>(m, l2)?, dense::<T>(v, l3)?);
        if m.len() != dst.len() || v.len() != dst.len() {
            candle_core::bail!("adamw_param: moments do not match the variable's {} elements", dst.len());
        }
        let (lr, keep, sm, sv, eps) =
            (T::c(self.lr), T::c(self.keep), T::c(self.scale_m), T::c(self.scale_v), T::c(self.eps));
        for_chunks(dst, |d, off| {
            crate::vmath::with_simd(
                #[inline(always)]
                || {
                    let (m, v) = (&m[off..off + d.len()], &v[off..off + d.len()]);
                    for ((x, &mi), &vi) in d.iter_mut().zip(m).zip(v) {
                        // candle: (v_hat.sqrt() + eps) is affine(1, eps).
                        let denom = scale(vi, sv).sqrt() * T::one() + eps;
                        *x = scale(*x, keep) - scale(scale(mi, sm) / denom, lr);
                    }
                },
            )
        });
        Ok(())
    }
}

impl InplaceOp3 for ParamUpdate {
    fn name(&self) -> &'static str {
        "adamw_param"
    }

    fn cpu_fwd(
        &self,
        s1: &mut CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<()> {
        match s1 {
            CpuStorage::F32(d) => self.run(d, l1, s2, l2, s3, l3),
            CpuStorage::F64(d) => self.run(d, l1, s2, l2, s3, l3),
            _ => candle_core::bail!("adamw_param: f32 or f64 only"),
        }
    }
}

/// Whether the in-place kernels apply to a variable: on the CPU, `f32`/`f64`, contiguous, and
/// fusion not switched off ([`crate::nn::with_composed`]).
pub(crate) fn applies(var: &Tensor, m: &Tensor, v: &Tensor, g: &Tensor) -> bool {
    crate::nn::fusion_enabled()
        && var.device().is_cpu()
        && matches!(var.dtype(), candle_core::DType::F32 | candle_core::DType::F64)
        && [var, m, v].iter().all(|t| t.is_contiguous())
        && g.dtype() == var.dtype()
        && g.dims() == var.dims()
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    /// The kernels themselves (not the optimiser's dispatch) against candle's expression for
    /// one update, bit for bit, with `-0.0` and exact-zero entries.
    #[test]
    fn kernels_equal_candles_expression() {
        let dev = Device::Cpu;
        for dtype in [DType::F32, DType::F64] {
            let t = |v: &[f64]| Tensor::new(v, &dev).unwrap().to_dtype(dtype).unwrap();
            let (theta, m, v, g) = (
                t(&[0.5, -0.0, 1.5, -2.0, 0.0]),
                t(&[0.1, 0.0, -0.3, 0.2, -0.0]),
                t(&[0.01, 0.0, 0.04, 0.09, 0.0]),
                t(&[0.0, 1.0, -0.0, 3.0, -2.5]),
            );
            let (b1, b2, lr, wd, eps, step) = (0.9, 0.999, 1e-2, 0.1, 1e-8, 3);
            let (sm, sv) = (1.0 / (1.0 - f64::powi(b1, step)), 1.0 / (1.0 - f64::powi(b2, step)));
            // candle-nn 0.11's AdamW::step.
            let next_m = ((&m * b1).unwrap() + (&g * (1.0 - b1)).unwrap()).unwrap();
            let next_v = ((&v * b2).unwrap() + (g.sqr().unwrap() * (1.0 - b2)).unwrap()).unwrap();
            let adjusted =
                ((&next_m * sm).unwrap() / ((&next_v * sv).unwrap().sqrt().unwrap() + eps).unwrap()).unwrap();
            let want = ((&theta * (1.0 - lr * wd)).unwrap() - (adjusted * lr).unwrap()).unwrap();
            assert!(applies(&theta, &m, &v, &g), "the in-place path must apply to CPU {dtype:?}");
            let (mi, vi, thi) = (m.copy().unwrap(), v.copy().unwrap(), theta.copy().unwrap());
            mi.inplace_op2(&g, &MomentUpdate { beta: b1, squared: false }).unwrap();
            vi.inplace_op2(&g, &MomentUpdate { beta: b2, squared: true }).unwrap();
            let update = ParamUpdate { lr, keep: 1.0 - lr * wd, scale_m: sm, scale_v: sv, eps };
            thi.inplace_op3(&mi, &vi, &update).unwrap();
            let bits = |t: &Tensor| -> Vec<u64> {
                t.to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap().into_iter().map(f64::to_bits).collect()
            };
            assert_eq!(bits(&mi), bits(&next_m), "{dtype:?} first moment");
            assert_eq!(bits(&vi), bits(&next_v), "{dtype:?} second moment");
            assert_eq!(bits(&thi), bits(&want), "{dtype:?} variable");
            assert_ne!(bits(&thi), bits(&theta));
        }
    }
}
