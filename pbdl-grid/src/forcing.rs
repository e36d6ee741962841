//! Body forces and sources: Boussinesq buoyancy and inflow sources with a differentiable
//! strength.
//!
//! * [`buoyancy`]: `f_v = beta * rho` on the v faces (density averaged from the two cells a face
//!   separates, ghosts from the density's boundary conditions), `f_u = 0`; a custom op with its
//!   adjoint.
//! * [`DensitySource`]: adds `dt * rate * mask` to a centred field, `rate` a tensor (trainable).
//! * [`VelocitySource`]: relaxes the faces inside a region to `strength * target(x, y)`.

use crate::boundary::{Boundaries, Ghosts};
use crate::field::{CenteredField, MacField};
use crate::obstacle::Obstacle;
use crate::pad::{pad, pad_adjoint};
use crate::scratch::zeros;
use crate::{Error, Grid, Result};
use candle_core::{Device, Shape, Tensor};
use pbdl_core::op::{apply1, apply_kernel1, Kernel1, Op1};
use pbdl_core::Real;

/// The Boussinesq buoyancy force `(0, beta rho)` on the faces of a MAC velocity with boundaries
/// `velocity_bc` (fixed boundary faces get 0). `density` must have one channel.
pub fn buoyancy(density: &CenteredField, velocity_bc: &Boundaries, beta: f64) -> Result<MacField> {
    let g = *density.grid();
    if density.values().dims()[1] != 1 || !beta.is_finite() {
        return Err(Error::Invalid {
            field: "buoyancy",
            reason: format!(
                "needs a one-channel density and a finite beta, got {:?} and {beta}",
                density.values().dims()
            ),
        });
    }
    let op = Buoyancy {
        grid: g,
        ghosts: density.bc().ghosts(g.nx, g.ny),
        beta,
        v_fixed: velocity_bc.mac_ghosts(g.nx, g.ny).v_fixed.is_some(),
    };
    Ok(MacField::from_parts(apply1(density.values(), op)?, g, *velocity_bc))
}

#[derive(Clone, Copy)]
pub(crate) struct Buoyancy {
    pub grid: Grid,
    pub ghosts: Ghosts,
    pub beta: f64,
    pub v_fixed: bool,
}

impl Kernel1 for Buoyancy {
    fn name(&self) -> &'static str {
        "buoyancy"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, c, ny, nx) = s.dims4()?;
        if (c, ny, nx) != (1, self.grid.ny, self.grid.nx) {
            candle_core::bail!("buoyancy: density {s:?} is not one channel on the grid");
        }
        Ok(Shape::from((b, 2, ny, nx)))
    }
    fn forward<T: Real>(&self, x: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let (n, w) = (nx * ny, nx + 2);
        let hb = T::c(0.5 * self.beta);
        let mut rp = zeros::<T>(w * (ny + 2));
        for (xb, ob) in x.chunks(n).zip(out.chunks_mut(2 * n)) {
            pad(xb, nx, ny, &self.ghosts, true, &mut rp);
            let ov = &mut ob[n..];
            for j in 0..ny {
                let r = (j + 1) * w;
                for i in 0..nx {
                    ov[j * nx + i] = hb * (rp[r + i + 1] + rp[r + w + i + 1]);
                }
            }
            if self.v_fixed {
                ov[(ny - 1) * nx..].iter_mut().for_each(|e| *e = T::zero());
            }
            ob[..n].iter_mut().for_each(|e| *e = T::zero());
        }
        Ok(())
    }
}

impl Op1 for Buoyancy {
    fn backward(&self, _x: &Tensor, _y: &Tensor, gy: &Tensor) -> candle_core::Result<Tensor> {
        apply_kernel1(gy, BuoyancyAdjoint(*self))
    }
}

struct BuoyancyAdjoint(Buoyancy);

impl Kernel1 for BuoyancyAdjoint {
    fn name(&self) -> &'static str {
        "buoyancy_adjoint"
    }
    fn output_shape(&self, s: &Shape) -> candle_core::Result<Shape> {
        let (b, _, ny, nx) = s.dims4()?;
        Ok(Shape::from((b, 1, ny, nx)))
    }
    fn forward<T: Real>(&self, g: &[T], _s: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let op = self.0;
        let (nx, ny) = (op.grid.nx, op.grid.ny);
        let (n, w) = (nx * ny, nx + 2);
        let hb = T::c(0.5 * op.beta);
        let mut gp = zeros::<T>(w * (ny + 2));
        for (gb, ob) in g.chunks(2 * n).zip(out.chunks_mut(n)) {
            gp.fill(T::zero());
            let gv = &gb[n..];
            for j in 0..ny {
                if op.v_fixed && j == ny - 1 {
                    continue;
                }
                let r = (j + 1) * w;
                for i in 0..nx {
                    let a = hb * gv[j * nx + i];
                    gp[r + i + 1] += a;
                    gp[r + w + i + 1] += a;
                }
            }
            pad_adjoint(&mut gp, nx, ny, &op.ghosts, ob);
        }
        Ok(())
    }
}

/// A region that injects a scalar (smoke, density) at a rate: `q + dt * rate * mask`.
#[derive(Clone, Debug)]
pub struct DensitySource {
    shape: Obstacle,
    mask: Tensor,
}

impl DensitySource {
    /// The cells whose centres lie in `shape` (validated against the grid, at least one cell).
    pub fn new(grid: Grid, shape: Obstacle) -> Result<Self> {
        shape.validate(&grid).map_err(|e| match e {
            Error::Invalid { reason, .. } => Error::Invalid { field: "inflow", reason },
            e => e,
        })?;
        let mut m = vec![0.0; grid.cells()];
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                if shape.contains((i as f64 + 0.5) * grid.dx(), (j as f64 + 0.5) * grid.dy()) {
                    m[j * grid.nx + i] = 1.0;
                }
            }
        }
        if m.iter().all(|v| *v == 0.0) {
            return Err(Error::Invalid {
                field: "inflow",
                reason: format!("{shape:?} covers no cell centre; enlarge it"),
            });
        }
        Ok(Self { shape, mask: Tensor::from_vec(m, (1, 1, grid.ny, grid.nx), &Device::Cpu)? })
    }

    /// The region.
    pub fn shape(&self) -> &Obstacle {
        &self.shape
    }

    /// The 0/1 cell mask, `[1, 1, ny, nx]` (f64).
    pub fn mask(&self) -> &Tensor {
        &self.mask
    }

    /// `q + dt * rate * mask`; `rate` broadcasts against `[batch, C, ny, nx]` (a scalar tensor,
    /// or one rate per batch item `[B, 1, 1, 1]`), and receives a gradient.
    pub fn apply(&self, q: &CenteredField, rate: &Tensor, dt: f64) -> Result<CenteredField> {
        let m = self.mask.to_dtype(q.values().dtype())?;
        let add = m.broadcast_mul(&rate.affine(dt, 0.0)?)?;
        q.with_values(q.values().broadcast_add(&add)?)
    }
}

/// A region that drives the velocity on its faces towards `strength * target(x, y)`:
/// `u <- (1 - m) u + m strength target` (m = 1 on faces inside the region). Used for inflow
/// profiles (e.g. a parabolic channel inlet) and jets.
#[derive(Clone, Debug)]
pub struct VelocitySource {
    mask: Tensor,
    target: Tensor,
}

impl VelocitySource {
    /// Faces inside `shape` (validated) get `target(x, y)` (`u` from `[0]` at x-faces, `v` from
    /// `[1]` at y-faces). Stored boundary faces fixed by a wall or an inflow of `bc` are left out.
    pub fn new(grid: Grid, bc: &Boundaries, shape: Obstacle, target: impl Fn(f64, f64) -> [f64; 2]) -> Result<Self> {
        shape.validate(&grid).map_err(|e| match e {
            Error::Invalid { reason, .. } => Error::Invalid { field: "velocity_source", reason },
            e => e,
        })?;
        let (nx, ny, n) = (grid.nx, grid.ny, grid.cells());
        let (dx, dy) = (grid.dx(), grid.dy());
        let mg = bc.mac_ghosts(nx, ny);
        let mut m = vec![0.0; 2 * n];
        let mut t = vec![0.0; 2 * n];
        for j in 0..ny {
            for i in 0..nx {
                let (xu, yu) = ((i as f64 + 1.0) * dx, (j as f64 + 0.5) * dy);
                if shape.contains(xu, yu) && !(mg.u_fixed.is_some() && i == nx - 1) {
                    m[j * nx + i] = 1.0;
                    t[j * nx + i] = target(xu, yu)[0];
                }
                let (xv, yv) = ((i as f64 + 0.5) * dx, (j as f64 + 1.0) * dy);
                if shape.contains(xv, yv) && !(mg.v_fixed.is_some() && j == ny - 1) {
                    m[n + j * nx + i] = 1.0;
                    t[n + j * nx + i] = target(xv, yv)[1];
                }
            }
        }
        if m.iter().all(|v| *v == 0.0) {
            return Err(Error::Invalid {
                field: "velocity_source",
                reason: format!("{shape:?} covers no face; enlarge it"),
            });
        }
        let shape4 = (1, 2, ny, nx);
        Ok(Self {
            mask: Tensor::from_vec(m, shape4, &Device::Cpu)?,
            target: Tensor::from_vec(t, shape4, &Device::Cpu)?,
        })
    }

    /// `(1 - m) u + m strength target`; `strength` (a scalar tensor, default 1) gets a gradient.
    pub fn apply(&self, u: &MacField, strength: Option<&Tensor>) -> Result<MacField> {
        let dt = u.values().dtype();
        let (m, t) = (self.mask.to_dtype(dt)?, self.target.to_dtype(dt)?);
        let t = match strength {
            Some(s) => t.broadcast_mul(s)?,
            None => t,
        };
        let keep = m.affine(-1.0, 1.0)?;
        u.with_values(u.values().broadcast_mul(&keep)?.broadcast_add(&m.mul(&t)?)?)
    }

    /// The face mask `[1, 2, ny, nx]` (f64).
    pub fn mask(&self) -> &Tensor {
        &self.mask
    }
}
