//! The wake behind a cylinder in a channel (Um et al. 2020, section 5.3), laid along x: uniform
//! inflow at `x = 0`, outflow at `x = lx`, free-slip walls at `y = 0, ly`, a staircase cylinder.
//! The same scene is built twice: the coarse *source* solver `P_s` and the *reference* at
//! `factor` times the resolution (and optionally `reference_substeps` smaller time steps).
//! The Reynolds number `Re = inflow * 2 radius / nu` sets the viscosity of both.

use crate::{Error, Result};
use candle_core::{DType, Tensor};
use pbdl_grid::fluid::{Advection, FluidOptions};
use pbdl_grid::{
    Bc, Boundaries, CenteredField, Fluid, FluidConfig, FluidState, Grid, MacField, Obstacle, ScalarBoundaries,
};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// A Solver-in-the-Loop scene: the source and reference solvers of one flow, as functions of
/// the one parameter that varies between simulations (the Reynolds number of the wake, the
/// buoyancy factor of the plume).
///
/// A state on the source grid is one tensor `[B, 2 + scalars, ny, nx]`: the MAC velocity
/// `u`, `v` followed by the scalars (cell-centred; the plume's marker density). The reference
/// is downsampled to it by [`downsample_mac`](super::data::downsample_mac) for the velocity and
/// [`downsample_cells`](super::data::downsample_cells) (cell average) for the scalars. The
/// data ([`generate`](super::data::generate)), training ([`train`](super::train::train)) and
/// evaluation ([`evaluate`](super::eval::evaluate)) are generic over it; the wake is their
/// default.
pub trait SilScene: Clone + std::fmt::Debug + PartialEq + Serialize + DeserializeOwned {
    /// A short name (`"wake"`, `"plume"`).
    fn scene_name(&self) -> &'static str;
    /// The name of the varying parameter (`"Re"`, `"buoyancy"`).
    fn parameter_name(&self) -> &'static str;
    /// Checks every setting (typed [`Error::InvalidConfig`] naming the field).
    fn check(&self) -> Result<()>;
    /// Typed error unless `p` is a valid value of the varying parameter.
    fn check_parameter(&self, p: f64) -> Result<()>;
    /// Cell-centred scalar channels after the velocity (0 for the wake, 1 for the plume).
    fn scalars(&self) -> usize;
    /// The reference resolution divided by the source resolution.
    fn refinement(&self) -> usize;
    /// The source grid.
    fn source_grid(&self) -> Result<Grid>;
    /// The reference grid.
    fn fine_grid(&self) -> Result<Grid>;
    /// The source solver `P_s` at parameter `p`.
    fn source_solver(&self, p: f64) -> Result<SourceSolver>;
    /// The reference stepper at `p` (one call of [`Fluid::step`] is one reference sub-step).
    fn fine_stepper(&self, p: f64) -> Result<Fluid>;
    /// Reference sub-steps per frame.
    fn substeps(&self) -> usize;
    /// The density inflow rate [`Fluid::step`] needs (`None` without an inflow).
    fn inflow_rate(&self) -> Option<f64>;
    /// The initial state of `fluid` (either solver) on `grid`.
    fn start(&self, fluid: &Fluid, grid: Grid, dtype: DType) -> Result<FluidState>;
}

impl SilScene for WakeConfig {
    fn scene_name(&self) -> &'static str {
        "wake"
    }
    fn parameter_name(&self) -> &'static str {
        "Re"
    }
    fn check(&self) -> Result<()> {
        self.validate()
    }
    fn check_parameter(&self, p: f64) -> Result<()> {
        self.viscosity(p).map(|_| ())
    }
    fn scalars(&self) -> usize {
        0
    }
    fn refinement(&self) -> usize {
        self.factor
    }
    fn source_grid(&self) -> Result<Grid> {
        self.coarse_grid()
    }
    fn fine_grid(&self) -> Result<Grid> {
        self.reference_grid()
    }
    fn source_solver(&self, p: f64) -> Result<SourceSolver> {
        self.source(p)
    }
    fn fine_stepper(&self, p: f64) -> Result<Fluid> {
        self.reference_stepper(p)
    }
    fn substeps(&self) -> usize {
        self.reference_substeps
    }
    fn inflow_rate(&self) -> Option<f64> {
        None
    }
    fn start(&self, fluid: &Fluid, grid: Grid, dtype: DType) -> Result<FluidState> {
        self.initial_state(fluid, grid, dtype)
    }
}

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
        Ok(SourceSolver {
            fluid: self.coarse_stepper(re)?,
            grid: self.coarse_grid()?,
            bc: self.boundaries()?,
            re,
            density_bc: None,
            inflow_rate: None,
        })
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

/// The source solver `P_s` at one value of the scene's parameter, with the grid and boundaries
/// its states live on (pbdl-grid's [`Fluid`] does not expose them). A state is
/// `[B, 2 + scalars, ny, nx]`: the MAC velocity, then the density when the scene has one.
pub struct SourceSolver {
    /// The stepper.
    pub fluid: Fluid,
    /// Its grid.
    pub grid: Grid,
    /// Its velocity boundaries.
    pub bc: Boundaries,
    /// The parameter it was built for (the Reynolds number of the wake, the buoyancy factor of
    /// the plume).
    pub re: f64,
    /// The density's boundaries when the state carries a density (channel 2); `None` for a
    /// velocity-only state.
    pub density_bc: Option<ScalarBoundaries>,
    /// The density inflow rate passed to every [`Fluid::step`] (`None` without an inflow).
    pub inflow_rate: Option<f64>,
}

impl std::fmt::Debug for SourceSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceSolver").field("grid", &self.grid).field("re", &self.re).finish()
    }
}

impl SourceSolver {
    /// Channels of a state: 2 (velocity) plus 1 with a density.
    pub fn channels(&self) -> usize {
        2 + usize::from(self.density_bc.is_some())
    }

    /// Checks that `u` is `[B, channels, ny, nx]` on this grid.
    pub fn check(&self, u: &Tensor) -> Result<()> {
        let d = u.dims();
        let c = self.channels();
        if d.len() != 4 || d[1] != c || d[2] != self.grid.ny || d[3] != self.grid.nx {
            return Err(Error::Shape {
                context: "SourceSolver",
                expected: format!("[batch, {c}, {}, {}] (the source grid)", self.grid.ny, self.grid.nx),
                got: d.to_vec(),
            });
        }
        Ok(())
    }

    /// One source step `P_s(s)` of a state `[B, channels, ny, nx]` (differentiable with respect
    /// to every channel: advection, buoyancy, inflow and pressure solve by their adjoints).
    pub fn step(&self, u: &Tensor) -> Result<Tensor> {
        self.check(u)?;
        let Some(dbc) = self.density_bc else {
            let s = FluidState { velocity: MacField::new(u.clone(), self.grid, self.bc)?, density: None };
            return Ok(self.fluid.step(&s, None)?.velocity.into_values());
        };
        let vel = u.narrow(1, 0, 2)?.contiguous()?;
        let rho = u.narrow(1, 2, 1)?.contiguous()?;
        let s = FluidState {
            velocity: MacField::new(vel, self.grid, self.bc)?,
            density: Some(CenteredField::new(rho, self.grid, dbc)?),
        };
        let rate = match self.inflow_rate {
            Some(r) => Some(Tensor::new(r, u.device())?.to_dtype(u.dtype())?),
            None => None,
        };
        let next = self.fluid.step(&s, rate.as_ref())?;
        let rho = next.density.expect("a stepper with density boundaries keeps the density").into_values();
        Ok(Tensor::cat(&[next.velocity.values(), &rho], 1)?)
    }
}
