//! Quantum control (Schnell & Thuerey, ICLR 2024): steer a particle in a 1D box from a mix of the
//! two lowest eigenstates into eigenstate 3, 4 or 5, with a network that picks the field `u`
//! from the current wave function at every step; differentiable in candle (`f64`), and the
//! stabilized-BPTT training run on it.
//!
//! `i dpsi/dt = (-d^2/dx^2 + u x) psi` on `[0, L]`, `psi = 0` at the walls, `n` interior points
//! `x_j = j dx` (`dx = L / (n + 1)`, `j = 1..n`). A step is Crank-Nicolson with `u` held over the
//! step, `A psi' = B psi` with `A = I + i dt/2 H`, `B = I - i dt/2 H`, `H = T + u X`
//! (a unitary Cayley transform), solved by one complex Thomas sweep in the custom op
//! [`cn_step`], whose vector-Jacobian product is hand-written:
//!
//! ```text
//! lambda = B^-1 g_y        (A^H = B, because H is real symmetric)
//! g_psi  = A lambda
//! g_u    = Re sum_j conj(lambda_j) (-i dt/2) x_j (psi_j + psi'_j)
//! ```
//!
//! with `g = dL/dRe + i dL/dIm`. The paper's setup ([`QuantumControl::paper`]): `L = 2`,
//! `n = 32`, `dt = 0.0625`, 128 steps. States are `2 n` reals, `Re, Im` interleaved per point.
//! Start: `(c_1 e^{i p_1} phi_1 + c_2 e^{i p_2} phi_2) / |c|` with `c_k ~ N(0, 1)`,
//! `p_k ~ U[0, 2 pi)`; `phi_m` is the discrete eigenstate `sin(pi m j / (n + 1))`, normalised
//! to `sum |phi|^2 = 1`. Loss: `sum_{k=1..N} (1 - |<phi_target|psi_k>|^2)`, averaged over the
//! batch (range `0..N`).
//!
//! Controller ([`ConvController`], as in the official model): conv 2 -> 60 channels (kernel 3,
//! stride 2, tanh), conv 60 -> 60 (kernel 3, stride 2, tanh), dense to one output, Glorot
//! weights and zero biases. [`train`] runs one configuration; the bench entry
//! `quantum_control` compares modes F, P and C for targets 3, 4 and 5.

use crate::bptt::Rollout;
use crate::error::{Error, Result};
use candle_core::{DType, Device, Shape, Tensor, Var};
use pbdl_core::conv::{conv1d, Conv1dParams};
use pbdl_core::op::{apply2, apply_kernel3, Kernel2, Kernel3, Op2};
use pbdl_core::Real;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// The driven particle in a box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct QuantumControl {
    /// Interior grid points `n` (at least 7 for the controller's two strided convolutions).
    pub points: usize,
    /// Box length `L`.
    pub length: f64,
    /// Time step.
    pub dt: f64,
    /// Steps of an episode.
    pub steps: usize,
    /// Target eigenstate (1 = ground state).
    pub target: usize,
}

impl QuantumControl {
    /// The paper's setup: `n = 32`, `L = 2`, `dt = 0.0625`, 128 steps, target eigenstate `target`.
    pub fn paper(target: usize) -> Self {
        Self { points: 32, length: 2.0, dt: 0.0625, steps: 128, target }
    }

    /// Grid spacing `L / (n + 1)`.
    pub fn dx(&self) -> f64 {
        self.length / (self.points + 1) as f64
    }

    /// Length of a state, `2 n`.
    pub fn state_dim(&self) -> usize {
        2 * self.points
    }

    /// Checks the settings.
    pub fn validate(&self) -> Result<()> {
        if self.points < 7 {
            return Err(Error::InvalidConfig {
                name: "points",
                value: self.points as f64,
                hint:
                    "use at least 7 interior points (the controller's two stride-2 convolutions need them; paper: 32)",
            });
        }
        for (name, v) in [("length", self.length), ("dt", self.dt)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(Error::InvalidConfig {
                    name,
                    value: v,
                    hint: "must be finite and > 0 (paper: L = 2, dt = 0.0625)",
                });
            }
        }
        if self.target == 0 || self.target > self.points {
            return Err(Error::InvalidConfig {
                name: "target",
                value: self.target as f64,
                hint: "the target eigenstate counts from 1 (ground state) up to the number of points",
            });
        }
        Ok(())
    }

    /// The discrete eigenstate `m` (1-based) as `2 n` interleaved reals (imaginary parts 0).
    pub fn eigenstate(&self, m: usize) -> Result<Vec<f64>> {
        if m == 0 || m > self.points {
            return Err(Error::InvalidConfig {
                name: "eigenstate",
                value: m as f64,
                hint: "eigenstates count from 1 up to the number of points",
            });
        }
        let n = self.points;
        let k = std::f64::consts::PI * m as f64 / (n + 1) as f64;
        let amp: Vec<f64> = (1..=n).map(|j| (k * j as f64).sin()).collect();
        let norm = amp.iter().map(|a| a * a).sum::<f64>().sqrt();
        Ok(amp.iter().flat_map(|a| [a / norm, 0.0]).collect())
    }

    /// Eigenvalue of the discrete `-d^2/dx^2` for eigenstate `m`: `(2 - 2 cos(pi m / (n + 1))) / dx^2`.
    pub fn eigenvalue(&self, m: usize) -> f64 {
        let k = std::f64::consts::PI * m as f64 / (self.points + 1) as f64;
        (2.0 - 2.0 * k.cos()) / (self.dx() * self.dx())
    }

    /// `count` start states from `seed`, `[count, 2 n]`: random complex mixes of eigenstates 1 and 2.
    pub fn initial_states(&self, count: usize, seed: u64) -> Result<Tensor> {
        self.validate()?;
        let (e1, e2) = (self.eigenstate(1)?, self.eigenstate(2)?);
        let mut rng = pbdl_core::seed::rng(seed);
        let normal = |rng: &mut rand::rngs::StdRng| -> f64 {
            // Box-Muller; 1 - U keeps the logarithm finite.
            let (u1, u2): (f64, f64) = (1.0 - rng.random::<f64>(), rng.random::<f64>());
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        };
        let mut v = Vec::with_capacity(count * self.state_dim());
        for _ in 0..count {
            let (c1, c2) = (normal(&mut rng), normal(&mut rng));
            let p1 = 2.0 * std::f64::consts::PI * rng.random::<f64>();
            let p2 = 2.0 * std::f64::consts::PI * rng.random::<f64>();
            let norm = (c1 * c1 + c2 * c2).sqrt().max(f64::MIN_POSITIVE);
            let (f1, f2) = ((c1 * p1.cos() / norm, c1 * p1.sin() / norm), (c2 * p2.cos() / norm, c2 * p2.sin() / norm));
            for j in 0..self.points {
                let (a, b) = (e1[2 * j], e2[2 * j]);
                v.push(f1.0 * a + f2.0 * b);
                v.push(f1.1 * a + f2.1 * b);
            }
        }
        Ok(Tensor::from_vec(v, (count, self.state_dim()), &Device::Cpu)?)
    }

    /// One Crank-Nicolson step of a batch, differentiable in `psi: [b, 2 n]` and `u: [b, 1]`.
    pub fn step(&self, psi: &Tensor, u: &Tensor) -> candle_core::Result<Tensor> {
        cn_step(psi, u, self.points, self.dx(), self.dt)
    }

    /// `sum_{k>=1} (1 - |<phi_target|psi_k>|^2)` over a rollout `[psi_0, ..., psi_N]`, averaged
    /// over the batch.
    pub fn loss(&self, traj: &[Tensor], target: &Tensor) -> candle_core::Result<Tensor> {
        if traj.len() < 2 {
            candle_core::bail!("quantum loss: the rollout has {} states; it needs at least 2 (steps >= 1)", traj.len());
        }
        let all = Tensor::stack(&traj[1..], 1)?;
        let (b, t) = (all.dim(0)?, all.dim(1)?);
        let all = all.reshape((b, t, self.points, 2))?;
        // The target is real, so Re<phi|psi> = phi . Re psi and Im<phi|psi> = phi . Im psi.
        let phi = target.reshape((1, 1, self.points, 2))?.narrow(3, 0, 1)?;
        let overlap = all.broadcast_mul(&phi)?.sum(2)?; // [b, t, 2]
        let fidelity = overlap.sqr()?.sum_all()?;
        (fidelity * (-1.0 / b as f64))? + t as f64
    }

    /// The target eigenstate as a `[2 n]` tensor.
    pub fn target_tensor(&self) -> Result<Tensor> {
        Ok(Tensor::from_vec(self.eigenstate(self.target)?, self.state_dim(), &Device::Cpu)?)
    }
}

/// One Crank-Nicolson step `A psi' = B psi` of a batch (see the module docs): `psi: [b, 2 n]`
/// (`Re, Im` interleaved), `u: [b, 1]`, grid spacing `dx`, step `dt`. Differentiable in both.
pub fn cn_step(psi: &Tensor, u: &Tensor, points: usize, dx: f64, dt: f64) -> candle_core::Result<Tensor> {
    apply2(psi, u, CnStep { points, dx, dt })
}

/// Complex numbers as `(re, im)` pairs; only what the sweeps need.
type Cx = (f64, f64);

fn mul(a: Cx, b: Cx) -> Cx {
    (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0)
}

fn div(a: Cx, b: Cx) -> Cx {
    let d = b.0 * b.0 + b.1 * b.1;
    ((a.0 * b.0 + a.1 * b.1) / d, (a.1 * b.0 - a.0 * b.1) / d)
}

fn sub(a: Cx, b: Cx) -> Cx {
    (a.0 - b.0, a.1 - b.1)
}

fn add(a: Cx, b: Cx) -> Cx {
    (a.0 + b.0, a.1 + b.1)
}

#[derive(Clone, Copy)]
struct CnStep {
    points: usize,
    dx: f64,
    dt: f64,
}

impl CnStep {
    /// `(diag_j, off)` of `A = I + i dt/2 H` for the control `u`; `B` is their conjugate.
    fn a_matrix(&self, u: f64) -> (Vec<Cx>, Cx) {
        let (h, inv2) = (0.5 * self.dt, 1.0 / (self.dx * self.dx));
        let diag = (1..=self.points).map(|j| (1.0, h * (2.0 * inv2 + u * j as f64 * self.dx))).collect();
        (diag, (0.0, -h * inv2))
    }

    /// `M v` for the tridiagonal `M` with diagonal `diag` and both off-diagonals `off`.
    fn apply(diag: &[Cx], off: Cx, v: &[Cx]) -> Vec<Cx> {
        let n = v.len();
        (0..n)
            .map(|j| {
                let mut r = mul(diag[j], v[j]);
                if j > 0 {
                    r = add(r, mul(off, v[j - 1]));
                }
                if j + 1 < n {
                    r = add(r, mul(off, v[j + 1]));
                }
                r
            })
            .collect()
    }

    /// Solves the tridiagonal system (Thomas); `A` and `B` are diagonally dominant, no pivoting needed.
    fn solve(diag: &[Cx], off: Cx, rhs: &[Cx]) -> Vec<Cx> {
        let n = rhs.len();
        let (mut cp, mut rp) = (vec![(0.0, 0.0); n], vec![(0.0, 0.0); n]);
        for j in 0..n {
            let m = if j == 0 { diag[0] } else { sub(diag[j], mul(off, cp[j - 1])) };
            cp[j] = div(off, m);
            rp[j] = if j == 0 { div(rhs[0], m) } else { div(sub(rhs[j], mul(off, rp[j - 1])), m) };
        }
        let mut y = rp;
        for j in (0..n.saturating_sub(1)).rev() {
            y[j] = sub(y[j], mul(cp[j], y[j + 1]));
        }
        y
    }

    fn conj(diag: &[Cx], off: Cx) -> (Vec<Cx>, Cx) {
        (diag.iter().map(|d| (d.0, -d.1)).collect(), (off.0, -off.1))
    }

    /// `psi'` of one sample.
    fn forward_one(&self, psi: &[Cx], u: f64) -> Vec<Cx> {
        let (ad, ao) = self.a_matrix(u);
        let (bd, bo) = Self::conj(&ad, ao);
        Self::solve(&ad, ao, &Self::apply(&bd, bo, psi))
    }

    fn check(&self, psi: &Shape, u: &Shape) -> candle_core::Result<usize> {
        let b = match psi.dims() {
            [b, m] if *m == 2 * self.points => *b,
            d => candle_core::bail!(
                "cn_step: psi must be [batch, {}] (Re, Im interleaved per point), got {d:?}",
                2 * self.points
            ),
        };
        if u.dims() != [b, 1] {
            candle_core::bail!("cn_step: u must be [batch, 1] = [{b}, 1] (one control per sample), got {:?}", u.dims());
        }
        Ok(b)
    }
}

fn to_cx<T: Real>(v: &[T]) -> Vec<Cx> {
    v.chunks_exact(2).map(|c| (c[0].wide(), c[1].wide())).collect()
}

impl Kernel2 for CnStep {
    fn name(&self) -> &'static str {
        "cn_step"
    }
    fn output_shape(&self, psi: &Shape, u: &Shape) -> candle_core::Result<Shape> {
        self.check(psi, u)?;
        Ok(psi.clone())
    }
    fn forward<T: Real>(&self, psi: &[T], _: &Shape, u: &[T], _: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let m = 2 * self.points;
        for ((p, o), uk) in psi.chunks_exact(m).zip(out.chunks_exact_mut(m)).zip(u) {
            let y = self.forward_one(&to_cx(p), uk.wide());
            for (j, c) in y.iter().enumerate() {
                o[2 * j] = T::c(c.0);
                o[2 * j + 1] = T::c(c.1);
            }
        }
        Ok(())
    }
}

impl Op2 for CnStep {
    fn backward(&self, psi: &Tensor, u: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let packed = apply_kernel3(psi, u, gy, CnAdjoint(*self))?;
        let m = 2 * self.points;
        Ok((packed.narrow(1, 0, m)?, packed.narrow(1, m, 1)?))
    }
}

/// The vector-Jacobian product of [`CnStep`]: `[b, 2 n + 1]` = (`g_psi`, `g_u`).
struct CnAdjoint(CnStep);

impl Kernel3 for CnAdjoint {
    fn name(&self) -> &'static str {
        "cn_step_adjoint"
    }
    fn output_shape(&self, psi: &Shape, u: &Shape, gy: &Shape) -> candle_core::Result<Shape> {
        let b = self.0.check(psi, u)?;
        if gy != psi {
            candle_core::bail!("cn_step_adjoint: the output gradient {gy:?} must have psi's shape {psi:?}");
        }
        Ok(Shape::from((b, 2 * self.0.points + 1)))
    }
    fn forward<T: Real>(
        &self,
        psi: &[T],
        _: &Shape,
        u: &[T],
        _: &Shape,
        gy: &[T],
        _: &Shape,
        out: &mut [T],
    ) -> candle_core::Result<()> {
        let op = &self.0;
        let m = 2 * op.points;
        let h = 0.5 * op.dt;
        for (((p, g), uk), o) in psi.chunks_exact(m).zip(gy.chunks_exact(m)).zip(u).zip(out.chunks_exact_mut(m + 1)) {
            let psi = to_cx(p);
            let uk = uk.wide();
            let y = op.forward_one(&psi, uk);
            let (ad, ao) = op.a_matrix(uk);
            let (bd, bo) = CnStep::conj(&ad, ao);
            let lambda = CnStep::solve(&bd, bo, &to_cx(g));
            let gx = CnStep::apply(&ad, ao, &lambda);
            // g_u = Re sum conj(lambda_j) s_j with s_j = -i h x_j (psi_j + y_j).
            let mut gu = 0.0;
            for j in 0..op.points {
                let x = (j + 1) as f64 * op.dx;
                let w = add(psi[j], y[j]);
                let s = (h * x * w.1, -h * x * w.0);
                gu += lambda[j].0 * s.0 + lambda[j].1 * s.1;
            }
            for (j, c) in gx.iter().enumerate() {
                o[2 * j] = T::c(c.0);
                o[2 * j + 1] = T::c(c.1);
            }
            o[m] = T::c(gu);
        }
        Ok(())
    }
}

/// The official quantum-control network: conv (2 -> `width`, kernel 3, stride 2, tanh),
/// conv (`width` -> `width`, kernel 3, stride 2, tanh), dense to one control.
#[derive(Clone, Debug)]
pub struct ConvController {
    vars: Vec<Var>,
    points: usize,
}

impl ConvController {
    /// Glorot-uniform weights (fans as in Keras: the first layer is a 3x2 Conv2D on one
    /// channel there) and zero biases, from `seed`.
    pub fn new(points: usize, width: usize, seed: u64) -> Result<Self> {
        if points < 7 || width == 0 {
            return Err(Error::InvalidConfig {
                name: "points/width",
                value: points.min(width) as f64,
                hint: "the controller needs at least 7 points and 1 channel (paper: 32 points, 60 channels)",
            });
        }
        let l1 = (points - 3) / 2 + 1;
        let l2 = (l1 - 3) / 2 + 1;
        let mut rng = pbdl_core::seed::rng(seed);
        let mut glorot = |shape: &[usize], fan_in: usize, fan_out: usize| -> Result<Var> {
            let lim = (6.0 / (fan_in + fan_out) as f64).sqrt();
            let count = shape.iter().product();
            let v: Vec<f64> = (0..count).map(|_| rng.random_range(-lim..lim)).collect();
            Ok(Var::from_tensor(&Tensor::from_vec(v, shape, &Device::Cpu)?)?)
        };
        let w1 = glorot(&[width, 2, 3], 6, 6 * width)?;
        let w2 = glorot(&[width, width, 3], 3 * width, 3 * width)?;
        let w3 = glorot(&[width * l2, 1], width * l2, 1)?;
        let zeros = |k: usize| -> Result<Var> { Ok(Var::zeros(k, DType::F64, &Device::Cpu)?) };
        let vars = vec![w1, zeros(width)?, w2, zeros(width)?, w3, zeros(1)?];
        Ok(Self { vars, points })
    }

    /// The trainable variables.
    pub fn vars(&self) -> &[Var] {
        &self.vars
    }

    /// The control `[b, 1]` for states `[b, 2 n]`.
    pub fn forward(&self, psi: &Tensor) -> candle_core::Result<Tensor> {
        let v = &self.vars;
        let b = psi.dim(0)?;
        let x = psi.reshape((b, self.points, 2))?.transpose(1, 2)?.contiguous()?;
        let p = Conv1dParams::default().stride(2);
        let h = conv1d(&x, v[0].as_tensor(), Some(v[1].as_tensor()), &p)?.tanh()?;
        let h = conv1d(&h, v[2].as_tensor(), Some(v[3].as_tensor()), &p)?.tanh()?;
        h.flatten_from(1)?.matmul(v[4].as_tensor())?.broadcast_add(v[5].as_tensor())
    }
}

crate::bptt::experiment_config! {
    /// Settings of one quantum-control training run.
    pub struct QuantumControlConfig {
        /// The physics (with the target eigenstate).
        pub physics: QuantumControl = QuantumControl::paper(target),
    }
    width: "Channels of the controller. Default `60`." = 60,
    /// The paper's settings for `target` and `mode`, with `iterations` optimizer steps (the
    /// paper: 1000 epochs = 32000).
    new(target: usize),
}

/// What a quantum-control run measured (test loss `sum_k (1 - fidelity_k)`).
pub type QuantumControlRun = crate::bptt::BpttRun;

/// Test loss of `net` on the start states `test` (a forward rollout, no gradient).
pub fn evaluate(phys: &QuantumControl, net: &ConvController, test: &Tensor) -> Result<f64> {
    let target = phys.target_tensor()?;
    let mut traj = vec![test.clone()];
    for _ in 0..phys.steps {
        let s = traj.last().expect("non-empty");
        let u = net.forward(s)?.detach();
        let next = phys.step(s, &u)?.detach();
        traj.push(next);
    }
    Ok(phys.loss(&traj, &target)?.to_scalar::<f64>()?)
}

/// Trains a fresh controller with `cfg` (Adam on the mode's gradient) and records the test loss.
pub fn train(cfg: &QuantumControlConfig) -> Result<QuantumControlRun> {
    let phys = cfg.physics;
    phys.validate()?;
    let net = ConvController::new(phys.points, cfg.width, cfg.seed)?;
    let train = phys.initial_states(cfg.train, cfg.seed)?;
    let test = phys.initial_states(cfg.test, cfg.seed + 1)?;
    let target = phys.target_tensor()?;
    let rollout = Rollout {
        steps: phys.steps,
        net: &|s| net.forward(s),
        physics: &|s, u| phys.step(s, u),
        loss: &|traj| phys.loss(traj, &target),
    };
    crate::bptt::train(net.vars(), &train, &rollout, &cfg.schedule(), || evaluate(&phys, &net, &test))
}
