//! Chains of coupled oscillators with a control force on one of them.
//!
//! State `[q_1..q_n, p_1..p_n]`; `dq_i/dt = p_i`, `dp_i/dt = -q_i + coupling_i + g u e_c`.
//!
//! * [`Oscillators::linear_chain`] — the pbdl-book example ("Coupled Oscillators with
//!   Half-Inverse Gradients"): `n = 2`, coupling `0.2 (L q)_i` with the chain Laplacian `L`
//!   whose end rows are `[-1, 1]` (free ends), gain `1` on the last oscillator; RK4 with
//!   `dt = 0.5`, 24 steps.
//! * [`Oscillators::nonlinear`] — the HIG paper's nonlinear oscillators:
//!   coupling `sum_nb (q_nb - q_i)^3`, gain `3` on the second oscillator; RK4 with
//!   `dt = 0.125`, 96 steps (`T = 12`).

use super::ode::{ControlledOde, Rk4Rollout};
use serde::{Deserialize, Serialize};

/// How neighbouring oscillators pull on each other.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Coupling {
    /// `strength * sum_nb (q_nb - q_i)` (the chain Laplacian with free ends).
    Linear(f64),
    /// `strength * sum_nb (q_nb - q_i)^3`.
    Cubic(f64),
}

/// `n` oscillators in a chain with a control force on `control_index`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Oscillators {
    /// Number of oscillators (state dimension `2 n`).
    pub n: usize,
    /// The coupling between neighbours.
    pub coupling: Coupling,
    /// Factor of the control in `dp/dt`.
    pub gain: f64,
    /// Which oscillator the control pushes.
    pub control_index: usize,
}

impl Oscillators {
    /// The pbdl-book linear chain: 2 oscillators, linear coupling 0.2, RK4 `dt = 0.5`, 24 steps.
    pub fn linear_chain() -> Rk4Rollout<Self> {
        Rk4Rollout {
            ode: Self { n: 2, coupling: Coupling::Linear(0.2), gain: 1.0, control_index: 1 },
            dt: 0.5,
            steps: 24,
        }
    }

    /// The HIG paper's nonlinear oscillators: 2 oscillators, cubic coupling, gain 3 on the
    /// second, RK4 `dt = 0.125`, 96 steps.
    pub fn nonlinear() -> Rk4Rollout<Self> {
        Rk4Rollout {
            ode: Self { n: 2, coupling: Coupling::Cubic(1.0), gain: 3.0, control_index: 1 },
            dt: 0.125,
            steps: 96,
        }
    }

    fn neighbours(&self, i: usize) -> impl Iterator<Item = usize> {
        let n = self.n;
        [i.checked_sub(1), (i + 1 < n).then_some(i + 1)].into_iter().flatten()
    }
}

impl ControlledOde for Oscillators {
    fn dim(&self) -> usize {
        2 * self.n
    }

    fn rhs(&self, x: &[f64], u: f64, out: &mut [f64]) {
        let n = self.n;
        let (q, p) = x.split_at(n);
        for i in 0..n {
            out[i] = p[i];
            let mut f = -q[i];
            for j in self.neighbours(i) {
                let d = q[j] - q[i];
                f += match self.coupling {
                    Coupling::Linear(s) => s * d,
                    Coupling::Cubic(s) => s * d * d * d,
                };
            }
            if i == self.control_index {
                f += self.gain * u;
            }
            out[n + i] = f;
        }
    }

    fn rhs_jacobian(&self, x: &[f64], _u: f64, jx: &mut [f64], ju: &mut [f64]) {
        let n = self.n;
        let m = 2 * n;
        jx.fill(0.0);
        ju.fill(0.0);
        let q = &x[..n];
        for i in 0..n {
            jx[i * m + n + i] = 1.0;
            let row = (n + i) * m;
            jx[row + i] = -1.0;
            for j in self.neighbours(i) {
                let d = q[j] - q[i];
                let dd = match self.coupling {
                    Coupling::Linear(s) => s,
                    Coupling::Cubic(s) => 3.0 * s * d * d,
                };
                jx[row + j] += dd;
                jx[row + i] -= dd;
            }
        }
        ju[n + self.control_index] = self.gain;
    }
}
