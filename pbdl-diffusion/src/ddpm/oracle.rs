//! The exact noise predictor for Gaussian data: the outside reference for the samplers.
//!
//! Per pixel the data is Gaussian over channels, `z_0 ~ N(m, S)`. Then `z_i = sqrt(abar) z_0 +
//! sqrt(1 - abar) eps` is jointly Gaussian with `eps`, and the minimiser of the epsilon-MSE is the
//! conditional mean `E[eps | z_i] = sqrt(1 - abar) (abar S + (1 - abar) I)^{-1} (z_i - sqrt(abar) m)`
//! (for a diagonal `S = diag(sigma^2)` this is `sqrt(1 - abar) (z_i - sqrt(abar) mu) /
//! (abar sigma^2 + 1 - abar)`). The remaining loss is the conditional variance
//! `tr(I - (1 - abar) (abar S + (1 - abar) I)^{-1}) / C`, averaged over the steps:
//! [`GaussianOracle::min_loss`].
//!
//! With clean conditioning on the first `k` channels the same formula is applied to the
//! conditional distribution of the target given the clean condition,
//! `N(m_x + S_xc S_cc^{-1} (c - m_c), S_xx - S_xc S_cc^{-1} S_cx)`.

use super::NoisePredictor;
use crate::schedule::NoiseSchedule;
use crate::{Error, Result};
use candle_core::{DType, Tensor};
use std::collections::HashMap;

/// The optimal noise predictor for per-pixel Gaussian data `N(mean, cov)` over channels.
#[derive(Debug, Clone)]
pub struct GaussianOracle {
    schedule: NoiseSchedule,
    mean: Vec<f64>,
    cov: Vec<f64>,
    cond_channels: usize,
}

/// The affine noise predictor of one step: `eps = a (x - sqrt(abar) m_x|c)`, with the
/// conditional mean `m_x|c = m_x + g (c - m_c)` for clean conditioning.
struct StepMap {
    a: Vec<f64>,
    sqrt_ab: f64,
}

impl GaussianOracle {
    /// Independent channels: `x_0[c] ~ N(mean[c], std[c]^2)`; all channels are diffused.
    pub fn diagonal(schedule: NoiseSchedule, mean: &[f64], std: &[f64]) -> Result<Self> {
        if mean.len() != std.len() || mean.is_empty() {
            return Err(Error::shape("GaussianOracle std (one per mean channel)", mean.len(), std.len()));
        }
        let n = mean.len();
        let mut cov = vec![0.0; n * n];
        for (c, s) in std.iter().enumerate() {
            cov[c * n + c] = s * s;
        }
        Self::joint(schedule, mean.to_vec(), cov)
    }

    /// Correlated channels: `z_0 ~ N(mean, cov)` per pixel (`cov` row-major `C x C`, symmetric
    /// positive definite); all channels are diffused (ACDM's noisy conditioning).
    pub fn joint(schedule: NoiseSchedule, mean: Vec<f64>, cov: Vec<f64>) -> Result<Self> {
        let n = mean.len();
        if n == 0 || cov.len() != n * n {
            return Err(Error::shape("GaussianOracle covariance (C x C for C mean channels)", n * n, cov.len()));
        }
        if mean.iter().chain(&cov).any(|v| !v.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "GaussianOracle mean/cov",
                value: "non-finite entry".into(),
                hint: "give finite means and covariances",
            });
        }
        let symmetric = (0..n).all(|i| (0..n).all(|j| (cov[i * n + j] - cov[j * n + i]).abs() <= 1e-12));
        if !symmetric || cholesky(&cov, n).is_none() {
            return Err(Error::InvalidConfig {
                name: "GaussianOracle covariance",
                value: format!("{cov:?}"),
                hint: "the covariance must be symmetric positive definite",
            });
        }
        Ok(Self { schedule, mean, cov, cond_channels: 0 })
    }

    /// Treats the first `k` channels as a clean condition: the model input is `[c, x_i]` and
    /// the output is the noise of the remaining channels (clean conditioning). `k = 0` undoes it.
    pub fn with_clean_condition(mut self, k: usize) -> Result<Self> {
        if k >= self.mean.len() {
            return Err(Error::InvalidConfig {
                name: "GaussianOracle condition channels",
                value: k.to_string(),
                hint: "leave at least one target channel after the condition channels",
            });
        }
        self.cond_channels = k;
        Ok(self)
    }

    /// The schedule the oracle was built for.
    pub fn schedule(&self) -> &NoiseSchedule {
        &self.schedule
    }

    /// Number of predicted (target) channels.
    pub fn output_channels(&self) -> usize {
        self.mean.len() - self.cond_channels
    }

    /// `(g, conditional covariance)` of the target given the clean condition: `g = S_xc S_cc^{-1}`.
    fn conditional(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.mean.len();
        let k = self.cond_channels;
        let m = n - k;
        let s = |i: usize, j: usize| self.cov[i * n + j];
        if k == 0 {
            return (vec![], self.cov.clone());
        }
        let scc: Vec<f64> = (0..k * k).map(|ij| s(ij / k, ij % k)).collect();
        let scc_inv = invert(&scc, k).expect("positive definite blocks are invertible");
        let g: Vec<f64> =
            (0..m * k).map(|ij| (0..k).map(|l| s(k + ij / k, l) * scc_inv[l * k + ij % k]).sum()).collect();
        let cond_cov: Vec<f64> = (0..m * m)
            .map(|ij| {
                let (i, j) = (ij / m, ij % m);
                s(k + i, k + j) - (0..k).map(|l| g[i * k + l] * s(l, k + j)).sum::<f64>()
            })
            .collect();
        (g, cond_cov)
    }

    /// `abar S + (1 - abar) I` of the target's (conditional) covariance at step `i`.
    fn noisy_cov(&self, cond_cov: &[f64], i: usize) -> Vec<f64> {
        let m = self.output_channels();
        let ab = self.schedule.alpha_bar(i);
        (0..m * m).map(|ij| ab * cond_cov[ij] + if ij / m == ij % m { 1.0 - ab } else { 0.0 }).collect()
    }

    fn step_map(&self, cond_cov: &[f64], i: usize) -> StepMap {
        let m = self.output_channels();
        let ab = self.schedule.alpha_bar(i);
        let inv = invert(&self.noisy_cov(cond_cov, i), m).expect("positive definite");
        StepMap { a: inv.iter().map(|v| v * (1.0 - ab).sqrt()).collect(), sqrt_ab: ab.sqrt() }
    }

    /// The minimum of the epsilon-MSE at step `i` (mean over target channels):
    /// `tr(I - (1 - abar) (abar S + (1 - abar) I)^{-1}) / C`.
    pub fn min_loss_at(&self, i: usize) -> f64 {
        let m = self.output_channels();
        let (_, cond_cov) = self.conditional();
        let ab = self.schedule.alpha_bar(i);
        let inv = invert(&self.noisy_cov(&cond_cov, i), m).expect("positive definite");
        (0..m).map(|c| 1.0 - (1.0 - ab) * inv[c * m + c]).sum::<f64>() / m as f64
    }

    /// The minimum of the training objective (epsilon-MSE, steps uniform over `0..R`): the loss
    /// this oracle reaches in expectation and no predictor can beat.
    pub fn min_loss(&self) -> f64 {
        let r = self.schedule.len();
        (0..r).map(|i| self.min_loss_at(i)).sum::<f64>() / r as f64
    }
}

impl NoisePredictor for GaussianOracle {
    fn predict(&self, x: &Tensor, t: &Tensor) -> Result<Tensor> {
        let n = self.mean.len();
        let k = self.cond_channels;
        let m = n - k;
        let (b, c, h, w) = super::dims4("GaussianOracle input", x)?;
        if c != n {
            return Err(Error::shape("GaussianOracle input channels", n, c));
        }
        if t.dims() != [b] {
            return Err(Error::shape("GaussianOracle steps t (one per sample)", [b], t.dims()));
        }
        let steps = t.to_dtype(DType::F64)?.to_vec1::<f64>()?;
        let xs = x.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
        let (g, cond_cov) = self.conditional();
        let mut maps: HashMap<usize, StepMap> = HashMap::new();
        let hw = h * w;
        let mut out = vec![0.0; b * m * hw];
        let mut centred = vec![0.0; m];
        for (bi, &tf) in steps.iter().enumerate() {
            let i = tf.round();
            if !(i >= 0.0 && i < self.schedule.len() as f64 && (tf - i).abs() < 1e-3) {
                return Err(Error::InvalidConfig {
                    name: "GaussianOracle step",
                    value: tf.to_string(),
                    hint: "the oracle is defined at the integer steps 0..R of its schedule",
                });
            }
            let i = i as usize;
            let map = maps.entry(i).or_insert_with(|| self.step_map(&cond_cov, i));
            let base = bi * n * hw;
            for p in 0..hw {
                let at = |ch: usize| xs[base + ch * hw + p];
                for (r, cen) in centred.iter_mut().enumerate() {
                    let shift: f64 = (0..k).map(|l| g[r * k + l] * (at(l) - self.mean[l])).sum();
                    *cen = at(k + r) - map.sqrt_ab * (self.mean[k + r] + shift);
                }
                for r in 0..m {
                    out[(bi * m + r) * hw + p] = (0..m).map(|q| map.a[r * m + q] * centred[q]).sum();
                }
            }
        }
        Ok(Tensor::from_vec(out, (b, m, h, w), x.device())?.to_dtype(x.dtype())?)
    }

    fn input_channels(&self) -> Option<usize> {
        Some(self.mean.len())
    }
}

/// The lower Cholesky factor of an `n x n` matrix, or `None` if it is not positive definite.
fn cholesky(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i * n + j] - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    Some(l)
}

/// The inverse of a small `n x n` matrix (Gauss-Jordan with partial pivoting).
fn invert(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut m = a.to_vec();
    let mut inv: Vec<f64> = (0..n * n).map(|ij| if ij / n == ij % n { 1.0 } else { 0.0 }).collect();
    for col in 0..n {
        let piv = (col..n).max_by(|&r, &s| m[r * n + col].abs().total_cmp(&m[s * n + col].abs()))?;
        if m[piv * n + col].abs() < 1e-300 {
            return None;
        }
        for j in 0..n {
            m.swap(col * n + j, piv * n + j);
            inv.swap(col * n + j, piv * n + j);
        }
        let d = m[col * n + col];
        for j in 0..n {
            m[col * n + j] /= d;
            inv[col * n + j] /= d;
        }
        for r in (0..n).filter(|&r| r != col) {
            let f = m[r * n + col];
            for j in 0..n {
                m[r * n + j] -= f * m[col * n + j];
                inv[r * n + j] -= f * inv[col * n + j];
            }
        }
    }
    Some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_and_cholesky_of_a_known_matrix() {
        // [[4, 2], [2, 3]]: det 8, inverse [[3, -2], [-2, 4]] / 8, L = [[2, 0], [1, sqrt 2]].
        let a = [4.0, 2.0, 2.0, 3.0];
        let inv = invert(&a, 2).unwrap();
        for (v, e) in inv.iter().zip([3.0 / 8.0, -0.25, -0.25, 0.5]) {
            assert!((v - e).abs() < 1e-14);
        }
        let l = cholesky(&a, 2).unwrap();
        assert!((l[2] - 1.0).abs() < 1e-14 && (l[3] - 2f64.sqrt()).abs() < 1e-14);
        assert!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2).is_none());
    }
}
