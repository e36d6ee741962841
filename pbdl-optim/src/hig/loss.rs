//! Per-sample losses `l(y, y*)` and their gradients `dl/dy`, shared by HIG, Gauss-Newton and Adam.
//!
//! The trainers sum `l` over a batch of `b` samples, report `L / b` and hand HIG the right-hand
//! side `g = d(L / b)/dy` (flattened sample after sample), exactly as for least squares.

use crate::error::{check_len, Error, Result};
use serde::{Deserialize, Serialize};

/// Which per-sample loss a trainer minimises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Loss {
    /// `||y - y*||^2` (no 1/2), gradient `2 (y - y*)`: the oscillators, the linear chain and
    /// the Poisson problem. The default.
    #[default]
    SquaredError,
    /// `1 - |<y*|y>|^2` for complex vectors stored as interleaved `(Re, Im)` pairs: the quantum
    /// dipole's infidelity between the reached state `y` and the target `y*` (both unit norm).
    Infidelity,
}

impl Loss {
    /// Checks that outcomes of length `dim` fit this loss (`Infidelity` needs `(Re, Im)` pairs).
    pub fn check_dim(&self, dim: usize) -> Result<()> {
        match self {
            Loss::SquaredError => Ok(()),
            Loss::Infidelity if dim % 2 == 0 && dim > 0 => Ok(()),
            Loss::Infidelity => Err(Error::shape(
                "outcome length for the infidelity loss (interleaved Re, Im pairs of a complex state)",
                "an even number > 0",
                dim,
            )),
        }
    }

    /// `l(y, y*)` of one sample.
    pub fn value(&self, y: &[f64], target: &[f64]) -> Result<f64> {
        check_len("loss target length (outcome length)", y.len(), target.len())?;
        self.check_dim(y.len())?;
        Ok(match self {
            Loss::SquaredError => y.iter().zip(target).map(|(a, b)| (a - b) * (a - b)).sum(),
            Loss::Infidelity => {
                let (re, im) = overlap(y, target);
                1.0 - (re * re + im * im)
            }
        })
    }

    /// `l(y, y*)` of one sample, writing `dl/dy` into `grad` (length of `y`).
    pub fn value_and_gradient(&self, y: &[f64], target: &[f64], grad: &mut [f64]) -> Result<f64> {
        check_len("loss target length (outcome length)", y.len(), target.len())?;
        check_len("loss gradient length (outcome length)", y.len(), grad.len())?;
        self.check_dim(y.len())?;
        Ok(match self {
            Loss::SquaredError => {
                let mut l = 0.0;
                for ((g, a), b) in grad.iter_mut().zip(y).zip(target) {
                    let r = a - b;
                    l += r * r;
                    *g = 2.0 * r;
                }
                l
            }
            Loss::Infidelity => {
                // <t|y> = a + i b with a = sum(t_r y_r + t_i y_i), b = sum(t_r y_i - t_i y_r);
                // l = 1 - a^2 - b^2, so dl/dy_r = -2 (a t_r - b t_i), dl/dy_i = -2 (a t_i + b t_r).
                let (a, b) = overlap(y, target);
                for (g, t) in grad.chunks_exact_mut(2).zip(target.chunks_exact(2)) {
                    g[0] = -2.0 * (a * t[0] - b * t[1]);
                    g[1] = -2.0 * (a * t[1] + b * t[0]);
                }
                1.0 - (a * a + b * b)
            }
        })
    }
}

/// `<t|y> = sum conj(t_j) y_j` of interleaved complex vectors, as `(Re, Im)`.
fn overlap(y: &[f64], t: &[f64]) -> (f64, f64) {
    y.chunks_exact(2)
        .zip(t.chunks_exact(2))
        .fold((0.0, 0.0), |(re, im), (y, t)| (re + t[0] * y[0] + t[1] * y[1], im + t[0] * y[1] - t[1] * y[0]))
}
