//! What every kind's builder needs from the scene: the grid, the precision, the initial fields and
//! the time-step rule.

use super::c;
use crate::scene::{Scene, SceneError, SceneResult};
use crate::time_stepping::{ButcherTableau, Scheme};
use crate::{Bc, Boundaries, Grid, MacField};
use candle_core::{DType, Device, Tensor};

/// A scene being built.
pub(crate) struct Setup<'a> {
    /// The scene (validated).
    pub scene: &'a Scene,
    /// The 2D grid (`None` for 1D scenes).
    pub grid: Option<Grid>,
    /// The precision of the state.
    pub dtype: DType,
    /// The Runge-Kutta scheme of `time.scheme`.
    pub tableau: ButcherTableau,
    /// Cell sizes.
    pub dx: f64,
    /// Cell sizes.
    pub dy: f64,
}

impl<'a> Setup<'a> {
    /// The grid, precision and scheme of a validated scene.
    pub fn new(scene: &'a Scene) -> SceneResult<Self> {
        let g = scene.grid;
        let grid = if g.ny > 1 { Some(Grid::new(g.nx, g.ny, g.lx, g.ly)?) } else { None };
        Ok(Self {
            scene,
            grid,
            dtype: scene.precision.dtype(),
            tableau: scene.time.scheme.tableau(),
            dx: g.lx / g.nx as f64,
            dy: g.ly / g.ny as f64,
        })
    }

    /// A [`SceneError::Invalid`] naming `field`.
    pub fn invalid(&self, field: &str, reason: String) -> SceneError {
        SceneError::Invalid { scene: self.scene.name.clone(), field: field.into(), reason }
    }

    /// The 2D grid (validation refuses `ny = 1` for 2D kinds).
    pub fn grid2d(&self) -> SceneResult<Grid> {
        self.grid.ok_or_else(|| self.invalid("grid.ny", "this physics kind is two-dimensional: use ny >= 2".into()))
    }

    /// The smallest cell size.
    fn h(&self) -> f64 {
        if self.scene.grid.ny > 1 {
            self.dx.min(self.dy)
        } else {
            self.dx
        }
    }

    /// The name of the time-stepping operator.
    pub fn time_stepping(&self) -> &'static str {
        match self.scene.time.scheme {
            Scheme::Rk4 => "time_stepping.rk4",
            Scheme::SspRk3 => "time_stepping.ssp_rk3",
            Scheme::ForwardEuler => "time_stepping.forward_euler",
        }
    }

    /// The initial scalar `[1, 1, ny, nx]` sampled at the cell centres.
    pub fn scalar(&self, bc_periodic: bool) -> SceneResult<Tensor> {
        let g = self.scene.grid;
        let (x0, y0) = (g.origin[0], g.origin[1]);
        let mut data = vec![0.0; g.nx * g.ny];
        for j in 0..g.ny {
            for i in 0..g.nx {
                let (x, y) = (x0 + (i as f64 + 0.5) * self.dx, y0 + (j as f64 + 0.5) * self.dy);
                data[j * g.nx + i] = self.scene.init.scalar(x, y, g.lx, g.ly, bc_periodic);
            }
        }
        c(Tensor::from_vec(data, (1, 1, g.ny, g.nx), &Device::Cpu).and_then(|t| t.to_dtype(self.dtype)))
    }

    /// The initial velocity on the faces (not projected).
    pub fn velocity(&self, grid: Grid, bc: Boundaries) -> SceneResult<MacField> {
        let g = self.scene.grid;
        let (x0, y0) = (g.origin[0], g.origin[1]);
        let f = self.scene.init.velocity(g.lx, g.ly);
        Ok(MacField::from_fn(grid, bc, self.dtype, move |x, y| f(x + x0, y + y0))?)
    }

    /// The characteristic speed of a velocity (its largest value or boundary speed) and the
    /// speed for the stability limit (`time.speed` when given).
    pub fn speeds(&self, u: &MacField, bc: &Boundaries) -> SceneResult<(f64, f64)> {
        let speed = u.max_abs()?.max(boundary_speed(bc));
        Ok((speed, self.scene.time.speed.unwrap_or(speed)))
    }

    /// The step: `time.dt` (refused beyond `stable`), or `cfl * h / speed` capped at 0.9 of the
    /// stable step; with `t_end`, shortened so that a whole number of steps ends there.
    pub fn pick_dt(&self, speed: f64, stable: f64) -> SceneResult<f64> {
        let time = &self.scene.time;
        match time.dt {
            Some(dt) if dt > stable * (1.0 + 1e-12) => Err(self.invalid(
                "time.dt",
                format!("{dt:.3e} exceeds the stable step {stable:.3e} of {} for this scene", self.tableau.name),
            )),
            Some(dt) => Ok(match (time.t_end, time.steps) {
                (Some(te), None) => te / (te / dt - 1e-9).ceil(),
                _ => dt,
            }),
            None => {
                let s = time.speed.unwrap_or(speed);
                let adv = if s > 0.0 { time.cfl * self.h() / s } else { f64::INFINITY };
                let dt = adv.min(0.9 * stable);
                if dt.is_finite() {
                    // A whole number of steps ends at t_end.
                    Ok(match (time.t_end, time.steps) {
                        (Some(te), None) => te / (te / dt).ceil(),
                        _ => dt,
                    })
                } else {
                    Err(self.invalid("time.dt", "nothing moves or diffuses; give time.dt".into()))
                }
            }
        }
    }
}

/// The largest speed a boundary imposes (moving walls, inflow).
fn boundary_speed(bc: &Boundaries) -> f64 {
    bc.faces()
        .iter()
        .map(|(_, b)| match b {
            Bc::MovingWall { velocity } => velocity.abs(),
            Bc::Inflow { velocity } => velocity[0].abs().max(velocity[1].abs()),
            _ => 0.0,
        })
        .fold(0.0, f64::max)
}
