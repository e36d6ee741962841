//! One explicit Runge-Kutta step with a projection after every stage (jax-cfd's
//! `navier_stokes_rk`): `u_i = P(u0 + dt sum_j a_ij k_j)`, `k_i = f(u_i)`,
//! `u1 = P(u0 + dt sum_i b_i k_i)`.

use super::ButcherTableau;
use crate::Result;
use candle_core::Tensor;

/// Advances `u0` (already projected) by `dt`; `rhs` is the tendency, `project` the constraint.
/// Differentiable when `rhs` and `project` are.
pub fn projected_runge_kutta<F, P>(u0: &Tensor, dt: f64, tableau: &ButcherTableau, rhs: F, project: P) -> Result<Tensor>
where
    F: Fn(&Tensor) -> Result<Tensor>,
    P: Fn(&Tensor) -> Result<Tensor>,
{
    let mut k: Vec<Tensor> = Vec::with_capacity(tableau.stages());
    k.push(rhs(u0)?);
    for i in 1..tableau.stages() {
        let ui = project(&combine(u0, dt, &tableau.a[i], &k)?)?;
        k.push(rhs(&ui)?);
    }
    project(&combine(u0, dt, &tableau.b, &k)?)
}

/// `u0 + dt sum_j w_j k_j`, skipping zero weights.
fn combine(u0: &Tensor, dt: f64, w: &[f64], k: &[Tensor]) -> Result<Tensor> {
    let mut acc: Option<Tensor> = None;
    for (&wj, kj) in w.iter().zip(k) {
        if wj == 0.0 {
            continue;
        }
        let term = kj.affine(dt * wj, 0.0)?;
        acc = Some(match acc {
            None => term,
            Some(a) => (a + term)?,
        });
    }
    Ok(match acc {
        None => u0.clone(),
        Some(a) => (u0 + a)?,
    })
}
