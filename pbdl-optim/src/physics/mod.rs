//! Differentiable physics with exact Jacobians, and the data sets of the experiments.
//!
//! A [`Physics`] maps a sample's context `x` (e.g. its initial state) and the network's
//! output `u` (e.g. a control sequence) to an outcome `y = P(x; u)`, and gives the exact
//! Jacobian `dy/du` (no finite differences). HIG composes it with the network's Jacobian:
//! `J = (dy/du) (du/dtheta)`.
//!
//! | file | physics | sizes (context, control, outcome) |
//! |---|---|---|
//! | [`ode`] | any small controlled ODE integrated by RK4, Jacobian by forward tangents per step | `n`, `steps`, `n` |
//! | [`oscillators`] | the pbdl-book linear chain and the HIG paper's nonlinear oscillators | `4`, `24` / `96`, `4` |
//! | [`dipole`] | the HIG paper's quantum dipole: Crank-Nicolson for `i psi_t = (-psi_xx + u(t) x) psi`, Jacobian and VJP by an adjoint sweep | `28`, `384`, `28` (complex states as `Re, Im` pairs) |
//! | [`poisson`] | the 5-point Laplacian on an 8x8 grid with zero boundary (`y = L u`) | `0`, `64`, `64` |
//! | [`stepper`] | any differentiable [`pbdl_core::stepper::Stepper`] on tensors ([`StepperPhysics`]): the control is the initial state, the outcome the state after `n` steps; Jacobian by one candle backward pass per output entry (small problems) | `0`, `len`, `len` (`len`: the state's element count) |

pub mod dipole;
pub mod ode;
pub mod oscillators;
pub mod poisson;
pub mod stepper;

pub use dipole::QuantumDipole;
pub use ode::{ControlledOde, Rk4Rollout};
pub use oscillators::{Coupling, Oscillators};
pub use poisson::Poisson8;
pub use stepper::StepperPhysics;

use crate::error::{check_len, Result};

/// A differentiable physics model with an exact Jacobian with respect to its control.
pub trait Physics: Sync {
    /// Length of a sample's context (0 if the physics has none).
    fn context_dim(&self) -> usize;
    /// Length of the control (the network's output).
    fn control_dim(&self) -> usize;
    /// Length of the outcome `y`.
    fn output_dim(&self) -> usize;
    /// `y = P(x; u)`.
    fn forward(&self, x: &[f64], u: &[f64], y: &mut [f64]) -> Result<()>;
    /// `y = P(x; u)` and `jac = dy/du`, `[output_dim, control_dim]` row-major.
    fn jacobian(&self, x: &[f64], u: &[f64], y: &mut [f64], jac: &mut [f64]) -> Result<()>;

    /// The vector-Jacobian product `cot_u = (dy/du)^T cot_y` at `(x, u)` (ordinary backprop,
    /// for first-order optimisers). The default builds the whole Jacobian; physics with a
    /// cheaper adjoint pass override it.
    fn vjp(&self, x: &[f64], u: &[f64], cot_y: &[f64], cot_u: &mut [f64]) -> Result<()> {
        let (ny, nu) = (self.output_dim(), self.control_dim());
        check_len("physics output cotangent length", ny, cot_y.len())?;
        check_len("physics control cotangent length", nu, cot_u.len())?;
        let mut y = vec![0.0; ny];
        let mut jac = vec![0.0; ny * nu];
        self.jacobian(x, u, &mut y, &mut jac)?;
        cot_u.fill(0.0);
        for (k, gk) in cot_y.iter().enumerate() {
            cot_u.iter_mut().zip(&jac[k * nu..(k + 1) * nu]).for_each(|(c, j)| *c += gk * j);
        }
        Ok(())
    }

    /// Checks the slice lengths of one sample.
    fn check_sample(&self, x: &[f64], u: &[f64], y: &[f64]) -> Result<()> {
        check_len("physics context length", self.context_dim(), x.len())?;
        check_len("physics control length", self.control_dim(), u.len())?;
        check_len("physics output length", self.output_dim(), y.len())
    }
}

/// Samples of a learning problem `min_theta sum_s ||P(x_s; f(i_s; theta)) - y*_s||^2` (or another
/// per-sample [`crate::hig::Loss`]): network inputs `i_s`, physics contexts `x_s` and targets
/// `y*_s`, each stored row after row.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// Network inputs `[n, input_dim]`.
    pub inputs: Vec<f64>,
    /// Physics contexts `[n, context_dim]`.
    pub contexts: Vec<f64>,
    /// Targets `[n, output_dim]`.
    pub targets: Vec<f64>,
    /// Number of samples.
    pub len: usize,
}

/// A contiguous range of samples of a [`Dataset`].
#[derive(Clone, Copy, Debug)]
pub struct Batch<'a> {
    /// Network inputs.
    pub inputs: &'a [f64],
    /// Physics contexts.
    pub contexts: &'a [f64],
    /// Targets.
    pub targets: &'a [f64],
    /// Number of samples.
    pub len: usize,
}

impl Dataset {
    /// A data set, checking that the three arrays hold `len` rows each.
    pub fn new(inputs: Vec<f64>, contexts: Vec<f64>, targets: Vec<f64>, len: usize) -> Result<Self> {
        for (what, v) in [("inputs", &inputs), ("targets", &targets)] {
            if len == 0 || v.len() % len != 0 || v.is_empty() {
                return Err(crate::Error::shape(
                    format!("dataset {what} length"),
                    format!("a positive multiple of {len}"),
                    v.len(),
                ));
            }
        }
        if contexts.len() % len.max(1) != 0 {
            return Err(crate::Error::shape("dataset contexts length", format!("a multiple of {len}"), contexts.len()));
        }
        Ok(Self { inputs, contexts, targets, len })
    }

    /// The return-to-start problem of the oscillator papers: `x0 ~ U[0, 1)^dim`, the network
    /// sees `x0`, the physics starts from it and the target is `x0` again.
    pub fn return_to_start(n: usize, dim: usize, seed: u64) -> Self {
        use rand::Rng;
        let mut rng = pbdl_core::seed::rng(seed);
        let x: Vec<f64> = (0..n * dim).map(|_| rng.random_range(0.0..1.0)).collect();
        Self { inputs: x.clone(), contexts: x.clone(), targets: x, len: n }
    }

    /// The whole set as one batch.
    pub fn all(&self) -> Batch<'_> {
        self.batch(0, self.len)
    }

    /// Samples `start..start + len`.
    pub fn batch(&self, start: usize, len: usize) -> Batch<'_> {
        let n = self.len.max(1);
        let (di, dc, dt) = (self.inputs.len() / n, self.contexts.len() / n, self.targets.len() / n);
        Batch {
            inputs: &self.inputs[start * di..(start + len) * di],
            contexts: &self.contexts[start * dc..(start + len) * dc],
            targets: &self.targets[start * dt..(start + len) * dt],
            len,
        }
    }
}
