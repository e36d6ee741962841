//! The heat equation `T_t = kappa lap T` (scalar `temperature`), explicit Runge-Kutta.

use super::{c, check_finite_scalar, FieldInput, PhysicsKind, Setup};
use crate::scene::{SceneResult, State};
use crate::stability::stable_time_step;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau};
use crate::{fd, CenteredField, ScalarBoundaries};
use candle_core::Tensor;

/// The heat equation and its temperature `[1, 1, ny, nx]`.
pub(super) struct HeatKind {
    /// Grid and boundaries of the temperature (its values are replaced at each use).
    template: CenteredField,
    kappa: f64,
    tableau: ButcherTableau,
    t: Tensor,
    operators: Vec<&'static str>,
}

impl HeatKind {
    /// Builds the stepper and samples the initial temperature.
    pub fn build(setup: &Setup<'_>, kappa: f64, boundaries: &ScalarBoundaries) -> SceneResult<(Self, f64)> {
        let grid = setup.grid2d()?;
        let t = setup.scalar(boundaries.is_periodic())?;
        let template = CenteredField::new(t.clone(), grid, *boundaries)?;
        let stable = stable_time_step(&grid, [0.0, 0.0], kappa, &setup.tableau);
        let dt = setup.pick_dt(0.0, stable)?;
        let mut operators = vec![];
        if kappa > 0.0 {
            operators.push("diffuse.laplacian");
        }
        operators.push(setup.time_stepping());
        Ok((Self { template, kappa, tableau: setup.tableau.clone(), t, operators }, dt))
    }
}

impl PhysicsKind for HeatKind {
    fn state(&self) -> State {
        State::Scalar(self.t.clone())
    }

    fn step(&mut self, dt: f64) -> SceneResult<()> {
        let (k, template) = (self.kappa, &self.template);
        self.t = projected_runge_kutta(
            &self.t,
            dt,
            &self.tableau,
            |x| Ok(fd::laplacian(&template.with_values(x.clone())?)?.into_values().affine(k, 0.0)?),
            |x| Ok(x.clone()),
        )?;
        Ok(())
    }

    fn check(&self, _dt: f64) -> SceneResult<()> {
        check_finite_scalar(&self.t)
    }

    fn fields(&self) -> SceneResult<Vec<(String, Tensor)>> {
        Ok(vec![("temperature".into(), c(self.t.squeeze(0))?)])
    }

    fn set_fields(&mut self, input: &FieldInput<'_>) -> SceneResult<Vec<String>> {
        let t = input.scalar("temperature")?;
        self.t = self.template.with_values(t)?.into_values();
        Ok(vec!["temperature".into()])
    }

    fn operators(&self) -> Vec<&'static str> {
        self.operators.clone()
    }

    fn scalar_name(&self) -> Option<&'static str> {
        Some("temperature")
    }
}
