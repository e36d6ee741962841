//! Closed forms for the affine toy: `dx = -a x dt + g dW` from `x0 in {+1, -1}` (equal weights).
//!
//! `p_t` is a mixture of two Gaussians `N(+-mu_t, sigma_t^2)`, so its score and the posterior
//! `P(x0 = +1 | x_t = y)` are closed form. [`AffineMixture::continuous`] uses the exact SDE
//! solution (`mu_t = e^{-a t}`, `sigma_t^2 = g^2 (1 - e^{-2 a t}) / (2 a)`);
//! [`AffineMixture::euler`] the exact law of the Euler-Maruyama chain with step `dt`, which is
//! what the simulator samples.

/// The two-Gaussian law of the affine toy at any time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineMixture {
    /// Drift coefficient `a` in `P(x) = -a x`.
    pub a: f64,
    /// Diffusion `g`.
    pub g: f64,
    /// `None`: the continuous SDE; `Some(dt)`: its Euler-Maruyama chain.
    pub dt: Option<f64>,
}

impl AffineMixture {
    /// The law of the continuous SDE.
    pub fn continuous(a: f64, g: f64) -> Self {
        AffineMixture { a, g, dt: None }
    }
    /// The law of the Euler-Maruyama chain with step `dt` (at `t = k dt`).
    pub fn euler(a: f64, g: f64, dt: f64) -> Self {
        AffineMixture { a, g, dt: Some(dt) }
    }

    /// `(mu_t, sigma_t)`: the component means are `+-mu_t`.
    pub fn moments(&self, t: f64) -> (f64, f64) {
        match self.dt {
            None => {
                let mu = (-self.a * t).exp();
                let var = if self.a == 0.0 {
                    self.g * self.g * t
                } else {
                    self.g * self.g * (1.0 - (-2.0 * self.a * t).exp()) / (2.0 * self.a)
                };
                (mu, var.sqrt())
            }
            Some(dt) => {
                let c = 1.0 - self.a * dt;
                let k = t / dt;
                let mu = c.powf(k);
                let var = if self.a == 0.0 {
                    self.g * self.g * t
                } else {
                    self.g * self.g * dt * (1.0 - c.powf(2.0 * k)) / (1.0 - c * c)
                };
                (mu, var.sqrt())
            }
        }
    }

    /// The density `p_t(x)`.
    pub fn density(&self, x: f64, t: f64) -> f64 {
        let (mu, s) = self.moments(t);
        let n = |m: f64| (-(x - m) * (x - m) / (2.0 * s * s)).exp() / (s * (2.0 * std::f64::consts::PI).sqrt());
        0.5 * (n(mu) + n(-mu))
    }

    /// The score `d/dx log p_t(x) = (-x + mu tanh(mu x / sigma^2)) / sigma^2`.
    pub fn score(&self, x: f64, t: f64) -> f64 {
        let (mu, s) = self.moments(t);
        let s2 = s * s;
        (-x + mu * (mu * x / s2).tanh()) / s2
    }

    /// `P(x0 = +1 | x_t = y) = sigmoid(2 mu y / sigma^2)`.
    pub fn posterior_plus(&self, y: f64, t: f64) -> f64 {
        let (mu, s) = self.moments(t);
        1.0 / (1.0 + (-2.0 * mu * y / (s * s)).exp())
    }

    /// The slope `2 mu_t / sigma_t^2` of the posterior's logit.
    pub fn posterior_slope(&self, t: f64) -> f64 {
        let (mu, s) = self.moments(t);
        2.0 * mu / (s * s)
    }
}

/// The quadratic toy's posterior `P(x0 = +1 | x_T = y)` from an independent 400k-path Monte
/// Carlo check at `dt = 0.02` (the method digest, section 4): `(y, P)` pairs.
pub const QUADRATIC_POSTERIOR_DT002: [(f64, f64); 6] =
    [(-0.095, 0.38), (-0.025, 0.46), (-0.005, 0.49), (0.005, 0.51), (0.025, 0.54), (0.095, 0.62)];

/// The quadratic toy's posterior `P(x0 = +1 | x_T = y)` at `dt = 0.02` from a larger Monte Carlo
/// run (4M Euler-Maruyama paths, `x_T` within `y +- 0.005`; computed independently of this crate
/// with numpy): `(y, P, standard error)`. The outer bins of the digest's 400k-path table rest
/// on about 500 paths each (standard error 0.02); here on about 5000 (0.007).
pub const QUADRATIC_POSTERIOR_DT002_4M: [(f64, f64, f64); 6] = [
    (-0.095, 0.4004, 0.0069),
    (-0.025, 0.4605, 0.0008),
    (-0.005, 0.4907, 0.0008),
    (0.005, 0.5086, 0.0008),
    (0.025, 0.5381, 0.0008),
    (0.095, 0.5938, 0.0069),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_numbers_of_the_affine_case() {
        let m = AffineMixture::continuous(0.5, 0.04);
        let (mu, s) = m.moments(10.0);
        assert!((mu - 0.00674).abs() < 1e-5, "mu_T = {mu}");
        assert!((s - 0.0400).abs() < 1e-4, "sigma_T = {s}");
        // The digest's sigmoid(8.42 y).
        assert!((m.posterior_slope(10.0) - 8.42).abs() < 0.01, "{}", m.posterior_slope(10.0));
    }

    #[test]
    fn score_is_the_derivative_of_log_density() {
        for m in [AffineMixture::continuous(0.5, 0.04), AffineMixture::euler(0.5, 0.04, 0.02)] {
            for &(x, t) in &[(0.3, 0.5), (-0.05, 2.0), (0.01, 10.0), (0.9, 1.0)] {
                let h = 1e-6;
                let fd = (m.density(x + h, t).ln() - m.density(x - h, t).ln()) / (2.0 * h);
                let s = m.score(x, t);
                assert!((fd - s).abs() < 1e-5 * (1.0 + s.abs()), "{x} {t}: {fd} vs {s}");
            }
        }
    }

    #[test]
    fn euler_law_approaches_the_continuous_one_as_dt_shrinks() {
        let c = AffineMixture::continuous(0.5, 0.04).moments(3.0);
        let e1 = AffineMixture::euler(0.5, 0.04, 0.02).moments(3.0);
        let e2 = AffineMixture::euler(0.5, 0.04, 0.01).moments(3.0);
        let (d1, d2) = ((e1.0 - c.0).abs(), (e2.0 - c.0).abs());
        // First order: halving dt halves the error.
        assert!((d1 / d2 - 2.0).abs() < 0.05, "{d1} {d2}");
    }
}
