//! Boundary conditions per face, travelling with the field.
//!
//! A velocity field carries [`Boundaries`] (one [`Bc`] per face); a centred scalar carries
//! [`ScalarBoundaries`]. Internally each condition becomes a *ghost rule*: the value one cell
//! outside the domain is `s * (an interior value) + c`, which makes every stencil branch-free and
//! gives the adjoint for free (`s` is the only linear part).
//!
//! Storage of a MAC velocity (`[batch, 2, ny, nx]`): channel 0 holds `u` on the faces
//! `x = (i + 1) dx`, channel 1 holds `v` on the faces `y = (j + 1) dy` (jax-cfd's offsets
//! `(1, 1/2)` and `(1/2, 1)`). The faces at `x = 0` and `y = 0` are not stored: periodic wrap or
//! the boundary condition gives them. The stored face at `x = lx` (`y = ly`) is a fixed value on
//! walls and inflows and a free unknown for periodic and outflow faces.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// The condition on one face of the domain, for a velocity field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Bc {
    /// Wraps around to the opposite face (both faces of an axis must be periodic).
    Periodic,
    /// Solid wall at rest: zero normal and zero tangential velocity.
    NoSlip,
    /// Solid wall without friction: zero normal velocity, zero tangential shear.
    FreeSlip,
    /// Solid wall sliding along itself (a lid): zero normal velocity, tangential velocity given.
    MovingWall {
        /// Tangential wall speed, along +x on y faces and along +y on x faces.
        velocity: f64,
    },
    /// Dirichlet velocity `[vx, vy]` (normal and tangential parts given).
    Inflow {
        /// The velocity on the face, `[x component, y component]`.
        velocity: [f64; 2],
    },
    /// Zero normal gradient of velocity, pressure zero (only on the upper faces `x_hi`, `y_hi`).
    Outflow,
}

impl Bc {
    fn is_wall(&self) -> bool {
        matches!(self, Bc::NoSlip | Bc::FreeSlip | Bc::MovingWall { .. })
    }
}

/// A non-uniform velocity profile on the inflow face `x = 0` of a channel `0 <= y <= ly`.
///
/// The per-face [`Bc`] values are constant along a face; a profile is imposed by the
/// [`crate::Fluid`] stepper instead ([`crate::fluid::FluidOptions::inflow_profile`]): the first
/// column of cells (`0 < x < dx`) becomes a solid buffer outside the pressure solve, and the
/// `u` faces at `x = dx` between it and the fluid carry the profile exactly (the projection keeps
/// them and counts their flux, [`crate::pressure::MaskedPressureSolver::with_prescribed_faces`]).
/// The inflow plane is therefore `x = dx`: lay out the grid one cell longer than the channel
/// and shift the geometry by `dx` (as tests/schaefer_turek.rs does; the scene kind `cylinder`
/// with `inflow_profile = "parabolic"` leaves that to the scene file).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InflowProfile {
    /// The uniform speed of the `x_lo` condition (no profile; the default).
    #[default]
    Uniform,
    /// Poiseuille profile `u(y) = 4 U_m y (ly - y) / ly^2` (`U_m` the centreline speed, the
    /// mean speed is `2 U_m / 3`), `v = 0`: the inflow of the Schaefer & Turek (1996) benchmarks.
    Parabolic {
        /// Centreline (maximum) speed `U_m`.
        max_velocity: f64,
    },
    /// Poiseuille profile over the band `y_lo < y < y_hi` only (zero outside it):
    /// `u(y) = 4 U_m (y - y_lo) (y_hi - y) / (y_hi - y_lo)^2`, `v = 0`. The inflow of a channel
    /// whose lower part is blocked at the inlet, e.g. above a backward-facing step
    /// (tests/backward_facing_step.rs); the band should end on cell faces.
    ParabolicBand {
        /// Centreline (maximum) speed `U_m`.
        max_velocity: f64,
        /// Lower edge of the band.
        y_lo: f64,
        /// Upper edge of the band.
        y_hi: f64,
    },
}

impl InflowProfile {
    /// The `x` velocity of the profile at height `y` in a channel of height `ly` (`None` for
    /// [`InflowProfile::Uniform`]).
    pub fn velocity(&self, y: f64, ly: f64) -> Option<f64> {
        match *self {
            InflowProfile::Uniform => None,
            InflowProfile::Parabolic { max_velocity } => Some(4.0 * max_velocity * y * (ly - y) / (ly * ly)),
            InflowProfile::ParabolicBand { max_velocity, y_lo, y_hi } => Some(if y > y_lo && y < y_hi {
                4.0 * max_velocity * (y - y_lo) * (y_hi - y) / ((y_hi - y_lo) * (y_hi - y_lo))
            } else {
                0.0
            }),
        }
    }

    /// The mean speed over the channel height (`2 U_m / 3` for the parabola; over the band for
    /// [`InflowProfile::ParabolicBand`]).
    pub fn mean_velocity(&self) -> Option<f64> {
        match *self {
            InflowProfile::Uniform => None,
            InflowProfile::Parabolic { max_velocity } | InflowProfile::ParabolicBand { max_velocity, .. } => {
                Some(2.0 * max_velocity / 3.0)
            }
        }
    }
}

/// The shape of an inflow profile, as a scene names it (`inflow_profile = "parabolic"`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InflowShape {
    /// Uniform (default).
    #[default]
    Uniform,
    /// Parabolic ([`InflowProfile::Parabolic`]).
    Parabolic,
}

impl InflowShape {
    /// The profile with centreline (or uniform) speed `speed`.
    pub fn profile(self, speed: f64) -> InflowProfile {
        match self {
            InflowShape::Uniform => InflowProfile::Uniform,
            InflowShape::Parabolic => InflowProfile::Parabolic { max_velocity: speed },
        }
    }
}

/// The four faces of a 2D domain with their velocity conditions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Boundaries {
    /// Face `x = 0`.
    pub x_lo: Bc,
    /// Face `x = lx`.
    pub x_hi: Bc,
    /// Face `y = 0`.
    pub y_lo: Bc,
    /// Face `y = ly`.
    pub y_hi: Bc,
}

/// The condition on one face, for a cell-centred scalar.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ScalarBc {
    /// Wraps around.
    Periodic,
    /// Zero normal gradient.
    Neumann,
    /// Given value on the face.
    Dirichlet {
        /// The face value.
        value: f64,
    },
}

/// The four faces of a 2D domain with their scalar conditions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScalarBoundaries {
    /// Face `x = 0`.
    pub x_lo: ScalarBc,
    /// Face `x = lx`.
    pub x_hi: ScalarBc,
    /// Face `y = 0`.
    pub y_lo: ScalarBc,
    /// Face `y = ly`.
    pub y_hi: ScalarBc,
}

impl Boundaries {
    /// Validated boundaries.
    pub fn new(x_lo: Bc, x_hi: Bc, y_lo: Bc, y_hi: Bc) -> Result<Self> {
        let b = Self { x_lo, x_hi, y_lo, y_hi };
        b.validate()?;
        Ok(b)
    }

    /// Periodic in both directions.
    pub fn periodic() -> Self {
        Self { x_lo: Bc::Periodic, x_hi: Bc::Periodic, y_lo: Bc::Periodic, y_hi: Bc::Periodic }
    }

    /// A channel along x: `inflow` (an [`Bc::Inflow`] velocity `[u, 0]`) at `x = 0`, outflow at
    /// `x = lx`, no-slip walls at `y = 0` and `y = ly` (the Schaefer & Turek setting; give the
    /// parabolic profile with [`InflowProfile`]).
    pub fn channel(inflow: f64) -> Self {
        Self { x_lo: Bc::Inflow { velocity: [inflow, 0.0] }, x_hi: Bc::Outflow, y_lo: Bc::NoSlip, y_hi: Bc::NoSlip }
    }

    /// A closed box of no-slip walls whose top wall (`y_hi`) slides at `lid` along +x.
    pub fn lid_driven_cavity(lid: f64) -> Self {
        Self { x_lo: Bc::NoSlip, x_hi: Bc::NoSlip, y_lo: Bc::NoSlip, y_hi: Bc::MovingWall { velocity: lid } }
    }

    /// The faces with their names, in the order x_lo, x_hi, y_lo, y_hi.
    pub fn faces(&self) -> [(&'static str, Bc); 4] {
        [("x_lo", self.x_lo), ("x_hi", self.x_hi), ("y_lo", self.y_lo), ("y_hi", self.y_hi)]
    }

    /// Checks that periodic faces come in pairs, outflow sits on an upper face and values are finite.
    pub fn validate(&self) -> Result<()> {
        for (lo, hi, lo_name, hi_name) in
            [(self.x_lo, self.x_hi, "x_lo", "x_hi"), (self.y_lo, self.y_hi, "y_lo", "y_hi")]
        {
            if (lo == Bc::Periodic) != (hi == Bc::Periodic) {
                let face = if lo == Bc::Periodic { hi_name } else { lo_name };
                return Err(Error::Boundary {
                    face,
                    reason: format!("{lo_name} and {hi_name} must both be periodic or both not (got {lo:?} / {hi:?})"),
                });
            }
            if lo == Bc::Outflow {
                return Err(Error::Boundary {
                    face: lo_name,
                    reason: format!("outflow is supported on the upper faces only; put the outflow on {hi_name}"),
                });
            }
        }
        for (face, bc) in self.faces() {
            let finite = match bc {
                Bc::MovingWall { velocity } => velocity.is_finite(),
                Bc::Inflow { velocity } => velocity.iter().all(|v| v.is_finite()),
                _ => true,
            };
            if !finite {
                return Err(Error::Boundary { face, reason: format!("velocity must be finite, got {bc:?}") });
            }
        }
        Ok(())
    }

    /// `true` when both axes are periodic (the FFT pressure path applies).
    pub fn is_periodic(&self) -> bool {
        self.x_lo == Bc::Periodic && self.y_lo == Bc::Periodic
    }

    /// The pressure conditions these velocity conditions imply: periodic stays periodic, walls and
    /// inflows give zero normal gradient, outflow gives `p = 0`.
    pub fn pressure(&self) -> ScalarBoundaries {
        let p = |b: Bc| match b {
            Bc::Periodic => ScalarBc::Periodic,
            Bc::Outflow => ScalarBc::Dirichlet { value: 0.0 },
            _ => ScalarBc::Neumann,
        };
        ScalarBoundaries { x_lo: p(self.x_lo), x_hi: p(self.x_hi), y_lo: p(self.y_lo), y_hi: p(self.y_hi) }
    }

    /// Ghost rules of the two velocity components on an `nx` x `ny` grid.
    pub(crate) fn mac_ghosts(&self, nx: usize, ny: usize) -> MacGhosts {
        // Normal component across a face: wall -> 0, inflow -> given, periodic -> wrap, outflow -> copy.
        let normal = |b: Bc, comp: usize, lo: bool, n: usize| match b {
            Bc::Periodic => Ghost { s: 1.0, src: if lo { n } else { 1 }, c: 0.0 },
            Bc::Outflow => Ghost { s: 1.0, src: n, c: 0.0 },
            Bc::Inflow { velocity } => Ghost { s: 0.0, src: 1, c: velocity[comp] },
            _ => Ghost { s: 0.0, src: 1, c: 0.0 },
        };
        // Tangential component: the ghost mirrors so that the face value is the wall's.
        let tangential = |b: Bc, comp: usize, lo: bool, n: usize| {
            let near = if lo { 1 } else { n };
            match b {
                Bc::Periodic => Ghost { s: 1.0, src: if lo { n } else { 1 }, c: 0.0 },
                Bc::NoSlip => Ghost { s: -1.0, src: near, c: 0.0 },
                Bc::MovingWall { velocity } => Ghost { s: -1.0, src: near, c: 2.0 * velocity },
                Bc::Inflow { velocity } => Ghost { s: -1.0, src: near, c: 2.0 * velocity[comp] },
                Bc::FreeSlip | Bc::Outflow => Ghost { s: 1.0, src: near, c: 0.0 },
            }
        };
        let fixed = |b: Bc, comp: usize| match b {
            Bc::Inflow { velocity } => Some(velocity[comp]),
            b if b.is_wall() => Some(0.0),
            _ => None,
        };
        MacGhosts {
            u: Ghosts {
                x_lo: normal(self.x_lo, 0, true, nx),
                x_hi: normal(self.x_hi, 0, false, nx),
                y_lo: tangential(self.y_lo, 0, true, ny),
                y_hi: tangential(self.y_hi, 0, false, ny),
            },
            v: Ghosts {
                x_lo: tangential(self.x_lo, 1, true, nx),
                x_hi: tangential(self.x_hi, 1, false, nx),
                y_lo: normal(self.y_lo, 1, true, ny),
                y_hi: normal(self.y_hi, 1, false, ny),
            },
            u_fixed: fixed(self.x_hi, 0),
            v_fixed: fixed(self.y_hi, 1),
        }
    }
}

impl ScalarBoundaries {
    /// Periodic in both directions.
    pub fn periodic() -> Self {
        Self { x_lo: ScalarBc::Periodic, x_hi: ScalarBc::Periodic, y_lo: ScalarBc::Periodic, y_hi: ScalarBc::Periodic }
    }

    /// Zero normal gradient on all faces.
    pub fn neumann() -> Self {
        Self { x_lo: ScalarBc::Neumann, x_hi: ScalarBc::Neumann, y_lo: ScalarBc::Neumann, y_hi: ScalarBc::Neumann }
    }

    /// The faces with their names.
    pub fn faces(&self) -> [(&'static str, ScalarBc); 4] {
        [("x_lo", self.x_lo), ("x_hi", self.x_hi), ("y_lo", self.y_lo), ("y_hi", self.y_hi)]
    }

    /// Checks that periodic faces come in pairs and values are finite.
    pub fn validate(&self) -> Result<()> {
        for (lo, hi, lo_name, hi_name) in
            [(self.x_lo, self.x_hi, "x_lo", "x_hi"), (self.y_lo, self.y_hi, "y_lo", "y_hi")]
        {
            if (lo == ScalarBc::Periodic) != (hi == ScalarBc::Periodic) {
                return Err(Error::Boundary {
                    face: lo_name,
                    reason: format!("{lo_name} and {hi_name} must both be periodic or both not"),
                });
            }
        }
        for (face, bc) in self.faces() {
            if let ScalarBc::Dirichlet { value } = bc {
                if !value.is_finite() {
                    return Err(Error::Boundary {
                        face,
                        reason: format!("Dirichlet value must be finite, got {value}"),
                    });
                }
            }
        }
        Ok(())
    }

    /// `true` when some face fixes the value (the Laplacian is then invertible).
    pub fn has_dirichlet(&self) -> bool {
        self.faces().iter().any(|(_, b)| matches!(b, ScalarBc::Dirichlet { .. }))
    }

    /// `true` when both axes are periodic.
    pub fn is_periodic(&self) -> bool {
        self.x_lo == ScalarBc::Periodic && self.y_lo == ScalarBc::Periodic
    }

    /// Ghost rules of a cell-centred scalar on an `nx` x `ny` grid.
    pub(crate) fn ghosts(&self, nx: usize, ny: usize) -> Ghosts {
        let g = |b: ScalarBc, lo: bool, n: usize| {
            let near = if lo { 1 } else { n };
            match b {
                ScalarBc::Periodic => Ghost { s: 1.0, src: if lo { n } else { 1 }, c: 0.0 },
                ScalarBc::Neumann => Ghost { s: 1.0, src: near, c: 0.0 },
                // The face value is the mean of the cell and its ghost.
                ScalarBc::Dirichlet { value } => Ghost { s: -1.0, src: near, c: 2.0 * value },
            }
        };
        Ghosts {
            x_lo: g(self.x_lo, true, nx),
            x_hi: g(self.x_hi, false, nx),
            y_lo: g(self.y_lo, true, ny),
            y_hi: g(self.y_hi, false, ny),
        }
    }
}

/// The value one cell outside the domain: `s * padded[src] + c`, where `src` indexes the padded
/// row (for x faces) or column (for y faces), interior values sitting at `1..=n`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Ghost {
    pub s: f64,
    pub src: usize,
    pub c: f64,
}

/// Ghost rules of one padded component on its four sides.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Ghosts {
    pub x_lo: Ghost,
    pub x_hi: Ghost,
    pub y_lo: Ghost,
    pub y_hi: Ghost,
}

/// Ghost rules of a MAC velocity, plus which stored boundary faces are fixed (and to what).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct MacGhosts {
    pub u: Ghosts,
    pub v: Ghosts,
    /// `Some(value)` when the stored `u` column at `x = lx` is fixed by the condition.
    pub u_fixed: Option<f64>,
    /// `Some(value)` when the stored `v` row at `y = ly` is fixed by the condition.
    pub v_fixed: Option<f64>,
}
