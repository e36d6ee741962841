//! Noise schedules of the discrete forward diffusion process.
//!
//! A schedule is a list of noise variances `beta_i`, `i = 0..R`, one per diffusion step. Step
//! `i` scales the previous state by `sqrt(alpha_i)`, `alpha_i = 1 - beta_i`, and adds Gaussian
//! noise of variance `beta_i`. Composing the steps gives the closed form used for training:
//! `x_i = sqrt(abar_i) x_0 + sqrt(1 - abar_i) eps` with `abar_i = prod_{j <= i} alpha_j` and
//! `eps ~ N(0, I)`. Indices are 0-based (`abar_0 = 1 - beta_0`, the last step is `R - 1`), as in
//! the ACDM code.
//!
//! Constructors:
//! - [`NoiseSchedule::linear`]: `beta` evenly spaced from `beta_start` to `beta_end`.
//! - [`NoiseSchedule::cosine`]: Nichol & Dhariwal's cosine schedule,
//!   `abar(t) = f(t) / f(0)`, `f(t) = cos^2(((t / T) + s) / (1 + s) * pi / 2)`,
//!   `beta_t = 1 - abar(t) / abar(t - 1)` clipped at 0.999 (the airfoil-paper setting is
//!   `T = 200`, `s = 0.008`).
//! - [`NoiseSchedule::acdm`]: ACDM's linear schedule scaled to `R` steps, `beta` from
//!   `1e-4 * 500 / R` to `0.02 * 500 / R`, clipped to `[1e-4, 0.9999]`.
//!
//! ```
//! use pbdl_diffusion::schedule::NoiseSchedule;
//! let s = NoiseSchedule::acdm(20).unwrap();
//! assert_eq!(s.len(), 20);
//! assert!((s.sqrt_alpha_bar(19) - 0.04484).abs() < 5e-5);
//! assert!(NoiseSchedule::linear(0, 1e-4, 0.02).is_err());
//! ```

use crate::{Error, Result};

/// The beta clip of the cosine schedule (Nichol & Dhariwal).
pub const COSINE_MAX_BETA: f64 = 0.999;
/// The offset `s` of the cosine schedule used by Nichol & Dhariwal and the airfoil paper.
pub const COSINE_S: f64 = 0.008;

/// A discrete noise schedule: `beta_i`, `alpha_i = 1 - beta_i` and `abar_i = prod_{j <= i} alpha_j`.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseSchedule {
    betas: Vec<f64>,
    alphas: Vec<f64>,
    alpha_bars: Vec<f64>,
}

impl NoiseSchedule {
    /// A schedule from explicit betas; each must lie in `(0, 1)` and there must be at least one.
    pub fn from_betas(betas: Vec<f64>) -> Result<Self> {
        if betas.is_empty() {
            return Err(Error::InvalidConfig {
                name: "steps",
                value: "0".into(),
                hint: "a schedule needs at least one diffusion step",
            });
        }
        if let Some((i, b)) = betas.iter().enumerate().find(|(_, b)| !(**b > 0.0 && **b < 1.0)) {
            return Err(Error::InvalidConfig {
                name: "beta",
                value: format!("{b} at step {i}"),
                hint: "every beta must lie strictly between 0 and 1",
            });
        }
        let alphas: Vec<f64> = betas.iter().map(|b| 1.0 - b).collect();
        let mut alpha_bars = Vec::with_capacity(alphas.len());
        let mut prod = 1.0;
        for a in &alphas {
            prod *= a;
            alpha_bars.push(prod);
        }
        Ok(Self { betas, alphas, alpha_bars })
    }

    /// `steps` betas evenly spaced from `beta_start` to `beta_end` (both inside `(0, 1)`).
    pub fn linear(steps: usize, beta_start: f64, beta_end: f64) -> Result<Self> {
        Self::from_betas(linspace(steps, beta_start, beta_end))
    }

    /// Nichol & Dhariwal's cosine schedule with `steps` steps, offset `s >= 0` and betas clipped
    /// at [`COSINE_MAX_BETA`].
    pub fn cosine(steps: usize, s: f64) -> Result<Self> {
        if !(s.is_finite() && s >= 0.0) {
            return Err(Error::InvalidConfig {
                name: "cosine offset s",
                value: s.to_string(),
                hint: "use a finite s >= 0 (Nichol & Dhariwal use 0.008)",
            });
        }
        let f = |t: f64| {
            let c = ((t / steps as f64 + s) / (1.0 + s) * std::f64::consts::FRAC_PI_2).cos();
            c * c
        };
        let f0 = f(0.0);
        let betas =
            (1..=steps).map(|t| (1.0 - f(t as f64) / f0 / (f((t - 1) as f64) / f0)).min(COSINE_MAX_BETA)).collect();
        Self::from_betas(betas)
    }

    /// ACDM's linear schedule scaled to `steps` steps: beta from `1e-4 * 500 / steps` to
    /// `0.02 * 500 / steps`, each clipped to `[1e-4, 0.9999]`.
    pub fn acdm(steps: usize) -> Result<Self> {
        if steps == 0 {
            return Self::from_betas(vec![]);
        }
        let scale = 500.0 / steps as f64;
        let betas = linspace(steps, 1e-4 * scale, 0.02 * scale).into_iter().map(|b| b.clamp(1e-4, 0.9999)).collect();
        Self::from_betas(betas)
    }

    /// The number of diffusion steps `R`.
    pub fn len(&self) -> usize {
        self.betas.len()
    }

    /// Always false: a schedule has at least one step.
    pub fn is_empty(&self) -> bool {
        self.betas.is_empty()
    }

    /// All `beta_i`.
    pub fn betas(&self) -> &[f64] {
        &self.betas
    }

    /// All `alpha_i = 1 - beta_i`.
    pub fn alphas(&self) -> &[f64] {
        &self.alphas
    }

    /// All `abar_i = prod_{j <= i} alpha_j`.
    pub fn alpha_bars(&self) -> &[f64] {
        &self.alpha_bars
    }

    /// `beta_i`. Panics if `i >= len()` (an index bug, not user input).
    pub fn beta(&self, i: usize) -> f64 {
        self.betas[i]
    }

    /// `alpha_i`.
    pub fn alpha(&self, i: usize) -> f64 {
        self.alphas[i]
    }

    /// `abar_i`.
    pub fn alpha_bar(&self, i: usize) -> f64 {
        self.alpha_bars[i]
    }

    /// `abar_{i-1}`, with `abar_{-1} = 1` (the clean data).
    pub fn alpha_bar_prev(&self, i: usize) -> f64 {
        if i == 0 {
            1.0
        } else {
            self.alpha_bars[i - 1]
        }
    }

    /// `sqrt(abar_i)`, the signal scale of step `i`.
    pub fn sqrt_alpha_bar(&self, i: usize) -> f64 {
        self.alpha_bars[i].sqrt()
    }

    /// `sqrt(1 - abar_i)`, the noise scale of step `i`.
    pub fn sqrt_one_minus_alpha_bar(&self, i: usize) -> f64 {
        (1.0 - self.alpha_bars[i]).sqrt()
    }

    /// The variance of the forward posterior `q(x_{i-1} | x_i, x_0)`:
    /// `beta_i (1 - abar_{i-1}) / (1 - abar_i)` (0 at `i = 0`).
    pub fn posterior_variance(&self, i: usize) -> f64 {
        self.betas[i] * (1.0 - self.alpha_bar_prev(i)) / (1.0 - self.alpha_bars[i])
    }
}

/// `n` evenly spaced values from `a` to `b` inclusive (`[a]` for `n = 1`).
fn linspace(n: usize, a: f64, b: f64) -> Vec<f64> {
    match n {
        0 => vec![],
        1 => vec![a],
        _ => (0..n).map(|i| a + (b - a) * i as f64 / (n - 1) as f64).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_settings_are_typed_errors() {
        assert!(matches!(NoiseSchedule::linear(0, 1e-4, 0.02), Err(Error::InvalidConfig { name: "steps", .. })));
        assert!(matches!(NoiseSchedule::acdm(0), Err(Error::InvalidConfig { name: "steps", .. })));
        assert!(matches!(NoiseSchedule::cosine(0, COSINE_S), Err(Error::InvalidConfig { .. })));
        assert!(matches!(NoiseSchedule::linear(10, 0.0, 0.02), Err(Error::InvalidConfig { name: "beta", .. })));
        assert!(matches!(NoiseSchedule::linear(10, 1e-4, 1.0), Err(Error::InvalidConfig { name: "beta", .. })));
        assert!(matches!(NoiseSchedule::from_betas(vec![0.1, f64::NAN]), Err(Error::InvalidConfig { .. })));
        assert!(matches!(NoiseSchedule::cosine(10, -0.1), Err(Error::InvalidConfig { .. })));
        let msg = NoiseSchedule::linear(3, 0.5, 1.5).unwrap_err().to_string();
        assert!(msg.contains("between 0 and 1"), "{msg}");
    }
}
