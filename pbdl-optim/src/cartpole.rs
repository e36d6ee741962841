//! Cart-pole with `NC` poles on one cart, differentiable in candle (`f64`), and the stabilized
//! BPTT experiment of Schnell & Thuerey (ICLR 2024) on it.
//!
//! Dynamics (per pole `i`, gravity `g`, pole mass `m`, total mass `M`, half length `l`):
//!
//! ```text
//! A_i     = (F + m l sin th_i th_d_i^2) / M
//! th_dd_i = (g sin th_i - cos th_i A_i) / (l (4/3 - m cos^2 th_i / M))
//! x_dd    = (F + m l sum_i (sin th_i th_d_i^2 - th_dd_i cos th_i)) / M
//! ```
//!
//! integrated by semi-implicit Euler (velocities first, then positions with the new
//! velocities). `th = 0` is upright. The state of a sample is
//! `[x, th_1..th_NC, x_d, th_d_1..th_d_NC]` (`2 (1 + NC)` values), which is also the
//! controller's input; the controller outputs the force `F`. Episodes start hanging down,
//! `th = pi +- U * pi / 6`, everything else `U[-1, 1]`; the loss is `1 - mean cos th` at the
//! final step (0: all poles upright).
//!
//! [`train`] runs one configuration (gradient mode, clipping, Adam) and returns the test loss
//! over training; the bench entry `cartpole` compares modes F, P and C for `NC = 1..4`.
//! [`adjoint`] is the same experiment with a hand-written adjoint (the paper-length runs).

pub mod adjoint;

use crate::bptt::Rollout;
pub use crate::controller::DenseController;
use crate::error::Result;
use candle_core::{Device, Tensor};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Physical constants and integration settings of a cart with `poles` poles.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CartPole {
    /// Number of poles `NC` (at least 1).
    pub poles: usize,
    /// Gravity. Default `9.8`.
    pub gravity: f64,
    /// Mass of one pole. Default `0.1`.
    pub pole_mass: f64,
    /// Total mass `M` in the equations. Default `1.1`.
    pub total_mass: f64,
    /// Half pole length `l`. Default `0.5`.
    pub half_length: f64,
    /// Time step. Default `0.01`.
    pub dt: f64,
    /// Steps of an episode. Default `100`.
    pub steps: usize,
}

impl CartPole {
    /// The paper's settings with `poles` poles.
    pub fn new(poles: usize) -> Self {
        Self { poles, gravity: 9.8, pole_mass: 0.1, total_mass: 1.1, half_length: 0.5, dt: 0.01, steps: 100 }
    }

    /// Length of a state, `2 (1 + poles)`.
    pub fn state_dim(&self) -> usize {
        2 * (1 + self.poles)
    }

    /// One semi-implicit Euler step of a batch: `s: [b, state_dim]`, `force: [b, 1]`.
    pub fn step(&self, s: &Tensor, force: &Tensor) -> candle_core::Result<Tensor> {
        let nc = self.poles;
        let (m, big_m, l) = (self.pole_mass, self.total_mass, self.half_length);
        let x = s.narrow(1, 0, 1)?;
        let th = s.narrow(1, 1, nc)?;
        let xd = s.narrow(1, 1 + nc, 1)?;
        let thd = s.narrow(1, 2 + nc, nc)?;
        let (sin, cos) = (th.sin()?, th.cos()?);
        let sin_thd2 = (&sin * thd.sqr()?)?;
        // A_i = (F + m l sin th_i th_d_i^2) / M
        let a = ((&sin_thd2 * (m * l))?.broadcast_add(force)? / big_m)?;
        let denom = ((cos.sqr()? * (-m / big_m))? + 4.0 / 3.0)? * l;
        let thdd = (((&sin * self.gravity)? - (&cos * &a)?)? / denom?)?;
        let sum = (&sin_thd2 - (&thdd * &cos)?)?.sum_keepdim(1)?;
        let xdd = ((force + (sum * (m * l))?)? / big_m)?;
        let xd_new = (xd + (xdd * self.dt)?)?;
        let thd_new = (thd + (thdd * self.dt)?)?;
        let x_new = (x + (&xd_new * self.dt)?)?;
        let th_new = (th + (&thd_new * self.dt)?)?;
        Tensor::cat(&[x_new, th_new, xd_new, thd_new], 1)
    }

    /// `1 - mean cos th` over the batch and the poles of `s: [b, state_dim]`.
    pub fn loss(&self, s: &Tensor) -> candle_core::Result<Tensor> {
        s.narrow(1, 1, self.poles)?.cos()?.mean_all()?.affine(-1.0, 1.0)
    }

    /// `n` start states from `seed`: `th = pi +- U * pi / 6`, the rest `U[-1, 1]`.
    pub fn initial_states(&self, n: usize, seed: u64) -> Result<Tensor> {
        let mut rng = pbdl_core::seed::rng(seed);
        let d = self.state_dim();
        let mut v = Vec::with_capacity(n * d);
        for _ in 0..n {
            for k in 0..d {
                let is_angle = (1..=self.poles).contains(&k);
                let r: f64 = rng.random_range(-1.0..1.0);
                v.push(if is_angle { std::f64::consts::PI + r * std::f64::consts::PI / 6.0 } else { r });
            }
        }
        Ok(Tensor::from_vec(v, (n, d), &Device::Cpu)?)
    }
}

/// The cart-pole controller `2 (1 + NC) -> width -> width -> 1` (tanh), built with
/// [`DenseController::with_zero_last_layer`] so training starts from `F = 0`.
pub type Controller = DenseController;

crate::bptt::experiment_config! {
    /// Settings of one cart-pole training run.
    pub struct CartPoleConfig {
        /// The physics.
        pub physics: CartPole = CartPole::new(poles),
    }
    width: "Hidden width of the controller. Default `100`." = 100,
    /// The paper's settings for `poles` poles and `mode`, with `iterations` optimizer steps.
    new(poles: usize),
}

/// What a cart-pole run measured (test loss `1 - mean cos th`).
pub type CartPoleRun = crate::bptt::BpttRun;

/// Test loss of `net` on `test` episodes (a forward rollout, no gradient).
pub fn evaluate(physics: &CartPole, net: &Controller, test: &Tensor) -> Result<f64> {
    let mut s = test.clone();
    for _ in 0..physics.steps {
        let f = net.forward(&s)?.detach();
        s = physics.step(&s, &f)?.detach();
    }
    Ok(physics.loss(&s)?.to_scalar::<f64>()?)
}

/// Trains a fresh controller with `cfg` (Adam on the mode's gradient) and records the test loss.
pub fn train(cfg: &CartPoleConfig) -> Result<CartPoleRun> {
    let phys = cfg.physics;
    let net = Controller::with_zero_last_layer(phys.state_dim(), cfg.width, 1, cfg.seed)?;
    let train = phys.initial_states(cfg.train, cfg.seed)?;
    let test = phys.initial_states(cfg.test, cfg.seed + 1)?;
    let rollout = Rollout {
        steps: phys.steps,
        net: &|s| net.forward(s),
        physics: &|s, u| phys.step(s, u),
        loss: &|traj| phys.loss(traj.last().expect("non-empty rollout")),
    };
    crate::bptt::train(net.vars(), &train, &rollout, &cfg.schedule(), || evaluate(&phys, &net, &test))
}
