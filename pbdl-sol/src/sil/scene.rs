//! The wake behind a cylinder in a channel (Um et al. 2020, section 5.3), laid along x: uniform
//! inflow at `x = 0`, outflow at `x = lx`, free-slip walls at `y = 0, ly`, a staircase cylinder.
//! The same scene is built twice: the coarse *source* solver `P_s` and the *reference* at
//! `factor` times the resolution (and optionally `reference_substeps` smaller time steps).
//! The Reynolds number `Re = inflow * 2 radius / nu` sets the viscosity of both.

use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_grid::fluid::{Advection, FluidOptions};
use pbdl_grid::{Bc, Boundaries, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle};
use serde::{Deserialize, Serialize};

/// Geometry, resolution and numerics of the wake scene; the default is the paper's layout
/// (a 200 x 100 channel, cylinder of radius 10 at (50, 50), inflow 1, source 64 x 32 cells,
/// reference 4x finer) on its side (flow along +x).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WakeConfig {
    /// Source (coarse) cells `[nx, ny]`. Default `[64, 32]`.
    pub coarse: [usize; 2],
    /// Reference resolution divided by the source resolution (integer >= 2). Default 4.
    pub factor: usize,
    /// Channel size `[lx, ly]`. Default `[200, 100]`.
    pub extent: [f64; 2],
    /// Cylinder centre. Default `[50, 50]`.
    pub center: [f64; 2],
    /// Cylinder radius. Default 10.
    pub radius: f64,
    /// Inflow speed. Default 1.
    pub inflow: f64,
    /// Time step of the source solver (one frame of data). Default 1.
    pub dt: f64,
    /// Reference sub-steps per frame (`>= 1`). Default 2.
    pub reference_substeps: usize,
    /// Self-advection of the velocity, both solvers. Default MacCormack.
    pub advection: Advection,
    /// Transverse velocity (in units of the inflow) put in a square behind the cylinder at
    /// `t = 0`, to start the shedding. Default 0.5.
    pub kick: f64,
}

impl Default for WakeConfig {
    fn default() -> Self {
        Self {
            coarse: [64, 32],
            factor: 4,
            extent: [200.0, 100.0],
            center: [50.0, 50.0],
            radius: 10.0,
            inflow: 1.0,
            dt: 1.0,
            reference_substeps: 2,
            advection: Advection::MacCormack,
            kick: 0.5,
        }
    }
}

const CTX: &str = "WakeConfig";

impl WakeConfig {
    /// Checks every setting (typed [`Error::InvalidConfig`] naming the field).
    pub fn validate(&self) -> Result<()> {
        if self.coarse[0] < 4 || self.coarse[1] < 4 {
            return Err(Error::invalid(CTX, "coarse", format!("needs at least 4 x 4 cells, got {:?}", self.coarse)));
        }
        if self.factor < 2 {
            return Err(Error::invalid(
                CTX,
                "factor",
                format!("the reference must be finer: use >= 2, got {}", self.factor),
            ));
        }
        if self.reference_substeps == 0 {
            return Err(Error::invalid(CTX, "reference_substeps", "use at least 1"));
        }
        let pos = |x: f64| x > 0.0 && x.is_finite();
        if !(pos(self.extent[0]) && pos(self.extent[1])) {
            return Err(Error::invalid(CTX, "extent", format!("must be positive, got {:?}", self.extent)));
        }
        if !(pos(self.dt) && pos(self.inflow) && pos(self.radius)) {
            return Err(Error::invalid(
                CTX,
                "dt / inflow / radius",
                format!("must be positive and finite, got {} / {} / {}", self.dt, self.inflow, self.radius),
            ));
        }
        let [cx, cy] = self.center;
        let r = self.radius;
        if !(cx - r > 0.0 && cx + r < self.extent[0] && cy - r > 0.0 && cy + r < self.extent[1]) {
            return Err(Error::invalid(CTX, "center", "the cylinder must lie inside the channel"));
        }
        if matches!(self.advection, Advection::Conservative) {
            return Err(Error::invalid(CTX, "advection", "conservative transport is for densities"));
        }
        if !self.kick.is_finite() {
            return Err(Error::invalid(CTX, "kick", "must be finite"));
        }
        Ok(())
    }

    /// The source grid.
    pub fn coarse_grid(&self) -> Result<Grid> {
        self.validate()?;
        Ok(Grid::new(self.coarse[0], self.coarse[1], self.extent[0], self.extent[1])?)
    }

    /// The reference grid (`factor` times finer in both directions).
    pub fn reference_grid(&self) -> Result<Grid> {
        self.validate()?;
        let f = self.factor;
        Ok(Grid::new(self.coarse[0] * f, self.coarse[1] * f, self.extent[0], self.extent[1])?)
    }

    /// Inflow at `x_lo`, outflow at `x_hi`, free-slip side walls.
    pub fn boundaries(&self) -> Result<Boundaries> {
        Ok(Boundaries::new(Bc::Inflow { velocity: [self.inflow, 0.0] }, Bc::Outflow, Bc::FreeSlip, Bc::FreeSlip)?)
    }

    /// `nu = inflow * 2 radius / Re` (typed error unless `Re > 0` and finite).
    pub fn viscosity(&self, re: f64) -> Result<f64> {
        if !(re > 0.0 && re.is_finite()) {
            return Err(Error::invalid(CTX, "re", format!("the Reynolds number must be positive, got {re}")));
        }
        Ok(self.inflow * 2.0 * self.radius / re)
    }

    fn stepper(&self, grid: Grid, dt: f64, re: f64) -> Result<Fluid> {
        let config = FluidConfig {
            dt,
            nu: self.viscosity(re)?,
            advection: self.advection,
            density_advection: Advection::MacCormack,
            buoyancy: None,
            inflow: None,
            obstacles: vec![Obstacle::Cylinder { center: self.center, radius: self.radius }],
        };
        Ok(Fluid::with_options(grid, self.boundaries()?, None, config, FluidOptions::default())?)
    }

    /// The source solver `P_s` at Reynolds number `re` (time step `dt`).
    pub fn coarse_stepper(&self, re: f64) -> Result<Fluid> {
        self.stepper(self.coarse_grid()?, self.dt, re)
    }

    /// [`WakeConfig::coarse_stepper`] with its grid and boundaries.
    pub fn source(&self, re: f64) -> Result<SourceSolver> {
        Ok(SourceSolver { fluid: self.coarse_stepper(re)?, grid: self.coarse_grid()?, bc: self.boundaries()?, re })
    }

    /// The reference solver at `re` (time step `dt / reference_substeps`).
    pub fn reference_stepper(&self, re: f64) -> Result<Fluid> {
        self.stepper(self.reference_grid()?, self.dt / self.reference_substeps as f64, re)
    }

    /// The initial state of `fluid` (either solver): the inflow velocity everywhere plus the
    /// kick in a square of one diameter behind the cylinder, projected.
    pub fn initial_state(&self, fluid: &Fluid, grid: Grid, dtype: DType) -> Result<FluidState> {
        let (u0, k, [cx, cy], d) = (self.inflow, self.kick * self.inflow, self.center, 2.0 * self.radius);
        let u = MacField::from_fn(grid, self.boundaries()?, dtype, move |x, y| {
            let behind = (x - cx - 1.5 * d).abs() < 0.5 * d && (y - cy - 0.5 * d).abs() < 0.5 * d;
            [u0, if behind { k } else { 0.0 }]
        })?;
        Ok(FluidState { velocity: fluid.project(&u)?, density: None })
    }
}

/// The source solver `P_s` at one Reynolds number, with the grid and boundaries its states
/// live on (pbdl-grid's [`Fluid`] does not expose them).
pub struct SourceSolver {
    /// The stepper.
    pub fluid: Fluid,
    /// Its grid.
    pub grid: Grid,
    /// Its velocity boundaries.
    pub bc: Boundaries,
    /// The Reynolds number it was built for.
    pub re: f64,
}

impl std::fmt::Debug for SourceSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceSolver").field("grid", &self.grid).field("re", &self.re).finish()
    }
}

impl SourceSolver {
    /// Checks that `u` is `[B, 2, ny, nx]` on this grid.
    pub fn check(&self, u: &Tensor) -> Result<()> {
        let d = u.dims();
        if d.len() != 4 || d[1] != 2 || d[2] != self.grid.ny || d[3] != self.grid.nx {
            return Err(Error::Shape {
                context: "SourceSolver",
                expected: format!("[batch, 2, {}, {}] (the source grid)", self.grid.ny, self.grid.nx),
                got: d.to_vec(),
            });
        }
        Ok(())
    }

    /// One source step `P_s(u)` of MAC values `[B, 2, ny, nx]` (differentiable).
    pub fn step(&self, u: &Tensor) -> Result<Tensor> {
        self.check(u)?;
        let s = FluidState { velocity: MacField::new(u.clone(), self.grid, self.bc)?, density: None };
        Ok(self.fluid.step(&s, None)?.velocity.into_values())
    }
}
