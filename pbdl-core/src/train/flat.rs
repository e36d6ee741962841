//! Adam and gradient clipping on one flat `f64` parameter vector.
//!
//! Hand-written networks (the cart-pole controller's fused BPTT, SMDP's score MLP, HIG's
//! Jacobian models) keep their parameters in one `Vec<f64>` and compute gradients without
//! candle. [`FlatAdam`] updates such a vector with candle-nn's Adam, operation for operation,
//! so a flat run and a [`super::OptimizerConfig::Adam`] run on `Var`s give the same numbers;
//! [`clip_in_place`] clips as [`ClipConfig::apply`] does.
//!
//! ```
//! use pbdl_core::train::{clip_in_place, AdamConfig, ClipConfig, FlatAdam};
//!
//! // Minimise (x - 3)^2 from 0.
//! let mut x = vec![0.0];
//! let mut adam = FlatAdam::new(AdamConfig { lr: 0.1, ..Default::default() }, 1);
//! for _ in 0..500 {
//!     let mut g = vec![2.0 * (x[0] - 3.0)];
//!     clip_in_place(&mut g, &ClipConfig::Norm { max_norm: 1.0 });
//!     adam.step(&mut x, &g)?;
//! }
//! assert!((x[0] - 3.0).abs() < 1e-2);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use super::{AdamConfig, ClipConfig};
use crate::{Error, Result};

/// Adam on a flat parameter vector with candle-nn's update, operation for operation.
#[derive(Clone, Debug)]
pub struct FlatAdam {
    cfg: AdamConfig,
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl FlatAdam {
    /// Zero moments for `n` parameters.
    pub fn new(cfg: AdamConfig, n: usize) -> Self {
        Self { cfg, m: vec![0.0; n], v: vec![0.0; n], t: 0 }
    }

    /// The settings.
    pub fn config(&self) -> &AdamConfig {
        &self.cfg
    }

    /// Changes the learning rate from the next step on (schedules).
    pub fn set_lr(&mut self, lr: f64) {
        self.cfg.lr = lr;
    }

    /// Updates taken so far.
    pub fn steps(&self) -> u64 {
        self.t as u64
    }

    /// The first and second moments (one entry per parameter), for checkpoints: with
    /// [`FlatAdam::steps`] and [`FlatAdam::restore`] a resumed run repeats the uninterrupted one
    /// bit for bit.
    pub fn moments(&self) -> (&[f64], &[f64]) {
        (&self.m, &self.v)
    }

    /// Puts checkpointed moments and the update count back (see [`FlatAdam::moments`]); both
    /// moment vectors must have the length given to [`FlatAdam::new`].
    pub fn restore(&mut self, m: &[f64], v: &[f64], steps: u64) -> Result<()> {
        for (arg, len) in [("m", m.len()), ("v", v.len())] {
            if len != self.m.len() {
                return Err(Error::InvalidArgument {
                    op: "FlatAdam::restore",
                    arg: if arg == "m" { "m" } else { "v" },
                    reason: format!("{arg} has {len} entries but the optimiser was built for {}", self.m.len()),
                });
            }
        }
        let t = i32::try_from(steps).map_err(|_| Error::InvalidArgument {
            op: "FlatAdam::restore",
            arg: "steps",
            reason: format!("{steps} updates is more than this optimiser counts ({})", i32::MAX),
        })?;
        self.m.copy_from_slice(m);
        self.v.copy_from_slice(v);
        self.t = t;
        Ok(())
    }

    /// One update of `theta` with gradient `g`; both must have the length given to
    /// [`FlatAdam::new`].
    pub fn step(&mut self, theta: &mut [f64], g: &[f64]) -> Result<()> {
        for (arg, len) in [("theta", theta.len()), ("gradient", g.len())] {
            if len != self.m.len() {
                return Err(Error::InvalidArgument {
                    op: "FlatAdam::step",
                    arg: if arg == "theta" { "theta" } else { "g" },
                    reason: format!("{arg} has {len} entries but the optimiser was built for {}", self.m.len()),
                });
            }
        }
        self.t = self.t.saturating_add(1);
        let (b1, b2, lr, eps) = (self.cfg.beta1, self.cfg.beta2, self.cfg.lr, self.cfg.eps);
        let scale_m = 1.0 / (1.0 - b1.powi(self.t));
        let scale_v = 1.0 / (1.0 - b2.powi(self.t));
        for (((th, m), v), gi) in theta.iter_mut().zip(&mut self.m).zip(&mut self.v).zip(g) {
            *m = *m * b1 + gi * (1.0 - b1);
            *v = *v * b2 + gi * gi * (1.0 - b2);
            let (m_hat, v_hat) = (*m * scale_m, *v * scale_v);
            // candle-nn multiplies theta by (1 - lr * weight_decay) = 1 first: exact, skipped.
            *th -= m_hat / (v_hat.sqrt() + eps) * lr;
        }
        Ok(())
    }
}

/// The global L2 norm, robust to overflow of the squares (as [`super::grad_norm`]).
pub fn global_norm(g: &[f64]) -> f64 {
    let sum_sq: f64 = g.iter().map(|v| v * v).sum();
    if !sum_sq.is_infinite() {
        return sum_sq.sqrt();
    }
    let max_abs = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if max_abs.is_infinite() {
        return max_abs;
    }
    max_abs * g.iter().map(|v| (v / max_abs) * (v / max_abs)).sum::<f64>().sqrt()
}

/// Clips `g` as [`ClipConfig::apply`] does and returns the norm before clipping.
pub fn clip_in_place(g: &mut [f64], clip: &ClipConfig) -> f64 {
    let norm = global_norm(g);
    match *clip {
        ClipConfig::None => {}
        ClipConfig::Value { max_value } => {
            for v in g.iter_mut() {
                *v = v.clamp(-max_value, max_value);
            }
        }
        ClipConfig::Norm { max_norm } => {
            if norm.is_finite() && norm > max_norm {
                let scale = max_norm / norm;
                for v in g.iter_mut() {
                    *v *= scale;
                }
            }
        }
    }
    norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::{ClipConfig, OptimizerConfig};
    use candle_core::{Device, Var};
    use candle_nn::Optimizer;

    /// The flat update equals candle-nn's Adam on a `Var` to the last bit, step after step.
    #[test]
    fn equals_candle_adam_bit_for_bit() {
        let cfg = AdamConfig { lr: 0.05, beta1: 0.8, beta2: 0.99, eps: 1e-7 };
        let init = [0.3, -1.2, 2.5, 0.0];
        let var = Var::from_slice(&init, 4, &Device::Cpu).unwrap();
        let mut opt = OptimizerConfig::Adam(cfg).build(vec![var.clone()]).unwrap();
        let mut flat = FlatAdam::new(cfg, 4);
        let mut theta = init.to_vec();
        for step in 0..20 {
            // Loss sum(a_i x_i^2 + x_i^3 / 10): a gradient that changes with x.
            let a = [1.0, 0.5, 2.0, 3.0];
            let x = var.as_tensor();
            let loss = ((x.sqr().unwrap() * candle_core::Tensor::new(&a, &Device::Cpu).unwrap()).unwrap()
                + (x.powf(3.0).unwrap() / 10.0).unwrap())
            .unwrap()
            .sum_all()
            .unwrap();
            let grads = loss.backward().unwrap();
            let g: Vec<f64> = grads.get(x).unwrap().to_vec1().unwrap();
            opt.step(&grads).unwrap();
            flat.step(&mut theta, &g).unwrap();
            let want: Vec<f64> = var.as_tensor().to_vec1().unwrap();
            assert_eq!(theta, want, "step {step}");
        }
    }

    /// Stopping after 7 updates, copying the moments and count into a fresh optimiser and
    /// going on gives the uninterrupted run's parameters bit for bit; a missing count does not.
    #[test]
    fn restored_moments_continue_the_run_exactly() {
        let cfg = AdamConfig { lr: 0.05, ..Default::default() };
        let grad = |th: &[f64]| -> Vec<f64> { th.iter().map(|x| 2.0 * x + x * x * x / 3.0 - 1.0).collect() };
        let run = |adam: &mut FlatAdam, th: &mut Vec<f64>, n: usize| {
            for _ in 0..n {
                let g = grad(th);
                adam.step(th, &g).unwrap();
            }
        };
        let (mut full, mut th_full) = (FlatAdam::new(cfg, 3), vec![0.4, -2.0, 1.5]);
        run(&mut full, &mut th_full, 15);
        let (mut first, mut th) = (FlatAdam::new(cfg, 3), vec![0.4, -2.0, 1.5]);
        run(&mut first, &mut th, 7);
        let (m, v) = first.moments();
        let mut resumed = FlatAdam::new(cfg, 3);
        resumed.restore(m, v, first.steps()).unwrap();
        let mut th_wrong = th.clone();
        let mut wrong = FlatAdam::new(cfg, 3);
        wrong.restore(m, v, 0).unwrap();
        run(&mut resumed, &mut th, 8);
        run(&mut wrong, &mut th_wrong, 8);
        assert_eq!(th, th_full);
        assert_ne!(th_wrong, th_full);
        assert!(resumed.restore(&[0.0; 2], &[0.0; 3], 1).unwrap_err().to_string().contains("built for 3"));
    }

    #[test]
    fn wrong_lengths_are_errors_and_clipping_matches_the_config() {
        let mut adam = FlatAdam::new(AdamConfig::default(), 3);
        let e = adam.step(&mut [0.0; 2], &[0.0; 3]).unwrap_err().to_string();
        assert!(e.contains("built for 3"), "{e}");
        let mut g = vec![3.0, 4.0];
        assert_eq!(clip_in_place(&mut g, &ClipConfig::Norm { max_norm: 1.0 }), 5.0);
        assert!((global_norm(&g) - 1.0).abs() < 1e-15);
        let mut g = vec![3.0, -4.0];
        clip_in_place(&mut g, &ClipConfig::Value { max_value: 2.0 });
        assert_eq!(g, vec![2.0, -2.0]);
        assert_eq!(global_norm(&[f64::MAX, f64::MAX]), f64::MAX * 2f64.sqrt());
    }
}
