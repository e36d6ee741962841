//! Building a scene: [`Scene::build`] / [`Scene::build_as`] and one builder per section.

use super::{
    scene_err, BlockDrop3dScene, DamBreak3dScene, DamBreakScene, DamSolver, InitState, Periodic1dScene,
    Periodic2dScene, Scene, Stepper,
};
use crate::dfsph::Dfsph;
use crate::error::{Error, Result};
use crate::iisph::Iisph;
use crate::neighbors::Domain;
use crate::sph1d::Sph1d;
use crate::wcsph::{Wcsph, WcsphPhysics};
use crate::wcsph3d::Wcsph3d;
use crate::{MAX_H_OVER_DX, MIN_H_OVER_DX};
use pbdl_core::noise::{perlin_1d, perlin_2d};
use pbdl_core::Real;

impl Scene {
    /// Builds the `f64` stepper for run `seed` (added to the scene's seed), optionally from
    /// initial particles (`--init`). This ignores [`Scene::precision`]: to honour it, match on
    /// it and call [`Scene::build_as`] with `f32` or `f64`.
    ///
    /// Errors: [`Error::SceneField`] naming the field for bad values,
    /// [`Error::OutsideDomain`] for initial particles outside the box.
    pub fn build(&self, seed: u64, init: Option<&InitState>) -> Result<Stepper> {
        self.build_as::<f64>(seed, init)
    }

    /// Builds the stepper in precision `T` (`f32` or `f64`); as [`Scene::build`] otherwise.
    /// Initial states (noise, layouts, `--init` arrays) are computed in `f64` and rounded once,
    /// so `f32` values read back from an `f32` trajectory are restored exactly.
    ///
    /// Errors: as [`Scene::build`].
    pub fn build_as<T: Real>(&self, seed: u64, init: Option<&InitState>) -> Result<Stepper<T>> {
        self.validate()?;
        let name = self.name.as_str();
        let seed = self.seed.wrapping_add(seed);
        if let Some(st) = &self.shock_tube {
            if st.n > MAX_PARTICLES {
                return Err(scene_err(
                    name,
                    "shock_tube.n",
                    format!("{}; use at most {MAX_PARTICLES} particles", st.n),
                ));
            }
            check_h_over_dx(name, "shock_tube.sph.eta", st.sph.eta)?;
            let tube = st.tube();
            let built = match init {
                None => tube.build_as::<T>(st.n, st.sph),
                Some(init) => {
                    init.check(1, name)?;
                    let n = init.len();
                    let default_mass = (st.left.rho * (st.x0 - st.x_lo) + st.right.rho * (st.x_hi - st.x0)) / n as f64;
                    let mass = init.mass.clone().unwrap_or_else(|| vec![default_mass; n]);
                    let v = init.velocities.clone().unwrap_or_else(|| vec![0.0; n]);
                    let g1 = st.gamma - 1.0;
                    let u = match (&init.internal_energy, &init.pressure, &init.density) {
                        (Some(e), _, _) => e.clone(),
                        (None, Some(p), Some(rho)) => p.iter().zip(rho).map(|(p, r)| p / (g1 * r)).collect(),
                        _ => {
                            return Err(scene_err(
                                name,
                                "init.internal_energy",
                                "a shock tube starts from `internal_energy`, or `pressure` and `density`; \
                                 the file has neither",
                            ))
                        }
                    };
                    tube.build_from_particles_as::<T>(
                        st.sph,
                        &init.positions,
                        &v,
                        &u,
                        &mass,
                        init.smoothing_length.as_deref(),
                        init.fixed_positions.as_deref(),
                    )
                    .and_then(|mut sim| {
                        // The viscosity switch continues where the trajectory left it.
                        if let Some(alpha) = &init.viscosity_alpha {
                            sim.set_viscosity_alpha(alpha)?;
                        }
                        Ok(sim)
                    })
                }
            };
            let sim = built.map_err(|e| match e {
                Error::Invalid { field, reason } if ["eta", "alpha", "cfl", "kernel"].contains(&field) => {
                    scene_err(name, &format!("shock_tube.sph.{field}"), reason)
                }
                Error::Invalid { field, reason }
                    if init.is_some() && ["x", "m", "u", "h", "buffers", "viscosity_alpha"].contains(&field) =>
                {
                    let f = match field {
                        "x" => "init.positions",
                        "buffers" => "init.fixed_positions",
                        "viscosity_alpha" => "init.viscosity_alpha",
                        "m" => "init.mass",
                        "u" => "init.internal_energy",
                        _ => "init.smoothing_length",
                    };
                    scene_err(name, f, reason)
                }
                e => field_err(name, "shock_tube", e),
            })?;
            return Ok(Stepper::Sph1d(Box::new(sim)));
        }
        if let Some(db) = &self.dam_break {
            return build_dam_break(name, db, init);
        }
        if let Some(p) = &self.periodic_1d {
            return build_periodic_1d(name, p, seed, init);
        }
        if let Some(p) = &self.periodic_2d {
            return build_periodic_2d(name, p, seed, init);
        }
        if let Some(db) = &self.dam_break_3d {
            return build_dam_break_3d(name, db, init);
        }
        if let Some(bd) = &self.block_drop_3d {
            return build_block_drop_3d(name, bd, init);
        }
        unreachable!("validate checks that one section is present")
    }
}

fn field_err(scene: &str, section: &str, e: Error) -> Error {
    match e {
        Error::Invalid { field, reason } => {
            Error::SceneField { scene: scene.into(), field: format!("{section}.{field}"), reason }
        }
        e => e,
    }
}

/// `f64` values rounded to `T`.
fn narrow<T: Real>(v: &[f64]) -> Vec<T> {
    v.iter().map(|&a| T::c(a)).collect()
}

/// `f64` points rounded to `T`.
fn narrow2<T: Real>(v: &[[f64; 2]]) -> Vec<[T; 2]> {
    v.iter().map(|p| [T::c(p[0]), T::c(p[1])]).collect()
}

/// Largest number of wall layers.
const MAX_WALL_LAYERS: usize = 64;
/// Most particles a scene may ask for (about 2^26; more cannot be stepped in memory anyway).
const MAX_PARTICLES: usize = 1 << 26;
/// Largest noise lattice (cells per side at the finest octave).
const MAX_NOISE_CELLS: usize = 1 << 20;

fn check_h_over_dx(name: &str, field: &str, h_over_dx: f64) -> Result<()> {
    if !(MIN_H_OVER_DX..=MAX_H_OVER_DX).contains(&h_over_dx) {
        return Err(scene_err(
            name,
            field,
            format!("{h_over_dx}; use a value in [{MIN_H_OVER_DX}, {MAX_H_OVER_DX}] (typically 1.2 to 2)"),
        ));
    }
    Ok(())
}

/// `base_cells * 2^(octaves - 1)` must stay a modest lattice (and the shift in range).
fn check_noise(name: &str, sec: &str, base_cells: usize, octaves: usize) -> Result<()> {
    if base_cells == 0 || octaves == 0 {
        return Err(scene_err(name, &format!("{sec}.base_cells"), "base_cells and octaves must be at least 1"));
    }
    if octaves > 20 || base_cells > MAX_NOISE_CELLS >> (octaves - 1) {
        return Err(scene_err(
            name,
            &format!("{sec}.octaves"),
            format!(
                "base_cells {base_cells} with {octaves} octaves makes a finest noise lattice above {MAX_NOISE_CELLS} cells; \
                 use fewer octaves or base cells"
            ),
        ));
    }
    Ok(())
}

fn build_dam_break<T: Real>(name: &str, db: &DamBreakScene, init: Option<&InitState>) -> Result<Stepper<T>> {
    let sec = "dam_break.geometry";
    match db.solver {
        DamSolver::Wcsph => check_h_over_dx(name, "dam_break.wcsph.h_over_dx", db.wcsph.h_over_dx)?,
        DamSolver::Iisph => check_h_over_dx(name, "dam_break.iisph.h_over_dx", db.iisph.h_over_dx)?,
        DamSolver::Dfsph => check_h_over_dx(name, "dam_break.dfsph.h_over_dx", db.dfsph.h_over_dx)?,
    }
    // Lengths are a times the ratios; an overflow to infinity would give an unbounded cell list.
    let g = &db.geometry;
    let extent = g.a * g.tank_width.abs().max(g.tank_height.abs()).max(g.height_ratio.abs()) * 4.0;
    if !extent.is_finite() {
        return Err(scene_err(
            name,
            "dam_break.geometry.a",
            format!("{} m with tank {} x {} a overflows; use metres-sized values", g.a, g.tank_width, g.tank_height),
        ));
    }
    if let Some(layers) = db.geometry.wall_layers.filter(|&l| l > MAX_WALL_LAYERS) {
        return Err(scene_err(
            name,
            "dam_break.geometry.wall_layers",
            format!("{layers}; use at most {MAX_WALL_LAYERS}"),
        ));
    }
    let mut stepper =
        match db.solver {
            DamSolver::Wcsph => Stepper::Wcsph(Box::new(db.geometry.build_as::<T>(db.wcsph).map_err(|e| match e {
                Error::Invalid { field, reason } if ["h_over_dx", "alpha", "delta", "cfl"].contains(&field) => {
                    scene_err(name, &format!("dam_break.wcsph.{field}"), reason)
                }
                e => field_err(name, sec, e),
            })?)),
            DamSolver::Iisph => Stepper::Iisph(Box::new(db.geometry.build_iisph_as::<T>(db.iisph).map_err(|e| {
                match e {
                    Error::Invalid { field, reason }
                        if ["h_over_dx", "cfl", "dt_max", "tolerance", "max_iterations", "omega", "nu"]
                            .contains(&field) =>
                    {
                        Error::SceneField { scene: name.into(), field: format!("dam_break.iisph.{field}"), reason }
                    }
                    e => field_err(name, sec, e),
                }
            })?)),
            DamSolver::Dfsph => {
                Stepper::Dfsph(Box::new(db.geometry.build_dfsph_as::<T>(db.dfsph).map_err(|e| match e {
                    Error::Invalid { field, reason } if DFSPH_FIELDS.contains(&field) => {
                        Error::SceneField { scene: name.into(), field: format!("dam_break.dfsph.{field}"), reason }
                    }
                    e => field_err(name, sec, e),
                })?))
            }
        };
    if let Some(init) = init {
        init.check(2, name)?;
        let x = narrow2::<T>(&init.points2());
        let v = narrow2::<T>(&init.velocities2());
        stepper = match stepper {
            Stepper::Wcsph(s) => {
                let walls = s.x[s.n_fluid()..].to_vec();
                let nf = x.len();
                let mut phys = *s.physics();
                phys.mass = init.uniform_mass(phys.mass, name)?;
                let rho = match &init.density {
                    Some(d) => narrow(d),
                    None => vec![T::c(phys.rho0); nf],
                };
                let all: Vec<[T; 2]> = x.into_iter().chain(walls).collect();
                let rho: Vec<T> = rho.into_iter().chain(std::iter::repeat_n(T::c(phys.rho0), all.len() - nf)).collect();
                Stepper::Wcsph(Box::new(Wcsph::new(
                    *s.params(),
                    phys,
                    all,
                    v,
                    rho,
                    nf,
                    container_domain(s.container()),
                    s.container(),
                )?))
            }
            Stepper::Iisph(s) => {
                let walls = s.x[s.n_fluid()..].to_vec();
                let nf = x.len();
                let all: Vec<[T; 2]> = x.into_iter().chain(walls).collect();
                Stepper::Iisph(Box::new(Iisph::new(
                    *s.params(),
                    s.rho0(),
                    s.dx(),
                    [0.0, -db.geometry.g],
                    all,
                    v,
                    nf,
                    container_domain(s.container()),
                    s.container(),
                )?))
            }
            Stepper::Dfsph(s) => {
                let walls = s.x[s.n_fluid()..].to_vec();
                let nf = x.len();
                let all: Vec<[T; 2]> = x.into_iter().chain(walls).collect();
                Stepper::Dfsph(Box::new(Dfsph::new(
                    *s.params(),
                    s.rho0(),
                    s.dx(),
                    [0.0, -db.geometry.g],
                    all,
                    v,
                    nf,
                    container_domain(s.container()),
                    s.container(),
                )?))
            }
            s => s,
        };
        // Fluid must start inside the tank.
        let [lo, hi] = match &stepper {
            Stepper::Wcsph(s) => s.container(),
            Stepper::Iisph(s) => s.container(),
            Stepper::Dfsph(s) => s.container(),
            Stepper::Sph1d(_) | Stepper::Wcsph3d(_) | Stepper::Dfsph3d(_) => unreachable!(),
        };
        for (i, p) in init.points2().iter().enumerate() {
            if !(p[0] >= lo[0] && p[0] <= hi[0] && p[1] >= lo[1] && p[1] <= hi[1]) {
                return Err(Error::OutsideDomain { index: i, position: p.to_vec(), lo: lo.to_vec(), hi: hi.to_vec() });
            }
        }
    }
    Ok(stepper)
}

/// The fields of [`DfsphParams`](crate::dfsph::DfsphParams) its validation names.
const DFSPH_FIELDS: [&str; 10] = [
    "h_over_dx",
    "cfl",
    "dt_max",
    "tolerance",
    "max_iterations",
    "divergence_tolerance",
    "max_divergence_iterations",
    "omega",
    "warm_start",
    "nu",
];

/// The fields of [`Wcsph3dParams`](crate::wcsph3d::Wcsph3dParams) its validation names.
const WCSPH3D_FIELDS: [&str; 4] = ["h_over_dx", "alpha", "delta", "cfl"];

/// A 3D box of `size` in spacing `dx` must hold at most [`MAX_PARTICLES`] lattice cells.
fn check_cells_3d(name: &str, field: &str, size: [f64; 3], dx: f64) -> Result<()> {
    if !(dx > 0.0 && dx.is_finite()) {
        return Err(scene_err(name, field, format!("{dx}; must be positive and finite")));
    }
    let cells: f64 = size.iter().map(|s| (s.abs() / dx).max(1.0)).product();
    if cells.is_nan() || cells > MAX_PARTICLES as f64 {
        return Err(scene_err(
            name,
            field,
            format!("{dx} gives {cells:.3e} lattice cells in the tank (at most {MAX_PARTICLES}); use a larger spacing"),
        ));
    }
    Ok(())
}

/// The `[dam_break_3d]` section's 3D WCSPH or DFSPH stepper, optionally restarted from `init`
/// (3D positions and velocities of the fluid; the walls are the scene's).
fn build_dam_break_3d<T: Real>(name: &str, db: &DamBreak3dScene, init: Option<&InitState>) -> Result<Stepper<T>> {
    let sec = "dam_break_3d.geometry";
    let g = &db.geometry;
    match db.solver {
        DamSolver::Wcsph => check_h_over_dx(name, "dam_break_3d.wcsph.h_over_dx", db.wcsph.h_over_dx)?,
        DamSolver::Dfsph => check_h_over_dx(name, "dam_break_3d.dfsph.h_over_dx", db.dfsph.h_over_dx)?,
        DamSolver::Iisph => {
            return Err(scene_err(
                name,
                "dam_break_3d.solver",
                "\"iisph\" has no 3D stepper; use \"wcsph\" or \"dfsph\"",
            ))
        }
    }
    if !(g.dx > 0.0 && g.dx.is_finite()) {
        return Err(scene_err(name, "dam_break_3d.geometry.dx", format!("{}; must be positive and finite", g.dx)));
    }
    let extent = g.a * g.tank_width.abs().max(g.tank_height.abs()).max(g.height_ratio.abs()).max(g.depth.abs()) * 4.0;
    if !extent.is_finite() {
        return Err(scene_err(
            name,
            "dam_break_3d.geometry.a",
            format!(
                "{} m with tank {} x {} x {} a overflows; use metres-sized values",
                g.a, g.tank_width, g.tank_height, g.depth
            ),
        ));
    }
    if let Some(layers) = g.wall_layers.filter(|&l| l > MAX_WALL_LAYERS) {
        return Err(scene_err(
            name,
            "dam_break_3d.geometry.wall_layers",
            format!("{layers}; use at most {MAX_WALL_LAYERS}"),
        ));
    }
    // Tank sizes over dx (both in units of a).
    check_cells_3d(name, "dam_break_3d.geometry.dx", [g.tank_width, g.tank_height, g.depth], g.dx)?;
    let stepper = match db.solver {
        DamSolver::Wcsph => Stepper::Wcsph3d(Box::new(g.build_as::<T>(db.wcsph).map_err(|e| match e {
            Error::Invalid { field, reason } if WCSPH3D_FIELDS.contains(&field) => {
                scene_err(name, &format!("dam_break_3d.wcsph.{field}"), reason)
            }
            e => field_err(name, sec, e),
        })?)),
        DamSolver::Dfsph => Stepper::Dfsph3d(Box::new(g.build_dfsph_as::<T>(db.dfsph).map_err(|e| match e {
            Error::Invalid { field, reason } if DFSPH_FIELDS.contains(&field) => {
                scene_err(name, &format!("dam_break_3d.dfsph.{field}"), reason)
            }
            e => field_err(name, sec, e),
        })?)),
        DamSolver::Iisph => unreachable!("refused above"),
    };
    match init {
        None => Ok(stepper),
        Some(init) => restart_3d(name, stepper, init, [0.0, -g.g, 0.0]),
    }
}

/// The `[block_drop_3d]` section's 3D WCSPH stepper, optionally restarted from `init`.
fn build_block_drop_3d<T: Real>(name: &str, bd: &BlockDrop3dScene, init: Option<&InitState>) -> Result<Stepper<T>> {
    let sec = "block_drop_3d.geometry";
    let g = &bd.geometry;
    check_h_over_dx(name, "block_drop_3d.wcsph.h_over_dx", bd.wcsph.h_over_dx)?;
    if let Some(layers) = g.wall_layers.filter(|&l| l > MAX_WALL_LAYERS) {
        return Err(scene_err(
            name,
            "block_drop_3d.geometry.wall_layers",
            format!("{layers}; use at most {MAX_WALL_LAYERS}"),
        ));
    }
    if !g.box_size.iter().all(|s| *s > 0.0 && s.is_finite()) {
        return Err(scene_err(
            name,
            "block_drop_3d.geometry.box_size",
            format!("{:?}; sides must be positive and finite", g.box_size),
        ));
    }
    check_cells_3d(name, "block_drop_3d.geometry.dx", g.box_size, g.dx)?;
    let sim = g.build_as::<T>(bd.wcsph).map_err(|e| match e {
        Error::Invalid { field, reason } if WCSPH3D_FIELDS.contains(&field) => {
            scene_err(name, &format!("block_drop_3d.wcsph.{field}"), reason)
        }
        e => field_err(name, sec, e),
    })?;
    let stepper = Stepper::Wcsph3d(Box::new(sim));
    match init {
        None => Ok(stepper),
        Some(init) => restart_3d(name, stepper, init, [0.0, -g.g, 0.0]),
    }
}

/// A 3D stepper with its fluid replaced by `init`'s (`[n, 3]` positions, optional velocities,
/// WCSPH: optional densities and a uniform mass); the walls, parameters and constants are the
/// built scene's. Fluid must start inside the tank.
fn restart_3d<T: Real>(name: &str, stepper: Stepper<T>, init: &InitState, gravity: [f64; 3]) -> Result<Stepper<T>> {
    init.check(3, name)?;
    let [lo, hi] = stepper.container_3d().expect("a 3D stepper");
    for (i, p) in init.points3().iter().enumerate() {
        if !(0..3).all(|d| p[d] >= lo[d] && p[d] <= hi[d]) {
            return Err(Error::OutsideDomain { index: i, position: p.to_vec(), lo: lo.to_vec(), hi: hi.to_vec() });
        }
    }
    let cast = |p: [f64; 3]| p.map(T::c);
    let x: Vec<[T; 3]> = init.points3().into_iter().map(cast).collect();
    let v: Vec<[T; 3]> = init.velocities3().into_iter().map(cast).collect();
    let nf = x.len();
    Ok(match stepper {
        Stepper::Wcsph3d(s) => {
            let mut phys = *s.physics();
            phys.mass = init.uniform_mass(phys.mass, name)?;
            let rho: Vec<T> = match &init.density {
                Some(d) => narrow(d),
                None => vec![T::c(phys.rho0); nf],
            };
            let walls = &s.x[s.n_fluid()..];
            let rho: Vec<T> = rho.into_iter().chain(std::iter::repeat_n(T::c(phys.rho0), walls.len())).collect();
            let all: Vec<[T; 3]> = x.into_iter().chain(walls.iter().copied()).collect();
            Stepper::Wcsph3d(Box::new(
                Wcsph3d::new(*s.params(), phys, all, v, rho, nf, *s.domain(), s.container())
                    .map_err(|e| field_err(name, "init", e))?,
            ))
        }
        Stepper::Dfsph3d(s) => {
            let walls = &s.x[s.n_fluid()..];
            let all: Vec<[T; 3]> = x.into_iter().chain(walls.iter().copied()).collect();
            // The search box: the tank and its walls, with two spacings to spare (as the tank's).
            let [mut blo, mut bhi] = s.container();
            for p in walls {
                for d in 0..3 {
                    blo[d] = blo[d].min(p[d].wide());
                    bhi[d] = bhi[d].max(p[d].wide());
                }
            }
            let m = 2.0 * s.dx();
            let domain = Domain::bounded(blo.map(|c| T::c(c - m)), bhi.map(|c| T::c(c + m)));
            Stepper::Dfsph3d(Box::new(
                Dfsph::new(*s.params(), s.rho0(), s.dx(), gravity, all, v, nf, domain, s.container())
                    .map_err(|e| field_err(name, "init", e))?,
            ))
        }
        s => s,
    })
}

/// The search box around a tank (walls included).
fn container_domain<T: Real>(c: [[f64; 2]; 2]) -> Domain<T, 2> {
    let m = 0.2 * (c[1][0] - c[0][0]).max(c[1][1] - c[0][1]);
    Domain::bounded([T::c(c[0][0] - m), T::c(c[0][1] - m)], [T::c(c[1][0] + m), T::c(c[1][1] + m)])
}

fn build_periodic_1d<T: Real>(
    name: &str,
    p: &Periodic1dScene,
    seed: u64,
    init: Option<&InitState>,
) -> Result<Stepper<T>> {
    let sec = "periodic_1d";
    let f = |field: &str, reason: String| scene_err(name, &format!("{sec}.{field}"), reason);
    if !(p.x_lo.is_finite() && p.x_hi.is_finite() && p.x_hi > p.x_lo) {
        return Err(f("x_hi", format!("need x_lo < x_hi, got {} {}", p.x_lo, p.x_hi)));
    }
    if !(p.rho0 > 0.0 && p.rho0.is_finite()) {
        return Err(f("rho0", format!("{}; must be positive", p.rho0)));
    }
    if !(p.c0 > 0.0 && p.c0.is_finite()) {
        return Err(f("c0", format!("{}; must be positive", p.c0)));
    }
    if !(0.0..1.0).contains(&p.amplitude) {
        return Err(f("amplitude", format!("{}; use 0 <= amplitude < 1", p.amplitude)));
    }
    if p.n < 16 || p.n > MAX_PARTICLES {
        return Err(f("n", format!("{}; use 16 to {MAX_PARTICLES} particles", p.n)));
    }
    check_noise(name, sec, p.base_cells, p.octaves)?;
    check_h_over_dx(name, "periodic_1d.sph.eta", p.sph.eta)?;
    let gamma = p.sph.gamma;
    if !(gamma > 1.0 && gamma.is_finite()) {
        return Err(f("sph.gamma", format!("{gamma}; the adiabatic index must exceed 1")));
    }
    let u0 = p.c0 * p.c0 / (gamma * (gamma - 1.0));
    let len = p.x_hi - p.x_lo;
    let domain = Domain::periodic([T::c(p.x_lo)], [T::c(p.x_hi)]);
    let (x, v, m, e, h) = match init {
        Some(init) => {
            init.check(1, name)?;
            let n = init.len();
            let mass = init.mass.clone().unwrap_or_else(|| vec![p.rho0 * len / n as f64; n]);
            let e = init.internal_energy.clone().unwrap_or_else(|| vec![u0; n]);
            (
                init.positions.clone(),
                init.velocities.clone().unwrap_or_else(|| vec![0.0; n]),
                mass,
                e,
                init.smoothing_length.clone(),
            )
        }
        None => {
            // Equal masses placed by inverting the cumulative mass of ρ(x).
            let noise = |x: f64| {
                let mut s = 0.0;
                for o in 0..p.octaves {
                    let cells = p.base_cells << o;
                    s += 0.5f64.powi(o as i32) * perlin_1d(seed, o as u64, (x - p.x_lo) / len * cells as f64, cells);
                }
                s
            };
            let fine = 64 * p.n;
            let samples: Vec<f64> = (0..fine).map(|k| noise(p.x_lo + (k as f64 + 0.5) * len / fine as f64)).collect();
            let nmax = samples.iter().fold(0.0f64, |a, &b| a.max(b.abs())).max(1e-300);
            let rho: Vec<f64> = samples.iter().map(|s| p.rho0 * (1.0 + p.amplitude * s / nmax)).collect();
            let cell = len / fine as f64;
            let total: f64 = rho.iter().sum::<f64>() * cell;
            let mass = total / p.n as f64;
            let mut x = Vec::with_capacity(p.n);
            let (mut k, mut acc) = (0usize, 0.0);
            for i in 0..p.n {
                let target = (i as f64 + 0.5) * mass;
                while k < fine - 1 && acc + rho[k] * cell < target {
                    acc += rho[k] * cell;
                    k += 1;
                }
                let frac = ((target - acc) / (rho[k] * cell)).clamp(0.0, 1.0);
                x.push(p.x_lo + (k as f64 + frac) * cell);
            }
            (x, vec![0.0; p.n], vec![mass; p.n], vec![u0; p.n], None)
        }
    };
    let n = x.len();
    let h = h.map(|h| narrow::<T>(&h));
    let restart_alpha = init.and_then(|i| i.viscosity_alpha.as_deref());
    let sim = Sph1d::new(p.sph, narrow(&x), narrow(&v), narrow(&e), narrow(&m), h, n, domain)
        .and_then(|mut sim| {
            // The viscosity switch continues where the trajectory left it.
            if let Some(alpha) = restart_alpha {
                sim.set_viscosity_alpha(alpha)?;
            }
            Ok(sim)
        })
        .map_err(|e| match e {
            Error::Invalid { field: "m", reason } => scene_err(name, "init.mass", reason),
            Error::Invalid { field: "u", reason } => scene_err(name, "init.internal_energy", reason),
            Error::Invalid { field: "h", reason } => scene_err(name, "init.smoothing_length", reason),
            Error::Invalid { field: "viscosity_alpha", reason } => scene_err(name, "init.viscosity_alpha", reason),
            e => field_err(name, "periodic_1d.sph", e),
        })?;
    Ok(Stepper::Sph1d(Box::new(sim)))
}

fn build_periodic_2d<T: Real>(
    name: &str,
    p: &Periodic2dScene,
    seed: u64,
    init: Option<&InitState>,
) -> Result<Stepper<T>> {
    let sec = "periodic_2d";
    let f = |field: &str, reason: String| scene_err(name, &format!("{sec}.{field}"), reason);
    if !(p.length > 0.0 && p.length.is_finite()) {
        return Err(f("length", format!("{}; must be positive", p.length)));
    }
    if !(p.rho0 > 0.0 && p.rho0.is_finite()) {
        return Err(f("rho0", format!("{}; must be positive", p.rho0)));
    }
    if !(p.c0 > 0.0 && p.c0.is_finite()) {
        return Err(f("c0", format!("{}; must be positive", p.c0)));
    }
    if !(p.u_max >= 0.0 && p.u_max.is_finite()) {
        return Err(f("u_max", format!("{}; must be non-negative", p.u_max)));
    }
    if p.n < 8 || p.n.saturating_mul(p.n) > MAX_PARTICLES {
        return Err(f("n", format!("{}; use 8 to {} particles per side", p.n, MAX_PARTICLES.isqrt())));
    }
    check_noise(name, sec, p.base_cells, p.octaves)?;
    check_h_over_dx(name, "periodic_2d.wcsph.h_over_dx", p.wcsph.h_over_dx)?;
    let l = p.length;
    let dx = l / p.n as f64;
    let domain = Domain::periodic([T::zero(); 2], [T::c(l); 2]);
    let mut phys = WcsphPhysics { rho0: p.rho0, c0: p.c0, gravity: [0.0, 0.0], mass: p.rho0 * dx * dx, dx };
    let (x, v, rho) = match init {
        Some(init) => {
            init.check(2, name)?;
            phys.mass = init.uniform_mass(phys.mass, name)?;
            let n = init.len();
            (init.points2(), init.velocities2(), init.density.clone().unwrap_or_else(|| vec![p.rho0; n]))
        }
        None => {
            let psi = |x: [f64; 2]| {
                let mut s = 0.0;
                for o in 0..p.octaves {
                    let cells = p.base_cells << o;
                    let c = cells as f64 / l;
                    s += 0.5f64.powi(o as i32) * perlin_2d(seed, o as u64, [x[0] * c, x[1] * c], cells);
                }
                s
            };
            let eps = 1e-5 * l;
            let mut x = Vec::with_capacity(p.n * p.n);
            let mut v = Vec::with_capacity(p.n * p.n);
            for j in 0..p.n {
                for i in 0..p.n {
                    let q = [(i as f64 + 0.5) * dx, (j as f64 + 0.5) * dx];
                    let dpy = (psi([q[0], q[1] + eps]) - psi([q[0], q[1] - eps])) / (2.0 * eps);
                    let dpx = (psi([q[0] + eps, q[1]]) - psi([q[0] - eps, q[1]])) / (2.0 * eps);
                    x.push(q);
                    v.push([dpy, -dpx]);
                }
            }
            let n = v.len() as f64;
            let mean = v.iter().fold([0.0; 2], |a, w| [a[0] + w[0] / n, a[1] + w[1] / n]);
            let vmax =
                v.iter().fold(0.0f64, |a, w| a.max(((w[0] - mean[0]).powi(2) + (w[1] - mean[1]).powi(2)).sqrt()));
            let s = if vmax > 0.0 { p.u_max / vmax } else { 0.0 };
            for w in &mut v {
                *w = [(w[0] - mean[0]) * s, (w[1] - mean[1]) * s];
            }
            let nn = x.len();
            (x, v, vec![p.rho0; nn])
        }
    };
    let nf = x.len();
    let sim = Wcsph::new(p.wcsph, phys, narrow2(&x), narrow2(&v), narrow(&rho), nf, domain, [[0.0, 0.0], [l, l]])
        .map_err(|e| field_err(name, "periodic_2d.wcsph", e))?;
    Ok(Stepper::Wcsph(Box::new(sim)))
}
