//! Guidance by repulsion (Schnell & Thuerey, ICLR 2024): `nd` drivers herd `ne` evaders to the
//! origin, differentiable in candle (`f64`), and the stabilized-BPTT training run on it.
//!
//! Objects move in 2D under explicit Euler (`x += dt v`, `v += dt a`, both from the old state).
//! With `d = eps + |r|` for the separation `r` of a pair:
//!
//! ```text
//! evader e:  a = sum_drivers k_ev (x_e - x_d) / d^2  - f_ev v_e  + k_fl sum_{j != e} ((r_fl / d - 1) / d) (x_j - x_e)
//! driver d:  a = c_r (x_d - C) + c_t perp(x_d - C)   - f_dr v_d  + k_sp sum_{j != d} (x_d - x_j) / d^2
//! ```
//!
//! with `C` the *sum* of the evader positions, `perp(x, y) = (-y, x)` and the controls
//! `(c_r, c_t)` of each driver from the network. Defaults (the paper's): `k_ev = 15`,
//! `f_ev = 4`, `k_fl = 0.2`, `r_fl = 0.5`, `f_dr = 1`, `k_sp = 0.2`, `eps = 0.1`, `T = 4` in 60
//! steps. The flocking term is signed as in the official simulator (there the force of the pair
//! `(i, j)` lands on `j`): evaders closer than `r_fl` attract, farther ones repel, the opposite
//! of the comment next to it ("stay close but not too close"); a negative `flocking` gives the
//! commented behaviour.
//!
//! State of a sample: per object (drivers first) `[x, y, vx, vy]`, then the last controls
//! `(c_r, c_t)` per driver, so that the loss can see them: `4 (nd + ne) + 2 nd` values. The
//! network sees the first `4 (nd + ne)`. Loss, averaged over the steps `1..=N`:
//! `mean(x_e^2) + rc mean(c^2)` (means over samples, evaders and coordinates, resp. drivers and
//! the two controls). Start: drivers on the annulus `r in [3, 4]`, an evader centre on
//! `r in [1, 2]`, evaders at the centre `+- 0.5` per coordinate, velocities zero.
//!
//! [`train`] runs one configuration; the bench entry `guidance` compares modes F, P and C for
//! `rc in {1, 0.1, 0.01, 0.001}`.

use crate::bptt::Rollout;
pub use crate::controller::DenseController;
use crate::error::{Error, Result};
use candle_core::{Device, Tensor};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Physical constants and integration settings of the driver-evader system.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Guidance {
    /// Number of drivers `nd` (at least 1). Default `2`.
    pub drivers: usize,
    /// Number of evaders `ne` (at least 1). Default `4`.
    pub evaders: usize,
    /// Repulsion of evaders by drivers `k_ev`. Default `15`.
    pub evade: f64,
    /// Evader friction `f_ev`. Default `4`.
    pub evader_friction: f64,
    /// Flocking strength `k_fl` (sign as in the official code, see the module docs). Default `0.2`.
    pub flocking: f64,
    /// Flocking distance `r_fl`. Default `0.5`.
    pub flock_distance: f64,
    /// Driver friction `f_dr`. Default `1`.
    pub driver_friction: f64,
    /// Repulsion between drivers `k_sp`. Default `0.2`.
    pub spreading: f64,
    /// Softening `eps` of the distance. Default `0.1`.
    pub epsilon: f64,
    /// Time step. Default `4 / 60`.
    pub dt: f64,
    /// Steps of an episode. Default `60`.
    pub steps: usize,
}

impl Default for Guidance {
    fn default() -> Self {
        Self::new(2, 4)
    }
}

impl Guidance {
    /// The paper's settings with `drivers` drivers and `evaders` evaders.
    pub fn new(drivers: usize, evaders: usize) -> Self {
        Self {
            drivers,
            evaders,
            evade: 15.0,
            evader_friction: 4.0,
            flocking: 0.2,
            flock_distance: 0.5,
            driver_friction: 1.0,
            spreading: 0.2,
            epsilon: 0.1,
            dt: 4.0 / 60.0,
            steps: 60,
        }
    }

    /// Number of objects `nd + ne`.
    pub fn objects(&self) -> usize {
        self.drivers + self.evaders
    }

    /// Length of the physical state (the network input), `4 (nd + ne)`.
    pub fn phys_dim(&self) -> usize {
        4 * self.objects()
    }

    /// Number of controls, `2 nd`.
    pub fn control_dim(&self) -> usize {
        2 * self.drivers
    }

    /// Length of a full state, physical state plus the last controls.
    pub fn state_dim(&self) -> usize {
        self.phys_dim() + self.control_dim()
    }

    /// Checks the settings.
    pub fn validate(&self) -> Result<()> {
        if self.drivers == 0 || self.evaders == 0 {
            return Err(Error::InvalidConfig {
                name: "drivers/evaders",
                value: self.drivers.min(self.evaders) as f64,
                hint: "use at least one driver and one evader (the paper: 2 and 4)",
            });
        }
        if !(self.epsilon > 0.0 && self.epsilon.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "epsilon",
                value: self.epsilon,
                hint: "the distance softening must be > 0 (default 0.1), else coincident objects divide by zero",
            });
        }
        if !(self.dt > 0.0 && self.dt.is_finite()) {
            return Err(Error::InvalidConfig {
                name: "dt",
                value: self.dt,
                hint: "use a positive time step (default 4/60)",
            });
        }
        Ok(())
    }

    /// Builds the stepper: the pair tables are made once here, not in every step.
    pub fn stepper(&self) -> Result<GuidanceStepper> {
        self.validate()?;
        let (nd, n) = (self.drivers, self.objects());
        let dev = Device::Cpu;
        // Every ordered pair (a, b), a != b, whose force acts on a, with
        // w(d) = alpha / d^2 + beta / d and force_a += w(d) (x_a - x_b).
        let (mut diff, mut scatter, mut alpha, mut beta) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for a in 0..n {
            for b in 0..n {
                let (al, be) = match (a < nd, b < nd) {
                    _ if a == b => continue,
                    (true, true) => (self.spreading, 0.0),
                    (true, false) => continue, // drivers feel no force from evaders
                    (false, true) => (self.evade, 0.0),
                    // k ((r / d - 1) / d) (x_b - x_a) = (-k r / d^2 + k / d) (x_a - x_b)
                    (false, false) => (-self.flocking * self.flock_distance, self.flocking),
                };
                let mut row = vec![0.0; n];
                row[a] = 1.0;
                row[b] = -1.0;
                diff.push(row);
                scatter.push(a);
                alpha.push(al);
                beta.push(be);
            }
        }
        let p = alpha.len();
        let diff = Tensor::from_vec(diff.concat(), (p, n), &dev)?;
        let mut s = vec![0.0; n * p];
        for (k, &a) in scatter.iter().enumerate() {
            s[a * p + k] = 1.0;
        }
        let scatter = Tensor::from_vec(s, (n, p), &dev)?;
        let friction: Vec<f64> =
            (0..n).map(|k| if k < nd { -self.driver_friction } else { -self.evader_friction }).collect();
        Ok(GuidanceStepper {
            phys: *self,
            diff,
            scatter,
            alpha: Tensor::from_vec(alpha, (1, p, 1), &dev)?,
            beta: Tensor::from_vec(beta, (1, p, 1), &dev)?,
            friction: Tensor::from_vec(friction, (1, n, 1), &dev)?,
        })
    }

    /// `n` start states from `seed` (drivers on `r in [3, 4]`, evaders around a centre on
    /// `r in [1, 2]`, zero velocities and controls), `[n, state_dim]`.
    pub fn initial_states(&self, n: usize, seed: u64) -> Result<Tensor> {
        self.validate()?;
        let mut rng = pbdl_core::seed::rng(seed);
        let annulus = |rng: &mut rand::rngs::StdRng, r0: f64, r1: f64| -> (f64, f64) {
            let phi = 2.0 * std::f64::consts::PI * rng.random::<f64>();
            let r = r0 + (r1 - r0) * rng.random::<f64>();
            (r * phi.cos(), r * phi.sin())
        };
        let d = self.state_dim();
        let mut v = vec![0.0; n * d];
        for i in 0..n {
            for k in 0..self.drivers {
                let (x, y) = annulus(&mut rng, 3.0, 4.0);
                v[i * d + 4 * k] = x;
                v[i * d + 4 * k + 1] = y;
            }
            let (cx, cy) = annulus(&mut rng, 1.0, 2.0);
            for k in self.drivers..self.objects() {
                v[i * d + 4 * k] = cx + rng.random_range(-0.5..0.5);
                v[i * d + 4 * k + 1] = cy + rng.random_range(-0.5..0.5);
            }
        }
        Ok(Tensor::from_vec(v, (n, d), &Device::Cpu)?)
    }
}

/// A built driver-evader stepper (see [`Guidance::stepper`]).
#[derive(Clone, Debug)]
pub struct GuidanceStepper {
    phys: Guidance,
    /// `[pairs, objects]`: `+1` at `a`, `-1` at `b`, so `diff x` is `x_a - x_b` per pair.
    diff: Tensor,
    /// `[objects, pairs]`: sums the pair forces onto the object they act on.
    scatter: Tensor,
    alpha: Tensor,
    beta: Tensor,
    friction: Tensor,
}

impl GuidanceStepper {
    /// The physics it was built from.
    pub fn physics(&self) -> &Guidance {
        &self.phys
    }

    /// One explicit Euler step of a batch: `s: [b, state_dim]`, `u: [b, 2 nd]` (per driver
    /// `c_r, c_t`). The new state carries `u` as its last controls.
    pub fn step(&self, s: &Tensor, u: &Tensor) -> candle_core::Result<Tensor> {
        let p = &self.phys;
        let (b, n, nd, ne) = (s.dim(0)?, p.objects(), p.drivers, p.evaders);
        let obj = s.narrow(1, 0, p.phys_dim())?.reshape((b, n, 2, 2))?;
        let x = obj.narrow(2, 0, 1)?.squeeze(2)?;
        let v = obj.narrow(2, 1, 1)?.squeeze(2)?;
        // Pair forces: r = x_a - x_b, d = eps + |r|, w = alpha / d^2 + beta / d.
        let r = self.diff.broadcast_matmul(&x)?;
        let d = (r.sqr()?.sum_keepdim(2)?.sqrt()? + p.epsilon)?;
        let inv = d.recip()?;
        let w = (inv.sqr()?.broadcast_mul(&self.alpha)? + inv.broadcast_mul(&self.beta)?)?;
        let pair = r.broadcast_mul(&w)?;
        let mut acc = (self.scatter.broadcast_matmul(&pair)? + v.broadcast_mul(&self.friction)?)?;
        // Control force on the drivers around the evaders' position sum C.
        let centre = x.narrow(1, nd, ne)?.sum_keepdim(1)?;
        let rc = x.narrow(1, 0, nd)?.broadcast_sub(&centre)?;
        let perp = Tensor::cat(&[rc.narrow(2, 1, 1)?.neg()?, rc.narrow(2, 0, 1)?], 2)?;
        let c = u.reshape((b, nd, 2))?;
        let f_con = (rc.broadcast_mul(&c.narrow(2, 0, 1)?)? + perp.broadcast_mul(&c.narrow(2, 1, 1)?)?)?;
        let f_con = Tensor::cat(&[f_con, Tensor::zeros((b, ne, 2), s.dtype(), s.device())?], 1)?;
        acc = (acc + f_con)?;
        let x_new = (&x + (&v * p.dt)?)?;
        let v_new = (v + (acc * p.dt)?)?;
        let obj_new = Tensor::stack(&[x_new, v_new], 2)?.reshape((b, p.phys_dim()))?;
        Tensor::cat(&[obj_new, u.clone()], 1)
    }

    /// The loss of a rollout `[s_0, ..., s_N]`, averaged over steps `1..=N`:
    /// `mean(x_e^2) + rc mean(c^2)`.
    pub fn loss(&self, traj: &[Tensor], rc: f64) -> candle_core::Result<Tensor> {
        let p = &self.phys;
        if traj.len() < 2 {
            candle_core::bail!(
                "guidance loss: the rollout has {} states; it needs at least 2 (steps >= 1)",
                traj.len()
            );
        }
        let all = Tensor::stack(&traj[1..], 1)?;
        let (b, t) = (all.dim(0)?, all.dim(1)?);
        let xe = all
            .narrow(2, 0, p.phys_dim())?
            .reshape((b, t, p.objects(), 4))?
            .narrow(2, p.drivers, p.evaders)?
            .narrow(3, 0, 2)?;
        let c = all.narrow(2, p.phys_dim(), p.control_dim())?;
        xe.sqr()?.mean_all()? + (c.sqr()?.mean_all()? * rc)?
    }
}

crate::bptt::experiment_config! {
    /// Settings of one guidance training run.
    pub struct GuidanceConfig {
        /// The physics.
        pub physics: Guidance = Guidance::default(),
        /// Weight `rc` of the control cost.
        pub rc: f64 = rc,
    }
    width: "Hidden width of the controller. Default `100`." = 100,
    /// The paper's settings (2 drivers, 4 evaders) for `rc` and `mode`, with `iterations` steps
    /// (the paper: 10 epochs = 320).
    new(rc: f64),
}

/// What a guidance run measured (test loss with the control cost).
pub type GuidanceRun = crate::bptt::BpttRun;

/// Test loss of `net` on the start states `test` (a forward rollout, no gradient).
pub fn evaluate(stepper: &GuidanceStepper, net: &DenseController, test: &Tensor, rc: f64) -> Result<f64> {
    let phys_dim = stepper.physics().phys_dim();
    let mut traj = vec![test.clone()];
    for _ in 0..stepper.physics().steps {
        let s = traj.last().expect("non-empty");
        let u = net.forward(&s.narrow(1, 0, phys_dim)?)?.detach();
        let next = stepper.step(s, &u)?.detach();
        traj.push(next);
    }
    Ok(stepper.loss(&traj, rc)?.to_scalar::<f64>()?)
}

/// Trains a fresh controller with `cfg` (Adam on the mode's gradient) and records the test loss.
pub fn train(cfg: &GuidanceConfig) -> Result<GuidanceRun> {
    let phys = cfg.physics;
    let stepper = phys.stepper()?;
    let net = DenseController::new(phys.phys_dim(), cfg.width, phys.control_dim(), cfg.seed)?;
    let train = phys.initial_states(cfg.train, cfg.seed)?;
    let test = phys.initial_states(cfg.test, cfg.seed + 1)?;
    let phys_dim = phys.phys_dim();
    let rollout = Rollout {
        steps: phys.steps,
        net: &|s| net.forward(&s.narrow(1, 0, phys_dim)?),
        physics: &|s, u| stepper.step(s, u),
        loss: &|traj| stepper.loss(traj, cfg.rc),
    };
    crate::bptt::train(net.vars(), &train, &rollout, &cfg.schedule(), || evaluate(&stepper, &net, &test, cfg.rc))
}
