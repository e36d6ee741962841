//! Controlled ODEs `dx/dt = f(x, u)` integrated by classical RK4 with one control value per
//! step (held constant within the step), with the exact Jacobian of the final state with
//! respect to every control value.
//!
//! Per step, tangents of the RK4 stages give `M_k = dx_{k+1}/dx_k` (`n x n`) and
//! `c_k = dx_{k+1}/du_k` (`n`), exactly (the chain rule through the four stages, no finite
//! differences). A backward sweep `P = I; for k = N-1..0 { J[:, k] = P c_k; P = P M_k }` then
//! gives `dx_N/du`. Cost: `O(N n^3)` per sample, tiny for the oscillators (`n = 4`).

use super::Physics;
use crate::error::Result;

/// A controlled ODE `dx/dt = f(x, u)` with a scalar control.
pub trait ControlledOde: Sync {
    /// State dimension `n`.
    fn dim(&self) -> usize;
    /// `out = f(x, u)`.
    fn rhs(&self, x: &[f64], u: f64, out: &mut [f64]);
    /// `jx = df/dx` (`[n, n]` row-major) and `ju = df/du` (`n`).
    fn rhs_jacobian(&self, x: &[f64], u: f64, jx: &mut [f64], ju: &mut [f64]);
}

/// `steps` RK4 steps of size `dt` of a [`ControlledOde`]: context = initial state, control =
/// one value per step, outcome = final state.
#[derive(Clone, Debug)]
pub struct Rk4Rollout<O> {
    /// The ODE.
    pub ode: O,
    /// Step size.
    pub dt: f64,
    /// Number of steps (= control length).
    pub steps: usize,
}

/// Scratch of one RK4 step with tangents.
struct Stage {
    k: [Vec<f64>; 4],
    xs: Vec<f64>,
    jx: Vec<f64>,
    ju: Vec<f64>,
    /// Stage tangents `[4][n, n + 1]` (columns: d/dx_0..d/dx_{n-1}, d/du).
    dk: [Vec<f64>; 4],
    /// Tangent of the stage point `[n, n + 1]`.
    dxs: Vec<f64>,
}

impl Stage {
    fn new(n: usize) -> Self {
        let v = || vec![0.0; n];
        let m = || vec![0.0; n * (n + 1)];
        Self { k: [v(), v(), v(), v()], xs: v(), jx: vec![0.0; n * n], ju: v(), dk: [m(), m(), m(), m()], dxs: m() }
    }
}

impl<O: ControlledOde> Rk4Rollout<O> {
    /// One RK4 step in place.
    fn step(&self, x: &mut [f64], u: f64, st: &mut Stage) {
        let n = x.len();
        let h = self.dt;
        let coef = [0.0, 0.5 * h, 0.5 * h, h];
        for s in 0..4 {
            for i in 0..n {
                st.xs[i] = x[i] + if s == 0 { 0.0 } else { coef[s] * st.k[s - 1][i] };
            }
            let (xs, k) = (&st.xs, &mut st.k[s]);
            self.ode.rhs(xs, u, k);
        }
        for i in 0..n {
            x[i] += h / 6.0 * (st.k[0][i] + 2.0 * st.k[1][i] + 2.0 * st.k[2][i] + st.k[3][i]);
        }
    }

    /// One RK4 step in place, writing `M = dx_new/dx` and `c = dx_new/du` into `tangent`
    /// (`[n, n + 1]`, last column `c`).
    fn step_tangent(&self, x: &mut [f64], u: f64, st: &mut Stage, tangent: &mut [f64]) {
        let n = x.len();
        let w = n + 1;
        let h = self.dt;
        let coef = [0.0, 0.5 * h, 0.5 * h, h];
        for s in 0..4 {
            // Stage point and its tangent: xs = x + a k_{s-1}, dxs = [I | 0] + a dk_{s-1}.
            for i in 0..n {
                st.xs[i] = x[i] + if s == 0 { 0.0 } else { coef[s] * st.k[s - 1][i] };
                for j in 0..w {
                    let id = if i == j { 1.0 } else { 0.0 };
                    st.dxs[i * w + j] = id + if s == 0 { 0.0 } else { coef[s] * st.dk[s - 1][i * w + j] };
                }
            }
            self.ode.rhs(&st.xs, u, &mut st.k[s]);
            self.ode.rhs_jacobian(&st.xs, u, &mut st.jx, &mut st.ju);
            // dk_s = Jx dxs + ju e_u^T.
            let dk = &mut st.dk[s];
            for i in 0..n {
                for j in 0..w {
                    let mut acc = if j == n { st.ju[i] } else { 0.0 };
                    for l in 0..n {
                        acc += st.jx[i * n + l] * st.dxs[l * w + j];
                    }
                    dk[i * w + j] = acc;
                }
            }
        }
        for i in 0..n {
            x[i] += h / 6.0 * (st.k[0][i] + 2.0 * st.k[1][i] + 2.0 * st.k[2][i] + st.k[3][i]);
            for j in 0..w {
                let id = if i == j { 1.0 } else { 0.0 };
                tangent[i * w + j] = id
                    + h / 6.0
                        * (st.dk[0][i * w + j]
                            + 2.0 * st.dk[1][i * w + j]
                            + 2.0 * st.dk[2][i * w + j]
                            + st.dk[3][i * w + j]);
            }
        }
    }

    /// The whole trajectory `[steps + 1, n]` (initial state first).
    pub fn trajectory(&self, x0: &[f64], u: &[f64]) -> Result<Vec<f64>> {
        let n = self.ode.dim();
        crate::error::check_len("initial state length", n, x0.len())?;
        crate::error::check_len("control length (steps)", self.steps, u.len())?;
        let mut st = Stage::new(n);
        let mut x = x0.to_vec();
        let mut out = x0.to_vec();
        for &uk in u {
            self.step(&mut x, uk, &mut st);
            out.extend_from_slice(&x);
        }
        Ok(out)
    }
}

impl<O: ControlledOde> Physics for Rk4Rollout<O> {
    fn context_dim(&self) -> usize {
        self.ode.dim()
    }

    fn control_dim(&self) -> usize {
        self.steps
    }

    fn output_dim(&self) -> usize {
        self.ode.dim()
    }

    fn forward(&self, x: &[f64], u: &[f64], y: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        let mut st = Stage::new(x.len());
        y.copy_from_slice(x);
        for &uk in u {
            self.step(y, uk, &mut st);
        }
        Ok(())
    }

    fn jacobian(&self, x: &[f64], u: &[f64], y: &mut [f64], jac: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        let n = x.len();
        let w = n + 1;
        crate::error::check_len("physics Jacobian length", n * self.steps, jac.len())?;
        let mut st = Stage::new(n);
        let mut tangents = vec![0.0; self.steps * n * w];
        y.copy_from_slice(x);
        for (k, &uk) in u.iter().enumerate() {
            self.step_tangent(y, uk, &mut st, &mut tangents[k * n * w..(k + 1) * n * w]);
        }
        // Backward sweep: P = dx_N/dx_{k+1}.
        let mut p = vec![0.0; n * n];
        let mut q = vec![0.0; n * n];
        for i in 0..n {
            p[i * n + i] = 1.0;
        }
        for k in (0..self.steps).rev() {
            let t = &tangents[k * n * w..(k + 1) * n * w];
            for i in 0..n {
                jac[i * self.steps + k] = (0..n).map(|l| p[i * n + l] * t[l * w + n]).sum();
            }
            for i in 0..n {
                for j in 0..n {
                    q[i * n + j] = (0..n).map(|l| p[i * n + l] * t[l * w + j]).sum();
                }
            }
            std::mem::swap(&mut p, &mut q);
        }
        Ok(())
    }
}
