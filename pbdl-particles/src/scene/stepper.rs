//! The built simulation: [`Stepper`] (one of the solvers, stepped through
//! [`Evolve`]), its output [`Frame`]s and [`run_frames`].

use super::Scene;
use crate::dfsph::Dfsph;
use crate::error::Result;
use crate::iisph::Iisph;
use crate::sph1d::Sph1d;
use crate::wcsph::Wcsph;
use crate::wcsph3d::Wcsph3d;
use pbdl_core::stepper::Evolve;
use pbdl_core::Real;

/// One output frame: per particle, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Simulated time.
    pub time: f64,
    /// Positions `[n * dim]`.
    pub positions: Vec<f64>,
    /// Velocities `[n * dim]`.
    pub velocities: Vec<f64>,
    /// Densities `[n]`.
    pub density: Vec<f64>,
    /// Masses `[n]`.
    pub mass: Vec<f64>,
    /// Pressures `[n]` (compressible 1D SPH only): `(γ - 1) ρ u` of the frame's density and
    /// energy.
    pub pressure: Option<Vec<f64>>,
    /// Specific internal energies `[n]` (compressible 1D SPH only).
    pub internal_energy: Option<Vec<f64>>,
    /// Smoothing lengths `[n]` (compressible 1D SPH only: adaptive per particle).
    pub smoothing_length: Option<Vec<f64>>,
    /// Per-particle linear viscosity `α_i` `[n]` (compressible 1D SPH only: the viscosity
    /// switch's state, so a restart continues it).
    pub viscosity_alpha: Option<Vec<f64>>,
}

/// A built stepper of one of the solvers, in precision `T` (`f32` or `f64`).
#[derive(Clone, Debug)]
pub enum Stepper<T: Real = f64> {
    /// 1D compressible SPH.
    Sph1d(Box<Sph1d<T>>),
    /// 2D weakly compressible SPH.
    Wcsph(Box<Wcsph<T>>),
    /// 2D incompressible SPH.
    Iisph(Box<Iisph<T>>),
    /// 2D divergence-free SPH.
    Dfsph(Box<Dfsph<T>>),
    /// 3D weakly compressible SPH.
    Wcsph3d(Box<Wcsph3d<T>>),
    /// 3D divergence-free SPH.
    Dfsph3d(Box<Dfsph<T, 3>>),
}

/// `T` values widened to `f64` (exact).
fn wide<T: Real>(v: &[T]) -> Vec<f64> {
    v.iter().map(|a| a.wide()).collect()
}

/// `[T; D]` points flattened and widened to `f64`.
fn wide_points<T: Real, const D: usize>(v: &[[T; D]]) -> Vec<f64> {
    v.iter().flat_map(|p| p.map(Real::wide)).collect()
}

/// A frame of the solvers with wall particles (WCSPH, IISPH, DFSPH in 2D and 3D): the fluid
/// particles with their density and uniform mass.
fn wall_solver_frame<T: Real, const D: usize>(
    time: f64,
    x: &[[T; D]],
    v: &[[T; D]],
    density: &[T],
    mass: f64,
) -> Frame {
    Frame {
        time,
        positions: wide_points(x),
        velocities: wide_points(v),
        density: wide(density),
        mass: vec![mass; x.len()],
        pressure: None,
        internal_energy: None,
        smoothing_length: None,
        viscosity_alpha: None,
    }
}

/// The box `[lo, hi]` grown by `margin` on every side.
fn padded([lo, hi]: [[f64; 2]; 2], margin: f64) -> [[f64; 2]; 2] {
    [[lo[0] - margin, lo[1] - margin], [hi[0] + margin, hi[1] + margin]]
}

impl<T: Real> Stepper<T> {
    /// Spatial dimension.
    pub fn dim(&self) -> usize {
        match self {
            Stepper::Sph1d(_) => 1,
            Stepper::Wcsph3d(_) | Stepper::Dfsph3d(_) => 3,
            _ => 2,
        }
    }

    /// The terms the stepper evaluates (see each solver's `operators`).
    pub fn operators(&self) -> Vec<&'static str> {
        match self {
            Stepper::Sph1d(s) => s.operators(),
            Stepper::Wcsph(s) => s.operators(),
            Stepper::Iisph(s) => s.operators(),
            Stepper::Dfsph(s) => s.operators(),
            Stepper::Wcsph3d(s) => s.operators(),
            Stepper::Dfsph3d(s) => s.operators(),
        }
    }

    /// Simulated time.
    pub fn time(&self) -> f64 {
        match self {
            Stepper::Sph1d(s) => s.time(),
            Stepper::Wcsph(s) => s.time(),
            Stepper::Iisph(s) => s.time(),
            Stepper::Dfsph(s) => s.time(),
            Stepper::Wcsph3d(s) => s.time(),
            Stepper::Dfsph3d(s) => s.time(),
        }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        match self {
            Stepper::Sph1d(s) => s.steps(),
            Stepper::Wcsph(s) => s.steps(),
            Stepper::Iisph(s) => s.steps(),
            Stepper::Dfsph(s) => s.steps(),
            Stepper::Wcsph3d(s) => s.steps(),
            Stepper::Dfsph3d(s) => s.steps(),
        }
    }

    /// The moving particles now (fluid / mobile only; ghosts and walls are in
    /// [`Stepper::fixed_positions`]), widened to `f64`; 1D compressible SPH adds pressure,
    /// specific internal energy and smoothing length. IISPH and DFSPH densities are summation densities
    /// at the current positions.
    pub fn frame(&mut self) -> Result<Frame> {
        Ok(match self {
            Stepper::Sph1d(s) => {
                let n = s.n_mobile();
                Frame {
                    time: s.time(),
                    positions: wide(&s.x[..n]),
                    velocities: wide(&s.v[..n]),
                    density: wide(&s.rho[..n]),
                    mass: wide(&s.m[..n]),
                    // The equation of state at the frame's density and energy (the solver's own
                    // `p` was evaluated with the energy predicted mid-step).
                    pressure: Some(
                        (0..n).map(|i| (s.params().gamma - 1.0) * s.rho[i].wide() * s.u[i].wide()).collect(),
                    ),
                    internal_energy: Some(wide(&s.u[..n])),
                    smoothing_length: Some(wide(&s.h[..n])),
                    viscosity_alpha: Some(wide(&s.viscosity_alpha()[..n])),
                }
            }
            Stepper::Wcsph(s) => {
                let n = s.n_fluid();
                wall_solver_frame(s.time(), &s.x[..n], &s.v, &s.rho[..n], s.physics().mass)
            }
            Stepper::Dfsph(s) => {
                let density = s.summation_density()?;
                wall_solver_frame(s.time(), &s.x[..s.n_fluid()], &s.v, &density, s.mass())
            }
            Stepper::Iisph(s) => {
                let density = s.summation_density()?;
                wall_solver_frame(s.time(), &s.x[..s.n_fluid()], &s.v, &density, s.mass())
            }
            Stepper::Wcsph3d(s) => {
                let n = s.n_fluid();
                wall_solver_frame(s.time(), &s.x[..n], &s.v, &s.rho[..n], s.physics().mass)
            }
            Stepper::Dfsph3d(s) => {
                let density = s.summation_density()?;
                wall_solver_frame(s.time(), &s.x[..s.n_fluid()], &s.v, &density, s.mass())
            }
        })
    }

    /// Fixed particles (shock-tube ghosts or moving buffers, walls), row-major `[n_fixed * dim]`, widened to `f64`.
    pub fn fixed_positions(&self) -> Vec<f64> {
        match self {
            Stepper::Sph1d(s) => wide(&s.x[s.n_mobile()..]),
            Stepper::Wcsph(s) => wide_points(&s.x[s.n_fluid()..]),
            Stepper::Iisph(s) => wide_points(&s.x[s.n_fluid()..]),
            Stepper::Dfsph(s) => wide_points(&s.x[s.n_fluid()..]),
            Stepper::Wcsph3d(s) => wide_points(&s.x[s.n_fluid()..]),
            Stepper::Dfsph3d(s) => wide_points(&s.x[s.n_fluid()..]),
        }
    }

    /// The 3D solvers' container box `[lo, hi]` (the tank the fluid stays in); `None` in 1D
    /// and 2D.
    pub fn container_3d(&self) -> Option<[[f64; 3]; 2]> {
        match self {
            Stepper::Wcsph3d(s) => Some(s.container()),
            Stepper::Dfsph3d(s) => Some(s.container()),
            _ => None,
        }
    }

    /// The box to draw: `[lo, hi]` (1D: x range and density range are chosen by the renderer;
    /// 3D: the x-y side of the tank, the view projected along z).
    pub fn view_box(&self) -> [[f64; 2]; 2] {
        match self {
            Stepper::Sph1d(s) => {
                let d = s.domain();
                [[d.lo[0].wide(), 0.0], [d.hi[0].wide(), 0.0]]
            }
            Stepper::Wcsph(s) => {
                if s.x.len() > s.n_fluid() {
                    padded(s.container(), 3.0 * s.physics().dx)
                } else {
                    let d = s.domain();
                    [d.lo.map(Real::wide), d.hi.map(Real::wide)]
                }
            }
            Stepper::Iisph(s) => padded(s.container(), 3.0 * s.dx()),
            Stepper::Dfsph(s) => padded(s.container(), 3.0 * s.dx()),
            Stepper::Wcsph3d(_) | Stepper::Dfsph3d(_) => {
                let [lo, hi] = self.container_3d().expect("3D stepper");
                padded([[lo[0], lo[1]], [hi[0], hi[1]]], 3.0 * self.spacing())
            }
        }
    }

    /// Particle spacing (for render disc sizes).
    pub fn spacing(&self) -> f64 {
        match self {
            Stepper::Sph1d(s) => {
                let d = s.domain();
                (d.hi[0].wide() - d.lo[0].wide()) / s.x.len().max(1) as f64
            }
            Stepper::Wcsph(s) => s.physics().dx,
            Stepper::Iisph(s) => s.dx(),
            Stepper::Dfsph(s) => s.dx(),
            Stepper::Wcsph3d(s) => s.physics().dx,
            Stepper::Dfsph3d(s) => s.dx(),
        }
    }
}

/// Steps the solver it holds: the same steps as the solver's own [`Evolve`] impl (IISPH in equal
/// steps, the others with the stable step and a shortened last one).
impl<T: Real> Evolve for Stepper<T> {
    type Error = crate::Error;

    fn time(&self) -> f64 {
        Stepper::time(self)
    }

    fn steps(&self) -> u64 {
        Stepper::steps(self)
    }

    fn stable_dt(&self) -> f64 {
        match self {
            Stepper::Sph1d(s) => Evolve::stable_dt(&**s),
            Stepper::Wcsph(s) => Evolve::stable_dt(&**s),
            Stepper::Iisph(s) => Evolve::stable_dt(&**s),
            Stepper::Dfsph(s) => Evolve::stable_dt(&**s),
            Stepper::Wcsph3d(s) => Evolve::stable_dt(&**s),
            Stepper::Dfsph3d(s) => Evolve::stable_dt(&**s),
        }
    }

    fn step(&mut self, dt: f64) -> Result<()> {
        match self {
            Stepper::Sph1d(s) => s.step(dt),
            Stepper::Wcsph(s) => s.step(dt),
            Stepper::Iisph(s) => s.step(dt),
            Stepper::Dfsph(s) => s.step(dt),
            Stepper::Wcsph3d(s) => s.step(dt),
            Stepper::Dfsph3d(s) => s.step(dt),
        }
    }

    fn next_dt(&self, t_end: f64) -> f64 {
        match self {
            Stepper::Sph1d(s) => s.next_dt(t_end),
            Stepper::Wcsph(s) => s.next_dt(t_end),
            Stepper::Iisph(s) => s.next_dt(t_end),
            Stepper::Dfsph(s) => s.next_dt(t_end),
            Stepper::Wcsph3d(s) => s.next_dt(t_end),
            Stepper::Dfsph3d(s) => s.next_dt(t_end),
        }
    }
}

/// Runs `stepper` for the scene's frames and returns the initial frame plus one per
/// `frame_dt`; `on_frame(k)` is called after frame `k`.
pub fn run_frames<T: Real>(
    scene: &Scene,
    stepper: &mut Stepper<T>,
    mut on_frame: impl FnMut(usize),
) -> Result<Vec<Frame>> {
    let mut frames = vec![stepper.frame()?];
    let t0 = stepper.time();
    for k in 1..=scene.frames {
        stepper.run_until(t0 + k as f64 * scene.frame_dt)?;
        frames.push(stepper.frame()?);
        on_frame(k);
    }
    Ok(frames)
}
