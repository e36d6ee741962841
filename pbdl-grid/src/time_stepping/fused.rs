//! The fused projected Runge-Kutta step that the 2D and 3D Navier-Stokes steppers share: each
//! stage's combination `u0 + dt sum_j w_j k_j` runs in one custom op together with the
//! projection ([`CombineProject`], two terms per op, the projection in the last one), so a step
//! makes fewer temporaries than [`super::projected_runge_kutta`] with the same operators.
//!
//! A projection joins in by implementing [`ProjectionKernel`]: its forward kernel runs inside
//! the fused op, its adjoint gives the fused op's backward.

use super::ButcherTableau;
use crate::scratch::uninit;
use crate::Result;
use candle_core::{Shape, Tensor};
use pbdl_core::op::{apply1, apply3, Kernel1, Kernel3, Op1, Op3};
use pbdl_core::Real;

/// A velocity projection `P` as a custom op (2D `pressure::Projection`, 3D periodic
/// `grid3d::pressure::Projection3d`).
pub(crate) trait ProjectionKernel: Kernel1 + Op1 + Clone {
    /// Name of the fused combine-and-project op.
    const COMBINE_NAME: &'static str;

    /// `P^T g`: the cotangent carried back through the projection (itself differentiable).
    fn adjoint(&self, g: &Tensor) -> candle_core::Result<Tensor>;
}

/// `P(x0 + w1 x1 + w2 x2)` (or without `P`) in one op: a Runge-Kutta stage update and its
/// projection without intermediate tensors. Backward: `h = P^T g`, gradients `(h, w1 h, w2 h)`.
#[derive(Clone)]
pub(crate) struct CombineProject<P> {
    pub w: [f64; 2],
    pub projection: Option<P>,
}

impl<P: ProjectionKernel> Kernel3 for CombineProject<P> {
    fn name(&self) -> &'static str {
        P::COMBINE_NAME
    }
    fn output_shape(&self, a: &Shape, b: &Shape, c: &Shape) -> candle_core::Result<Shape> {
        if a != b || a != c {
            candle_core::bail!("{}: shapes differ: {a:?} {b:?} {c:?}", self.name());
        }
        Ok(a.clone())
    }
    fn forward<T: Real>(
        &self,
        a: &[T],
        s: &Shape,
        b: &[T],
        _bs: &Shape,
        c: &[T],
        _cs: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let (w1, w2) = (T::c(self.w[0]), T::c(self.w[1]));
        let comb = |o: &mut [T]| {
            for ((o, &x), (&y, &z)) in o.iter_mut().zip(a).zip(b.iter().zip(c)) {
                *o = x + w1 * y + w2 * z;
            }
        };
        match &self.projection {
            None => {
                comb(out);
                Ok(())
            }
            Some(p) => {
                let mut tmp = uninit::<T>(a.len());
                comb(&mut tmp);
                p.forward(&tmp, s, out)
            }
        }
    }
}

impl<P: ProjectionKernel> Op3 for CombineProject<P> {
    fn backward(
        &self,
        _a: &Tensor,
        _b: &Tensor,
        _c: &Tensor,
        _y: &Tensor,
        gy: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor)> {
        let h = match &self.projection {
            Some(p) => p.adjoint(gy)?,
            None => gy.clone(),
        };
        Ok((h.clone(), h.affine(self.w[0], 0.0)?, h.affine(self.w[1], 0.0)?))
    }
}

/// One projected Runge-Kutta step of `u0` (already projected) with the stage combinations fused
/// with `projection`: the numbers of [`super::projected_runge_kutta`] up to round-off.
pub(crate) fn fused_projected_runge_kutta<P: ProjectionKernel>(
    u0: &Tensor,
    dt: f64,
    tableau: &ButcherTableau,
    rhs: impl Fn(&Tensor) -> Result<Tensor>,
    projection: &P,
) -> Result<Tensor> {
    let mut k: Vec<Tensor> = Vec::with_capacity(tableau.stages());
    k.push(rhs(u0)?);
    for i in 1..tableau.stages() {
        let ui = combine_project(u0, dt, &tableau.a[i], &k, projection)?;
        k.push(rhs(&ui)?);
    }
    combine_project(u0, dt, &tableau.b, &k, projection)
}

/// `P(u0 + dt sum_j w_j k_j)`, two terms per fused op, the projection in the last one.
fn combine_project<P: ProjectionKernel>(
    u0: &Tensor,
    dt: f64,
    w: &[f64],
    k: &[Tensor],
    projection: &P,
) -> Result<Tensor> {
    let terms: Vec<(f64, &Tensor)> = w.iter().zip(k).filter(|(w, _)| **w != 0.0).map(|(w, k)| (dt * w, k)).collect();
    let mut acc = u0.clone();
    let mut rest = &terms[..];
    loop {
        let last = rest.len() <= 2;
        let p = if last { Some(projection.clone()) } else { None };
        let (w1, k1, w2, k2) = match rest {
            [] => return Ok(apply1(&acc, projection.clone())?),
            [(w1, k1)] => (*w1, *k1, 0.0, *k1),
            [(w1, k1), (w2, k2), ..] => (*w1, *k1, *w2, *k2),
        };
        acc = apply3(&acc, k1, k2, CombineProject { w: [w1, w2], projection: p })?;
        if last {
            return Ok(acc);
        }
        rest = &rest[2..];
    }
}
