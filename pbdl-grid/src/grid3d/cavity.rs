//! Incompressible Navier-Stokes in the closed 3D box of [`super::walls`] (lid-driven cavity):
//! the walled flux-form right-hand side and the walled projection after every Runge-Kutta
//! stage, through the generic [`projected_runge_kutta`]. The pressure solver is a choice
//! ([`BoxPressure`]: sparse Cholesky by default, or preconditioned CG).

use super::box_pressure::{BoxPressure, BoxSolver, WallProjection};
use super::field::MacField3d;
use super::stability::{check_time_step, stable_time_step};
use super::walls::{CavityWalls, WallMomentumRhs};
use super::{Grid3d, NavierStokes3dConfig};
use crate::stability::StabilityReport;
use crate::time_stepping::{projected_runge_kutta, ButcherTableau};
use crate::Result;

/// A built 3D lid-driven-cavity stepper.
pub struct Cavity3d {
    grid: Grid3d,
    walls: CavityWalls,
    config: NavierStokes3dConfig,
    tableau: ButcherTableau,
    rhs: WallMomentumRhs,
    projection: WallProjection,
    operators: Vec<&'static str>,
}

impl std::fmt::Debug for Cavity3d {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cavity3d")
            .field("grid", &self.grid)
            .field("walls", &self.walls)
            .field("config", &self.config)
            .field("operators", &self.operators)
            .finish()
    }
}

impl Cavity3d {
    /// Builds the stepper: validates the parameters, refuses a `dt` beyond the diffusive limit,
    /// builds the pressure solver (`pressure`: [`BoxPressure::default()`] = `Auto` (sparse
    /// Cholesky factored here once up to 32^3 cells, CG above), [`BoxPressure::Cholesky`] or
    /// [`BoxPressure::Cg`]; a bare [`crate::pressure::CgSettings`] converts into the latter).
    pub fn new(
        grid: Grid3d,
        walls: CavityWalls,
        config: NavierStokes3dConfig,
        pressure: impl Into<BoxPressure>,
    ) -> Result<Self> {
        grid.validate()?;
        walls.validate()?;
        let tableau = config.tableau()?;
        check_time_step(&grid, [walls.lid_velocity.abs(), 0.0, 0.0], config.nu, &tableau, config.dt)?;
        let projection = WallProjection { solver: pressure.into().build(grid)?, homogeneous: false };
        let rhs = WallMomentumRhs { grid, walls, advect: true, nu: config.nu, faces: Default::default() };
        let operators = config.operators(
            "grid3d.advect.flux_form_walls",
            "grid3d.diffuse.explicit",
            projection.solver.operator_name(),
        );
        Ok(Self { grid, walls, config, tableau, rhs, projection, operators })
    }

    /// The operators this stepper runs.
    pub fn operators(&self) -> &[&'static str] {
        &self.operators
    }

    /// The pressure solver (shared).
    pub fn solver(&self) -> &BoxSolver {
        &self.projection.solver
    }

    /// The largest stable time step for the largest speeds `[|u|, |v|, |w|]` (the lid speed is
    /// included in `|u|`).
    pub fn stable_time_step(&self, max_speed: [f64; 3]) -> f64 {
        let s = [max_speed[0].max(self.walls.lid_velocity.abs()), max_speed[1], max_speed[2]];
        stable_time_step(&self.grid, s, self.config.nu, &self.tableau)
    }

    /// Checks that `dt` is stable for `u` (and the lid).
    pub fn check(&self, u: &MacField3d) -> Result<StabilityReport> {
        let m = u.max_abs_components()?;
        let s = [m[0].max(self.walls.lid_velocity.abs()), m[1], m[2]];
        check_time_step(&self.grid, s, self.config.nu, &self.tableau, self.config.dt)
    }

    /// Projects `u` (use once on an initial condition).
    pub fn project(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        Ok(MacField3d::from_parts(self.projection.apply(u.values())?, self.grid))
    }

    /// One time step; refuses an unstable `dt` or a non-finite `u` (typed errors).
    pub fn step(&self, u: &MacField3d) -> Result<MacField3d> {
        self.check_field(u)?;
        self.check(u)?;
        let out = projected_runge_kutta(
            u.values(),
            self.config.dt,
            &self.tableau,
            |x| Ok(self.rhs.apply(x)?),
            |x| Ok(self.projection.apply(x)?),
        )?;
        Ok(MacField3d::from_parts(out, self.grid))
    }

    fn check_field(&self, u: &MacField3d) -> Result<()> {
        u.check_stepper_grid(&self.grid)
    }
}
