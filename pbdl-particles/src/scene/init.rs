//! Initial particles from a file (`--init`): [`InitState`] read from `.npz` arrays.

use crate::error::{Error, Result};
use candle_core::{DType, Tensor};

/// Initial particles from a file (`--init`), per particle, row-major `[n, dim]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InitState {
    /// Dimension of positions and velocities.
    pub dim: usize,
    /// Positions `[n * dim]`.
    pub positions: Vec<f64>,
    /// Velocities `[n * dim]` (zero when absent).
    pub velocities: Option<Vec<f64>>,
    /// Masses `[n]` (the scene's when absent).
    pub mass: Option<Vec<f64>>,
    /// Densities `[n]` (the scene's rest state when absent; used by WCSPH, and by shock tubes
    /// to derive the internal energy from `pressure` when `internal_energy` is absent).
    pub density: Option<Vec<f64>>,
    /// Pressures `[n]` (1D compressible SPH: with `density`, the internal energy when
    /// `internal_energy` is absent).
    pub pressure: Option<Vec<f64>>,
    /// Specific internal energies `[n]` (1D compressible SPH).
    pub internal_energy: Option<Vec<f64>>,
    /// Smoothing lengths `[n]` (1D compressible SPH; the starting guess of the density solve).
    pub smoothing_length: Option<Vec<f64>>,
    /// Per-particle linear viscosity `α_i` `[n]` (1D compressible SPH: the viscosity switch's
    /// state; absent, every particle starts at `alpha`).
    pub viscosity_alpha: Option<Vec<f64>>,
    /// Fixed particles `[F * dim]` (`fixed_positions` `[F, d]` of a trajectory: a shock tube's
    /// ghosts or buffers at its last frame, which a shock tube restarts from).
    pub fixed_positions: Option<Vec<f64>>,
}

impl InitState {
    /// Reads `positions` (`[n, d]` or a trajectory `[T, n, d]`: its last frame), and optional
    /// `velocities`, `mass`, `density`, `pressure`, `internal_energy`, `smoothing_length`,
    /// `viscosity_alpha` (`[n]` / `[T, n]`) and `fixed_positions` (`[F, d]`) from `.npz` arrays,
    /// widened to `f64` (exact for `f32` and `f64` arrays).
    pub fn from_arrays(arrays: &[(String, Tensor)]) -> Result<Self> {
        let get = |name: &str| arrays.iter().find(|(n, _)| n == name).map(|(_, t)| t);
        let last = |name: &str, t: &Tensor, rank: usize| -> Result<Tensor> {
            let t = t.to_dtype(DType::F64)?;
            if t.rank() != rank + 1 {
                return Ok(t);
            }
            // A trajectory of zero frames has no last frame to start from.
            match t.dim(0)?.checked_sub(1) {
                Some(k) => Ok(t.get(k)?),
                None => Err(Error::SceneField {
                    scene: "--init".into(),
                    field: name.into(),
                    reason: format!("the trajectory {:?} has no frames (T = 0)", t.dims()),
                }),
            }
        };
        let pos = get("positions").ok_or_else(|| Error::SceneField {
            scene: "--init".into(),
            field: "positions".into(),
            reason: "missing array `positions` ([n, d] or [T, n, d])".into(),
        })?;
        let pos = last("positions", pos, 2)?;
        let (n, dim) = pos.dims2().map_err(|_| Error::SceneField {
            scene: "--init".into(),
            field: "positions".into(),
            reason: format!("shape {:?}; expected [n, d] or [T, n, d]", pos.dims()),
        })?;
        if n == 0 || dim == 0 {
            return Err(Error::SceneField {
                scene: "--init".into(),
                field: "positions".into(),
                reason: format!("shape {:?} holds no particles; give at least one particle [n >= 1, d]", pos.dims()),
            });
        }
        let read = |name: &'static str, rank: usize, len: usize| -> Result<Option<Vec<f64>>> {
            match get(name) {
                None => Ok(None),
                Some(t) => {
                    let v = last(name, t, rank)?.flatten_all()?.to_vec1::<f64>()?;
                    if v.len() != len {
                        return Err(Error::Length { op: "--init", arg: name, expected: len, got: v.len() });
                    }
                    Ok(Some(v))
                }
            }
        };
        Ok(InitState {
            dim,
            positions: pos.flatten_all()?.to_vec1::<f64>()?,
            velocities: read("velocities", 2, n * dim)?,
            mass: read("mass", 1, n)?,
            density: read("density", 1, n)?,
            pressure: read("pressure", 1, n)?,
            internal_energy: read("internal_energy", 1, n)?,
            smoothing_length: read("smoothing_length", 1, n)?,
            viscosity_alpha: read("viscosity_alpha", 1, n)?,
            fixed_positions: match get("fixed_positions") {
                Some(t) => Some(last("fixed_positions", t, 2)?.flatten_all()?.to_vec1::<f64>()?),
                None => None,
            },
        })
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.positions.len() / self.dim.max(1)
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub(super) fn check(&self, dim: usize, scene: &str) -> Result<()> {
        if self.dim != dim {
            return Err(Error::SceneField {
                scene: scene.into(),
                field: "init.positions".into(),
                reason: format!("{}D positions for a {dim}D scene", self.dim),
            });
        }
        if let Some(m) = &self.mass {
            if let Some(i) = m.iter().position(|&v| !(v > 0.0 && v.is_finite())) {
                return Err(Error::SceneField {
                    scene: scene.into(),
                    field: "init.mass".into(),
                    reason: format!("particle {i} has mass {}; masses must be positive", m[i]),
                });
            }
        }
        Ok(())
    }

    pub(super) fn points2(&self) -> Vec<[f64; 2]> {
        self.positions.chunks(2).map(|c| [c[0], c[1]]).collect()
    }

    pub(super) fn velocities2(&self) -> Vec<[f64; 2]> {
        match &self.velocities {
            Some(v) => v.chunks(2).map(|c| [c[0], c[1]]).collect(),
            None => vec![[0.0; 2]; self.len()],
        }
    }

    pub(super) fn points3(&self) -> Vec<[f64; 3]> {
        self.positions.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    pub(super) fn velocities3(&self) -> Vec<[f64; 3]> {
        match &self.velocities {
            Some(v) => v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
            None => vec![[0.0; 3]; self.len()],
        }
    }

    /// The single mass of a 2D or 3D solver (all equal), or `default`.
    pub(super) fn uniform_mass(&self, default: f64, scene: &str) -> Result<f64> {
        match &self.mass {
            None => Ok(default),
            Some(m) => {
                let m0 = m.first().copied().unwrap_or(default);
                if m.iter().any(|&v| (v - m0).abs() > 1e-12 * m0.abs()) {
                    return Err(Error::SceneField {
                        scene: scene.into(),
                        field: "init.mass".into(),
                        reason: "the 2D and 3D solvers need equal masses".into(),
                    });
                }
                Ok(m0)
            }
        }
    }
}
