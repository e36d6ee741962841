//! Learning-rate schedules: constant, step decay, cosine with warmup, reduce-on-plateau.
//!
//! A [`ScheduleConfig`] (serde) plus the optimiser's base learning rate make an
//! [`LrScheduler`]. Steps count from 0; `scheduler.lr(step)` is the rate to use *for* that step,
//! and [`LrScheduler::apply`] sets it on any candle-nn [`Optimizer`]. Reduce-on-plateau has no
//! step formula: it changes the rate when [`LrScheduler::observe`] sees a metric stop improving.
//!
//! ```
//! use pbdl_core::train::{LrScheduler, ScheduleConfig};
//!
//! let cfg: ScheduleConfig = serde_json::from_str(r#"{"kind": "cosine", "total_steps": 100}"#).unwrap();
//! let s = LrScheduler::new(cfg, 1e-3)?;
//! assert_eq!(s.lr(0), 1e-3);
//! assert!((s.lr(50) - 0.5e-3).abs() < 1e-15); // half way down the half cosine
//! assert_eq!(s.lr(100), 0.0); // min_lr from then on
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use candle_nn::Optimizer;
use serde::{Deserialize, Serialize};

fn default_gamma() -> f64 {
    0.1
}

/// A learning-rate schedule. Serialised with a `kind` tag, e.g.
/// `{"kind": "step_decay", "step_size": 1000, "gamma": 0.5}`. The default is `Constant`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ScheduleConfig {
    /// The base rate throughout.
    #[default]
    Constant,
    /// `base * gamma^floor(step / step_size)`.
    StepDecay {
        /// Steps between decays (> 0).
        step_size: u64,
        /// Factor per decay, in `(0, 1]`. Default `0.1`.
        #[serde(default = "default_gamma")]
        gamma: f64,
    },
    /// Linear warmup, then half a cosine from the base rate down to `min_lr`.
    ///
    /// For `step < warmup_steps`: `base * (step + 1) / warmup_steps`. Then with
    /// `t = step - warmup_steps` and `T = total_steps - warmup_steps`:
    /// `min_lr + (base - min_lr) (1 + cos(pi t / T)) / 2`, and `min_lr` for `t >= T`.
    Cosine {
        /// Length of warmup plus decay (> `warmup_steps`).
        total_steps: u64,
        /// Steps of linear warmup. Default 0.
        #[serde(default)]
        warmup_steps: u64,
        /// Rate at the end, in `[0, base]`. Default 0.
        #[serde(default)]
        min_lr: f64,
    },
    /// Multiply the rate by `factor` when the observed metric has not improved for `patience`
    /// observations; see [`PlateauConfig`].
    ReduceOnPlateau(PlateauConfig),
}

/// Settings of reduce-on-plateau (PyTorch's `ReduceLROnPlateau`, mode `min`, relative
/// threshold).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PlateauConfig {
    /// Observations without improvement that are tolerated; the rate drops on the next one.
    /// Default 10.
    pub patience: u64,
    /// Factor applied to the rate, in `(0, 1)`. Default `0.1`.
    pub factor: f64,
    /// A metric improves when it is below `best * (1 - threshold)` (for a positive best).
    /// Default `1e-4`.
    pub threshold: f64,
    /// The rate never drops below this. Default 0.
    pub min_lr: f64,
    /// Observations after a reduction during which no new bad ones are counted. Default 0.
    pub cooldown: u64,
}

impl Default for PlateauConfig {
    fn default() -> Self {
        Self { patience: 10, factor: 0.1, threshold: 1e-4, min_lr: 0.0, cooldown: 0 }
    }
}

#[derive(Clone, Debug)]
struct PlateauState {
    lr: f64,
    best: Option<f64>,
    bad: u64,
    cooldown_left: u64,
}

/// A [`ScheduleConfig`] bound to a base learning rate, plus the state reduce-on-plateau needs.
#[derive(Clone, Debug)]
pub struct LrScheduler {
    config: ScheduleConfig,
    base_lr: f64,
    plateau: PlateauState,
}

fn invalid(arg: &'static str, reason: String) -> Error {
    Error::invalid("ScheduleConfig", arg, reason)
}

impl LrScheduler {
    /// Binds `config` to `base_lr` (usually the optimiser's configured rate), after checking
    /// every setting.
    pub fn new(config: ScheduleConfig, base_lr: f64) -> Result<Self> {
        if !(base_lr.is_finite() && base_lr >= 0.0) {
            return Err(invalid("base_lr", format!("{base_lr} must be finite and >= 0")));
        }
        match config {
            ScheduleConfig::Constant => {}
            ScheduleConfig::StepDecay { step_size, gamma } => {
                if step_size == 0 {
                    return Err(invalid("step_size", "must be > 0 steps".into()));
                }
                if !(gamma > 0.0 && gamma <= 1.0) {
                    return Err(invalid("gamma", format!("{gamma} must be in (0, 1], e.g. 0.1")));
                }
            }
            ScheduleConfig::Cosine { total_steps, warmup_steps, min_lr } => {
                if total_steps <= warmup_steps {
                    return Err(invalid(
                        "total_steps",
                        format!("{total_steps} must exceed warmup_steps = {warmup_steps}; it counts warmup and decay"),
                    ));
                }
                if !(min_lr >= 0.0 && min_lr <= base_lr) {
                    return Err(invalid("min_lr", format!("{min_lr} must be in [0, base_lr = {base_lr}]")));
                }
            }
            ScheduleConfig::ReduceOnPlateau(p) => {
                if !(p.factor > 0.0 && p.factor < 1.0) {
                    return Err(invalid("factor", format!("{} must be in (0, 1), e.g. 0.1", p.factor)));
                }
                if !(p.threshold >= 0.0 && p.threshold < 1.0) {
                    return Err(invalid("threshold", format!("{} must be in [0, 1), e.g. 1e-4", p.threshold)));
                }
                if !(p.min_lr >= 0.0 && p.min_lr.is_finite()) {
                    return Err(invalid("min_lr", format!("{} must be finite and >= 0", p.min_lr)));
                }
            }
        }
        Ok(Self { config, base_lr, plateau: PlateauState { lr: base_lr, best: None, bad: 0, cooldown_left: 0 } })
    }

    /// The schedule's settings.
    pub fn config(&self) -> &ScheduleConfig {
        &self.config
    }

    /// The base learning rate.
    pub fn base_lr(&self) -> f64 {
        self.base_lr
    }

    /// The learning rate for step `step` (counting from 0). For reduce-on-plateau it is the
    /// current rate, whatever `step`.
    pub fn lr(&self, step: u64) -> f64 {
        let base = self.base_lr;
        match self.config {
            ScheduleConfig::Constant => base,
            ScheduleConfig::StepDecay { step_size, gamma } => {
                let k = (step / step_size).min(i32::MAX as u64) as i32;
                base * gamma.powi(k)
            }
            ScheduleConfig::Cosine { total_steps, warmup_steps, min_lr } => {
                if step < warmup_steps {
                    // (step + 1): the first step already moves; the last warmup step reaches base.
                    return base * (step + 1) as f64 / warmup_steps as f64;
                }
                let t = step - warmup_steps;
                let period = total_steps - warmup_steps;
                if t >= period {
                    return min_lr;
                }
                let c = 0.5 * (1.0 + (std::f64::consts::PI * t as f64 / period as f64).cos());
                min_lr + (base - min_lr) * c
            }
            ScheduleConfig::ReduceOnPlateau(_) => self.plateau.lr,
        }
    }

    /// Sets `lr(step)` on `opt` and returns it; call it before each optimiser step.
    pub fn apply<O: Optimizer>(&self, opt: &mut O, step: u64) -> f64 {
        let lr = self.lr(step);
        opt.set_learning_rate(lr);
        lr
    }

    /// Reports a metric to minimise (e.g. the validation loss, once per epoch). Only
    /// reduce-on-plateau uses it; returns `true` when the rate was reduced by this observation.
    /// A NaN metric counts as no improvement.
    pub fn observe(&mut self, metric: f64) -> bool {
        let ScheduleConfig::ReduceOnPlateau(p) = self.config else { return false };
        let s = &mut self.plateau;
        let improved = match s.best {
            None => !metric.is_nan(),
            // Relative threshold as in PyTorch's "rel" mode; `best - |best| t` also works for best < 0.
            Some(best) => metric < best - best.abs() * p.threshold,
        };
        if improved {
            s.best = Some(metric);
            s.bad = 0;
        } else {
            s.bad += 1;
        }
        if s.cooldown_left > 0 {
            s.cooldown_left -= 1;
            s.bad = 0;
        }
        if s.bad > p.patience {
            let new_lr = (s.lr * p.factor).max(p.min_lr);
            s.bad = 0;
            s.cooldown_left = p.cooldown;
            if new_lr < s.lr {
                s.lr = new_lr;
                return true;
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_settings_name_the_setting() {
        let e = LrScheduler::new(ScheduleConfig::Cosine { total_steps: 10, warmup_steps: 10, min_lr: 0.0 }, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("total_steps") && e.contains("warmup_steps"), "{e}");
        let e = LrScheduler::new(ScheduleConfig::StepDecay { step_size: 0, gamma: 0.5 }, 1.0).unwrap_err().to_string();
        assert!(e.contains("step_size"), "{e}");
    }

    #[test]
    fn serde_defaults() {
        let c: ScheduleConfig = serde_json::from_str(r#"{"kind":"step_decay","step_size":5}"#).unwrap();
        assert_eq!(c, ScheduleConfig::StepDecay { step_size: 5, gamma: 0.1 });
        let p: ScheduleConfig = serde_json::from_str(r#"{"kind":"reduce_on_plateau","patience":3}"#).unwrap();
        assert_eq!(p, ScheduleConfig::ReduceOnPlateau(PlateauConfig { patience: 3, ..Default::default() }));
        let c: ScheduleConfig = serde_json::from_str(r#"{"kind":"constant"}"#).unwrap();
        assert_eq!(c, ScheduleConfig::Constant);
    }
}
