//! Any differentiable [`Stepper`] on candle tensors as a HIG [`Physics`]: the control is the
//! initial state, the outcome the state after a fixed number of steps.
//!
//! [`StepperPhysics`] runs [`Stepper::advance`] from `u` (the flattened initial state, `f64`,
//! reshaped to the shape given at construction) and flattens the final state into `y`; there
//! is no context (`context_dim() == 0`). The Jacobian `dy/du` comes from candle's backprop
//! through the rollout, **one backward pass per output entry** (row of `dy/du`), so a Jacobian
//! costs `output_dim` backward passes over the whole rollout: meant for small problems (tens
//! to a few hundred cells and a handful of steps). The [`Physics::vjp`] override needs a single
//! backward pass.
//!
//! ```
//! use candle_core::Tensor;
//! use pbdl_core::stepper::{Differentiability, Stepper};
//! use pbdl_optim::physics::{Physics, StepperPhysics};
//!
//! /// `x -> 0.5 x`, made of candle ops.
//! struct Halve;
//!
//! impl Stepper for Halve {
//!     type State = Tensor;
//!     type Error = candle_core::Error;
//!     fn dt(&self) -> f64 { 1.0 }
//!     fn operators(&self) -> Vec<&'static str> { vec!["halve"] }
//!     fn differentiability(&self) -> Differentiability { Differentiability::Full }
//!     fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> { x.affine(0.5, 0.0) }
//! }
//!
//! // Control: a 2x2 initial state; outcome: the state after 3 steps, `u / 8`.
//! let physics = StepperPhysics::new(Halve, &[2, 2], 3)?;
//! assert_eq!((physics.context_dim(), physics.control_dim(), physics.output_dim()), (0, 4, 4));
//! let u = [1.0, 2.0, 3.0, 4.0];
//! let (mut y, mut jac) = (vec![0.0; 4], vec![0.0; 16]);
//! physics.jacobian(&[], &u, &mut y, &mut jac)?;
//! assert_eq!(y, [0.125, 0.25, 0.375, 0.5]);
//! for i in 0..4 {
//!     for j in 0..4 {
//!         assert_eq!(jac[i * 4 + j], if i == j { 0.125 } else { 0.0 });
//!     }
//! }
//! # Ok::<(), pbdl_optim::Error>(())
//! ```

use super::Physics;
use crate::error::{check_len, Result};
use candle_core::{DType, Device, Tensor, Var};
use pbdl_core::stepper::{Differentiability, Stepper};

/// A differentiable [`Stepper`] with tensor state as a [`Physics`]: `y = advance(u, steps)`,
/// flattened, with `u` the flattened initial state. See the [module docs](self) for the cost.
///
/// A stepper's error is passed on as [`crate::Error::Candle`] wrapping it
/// (`candle_core::Error::Wrapped`, so it can be downcast to `S::Error`). A stepper that is only
/// [`Differentiability::Partial`] is accepted; its Jacobian then treats the listed operators as
/// their own documentation says (zero or identity adjoint).
#[derive(Clone, Debug)]
pub struct StepperPhysics<S> {
    stepper: S,
    shape: Vec<usize>,
    len: usize,
    steps: usize,
    device: Device,
}

impl<S> StepperPhysics<S>
where
    S: Stepper<State = Tensor>,
{
    /// The stepper `stepper` advanced `steps` steps from an initial state of shape `shape`
    /// (`f64`, on the CPU; see [`StepperPhysics::with_device`]).
    ///
    /// Errors: [`crate::Error::Core`] (`InvalidArgument`) if the stepper is not differentiable
    /// ([`Differentiability::None`]); [`crate::Error::ShapeMismatch`] if `shape` is empty or
    /// holds a zero.
    pub fn new(stepper: S, shape: &[usize], steps: usize) -> Result<Self> {
        if stepper.differentiability() == Differentiability::None {
            return Err(pbdl_core::Error::invalid(
                "StepperPhysics::new",
                "stepper",
                format!(
                    "its differentiability is None (operators {:?}): the exact Jacobian dy/du needs a step made of \
                     candle ops or custom ops with adjoints",
                    stepper.operators()
                ),
            )
            .into());
        }
        if shape.is_empty() || shape.contains(&0) {
            return Err(crate::Error::shape(
                "StepperPhysics state shape",
                "at least one axis, all > 0",
                format!("{shape:?}"),
            ));
        }
        Ok(Self { stepper, shape: shape.to_vec(), len: shape.iter().product(), steps, device: Device::Cpu })
    }

    /// The same physics with the initial state built on `device`.
    pub fn with_device(mut self, device: Device) -> Self {
        self.device = device;
        self
    }

    /// The wrapped stepper.
    pub fn stepper(&self) -> &S {
        &self.stepper
    }

    /// The shape of the initial state.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Steps per outcome.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The final state from the initial state `u0`, flattened (any float dtype of the stepper's
    /// output is fine; the values are read as `f64` by the callers).
    fn run(&self, u0: &Tensor) -> Result<Tensor> {
        let end = self.stepper.advance(u0, self.steps).map_err(candle_core::Error::wrap)?;
        let flat = end.flatten_all()?;
        check_len("StepperPhysics final state length", self.len, flat.elem_count())?;
        Ok(flat)
    }

    /// `u` as a trainable initial state, and the flattened final state built from it.
    fn run_var(&self, u: &[f64]) -> Result<(Var, Tensor)> {
        let u0 = Var::from_tensor(&Tensor::from_slice(u, self.shape.as_slice(), &self.device)?)?;
        let y = self.run(u0.as_tensor())?;
        Ok((u0, y))
    }

    /// The gradient of `scalar` with respect to `u0`, flattened into `out` (zeros if none
    /// reaches it: the scalar does not depend on the initial state).
    fn grad_into(scalar: &Tensor, u0: &Var, out: &mut [f64]) -> Result<()> {
        let grads = scalar.backward()?;
        match grads.get(u0.as_tensor()) {
            Some(g) => {
                let g = g.flatten_all()?.to_dtype(DType::F64)?.to_vec1::<f64>()?;
                out.copy_from_slice(&g);
            }
            None => out.fill(0.0),
        }
        Ok(())
    }
}

/// Copies the flattened tensor `t` into `y` as `f64`.
fn read_into(t: &Tensor, y: &mut [f64]) -> Result<()> {
    y.copy_from_slice(&t.to_dtype(DType::F64)?.to_vec1::<f64>()?);
    Ok(())
}

impl<S> Physics for StepperPhysics<S>
where
    S: Stepper<State = Tensor> + Sync,
{
    fn context_dim(&self) -> usize {
        0
    }

    fn control_dim(&self) -> usize {
        self.len
    }

    fn output_dim(&self) -> usize {
        self.len
    }

    fn forward(&self, x: &[f64], u: &[f64], y: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        let u0 = Tensor::from_slice(u, self.shape.as_slice(), &self.device)?;
        read_into(&self.run(&u0)?, y)
    }

    fn jacobian(&self, x: &[f64], u: &[f64], y: &mut [f64], jac: &mut [f64]) -> Result<()> {
        self.check_sample(x, u, y)?;
        check_len("physics Jacobian length", self.len * self.len, jac.len())?;
        let (u0, out) = self.run_var(u)?;
        read_into(&out, y)?;
        for (k, row) in jac.chunks_exact_mut(self.len).enumerate() {
            Self::grad_into(&out.get(k)?, &u0, row)?;
        }
        Ok(())
    }

    fn vjp(&self, x: &[f64], u: &[f64], cot_y: &[f64], cot_u: &mut [f64]) -> Result<()> {
        check_len("physics context length", 0, x.len())?;
        check_len("physics control length", self.len, u.len())?;
        check_len("physics output cotangent length", self.len, cot_y.len())?;
        check_len("physics control cotangent length", self.len, cot_u.len())?;
        let (u0, out) = self.run_var(u)?;
        let c = Tensor::from_slice(cot_y, self.len, out.device())?.to_dtype(out.dtype())?;
        Self::grad_into(&(out * c)?.sum_all()?, &u0, cot_u)
    }
}
