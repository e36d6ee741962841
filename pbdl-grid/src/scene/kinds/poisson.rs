//! The Poisson equation `lap phi = f`, solved once (scalar `phi`; the source `f` from `init`).

use super::{c, check_finite_scalar, FieldInput, PhysicsKind, Setup};
use crate::pressure::solve_poisson;
use crate::scene::{SceneResult, State};
use crate::{CenteredField, PressureSolver, ScalarBoundaries};
use candle_core::Tensor;
use std::sync::Arc;

/// The Poisson solver, its source and the solution `phi` (zero until the one step).
pub(super) struct PoissonKind {
    solver: Arc<PressureSolver>,
    source: CenteredField,
    solved: bool,
    phi: Tensor,
    operators: Vec<&'static str>,
}

impl PoissonKind {
    /// Builds the solver and samples the source; the "time step" is 1.
    pub fn build(setup: &Setup<'_>, boundaries: &ScalarBoundaries) -> SceneResult<(Self, f64)> {
        let grid = setup.grid2d()?;
        let solver = PressureSolver::for_scalar(grid, boundaries, false)?;
        let source = CenteredField::new(setup.scalar(boundaries.is_periodic())?, grid, *boundaries)?;
        let operators = vec![if solver.method_name() == "fft" { "poisson.fft" } else { "poisson.sparse_cholesky" }];
        let phi = c(source.values().zeros_like())?;
        Ok((Self { solver, source, solved: false, phi, operators }, 1.0))
    }
}

impl PhysicsKind for PoissonKind {
    fn state(&self) -> State {
        State::Scalar(self.phi.clone())
    }

    /// Solves on the first step (and after a new source); later steps keep `phi`.
    fn step(&mut self, _dt: f64) -> SceneResult<()> {
        if !self.solved {
            self.solved = true;
            self.phi = solve_poisson(&self.source, &self.solver)?.into_values();
        }
        Ok(())
    }

    fn check(&self, _dt: f64) -> SceneResult<()> {
        check_finite_scalar(&self.phi)
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        Ok(vec![("phi".into(), c(self.phi.squeeze(0))?), ("source".into(), c(self.source.values().squeeze(0))?)])
    }

    /// Takes a new `source` (the solution is recomputed on the next step).
    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let t = input.scalar("source")?;
        self.source = self.source.with_values(t)?;
        self.solved = false;
        Ok(vec!["source".into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    fn scalar_name(&self) -> Option<&'static str> {
        Some("phi")
    }

    fn planned_steps(&self, _steps: usize) -> usize {
        1
    }
}
