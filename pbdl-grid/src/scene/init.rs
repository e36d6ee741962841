//! Initial conditions of a scene: closed-form fields sampled on the grid.

use super::{Physics, Scene, SceneError, SceneResult};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// An initial state (or, for the Poisson scene, the source). Coordinates `(x, y)` are physical
/// (the grid's `origin` included); `lx`, `ly` are the domain lengths.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Init {
    /// All zero (velocity at rest, satisfying the boundary conditions).
    #[default]
    Zero,
    /// A uniform velocity.
    Uniform {
        /// `[vx, vy]`.
        velocity: [f64; 2],
    },
    /// Taylor-Green vortex `u = A sin(kx x) cos(ky y)`, `v = -A (kx/ky) cos(kx x) sin(ky y)`,
    /// `k = 2 pi / l` (one vortex pair per period).
    TaylorGreen {
        /// Amplitude `A`. Default: 1.
        #[serde(default = "unit")]
        amplitude: f64,
    },
    /// A smooth random velocity: Fourier modes up to `max_wavenumber` with seeded random
    /// amplitudes and phases, scaled to `max |u| = amplitude` (projected when the scene has a
    /// pressure solve).
    RandomModes {
        /// Largest velocity component.
        amplitude: f64,
        /// Highest wavenumber per axis (1 to 32).
        max_wavenumber: u32,
        /// Random seed.
        seed: u64,
    },
    /// A scalar `A prod_k sin(2 pi w_k x_k / l_k)` over the axes with `w_k != 0`.
    Sine {
        /// Amplitude `A`.
        amplitude: f64,
        /// Periods per domain length `[w_x, w_y]` (0: constant along that axis).
        waves: [f64; 2],
    },
    /// A scalar Gaussian bump `A exp(-|x - c|^2 / (2 w^2))` (periodic images summed on periodic
    /// scenes, so that the bump is smooth across the boundary).
    Gaussian {
        /// Centre `c`.
        center: [f64; 2],
        /// Width `w` (> 0).
        width: f64,
        /// Amplitude `A`.
        amplitude: f64,
    },
}

/// Largest `max_wavenumber` of [`Init::RandomModes`].
const MAX_WAVENUMBER: u32 = 32;

fn unit() -> f64 {
    1.0
}

/// What a physics kind evolves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Scalar,
    Velocity,
}

pub(crate) fn state_kind(p: &Physics) -> Kind {
    match p {
        Physics::Burgers1d { .. }
        | Physics::Heat { .. }
        | Physics::Poisson { .. }
        | Physics::AdvectionDiffusion { .. } => Kind::Scalar,
        _ => Kind::Velocity,
    }
}

impl Init {
    fn kind(&self) -> Option<Kind> {
        match self {
            Init::Zero => None,
            Init::Uniform { .. } | Init::TaylorGreen { .. } | Init::RandomModes { .. } => Some(Kind::Velocity),
            Init::Sine { .. } | Init::Gaussian { .. } => Some(Kind::Scalar),
        }
    }

    pub(crate) fn validate(&self, scene: &Scene) -> SceneResult<()> {
        let bad = |field: &str, reason: String| {
            Err(SceneError::Invalid { scene: scene.name.clone(), field: field.into(), reason })
        };
        let want = state_kind(&scene.physics);
        if let Some(k) = self.kind() {
            if k != want {
                let what = if want == Kind::Scalar {
                    "a scalar (sine, gaussian, zero)"
                } else {
                    "a velocity (uniform, taylor_green, random_modes, zero)"
                };
                return bad("init.kind", format!("this physics evolves {what}; got {self:?}"));
            }
        }
        let finite = match *self {
            Init::Zero => true,
            Init::Uniform { velocity } => velocity.iter().all(|v| v.is_finite()),
            Init::TaylorGreen { amplitude } => amplitude.is_finite(),
            Init::RandomModes { amplitude, max_wavenumber, .. } => {
                if max_wavenumber == 0 {
                    return bad("init.max_wavenumber", "must be >= 1".into());
                }
                // The field is normalised on a 64^2 sample, where higher modes alias; the bound
                // also keeps the (2k+1)(k+1) modes per cell cheap and `k^2` in range.
                if max_wavenumber > MAX_WAVENUMBER {
                    return bad(
                        "init.max_wavenumber",
                        format!("{max_wavenumber} is above {MAX_WAVENUMBER}; use at most {MAX_WAVENUMBER}"),
                    );
                }
                amplitude.is_finite()
            }
            Init::Sine { amplitude, waves } => amplitude.is_finite() && waves.iter().all(|v| v.is_finite()),
            Init::Gaussian { center, width, amplitude } => {
                if !(width > 0.0 && width.is_finite()) {
                    return bad("init.width", format!("must be positive, got {width}"));
                }
                amplitude.is_finite() && center.iter().all(|v| v.is_finite())
            }
        };
        if !finite {
            return bad("init", format!("values must be finite, got {self:?}"));
        }
        Ok(())
    }

    /// The scalar at `(x, y)`.
    pub(crate) fn scalar(&self, x: f64, y: f64, lx: f64, ly: f64, periodic: bool) -> f64 {
        match *self {
            Init::Sine { amplitude, waves } => {
                let mut v = amplitude;
                for (w, (c, l)) in waves.iter().zip([(x, lx), (y, ly)]) {
                    if *w != 0.0 {
                        v *= (2.0 * PI * w * c / l).sin();
                    }
                }
                v
            }
            Init::Gaussian { center, width, amplitude } => {
                let images: &[f64] = if periodic { &[-1.0, 0.0, 1.0] } else { &[0.0] };
                let mut v = 0.0;
                for &a in images {
                    for &b in images {
                        let (dx, dy) = (x - center[0] + a * lx, y - center[1] + b * ly);
                        v += (-(dx * dx + dy * dy) / (2.0 * width * width)).exp();
                    }
                }
                amplitude * v
            }
            _ => 0.0,
        }
    }

    /// The velocity function `(x, y) -> [vx, vy]` (random modes drawn once).
    pub(crate) fn velocity(&self, lx: f64, ly: f64) -> Box<dyn Fn(f64, f64) -> [f64; 2]> {
        match *self {
            Init::Uniform { velocity } => Box::new(move |_, _| velocity),
            Init::TaylorGreen { amplitude } => {
                let (kx, ky) = (2.0 * PI / lx, 2.0 * PI / ly);
                Box::new(move |x, y| {
                    [
                        amplitude * (kx * x).sin() * (ky * y).cos(),
                        -amplitude * kx / ky * (kx * x).cos() * (ky * y).sin(),
                    ]
                })
            }
            Init::RandomModes { amplitude, max_wavenumber, seed } => {
                use rand::Rng;
                let mut rng = pbdl_core::seed::rng(seed);
                let k = max_wavenumber as i32;
                // (kx, ky, amplitude, phase) for each component.
                let mut modes: [Vec<(f64, f64, f64, f64)>; 2] = [Vec::new(), Vec::new()];
                for comp in &mut modes {
                    for a in 0..=k {
                        for b in -k..=k {
                            if a == 0 && b <= 0 {
                                continue;
                            }
                            let r = (a * a + b * b) as f64;
                            comp.push((
                                a as f64,
                                b as f64,
                                rng.random_range(-1.0..1.0) / r,
                                rng.random_range(0.0..2.0 * PI),
                            ));
                        }
                    }
                }
                let eval = move |x: f64, y: f64| {
                    let mut out = [0.0; 2];
                    for (o, comp) in out.iter_mut().zip(&modes) {
                        for &(a, b, amp, ph) in comp {
                            *o += amp * (2.0 * PI * (a * x / lx + b * y / ly) + ph).sin();
                        }
                    }
                    out
                };
                // Normalise on a fixed 64^2 sample so the scale does not depend on the resolution.
                let mut m: f64 = 0.0;
                for j in 0..64 {
                    for i in 0..64 {
                        let v = eval(i as f64 * lx / 64.0, j as f64 * ly / 64.0);
                        m = m.max(v[0].abs()).max(v[1].abs());
                    }
                }
                let s = if m > 0.0 { amplitude / m } else { 0.0 };
                Box::new(move |x, y| {
                    let v = eval(x, y);
                    [s * v[0], s * v[1]]
                })
            }
            _ => Box::new(|_, _| [0.0, 0.0]),
        }
    }

    /// The 3D velocity function `(x, y, z) -> [vx, vy, vz]` of a 3D scene: `uniform` (`vz = 0`),
    /// `taylor_green` (Brachet et al. 1983: `u = A sin x cos y cos z`, `v = -A cos x sin y cos z`,
    /// `w = 0` in units of the box), `random_modes` (Fourier modes up to `max_wavenumber` per
    /// axis, seeded, scaled to `max |u_i| = amplitude` on a 32^3 sample), zero otherwise.
    pub(crate) fn velocity3d(&self, l: [f64; 3]) -> Box<dyn Fn(f64, f64, f64) -> [f64; 3]> {
        let k = [2.0 * PI / l[0], 2.0 * PI / l[1], 2.0 * PI / l[2]];
        match *self {
            Init::Uniform { velocity } => Box::new(move |_, _, _| [velocity[0], velocity[1], 0.0]),
            Init::TaylorGreen { amplitude } => Box::new(move |x, y, z| {
                let (sx, cx) = (k[0] * x).sin_cos();
                let (sy, cy) = (k[1] * y).sin_cos();
                let cz = (k[2] * z).cos();
                [amplitude * sx * cy * cz, -amplitude * cx * sy * cz, 0.0]
            }),
            Init::RandomModes { amplitude, max_wavenumber, seed } => {
                use rand::Rng;
                let mut rng = pbdl_core::seed::rng(seed);
                let m = max_wavenumber as i32;
                // ([kx, ky, kz], amplitude, phase) per component; half of the wavevectors (the
                // other half are their negatives).
                let mut modes: [Vec<([f64; 3], f64, f64)>; 3] = [Vec::new(), Vec::new(), Vec::new()];
                for comp in &mut modes {
                    for a in 0..=m {
                        for b in -m..=m {
                            for c in -m..=m {
                                if a == 0 && (b < 0 || (b == 0 && c <= 0)) {
                                    continue;
                                }
                                let r = (a * a + b * b + c * c) as f64;
                                let kv = [a as f64 * k[0], b as f64 * k[1], c as f64 * k[2]];
                                comp.push((kv, rng.random_range(-1.0..1.0) / r, rng.random_range(0.0..2.0 * PI)));
                            }
                        }
                    }
                }
                let eval = move |x: f64, y: f64, z: f64| {
                    let mut out = [0.0; 3];
                    for (o, comp) in out.iter_mut().zip(&modes) {
                        for &(kv, amp, ph) in comp {
                            *o += amp * (kv[0] * x + kv[1] * y + kv[2] * z + ph).sin();
                        }
                    }
                    out
                };
                let mut mx: f64 = 0.0;
                for q in 0..32usize.pow(3) {
                    let (i, j, kk) = (q % 32, (q / 32) % 32, q / 1024);
                    let v = eval(i as f64 * l[0] / 32.0, j as f64 * l[1] / 32.0, kk as f64 * l[2] / 32.0);
                    mx = mx.max(v[0].abs()).max(v[1].abs()).max(v[2].abs());
                }
                let s = if mx > 0.0 { amplitude / mx } else { 0.0 };
                Box::new(move |x, y, z| {
                    let v = eval(x, y, z);
                    [s * v[0], s * v[1], s * v[2]]
                })
            }
            _ => Box::new(|_, _, _| [0.0, 0.0, 0.0]),
        }
    }
}
