//! The controlled smoke step on pbdl-grid's differentiable fluid operators.

use super::config::SmokeControlConfig;
use crate::{Error, Result};
use candle_core::{DType, Device, Tensor};
use pbdl_grid::advect::{conservative, mac_cormack, semi_lagrangian};
use pbdl_grid::fluid::Advection;
use pbdl_grid::{Bc, Boundaries, CenteredField, Fluid, FluidConfig, FluidState, Grid, MacField, ScalarBoundaries};

/// The state of a controlled scene: a MAC velocity `[batch, 2, n, n]` and a passive density
/// `[batch, 1, n, n]` (plain tensors; [`SmokePhysics`] wraps them into pbdl-grid fields).
#[derive(Clone, Debug)]
pub struct SmokeState {
    /// MAC velocity values: channel 0 `u` on the faces `x = (i + 1)`, channel 1 `v` on `y = (j + 1)`.
    pub velocity: Tensor,
    /// Cell-centred density.
    pub density: Tensor,
}

/// One controlled step in a closed box of free-slip walls:
/// 1. `v' = v + dt (m * F)`, `m` the mask of the faces the walls leave free (the stored faces
///    on `x = n` and `y = n` are walls);
/// 2. `v''`: one step of a velocity-only [`Fluid`] (self-advection, semi-Lagrangian or
///    MacCormack, then the pressure projection, a sparse Cholesky solve factored once);
/// 3. the density advected by `v''` ([`conservative()`] by default: mass conserved to round-off).
///
/// Every part is a pbdl-grid op with a hand-written adjoint: gradients flow to the forces, the
/// initial state and everything upstream of them.
pub struct SmokePhysics {
    cfg: SmokeControlConfig,
    grid: Grid,
    bc: Boundaries,
    density_bc: ScalarBoundaries,
    fluid: Fluid,
    mask: Tensor,
}

impl std::fmt::Debug for SmokePhysics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SmokePhysics").field("cfg", &self.cfg).field("operators", &self.operators()).finish()
    }
}

impl SmokePhysics {
    /// Builds the stepper of `cfg` (validated); the force mask is made in `dtype` on `device`.
    pub fn new(cfg: &SmokeControlConfig, dtype: DType, device: &Device) -> Result<Self> {
        cfg.validate()?;
        let n = cfg.cells;
        let grid = Grid::square(n, n as f64)?;
        let bc = Boundaries::new(Bc::FreeSlip, Bc::FreeSlip, Bc::FreeSlip, Bc::FreeSlip)?;
        let density_bc = ScalarBoundaries::neumann();
        let fluid = Fluid::new(
            grid,
            bc,
            None,
            FluidConfig {
                dt: cfg.dt,
                nu: 0.0,
                advection: cfg.velocity_advection,
                density_advection: Advection::SemiLagrangian,
                buoyancy: None,
                inflow: None,
                obstacles: Vec::new(),
            },
        )?;
        let mut m = vec![1.0f64; 2 * n * n];
        for j in 0..n {
            m[j * n + n - 1] = 0.0; // u on the wall x = n
            m[n * n + (n - 1) * n + j] = 0.0; // v on the wall y = n
        }
        let mask = Tensor::from_vec(m, (1, 2, n, n), device)?.to_dtype(dtype)?;
        Ok(Self { cfg: *cfg, grid, bc, density_bc, fluid, mask })
    }

    /// The problem.
    pub fn config(&self) -> &SmokeControlConfig {
        &self.cfg
    }

    /// The grid (`cells x cells`, cell width 1).
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The velocity-only fluid stepper's operators, then the density advection.
    pub fn operators(&self) -> Vec<&'static str> {
        let mut ops = vec!["force"];
        ops.extend_from_slice(self.fluid.operators());
        ops.push(match self.cfg.density_advection {
            Advection::Conservative => "advect.conservative(density)",
            Advection::MacCormack => "advect.mac_cormack(density)",
            _ => "advect.semi_lagrangian(density)",
        });
        ops
    }

    /// The mask `[1, 2, n, n]` of the force entries that act (0 on the wall faces).
    pub fn force_mask(&self) -> &Tensor {
        &self.mask
    }

    /// `mask * force`: the part of a force that acts (what the effort counts).
    pub fn mask_force(&self, force: &Tensor) -> Result<Tensor> {
        Ok(force.broadcast_mul(&self.mask)?)
    }

    /// Checks that `t` is `[batch, channels, n, n]`.
    pub fn check(&self, context: &'static str, t: &Tensor, channels: usize) -> Result<()> {
        let d = t.dims();
        let n = self.cfg.cells;
        if d.len() != 4 || d[1] != channels || d[2] != n || d[3] != n {
            return Err(Error::Shape { context, expected: format!("[batch, {channels}, {n}, {n}]"), got: d.to_vec() });
        }
        Ok(())
    }

    /// A state at rest with the density `density` (`[batch, 1, n, n]`).
    pub fn rest(&self, density: &Tensor) -> Result<SmokeState> {
        self.check("SmokePhysics::rest (density)", density, 1)?;
        let (b, _, n, _) = density.dims4()?;
        let velocity = Tensor::zeros((b, 2, n, n), density.dtype(), density.device())?;
        Ok(SmokeState { velocity, density: density.clone() })
    }

    /// One controlled step under `force` (`[batch, 2, n, n]`; the wall entries are masked out).
    pub fn step(&self, s: &SmokeState, force: &Tensor) -> Result<SmokeState> {
        self.check("SmokePhysics::step (velocity)", &s.velocity, 2)?;
        self.check("SmokePhysics::step (density)", &s.density, 1)?;
        self.check("SmokePhysics::step (force)", force, 2)?;
        let b = s.velocity.dims()[0];
        for (what, t) in [("density", &s.density), ("force", force)] {
            if t.dims()[0] != b {
                return Err(Error::Shape {
                    context: if what == "density" {
                        "SmokePhysics::step (density batch)"
                    } else {
                        "SmokePhysics::step (force batch)"
                    },
                    expected: format!("batch {b} (the velocity's)"),
                    got: t.dims().to_vec(),
                });
            }
        }
        let forced = (&s.velocity + self.mask_force(force)?.affine(self.cfg.dt, 0.0)?)?;
        let v = MacField::new(forced, self.grid, self.bc)?;
        let next = self.fluid.step(&FluidState { velocity: v, density: None }, None)?.velocity;
        let rho = CenteredField::new(s.density.clone(), self.grid, self.density_bc)?;
        let rho = match self.cfg.density_advection {
            Advection::Conservative => conservative(&rho, &next, self.cfg.dt)?,
            Advection::MacCormack => mac_cormack(&rho, &next, self.cfg.dt)?,
            _ => semi_lagrangian(&rho, &next, self.cfg.dt)?,
        };
        Ok(SmokeState { velocity: next.into_values(), density: rho.into_values() })
    }

    /// The states `s_0 .. s_T` under the forces `F_0 .. F_{T-1}` (`T = forces.len()`).
    pub fn rollout(&self, s0: &SmokeState, forces: &[Tensor]) -> Result<Vec<SmokeState>> {
        let mut states = Vec::with_capacity(forces.len() + 1);
        states.push(s0.clone());
        for (t, f) in forces.iter().enumerate() {
            let next = self.step(&states[t], f)?;
            states.push(next);
        }
        Ok(states)
    }
}
