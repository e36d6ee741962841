//! The simulator seams: what a learning method needs from a simulator, whatever its kind.
//!
//! Two shapes of simulator meet here:
//!
//! * [`Stepper`]: a pure map `state -> next state` with a fixed time step, built once from a
//!   scene with only the operators it needs. Grid solvers (Navier-Stokes, Burgers, heat) have
//!   this shape. When [`Stepper::differentiability`] says so, `step` is made of candle ops and
//!   custom ops with adjoints, so a loss on a rollout can be backpropagated to the initial state
//!   and to any network in the loop (solver-in-the-loop, SMDP's physics drift, control).
//! * [`Evolve`]: a solver that advances its own state in place with an adaptive stable step
//!   (particle methods: SPH, IISPH). [`Evolve::run_until`] is written once here; a solver only
//!   says how long its next step may be.
//!
//! ```
//! use pbdl_core::stepper::{Differentiability, Stepper};
//!
//! /// Exponential decay `du/dt = -k u`, explicit Euler.
//! struct Decay { k: f64, dt: f64 }
//!
//! impl Stepper for Decay {
//!     type State = f64;
//!     type Error = pbdl_core::Error;
//!     fn dt(&self) -> f64 { self.dt }
//!     fn operators(&self) -> Vec<&'static str> { vec!["decay.explicit_euler"] }
//!     fn differentiability(&self) -> Differentiability { Differentiability::None }
//!     fn step(&self, u: &f64) -> Result<f64, Self::Error> { Ok(u * (1.0 - self.k * self.dt)) }
//! }
//!
//! let s = Decay { k: 1.0, dt: 0.001 };
//! let states = s.rollout(&1.0, 1000)?;
//! assert_eq!(states.len(), 1001); // the start and every step
//! assert!((states[1000] - (-1.0f64).exp()).abs() < 1e-3);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

/// How far gradients flow through a [`Stepper::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Differentiability {
    /// Not differentiable (plain `f64` loops, in-place updates, discrete decisions).
    None,
    /// Every operator is a candle op or a custom op with a hand-written adjoint: gradients
    /// reach the state tensors (and the parameters held as `Var`s).
    Full,
    /// Differentiable except for the listed operators (their adjoint is treated as zero or the
    /// identity, as documented by the operator).
    Partial(&'static [&'static str]),
}

/// A simulator with a fixed time step: state in, state out.
pub trait Stepper {
    /// What evolves: a tensor, a field, or a struct of them.
    type State;
    /// The simulator's error type.
    type Error: std::error::Error + Send + Sync + 'static;

    /// The time step of one [`Stepper::step`].
    fn dt(&self) -> f64;

    /// The operators this stepper was built with, in the order one step applies them
    /// (e.g. `["advect.flux_form", "diffuse.explicit", "pressure.fft", "time_stepping.rk4"]`).
    fn operators(&self) -> Vec<&'static str>;

    /// Whether gradients flow through [`Stepper::step`].
    fn differentiability(&self) -> Differentiability;

    /// One step from `state`.
    fn step(&self, state: &Self::State) -> Result<Self::State, Self::Error>;

    /// `steps` steps from `start`; returns the start and every state after it (`steps + 1`).
    fn rollout(&self, start: &Self::State, steps: usize) -> Result<Vec<Self::State>, Self::Error>
    where
        Self::State: Clone,
    {
        let mut states = Vec::with_capacity(steps + 1);
        states.push(start.clone());
        for k in 0..steps {
            let next = self.step(&states[k])?;
            states.push(next);
        }
        Ok(states)
    }

    /// The state after `steps` steps, keeping only the last one.
    fn advance(&self, start: &Self::State, steps: usize) -> Result<Self::State, Self::Error>
    where
        Self::State: Clone,
    {
        let mut state = start.clone();
        for _ in 0..steps {
            state = self.step(&state)?;
        }
        Ok(state)
    }
}

/// A solver that advances its own state in place with an adaptive stable time step.
pub trait Evolve {
    /// The solver's error type.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Simulated time now.
    fn time(&self) -> f64;

    /// Steps taken so far.
    fn steps(&self) -> u64;

    /// The largest stable time step for the current state.
    fn stable_dt(&self) -> f64;

    /// One step of length `dt` (at most [`Evolve::stable_dt`]).
    fn step(&mut self, dt: f64) -> Result<(), Self::Error>;

    /// The length of the next step on the way to `t_end`. The default takes the stable step and
    /// shortens only the last one; a solver whose accuracy suffers from a sliver step at the end
    /// can return [`equal_steps_dt`] instead.
    fn next_dt(&self, t_end: f64) -> f64 {
        self.stable_dt().min(t_end - self.time())
    }

    /// Steps until `t_end` (up to a relative `1e-14`); returns the steps taken.
    fn run_until(&mut self, t_end: f64) -> Result<u64, Self::Error> {
        let start = self.steps();
        while self.time() < t_end * (1.0 - 1e-14) {
            let dt = self.next_dt(t_end);
            self.step(dt)?;
        }
        Ok(self.steps() - start)
    }
}

/// The step length that splits the rest of the way to `t_end` into equal steps no longer than
/// `stable`, so that no sliver step is left at the end.
pub fn equal_steps_dt(time: f64, t_end: f64, stable: f64) -> f64 {
    let rest = t_end - time;
    let n = (rest / stable * (1.0 - 1e-9)).ceil().max(1.0);
    (rest / n).min(stable)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Counts steps; stable step 0.3.
    struct Clock {
        t: f64,
        n: u64,
        equal: bool,
        taken: Vec<f64>,
    }

    impl Evolve for Clock {
        type Error = crate::Error;
        fn time(&self) -> f64 {
            self.t
        }
        fn steps(&self) -> u64 {
            self.n
        }
        fn stable_dt(&self) -> f64 {
            0.3
        }
        fn step(&mut self, dt: f64) -> Result<(), Self::Error> {
            assert!(dt <= 0.3 + 1e-15);
            self.t += dt;
            self.n += 1;
            self.taken.push(dt);
            Ok(())
        }
        fn next_dt(&self, t_end: f64) -> f64 {
            if self.equal {
                equal_steps_dt(self.t, t_end, self.stable_dt())
            } else {
                self.stable_dt().min(t_end - self.t)
            }
        }
    }

    #[test]
    fn run_until_ends_on_time_with_either_step_policy() {
        let mut c = Clock { t: 0.0, n: 0, equal: false, taken: vec![] };
        assert_eq!(c.run_until(1.0).unwrap(), 4);
        assert!((c.t - 1.0).abs() < 1e-12);
        assert!((c.taken[3] - 0.1).abs() < 1e-12, "last step is the sliver: {:?}", c.taken);
        let mut c = Clock { t: 0.0, n: 0, equal: true, taken: vec![] };
        assert_eq!(c.run_until(1.0).unwrap(), 4);
        assert!((c.t - 1.0).abs() < 1e-12);
        assert!(c.taken.iter().all(|&d| (d - 0.25).abs() < 1e-12), "equal steps: {:?}", c.taken);
        // Already there: no step.
        assert_eq!(c.run_until(1.0).unwrap(), 0);
    }
}
