//! The forced Burgers step `u_{t+1} = P(u_t) + dt F_t` on pbdl-grid's differentiable solver.

use super::config::BurgersControlConfig;
use crate::{Error, Result};
use candle_core::Tensor;
use pbdl_grid::scalar_law::ScalarLaw;
use pbdl_grid::time_stepping::ButcherTableau;

/// One controlled step of 1D viscous Burgers: `substeps` RK4 steps of
/// [`ScalarLaw::step`] (a custom op with a hand-written adjoint, so gradients flow through it),
/// then the force `dt F` added. States and forces are `[batch, 1, 1, cells]`.
#[derive(Clone, Debug)]
pub struct ForcedBurgers {
    law: ScalarLaw,
    tableau: ButcherTableau,
    dt: f64,
    substeps: usize,
    cells: usize,
}

impl ForcedBurgers {
    /// Builds the stepper of `cfg` (validated).
    pub fn new(cfg: &BurgersControlConfig) -> Result<Self> {
        Ok(Self {
            law: cfg.law()?,
            tableau: ButcherTableau::rk4(),
            dt: cfg.dt,
            substeps: cfg.substeps()?,
            cells: cfg.cells,
        })
    }

    /// The controlled time step.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// RK4 sub-steps per controlled step.
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Checks that `t` is `[batch, 1, 1, cells]`.
    pub fn check_state(&self, context: &'static str, t: &Tensor) -> Result<()> {
        let d = t.dims();
        if d.len() != 4 || d[1] != 1 || d[2] != 1 || d[3] != self.cells {
            return Err(Error::Shape { context, expected: format!("[batch, 1, 1, {}]", self.cells), got: d.to_vec() });
        }
        Ok(())
    }

    /// `P(u)`: the unforced step.
    pub fn natural_step(&self, u: &Tensor) -> Result<Tensor> {
        let h = self.dt / self.substeps as f64;
        let mut u = u.clone();
        for _ in 0..self.substeps {
            u = self.law.step(&u, h, &self.tableau)?;
        }
        Ok(u)
    }

    /// `P(u) + dt F`.
    pub fn step(&self, u: &Tensor, force: &Tensor) -> Result<Tensor> {
        Ok((self.natural_step(u)? + force.affine(self.dt, 0.0)?)?)
    }

    /// The states `u_0 .. u_T` under the forces `F_0 .. F_{T-1}` (`T = forces.len()`).
    pub fn rollout(&self, u0: &Tensor, forces: &[Tensor]) -> Result<Vec<Tensor>> {
        self.check_state("ForcedBurgers::rollout", u0)?;
        let mut states = Vec::with_capacity(forces.len() + 1);
        states.push(u0.clone());
        for (t, f) in forces.iter().enumerate() {
            if f.dims() != u0.dims() {
                return Err(Error::Shape {
                    context: "ForcedBurgers::rollout (force)",
                    expected: format!("{:?} (the state's shape)", u0.dims()),
                    got: f.dims().to_vec(),
                });
            }
            let next = self.step(&states[t], f)?;
            states.push(next);
        }
        Ok(states)
    }
}
