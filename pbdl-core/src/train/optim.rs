//! Optimisers behind one serde config: Adam, AdamW (candle-nn's) and SGD with momentum.
//!
//! candle-nn's `SGD` has no momentum, so [`Sgd`] implements PyTorch's SGD (momentum,
//! dampening, Nesterov, L2 weight decay) itself. Everything implements candle-nn's
//! [`Optimizer`] trait, whose `set_learning_rate` is how a [`super::LrScheduler`] drives it.
//!
//! [`AdamW`] is candle-nn's AdamW, operation for operation (the same numbers, bit for bit),
//! with its moments and update count readable and settable: candle-nn keeps them private, and
//! an exact resume has to checkpoint them ([`Optim::state`], [`Optim::set_state`]).

use crate::{Error, Result};
use candle_core::{backprop::GradStore, Tensor, Var};
use candle_nn::{Optimizer, ParamsAdamW};
use serde::{Deserialize, Serialize};

/// Settings of Adam (no weight decay).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AdamConfig {
    /// Learning rate. Default `1e-3`.
    pub lr: f64,
    /// Decay of the first-moment average. Default `0.9`.
    pub beta1: f64,
    /// Decay of the second-moment average. Default `0.999`.
    pub beta2: f64,
    /// Added to the root of the second moment. Default `1e-8`.
    pub eps: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { lr: 1e-3, beta1: 0.9, beta2: 0.999, eps: 1e-8 }
    }
}

/// Settings of AdamW (Adam with decoupled weight decay: `theta -= lr * weight_decay * theta`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AdamWConfig {
    /// Learning rate. Default `1e-3`.
    pub lr: f64,
    /// Decay of the first-moment average. Default `0.9`.
    pub beta1: f64,
    /// Decay of the second-moment average. Default `0.999`.
    pub beta2: f64,
    /// Added to the root of the second moment. Default `1e-8`.
    pub eps: f64,
    /// Decoupled weight decay. Default `0.01` (PyTorch's and candle-nn's).
    pub weight_decay: f64,
}

impl Default for AdamWConfig {
    fn default() -> Self {
        Self { lr: 1e-3, beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.01 }
    }
}

/// Settings of SGD, with PyTorch's semantics:
/// `g += weight_decay * theta; b = momentum * b + (1 - dampening) * g` (`b = g` on the first
/// step); `g = nesterov ? g + momentum * b : b`; `theta -= lr * g`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SgdConfig {
    /// Learning rate. Default `1e-2`.
    pub lr: f64,
    /// Momentum factor in `[0, 1)`; 0 is plain gradient descent. Default `0.0`.
    pub momentum: f64,
    /// Dampening of the gradient in the momentum buffer, in `[0, 1]`. Default `0.0`.
    pub dampening: f64,
    /// Nesterov momentum (needs `momentum > 0` and `dampening = 0`). Default `false`.
    pub nesterov: bool,
    /// L2 penalty added to the gradient. Default `0.0`.
    pub weight_decay: f64,
}

impl Default for SgdConfig {
    fn default() -> Self {
        Self { lr: 1e-2, momentum: 0.0, dampening: 0.0, nesterov: false, weight_decay: 0.0 }
    }
}

/// Which optimiser to use, with its settings. Serialised with a `kind` tag, e.g.
/// `{"kind": "adamw", "lr": 3e-4}`; missing fields take the documented defaults.
/// The default is Adam with [`AdamConfig::default`].
///
/// ```
/// use candle_core::{DType, Device, Var};
/// use candle_nn::Optimizer;
/// use pbdl_core::train::{Optim, OptimizerConfig};
///
/// let cfg: OptimizerConfig = serde_json::from_str(r#"{"kind": "sgd", "lr": 0.1, "momentum": 0.5}"#).unwrap();
/// let x = Var::new(&[3.0f64, -2.0], &Device::Cpu)?;
/// let mut opt = cfg.build(vec![x.clone()])?;
/// for _ in 0..200 {
///     opt.backward_step(&x.as_tensor().sqr()?.sum_all()?)?; // minimise |x|^2
/// }
/// assert!(x.as_tensor().sqr()?.sum_all()?.to_scalar::<f64>()? < 1e-12);
/// opt.set_learning_rate(0.01); // what a schedule does each step
/// # Ok::<(), pbdl_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum OptimizerConfig {
    /// Adam (candle-nn's AdamW with zero weight decay).
    Adam(AdamConfig),
    /// AdamW with decoupled weight decay (candle-nn's). Tag `"adamw"`.
    #[serde(rename = "adamw", alias = "adam_w")]
    AdamW(AdamWConfig),
    /// SGD with optional momentum (pbdl's [`Sgd`]).
    Sgd(SgdConfig),
}

impl Default for OptimizerConfig {
    fn default() -> Self {
        OptimizerConfig::Adam(AdamConfig::default())
    }
}

fn check_range(arg: &'static str, v: f64, lo: f64, hi: f64, hi_open: bool, hint: &str) -> Result<()> {
    let ok = v.is_finite() && v >= lo && if hi_open { v < hi } else { v <= hi };
    if !ok {
        let close = if hi_open { ")" } else { "]" };
        return Err(Error::invalid("OptimizerConfig", arg, format!("{v} is outside [{lo}, {hi}{close}; {hint}")));
    }
    Ok(())
}

fn check_lr(lr: f64) -> Result<()> {
    check_range("lr", lr, 0.0, f64::MAX, false, "use a finite learning rate >= 0, e.g. 1e-3")
}

impl OptimizerConfig {
    /// The configured (initial) learning rate.
    pub fn lr(&self) -> f64 {
        match self {
            OptimizerConfig::Adam(c) => c.lr,
            OptimizerConfig::AdamW(c) => c.lr,
            OptimizerConfig::Sgd(c) => c.lr,
        }
    }

    /// Checks every setting; the error names the setting and a valid range.
    pub fn validate(&self) -> Result<()> {
        let adam = |lr, beta1, beta2, eps| -> Result<()> {
            check_lr(lr)?;
            check_range("beta1", beta1, 0.0, 1.0, true, "typical is 0.9")?;
            check_range("beta2", beta2, 0.0, 1.0, true, "typical is 0.999")?;
            if !(eps > 0.0 && f64::is_finite(eps)) {
                return Err(Error::invalid("OptimizerConfig", "eps", format!("{eps} must be > 0; typical is 1e-8")));
            }
            Ok(())
        };
        match *self {
            OptimizerConfig::Adam(c) => adam(c.lr, c.beta1, c.beta2, c.eps),
            OptimizerConfig::AdamW(c) => {
                adam(c.lr, c.beta1, c.beta2, c.eps)?;
                check_range("weight_decay", c.weight_decay, 0.0, f64::MAX, false, "typical is 0.01")
            }
            OptimizerConfig::Sgd(c) => {
                check_lr(c.lr)?;
                check_range("momentum", c.momentum, 0.0, 1.0, true, "typical is 0.9, or 0 for none")?;
                check_range("dampening", c.dampening, 0.0, 1.0, false, "usually 0")?;
                check_range("weight_decay", c.weight_decay, 0.0, f64::MAX, false, "usually 0")?;
                if c.nesterov && (c.momentum == 0.0 || c.dampening != 0.0) {
                    return Err(Error::invalid(
                        "OptimizerConfig",
                        "nesterov",
                        "needs momentum > 0 and dampening = 0; set those or turn nesterov off",
                    ));
                }
                Ok(())
            }
        }
    }

    /// Builds the optimiser for `vars` (non-float vars are skipped, as in candle-nn).
    pub fn build(&self, vars: Vec<Var>) -> Result<Optim> {
        self.validate()?;
        Ok(match *self {
            OptimizerConfig::Adam(c) => Optim::AdamW(AdamW::new(
                vars,
                ParamsAdamW { lr: c.lr, beta1: c.beta1, beta2: c.beta2, eps: c.eps, weight_decay: 0.0 },
            )?),
            OptimizerConfig::AdamW(c) => Optim::AdamW(AdamW::new(
                vars,
                ParamsAdamW { lr: c.lr, beta1: c.beta1, beta2: c.beta2, eps: c.eps, weight_decay: c.weight_decay },
            )?),
            OptimizerConfig::Sgd(c) => Optim::Sgd(Sgd::with_config(vars, c)?),
        })
    }
}

/// An optimiser built from an [`OptimizerConfig`]. Use it through candle-nn's [`Optimizer`]
/// trait: `step(&grads)`, `backward_step(&loss)`, `learning_rate()`, `set_learning_rate(lr)`.
#[derive(Debug)]
pub enum Optim {
    /// Adam and AdamW (candle-nn's update, see [`AdamW`]).
    AdamW(AdamW),
    /// SGD with momentum.
    Sgd(Sgd),
}

impl Optimizer for Optim {
    type Config = OptimizerConfig;

    fn new(vars: Vec<Var>, config: OptimizerConfig) -> candle_core::Result<Self> {
        Ok(config.build(vars)?)
    }

    fn step(&mut self, grads: &GradStore) -> candle_core::Result<()> {
        match self {
            Optim::AdamW(o) => o.step(grads),
            Optim::Sgd(o) => o.step(grads),
        }
    }

    fn learning_rate(&self) -> f64 {
        match self {
            Optim::AdamW(o) => o.learning_rate(),
            Optim::Sgd(o) => o.learning_rate(),
        }
    }

    fn set_learning_rate(&mut self, lr: f64) {
        match self {
            Optim::AdamW(o) => o.set_learning_rate(lr),
            Optim::Sgd(o) => o.set_learning_rate(lr),
        }
    }
}

/// What an optimiser carries from one update to the next besides its settings: the update
/// count and per-variable slots (Adam's moments `m` and `v`, SGD's `momentum` buffer). Slots
/// are indexed by the position of the variable in the optimiser ([`Optim::vars`]).
#[derive(Clone, Debug)]
pub struct OptimState {
    /// The optimiser's kind, `"adamw"` (Adam included) or `"sgd"`; a state only loads into the
    /// same kind.
    pub kind: &'static str,
    /// Updates taken so far (Adam's bias correction depends on it).
    pub steps: u64,
    /// `(variable index, slot name, tensor)`. A variable without a slot (SGD before its first
    /// gradient) has none.
    pub slots: Vec<(usize, &'static str, Tensor)>,
}

impl Optim {
    /// The optimised variables, in the order of the slot indices of [`Optim::state`]
    /// (non-float variables were left out when it was built).
    pub fn vars(&self) -> Vec<Var> {
        match self {
            Optim::AdamW(o) => o.vars(),
            Optim::Sgd(o) => o.vars().to_vec(),
        }
    }

    /// The optimiser's state (copies of its tensors), for a checkpoint.
    pub fn state(&self) -> Result<OptimState> {
        match self {
            Optim::AdamW(o) => o.state(),
            Optim::Sgd(o) => o.state(),
        }
    }

    /// Restores a state taken by [`Optim::state`] of an optimiser of the same kind over
    /// variables of the same shapes. Slots absent from `state` are reset (zero moments, no
    /// momentum buffer). Errors name the mismatch.
    pub fn set_state(&mut self, state: &OptimState) -> Result<()> {
        match self {
            Optim::AdamW(o) => o.set_state(state),
            Optim::Sgd(o) => o.set_state(state),
        }
    }
}

/// Checks `state` against an optimiser of `kind` over `vars`, slot names in `slots`.
fn check_state(kind: &'static str, vars: &[Var], slots: &[&str], state: &OptimState) -> Result<()> {
    let op = "Optim::set_state";
    if state.kind != kind {
        return Err(Error::invalid(
            op,
            "state",
            format!(
                "a {} state does not load into {kind}; resume with the optimiser the run was started with",
                state.kind
            ),
        ));
    }
    for (i, slot, t) in &state.slots {
        let Some(var) = vars.get(*i) else {
            return Err(Error::invalid(
                op,
                "state",
                format!("slot `{slot}` of variable {i}, but the optimiser has {}", vars.len()),
            ));
        };
        if !slots.contains(slot) {
            return Err(Error::invalid(
                op,
                "state",
                format!("unknown {kind} slot `{slot}` (expected one of {slots:?})"),
            ));
        }
        if t.dims() != var.dims() {
            return Err(Error::invalid(
                op,
                "state",
                format!("slot `{slot}` of variable {i} has shape {:?}, the variable {:?}", t.dims(), var.dims()),
            ));
        }
    }
    Ok(())
}

#[derive(Debug)]
struct VarAdamW {
    var: Var,
    first_moment: Var,
    second_moment: Var,
}

/// Adam with decoupled weight decay: candle-nn's `AdamW`, operation for operation (so the
/// same numbers bit for bit), with readable state for checkpoints ([`Optim::state`]). On the
/// CPU (`f32`/`f64`) the update runs as three in-place passes per variable computing those
/// same operations (bit-identical, tested); inside [`crate::nn::with_composed`] and on other
/// devices as candle-nn's tensor expression.
#[derive(Debug)]
pub struct AdamW {
    vars: Vec<VarAdamW>,
    step_t: usize,
    params: ParamsAdamW,
}

impl AdamW {
    /// The settings.
    pub fn params(&self) -> &ParamsAdamW {
        &self.params
    }

    /// Replaces the settings (the moments stay).
    pub fn set_params(&mut self, params: ParamsAdamW) {
        self.params = params;
    }

    /// The optimised variables.
    pub fn vars(&self) -> Vec<Var> {
        self.vars.iter().map(|v| v.var.clone()).collect()
    }

    fn state(&self) -> Result<OptimState> {
        let mut slots = Vec::with_capacity(2 * self.vars.len());
        for (i, v) in self.vars.iter().enumerate() {
            slots.push((i, "m", v.first_moment.as_tensor().copy()?));
            slots.push((i, "v", v.second_moment.as_tensor().copy()?));
        }
        Ok(OptimState { kind: "adamw", steps: self.step_t as u64, slots })
    }

    fn set_state(&mut self, state: &OptimState) -> Result<()> {
        let vars = self.vars();
        check_state("adamw", &vars, &["m", "v"], state)?;
        for v in &self.vars {
            v.first_moment.set(&v.first_moment.zeros_like()?)?;
            v.second_moment.set(&v.second_moment.zeros_like()?)?;
        }
        for (i, slot, t) in &state.slots {
            let v = &self.vars[*i];
            let target = if *slot == "m" { &v.first_moment } else { &v.second_moment };
            target.set(&t.to_dtype(target.dtype())?.to_device(target.device())?)?;
        }
        self.step_t = usize::try_from(state.steps)
            .map_err(|_| Error::invalid("Optim::set_state", "state", format!("{} updates", state.steps)))?;
        Ok(())
    }
}

impl Optimizer for AdamW {
    type Config = ParamsAdamW;

    fn new(vars: Vec<Var>, params: ParamsAdamW) -> candle_core::Result<Self> {
        let vars = vars
            .into_iter()
            .filter(|var| var.dtype().is_float())
            .map(|var| {
                let first_moment = Var::zeros(var.shape(), var.dtype(), var.device())?;
                let second_moment = Var::zeros(var.shape(), var.dtype(), var.device())?;
                Ok(VarAdamW { var, first_moment, second_moment })
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self { vars, params, step_t: 0 })
    }

    fn learning_rate(&self) -> f64 {
        self.params.lr
    }

    fn set_learning_rate(&mut self, lr: f64) {
        self.params.lr = lr
    }

    // candle-nn 0.11's AdamW::step, expression for expression: any change of order changes the
    // rounding, and pinned loss curves (and resumed runs) would no longer match.
    fn step(&mut self, grads: &GradStore) -> candle_core::Result<()> {
        self.step_t += 1;
        let lr = self.params.lr;
        let lambda = self.params.weight_decay;
        let lr_lambda = lr * lambda;
        let beta1 = self.params.beta1;
        let beta2 = self.params.beta2;
        let scale_m = 1f64 / (1f64 - beta1.powi(self.step_t as i32));
        let scale_v = 1f64 / (1f64 - beta2.powi(self.step_t as i32));
        for var in self.vars.iter() {
            let theta = &var.var;
            let m = &var.first_moment;
            let v = &var.second_moment;
            let Some(g) = grads.get(theta) else { continue };
            if super::adamw_inplace::applies(theta.as_tensor(), m.as_tensor(), v.as_tensor(), g) {
                // The same operations in place: three passes instead of ~30 (bit-identical).
                use super::adamw_inplace::{MomentUpdate, ParamUpdate};
                m.as_tensor().inplace_op2(g, &MomentUpdate { beta: beta1, squared: false })?;
                v.as_tensor().inplace_op2(g, &MomentUpdate { beta: beta2, squared: true })?;
                let update = ParamUpdate { lr, keep: 1f64 - lr_lambda, scale_m, scale_v, eps: self.params.eps };
                theta.as_tensor().inplace_op3(m.as_tensor(), v.as_tensor(), &update)?;
                continue;
            }
            {
                let next_m = ((m.as_tensor() * beta1)? + (g * (1.0 - beta1))?)?;
                let next_v = ((v.as_tensor() * beta2)? + (g.sqr()? * (1.0 - beta2))?)?;
                let m_hat = (&next_m * scale_m)?;
                let v_hat = (&next_v * scale_v)?;
                let next_theta = (theta.as_tensor() * (1f64 - lr_lambda))?;
                let adjusted_grad = (m_hat / (v_hat.sqrt()? + self.params.eps)?)?;
                let next_theta = (next_theta - (adjusted_grad * lr)?)?;
                m.set(&next_m)?;
                v.set(&next_v)?;
                theta.set(&next_theta)?;
            }
        }
        Ok(())
    }
}

/// Stochastic gradient descent with momentum, dampening, Nesterov and weight decay
/// (PyTorch's `torch.optim.SGD`); see [`SgdConfig`].
#[derive(Debug)]
pub struct Sgd {
    vars: Vec<Var>,
    /// One momentum buffer per var, created on its first gradient.
    buffers: Vec<Option<Tensor>>,
    config: SgdConfig,
}

impl Sgd {
    /// Creates the optimiser after validating `config`; non-float vars are skipped.
    pub fn with_config(vars: Vec<Var>, config: SgdConfig) -> Result<Self> {
        OptimizerConfig::Sgd(config).validate()?;
        let vars: Vec<Var> = vars.into_iter().filter(|v| v.dtype().is_float()).collect();
        let buffers = vec![None; vars.len()];
        Ok(Self { vars, buffers, config })
    }

    /// The current settings (the learning rate included).
    pub fn config(&self) -> &SgdConfig {
        &self.config
    }

    /// The optimised variables.
    pub fn vars(&self) -> &[Var] {
        &self.vars
    }

    fn state(&self) -> Result<OptimState> {
        let mut slots = Vec::new();
        for (i, b) in self.buffers.iter().enumerate() {
            if let Some(b) = b {
                slots.push((i, "momentum", b.copy()?));
            }
        }
        Ok(OptimState { kind: "sgd", steps: 0, slots })
    }

    fn set_state(&mut self, state: &OptimState) -> Result<()> {
        check_state("sgd", &self.vars, &["momentum"], state)?;
        self.buffers = vec![None; self.vars.len()];
        for (i, _, t) in &state.slots {
            let var = &self.vars[*i];
            self.buffers[*i] = Some(t.to_dtype(var.dtype())?.to_device(var.device())?);
        }
        Ok(())
    }
}

impl Optimizer for Sgd {
    type Config = SgdConfig;

    fn new(vars: Vec<Var>, config: SgdConfig) -> candle_core::Result<Self> {
        Ok(Self::with_config(vars, config)?)
    }

    fn step(&mut self, grads: &GradStore) -> candle_core::Result<()> {
        let c = self.config;
        for (var, buf) in self.vars.iter().zip(self.buffers.iter_mut()) {
            let Some(g) = grads.get(var.as_tensor()) else { continue };
            // Detached: the update must not extend the autograd graph of the var.
            let theta = var.as_tensor().detach();
            let mut g = g.detach();
            if c.weight_decay != 0.0 {
                g = (g + (&theta * c.weight_decay)?)?;
            }
            if c.momentum != 0.0 {
                let b = match buf.take() {
                    None => g.clone(),
                    Some(b) => ((b * c.momentum)? + (&g * (1.0 - c.dampening))?)?,
                };
                g = if c.nesterov { (g + (&b * c.momentum)?)? } else { b.clone() };
                *buf = Some(b);
            }
            var.set(&(theta - (g * c.lr)?)?)?;
        }
        Ok(())
    }

    fn learning_rate(&self) -> f64 {
        self.config.lr
    }

    fn set_learning_rate(&mut self, lr: f64) {
        self.config.lr = lr;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// One SGD-momentum step by hand: b1 = g1, b2 = m b1 + g2.
    #[test]
    fn sgd_momentum_matches_hand_computation() {
        let x = Var::new(&[1.0f64], &Device::Cpu).unwrap();
        let cfg = SgdConfig { lr: 0.1, momentum: 0.5, ..Default::default() };
        let mut opt = Sgd::with_config(vec![x.clone()], cfg).unwrap();
        // loss = x^2, g = 2x
        opt.backward_step(&x.as_tensor().sqr().unwrap().sum_all().unwrap()).unwrap();
        // x1 = 1 - 0.1 * 2 = 0.8
        assert!((x.as_tensor().to_vec1::<f64>().unwrap()[0] - 0.8).abs() < 1e-15);
        opt.backward_step(&x.as_tensor().sqr().unwrap().sum_all().unwrap()).unwrap();
        // b2 = 0.5 * 2 + 1.6 = 2.6, x2 = 0.8 - 0.26 = 0.54
        assert!((x.as_tensor().to_vec1::<f64>().unwrap()[0] - 0.54).abs() < 1e-15);
    }

    /// Nesterov and weight decay by hand, f = x^2 from x = 1, lr 0.1, momentum 0.5, wd 0.5:
    /// step 1: g = 2 + 0.5 = 2.5, b = 2.5, g' = 2.5 + 1.25 = 3.75, x = 0.625;
    /// step 2: g = 1.25 + 0.3125 = 1.5625, b = 1.25 + 1.5625 = 2.8125,
    ///         g' = 1.5625 + 1.40625 = 2.96875, x = 0.625 - 0.296875 = 0.328125.
    #[test]
    fn sgd_nesterov_with_weight_decay_matches_hand_computation() {
        let x = Var::new(&[1.0f64], &Device::Cpu).unwrap();
        let cfg = SgdConfig { lr: 0.1, momentum: 0.5, nesterov: true, weight_decay: 0.5, ..Default::default() };
        let mut opt = Sgd::with_config(vec![x.clone()], cfg).unwrap();
        for expect in [0.625, 0.328125] {
            opt.backward_step(&x.as_tensor().sqr().unwrap().sum_all().unwrap()).unwrap();
            assert!((x.as_tensor().to_vec1::<f64>().unwrap()[0] - expect).abs() < 1e-15);
        }
    }

    #[test]
    fn nesterov_without_momentum_is_rejected_with_advice() {
        let cfg = OptimizerConfig::Sgd(SgdConfig { nesterov: true, ..Default::default() });
        let msg = cfg.validate().unwrap_err().to_string();
        assert!(msg.contains("nesterov") && msg.contains("momentum > 0"), "{msg}");
        let bad_beta = OptimizerConfig::Adam(AdamConfig { beta2: 1.0, ..Default::default() });
        assert!(bad_beta.validate().unwrap_err().to_string().contains("beta2"));
    }

    #[test]
    fn serde_fills_documented_defaults() {
        let c: OptimizerConfig = serde_json::from_str(r#"{"kind":"adamw","lr":0.5}"#).unwrap();
        assert_eq!(c, OptimizerConfig::AdamW(AdamWConfig { lr: 0.5, ..Default::default() }));
        let back: OptimizerConfig = serde_json::from_str(&serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        let d: OptimizerConfig = serde_json::from_str(r#"{"kind":"adam"}"#).unwrap();
        assert_eq!(d, OptimizerConfig::default());
    }
}
