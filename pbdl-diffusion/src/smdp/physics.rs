//! The physics drift `P(x, t)` of the SDE `dx = P(x) dt + g dW`, and its inverse step.
//!
//! [`PhysicsDrift`] works on candle tensors (differentiable, any shape); [`ScalarDrift`] is the
//! same drift on plain `f64` for the 1-D toy problems, where the simulator and the hand-written
//! score network run without tensors.

use crate::{Error, Result};
use candle_core::Tensor;

/// A physics drift that can be differentiated through.
pub trait PhysicsDrift {
    /// The increment of one physics step of length `dt` from `x` at time `t`: `dt * P(x, t)`
    /// (for a solver step `x -> S(x)` this is `S(x) - x`).
    fn increment(&self, x: &Tensor, t: f64, dt: f64) -> Result<Tensor>;

    /// The inverse physics step `x - increment(x)`: the physics part of one backward step.
    fn inverse_step(&self, x: &Tensor, t: f64, dt: f64) -> Result<Tensor> {
        Ok((x - self.increment(x, t, dt)?)?)
    }
}

/// A 1-D drift on `f64`, with its derivative (needed to backpropagate through a rollout).
pub trait ScalarDrift: Sync {
    /// `P(x)`.
    fn drift(&self, x: f64) -> f64;
    /// `dP/dx`.
    fn drift_dx(&self, x: f64) -> f64;
}

/// The toy problem's drift `P(x) = -lambda sign(x) x^2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuadraticDrift {
    /// `lambda` (7 in the paper).
    pub lambda: f64,
}

/// The analytic check case's drift `P(x) = -a x` (an Ornstein-Uhlenbeck process; `a = 0.5`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineDrift {
    /// `a` (0.5 in the paper's check).
    pub a: f64,
}

/// The two drifts of the toy problem, chosen at run time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToyDrift {
    /// `-lambda sign(x) x^2`.
    Quadratic(QuadraticDrift),
    /// `-a x`.
    Affine(AffineDrift),
}

impl ToyDrift {
    /// The paper's toy drift, `lambda = 7`.
    pub fn quadratic() -> Self {
        ToyDrift::Quadratic(QuadraticDrift { lambda: 7.0 })
    }
    /// The analytic check drift, `a = 0.5`.
    pub fn affine() -> Self {
        ToyDrift::Affine(AffineDrift { a: 0.5 })
    }
    /// Rejects non-finite or negative coefficients (a negative one makes the SDE blow up).
    pub fn validate(&self) -> Result<()> {
        let (name, v) = match self {
            ToyDrift::Quadratic(q) => ("lambda", q.lambda),
            ToyDrift::Affine(a) => ("a", a.a),
        };
        if !v.is_finite() || v < 0.0 {
            return Err(Error::InvalidConfig {
                name,
                value: v.to_string(),
                hint: "use a finite, non-negative drift coefficient (7 for the quadratic toy, 0.5 for the affine one)",
            });
        }
        Ok(())
    }
}

impl ScalarDrift for QuadraticDrift {
    fn drift(&self, x: f64) -> f64 {
        -self.lambda * x.abs() * x
    }
    fn drift_dx(&self, x: f64) -> f64 {
        -2.0 * self.lambda * x.abs()
    }
}

impl ScalarDrift for AffineDrift {
    fn drift(&self, x: f64) -> f64 {
        -self.a * x
    }
    fn drift_dx(&self, _x: f64) -> f64 {
        -self.a
    }
}

impl ScalarDrift for ToyDrift {
    fn drift(&self, x: f64) -> f64 {
        match self {
            ToyDrift::Quadratic(q) => q.drift(x),
            ToyDrift::Affine(a) => a.drift(x),
        }
    }
    fn drift_dx(&self, x: f64) -> f64 {
        match self {
            ToyDrift::Quadratic(q) => q.drift_dx(x),
            ToyDrift::Affine(a) => a.drift_dx(x),
        }
    }
}

impl PhysicsDrift for QuadraticDrift {
    fn increment(&self, x: &Tensor, _t: f64, dt: f64) -> Result<Tensor> {
        // -lambda |x| x, written with differentiable pieces.
        Ok((x.abs()? * x)?.affine(-self.lambda * dt, 0.0)?)
    }
}

impl PhysicsDrift for AffineDrift {
    fn increment(&self, x: &Tensor, _t: f64, dt: f64) -> Result<Tensor> {
        Ok(x.affine(-self.a * dt, 0.0)?)
    }
}

impl PhysicsDrift for ToyDrift {
    fn increment(&self, x: &Tensor, t: f64, dt: f64) -> Result<Tensor> {
        match self {
            ToyDrift::Quadratic(q) => q.increment(x, t, dt),
            ToyDrift::Affine(a) => a.increment(x, t, dt),
        }
    }
}

/// Any simulator with a fixed step as SMDP's physics: the increment of one step is
/// `step(x) - x`. The pbdl-grid solvers (and any [`pbdl_core::stepper::Stepper`] on tensors)
/// plug into SMDP's losses and samplers this way; the sampler's `dt` must be the stepper's.
#[derive(Clone, Debug)]
pub struct StepperDrift<S>(pub S);

impl<S> PhysicsDrift for StepperDrift<S>
where
    S: pbdl_core::stepper::Stepper<State = Tensor>,
    Error: From<S::Error>,
{
    fn increment(&self, x: &Tensor, _t: f64, dt: f64) -> Result<Tensor> {
        let own = self.0.dt();
        if (dt - own).abs() > 1e-12 * own.abs().max(1.0) {
            return Err(Error::InvalidConfig {
                name: "dt",
                value: dt.to_string(),
                hint: "a stepper has a fixed time step: sample and train with the stepper's dt",
            });
        }
        Ok((self.0.step(x)? - x)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// The affine drift as a stepper (explicit Euler) gives the same increments through the
    /// adapter, and a wrong dt is a typed error.
    #[test]
    fn a_stepper_is_physics_through_the_adapter() {
        struct EulerDecay {
            a: f64,
            dt: f64,
        }
        impl pbdl_core::stepper::Stepper for EulerDecay {
            type State = Tensor;
            type Error = candle_core::Error;
            fn dt(&self) -> f64 {
                self.dt
            }
            fn operators(&self) -> Vec<&'static str> {
                vec!["decay.explicit_euler"]
            }
            fn differentiability(&self) -> pbdl_core::stepper::Differentiability {
                pbdl_core::stepper::Differentiability::Full
            }
            fn step(&self, x: &Tensor) -> candle_core::Result<Tensor> {
                x.affine(1.0 - self.a * self.dt, 0.0)
            }
        }
        let x = Tensor::new(&[0.3f64, -1.2, 2.0], &Device::Cpu).unwrap();
        let p = StepperDrift(EulerDecay { a: 0.5, dt: 0.01 });
        let got: Vec<f64> = p.increment(&x, 0.0, 0.01).unwrap().to_vec1().unwrap();
        let want: Vec<f64> = AffineDrift { a: 0.5 }.increment(&x, 0.0, 0.01).unwrap().to_vec1().unwrap();
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-15, "{got:?} vs {want:?}");
        }
        assert!(matches!(p.increment(&x, 0.0, 0.02), Err(Error::InvalidConfig { name: "dt", .. })));
    }

    #[test]
    fn tensor_drift_matches_scalar_drift_and_its_derivative() {
        for d in [ToyDrift::quadratic(), ToyDrift::affine()] {
            let xs = [-1.3, -0.2, 0.0, 0.05, 0.9];
            let x = Tensor::new(&xs, &Device::Cpu).unwrap();
            let inc = d.increment(&x, 0.0, 0.02).unwrap().to_vec1::<f64>().unwrap();
            for (i, &xi) in xs.iter().enumerate() {
                assert!((inc[i] - 0.02 * d.drift(xi)).abs() < 1e-15);
                let h = 1e-6;
                let fd = (d.drift(xi + h) - d.drift(xi - h)) / (2.0 * h);
                // O(h) difference error at the kink x = 0.
                assert!((fd - d.drift_dx(xi)).abs() < 1e-5, "{d:?} at {xi}: {fd} vs {}", d.drift_dx(xi));
            }
        }
    }

    #[test]
    fn negative_coefficient_is_a_typed_error() {
        let e = ToyDrift::Quadratic(QuadraticDrift { lambda: -1.0 }).validate().unwrap_err();
        assert!(e.to_string().contains("lambda"), "{e}");
    }
}
