//! The HIG paper's Poisson problem: the network maps `y = L x_gt` back to `x`, and the loss is
//! `||L x - y||^2`, with `L` the 5-point Laplacian on an 8x8 grid (unit spacing) and zero
//! Dirichlet values outside the grid. The physics is linear, so its Jacobian is `L` itself.

use super::{Dataset, Physics};
use crate::error::Result;

/// Grid size of the Poisson problem.
pub const N: usize = 8;

/// `y = L u` on the 8x8 grid (no context).
#[derive(Clone, Copy, Debug, Default)]
pub struct Poisson8;

impl Poisson8 {
    fn apply(u: &[f64], y: &mut [f64]) {
        for r in 0..N {
            for c in 0..N {
                let at = |rr: isize, cc: isize| {
                    if rr < 0 || cc < 0 || rr >= N as isize || cc >= N as isize {
                        0.0
                    } else {
                        u[rr as usize * N + cc as usize]
                    }
                };
                let (ri, ci) = (r as isize, c as isize);
                y[r * N + c] = at(ri - 1, ci) + at(ri + 1, ci) + at(ri, ci - 1) + at(ri, ci + 1) - 4.0 * at(ri, ci);
            }
        }
    }

    /// `n` samples: `x_gt ~ N(0, 1)` per cell, network input and target `y = L x_gt`.
    pub fn dataset(n: usize, seed: u64) -> Dataset {
        use rand_distr_free::normal;
        let mut rng = pbdl_core::seed::rng(seed);
        let mut y = vec![0.0; n * N * N];
        let mut x = vec![0.0; N * N];
        for s in 0..n {
            x.iter_mut().for_each(|v| *v = normal(&mut rng));
            Self::apply(&x, &mut y[s * N * N..(s + 1) * N * N]);
        }
        Dataset { inputs: y.clone(), contexts: Vec::new(), targets: y, len: n }
    }
}

/// A standard normal draw by Box-Muller (keeps `rand_distr` out of this crate's dependencies).
mod rand_distr_free {
    use rand::Rng;
    pub fn normal(rng: &mut impl Rng) -> f64 {
        let u1: f64 = 1.0 - rng.random_range(0.0..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

impl Physics for Poisson8 {
    fn context_dim(&self) -> usize {
        0
    }

    fn control_dim(&self) -> usize {
        N * N
    }

    fn output_dim(&self) -> usize {
        N * N
    }

    fn forward(&self, x: &[f64], u: &[f64], y: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        Self::apply(u, y);
        Ok(())
    }

    fn jacobian(&self, x: &[f64], u: &[f64], y: &mut [f64], jac: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        crate::error::check_len("physics Jacobian length", N * N * N * N, jac.len())?;
        Self::apply(u, y);
        // Column j of L is L e_j.
        let mut e = vec![0.0; N * N];
        let mut col = vec![0.0; N * N];
        for j in 0..N * N {
            e[j] = 1.0;
            Self::apply(&e, &mut col);
            e[j] = 0.0;
            for i in 0..N * N {
                jac[i * N * N + j] = col[i];
            }
        }
        Ok(())
    }
}
