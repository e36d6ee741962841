//! The 3D smoke plume's boundaries (issue 23): per-face walls (free-slip, periodic pairs,
//! outflow), static obstacles, and their gradients; bars G3D-1 / G3D-2 of the README (written
//! before any run) and the checks behind them.
//!
//! Bounds, stated before measuring:
//! * G3D-1: a uniform `u = 1` (x periodic, free-slip walls at y and z, inviscid, f64) stays
//!   uniform to 1e-6 after 50 steps. Discriminating check (the bar's "with no-slip walls the
//!   same test must fail"): with `nu > 0` the free-slip box still keeps it to 1e-6 and the
//!   no-slip box must lose more than 1e-3 of it near the walls. The inviscid no-slip run is
//!   reported, not asserted (see the test's comment).
//! * G3D-2 (fast form, 16^3 f32, 60 steps; the `#[ignore]`d release run is the bar's 32^3 x 300):
//!   `||D u||_2 h / ||u||_2 <= 1e-5` after every step (the f32 rounding bound of
//!   tests/smoke3d.rs), every velocity face touching a solid cell exactly 0, density exactly 0
//!   in every solid cell; the 32^3 run also needs density above the sphere's top at the end
//!   (more than 1% of the box's mass in the cells whose centre lies above the sphere's top).
//! * gradients (f64, central differences): relative error <= 1e-6 as for the closed box.
//! * conservative density transport with an obstacle: mass = injected to 1e-12 relative (f64).

use candle_core::{DType, Device, Tensor};
use pbdl_core::tolerance::GRAD_CHECK_F64 as TOL;
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_grid::grid3d::{
    Advection3d, BoxPressure, Face3d, Grid3d, InflowFace3d, InflowPatch3d, MacField3d, Obstacle3d, PatchShape3d,
    Smoke3d, Smoke3dBoundaries, Smoke3dConfig, Smoke3dState, SphereSource, Viscosity3d, Walls3d,
};
use pbdl_grid::pressure::CgSettings;
use pbdl_grid::Error;
use std::time::Instant;

fn to_vec(t: &Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap()
}

/// `||D u||_2 h / ||u||_2` with the walls of `walls` (the face at 0 of a non-periodic axis is a
/// wall at 0; a periodic axis wraps; an outflow face is the stored last face).
fn rel_divergence(u: &MacField3d, walls: &Walls3d) -> f64 {
    rel_divergence_where(u, walls, &vec![false; u.grid().cells()])
}

/// [`rel_divergence`] over the cells not marked in `skip`.
fn rel_divergence_where(u: &MacField3d, walls: &Walls3d, skip: &[bool]) -> f64 {
    let g = *u.grid();
    let v = to_vec(u.values());
    let n = [g.nx, g.ny, g.nz];
    let nc = g.cells();
    let st = [1, n[0], n[0] * n[1]];
    let h = g.spacing();
    let (mut d2, mut u2) = (0.0, 0.0);
    for m in 0..nc {
        if skip[m] {
            continue;
        }
        let p = [m % n[0], (m / n[0]) % n[1], m / st[2]];
        let mut div = 0.0;
        for a in 0..3 {
            let back = if p[a] > 0 {
                v[a * nc + m - st[a]]
            } else if walls.periodic(a) {
                v[a * nc + m + (n[a] - 1) * st[a]]
            } else {
                0.0
            };
            div += (v[a * nc + m] - back) / h[a];
        }
        d2 += div * div;
    }
    for x in &v {
        u2 += x * x;
    }
    if u2 == 0.0 {
        0.0
    } else {
        d2.sqrt() * g.min_spacing() / u2.sqrt()
    }
}

fn no_source(dt: f64, nu: f64) -> Smoke3dConfig {
    Smoke3dConfig {
        dt,
        nu,
        viscosity: Viscosity3d::Implicit,
        advection: Advection3d::MacCormack,
        density_advection: Advection3d::MacCormack,
        buoyancy: 0.0,
        source: None,
    }
}

/// `max |u - 1|, max |v|, max |w|` after `steps` steps from `u = 1` in a box periodic along x
/// with `yz` walls at y and z.
fn uniform_flow_error(yz: Face3d, nu: f64, steps: usize) -> f64 {
    let grid = Grid3d::new(12, 8, 8, 1.5, 1.0, 1.0).unwrap();
    let walls = Walls3d { x_lo: Face3d::Periodic, x_hi: Face3d::Periodic, y_lo: yz, y_hi: yz, z_lo: yz, z_hi: yz };
    let b = Smoke3dBoundaries { walls, ..Default::default() };
    let smoke = Smoke3d::with_boundaries(grid, no_source(0.05, nu), b, BoxPressure::default()).unwrap();
    let n = grid.cells();
    let mut u = vec![0.0f64; 3 * n];
    u[..n].iter_mut().for_each(|x| *x = 1.0);
    let u = Tensor::from_vec(u, grid.shape(1, 3).to_vec(), &Device::Cpu).unwrap();
    let mut s = Smoke3dState {
        velocity: MacField3d::new(u, grid).unwrap(),
        density: Tensor::zeros(grid.shape(1, 1).to_vec(), DType::F64, &Device::Cpu).unwrap(),
    };
    for _ in 0..steps {
        s = smoke.step(&s, None).unwrap();
    }
    let v = to_vec(s.velocity.values());
    let mut e = 0.0f64;
    for (k, x) in v.iter().enumerate() {
        let target = if k < n { 1.0 } else { 0.0 };
        e = e.max((x - target).abs());
    }
    e
}

/// Bar G3D-1.
#[test]
fn g3d1_free_slip_walls_keep_a_uniform_tangential_flow() {
    let free = uniform_flow_error(Face3d::FreeSlip, 0.0, 50);
    // Inviscid, the no-slip ghosts are never read by this flow (v = w = 0, so no backtrace
    // leaves its row; the projection does not see tangential ghosts): no-slip keeps it too.
    // Reported, not asserted: the discriminating check below needs viscosity.
    let no_slip_inviscid = uniform_flow_error(Face3d::NoSlip, 0.0, 50);
    let free_visc = uniform_flow_error(Face3d::FreeSlip, 0.01, 50);
    let no_slip_visc = uniform_flow_error(Face3d::NoSlip, 0.01, 50);
    eprintln!(
        "G3D-1 (50 steps, f64): free-slip inviscid {free:.2e}, no-slip inviscid {no_slip_inviscid:.2e}; \
         nu = 0.01: free-slip {free_visc:.2e}, no-slip {no_slip_visc:.2e}"
    );
    assert!(free <= 1e-6, "G3D-1 free-slip: {free:e}");
    assert!(free_visc <= 1e-6, "free-slip with viscosity: {free_visc:e}");
    assert!(no_slip_visc > 1e-3, "no-slip with viscosity must slow the flow at the walls: {no_slip_visc:e}");
}

fn randn(shape: (usize, usize, usize, usize, usize), seed_: u64, std: f64) -> Tensor {
    seed::randn(shape, 0.0, std, DType::F64, &Device::Cpu, seed_).unwrap()
}

/// Every backward through a step with free-slip, periodic and outflow faces and an obstacle
/// agrees with central differences.
#[test]
fn step_gradients_with_boundaries_match_finite_differences() {
    let grid = Grid3d::new(6, 5, 4, 1.2, 1.0, 0.9).unwrap();
    let cfg = Smoke3dConfig {
        dt: 0.08,
        nu: 0.02,
        viscosity: Viscosity3d::Implicit,
        advection: Advection3d::MacCormack,
        density_advection: Advection3d::MacCormack,
        buoyancy: 0.8,
        source: Some(SphereSource { centre: [0.6, 0.3, 0.45], radius: 0.3, rate: 1.0 }),
    };
    let layouts = [
        Walls3d {
            x_lo: Face3d::Periodic,
            x_hi: Face3d::Periodic,
            y_lo: Face3d::FreeSlip,
            y_hi: Face3d::NoSlip,
            z_lo: Face3d::NoSlip,
            z_hi: Face3d::FreeSlip,
        },
        Walls3d { y_hi: Face3d::Outflow, x_lo: Face3d::FreeSlip, ..Walls3d::closed() },
    ];
    let obstacle = Obstacle3d::Box { lower: [0.0, 0.7, 0.0], upper: [0.4, 0.9, 0.5] };
    let u0 = randn((1, 3, 4, 5, 6), 8, 0.5);
    let rho0 = randn((1, 1, 4, 5, 6), 9, 1.0).abs().unwrap();
    for (k, walls) in layouts.into_iter().enumerate() {
        for visc in [Viscosity3d::Implicit, Viscosity3d::Explicit] {
            let b = Smoke3dBoundaries { walls, obstacles: if k == 0 { vec![obstacle] } else { vec![] }, inflow: None };
            let smoke = Smoke3d::with_boundaries(
                grid,
                Smoke3dConfig { viscosity: visc, ..cfg.clone() },
                b,
                BoxPressure::Cholesky,
            )
            .unwrap();
            let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
                let state = Smoke3dState { velocity: MacField3d::new(xs[0].clone(), grid)?, density: xs[1].clone() };
                let s = smoke.step(&state, None)?;
                Tensor::cat(&[s.velocity.values(), &s.density], 1)
            };
            let r =
                check_grad(f, &[u0.clone(), rho0.clone()], &GradCheckOptions { max_probes: 48, ..Default::default() })
                    .unwrap();
            eprintln!("layout {k} {visc:?} {:?}: max rel error {:.2e}", smoke.operators(), r.max_rel_error);
            r.ensure(TOL).unwrap();
        }
    }
}

/// The projection with periodic, outflow and solid cells leaves a divergence-free field (f64,
/// Cholesky: round-off) whose blocked faces are 0.
#[test]
fn projection_with_boundaries_is_divergence_free() {
    let grid = Grid3d::new(8, 7, 6, 1.0, 1.0, 1.0).unwrap();
    let u = randn((2, 3, 6, 7, 8), 3, 1.0);
    for walls in [
        Walls3d { x_lo: Face3d::Periodic, x_hi: Face3d::Periodic, ..Walls3d::closed() },
        Walls3d::all(Face3d::Periodic),
        Walls3d { y_hi: Face3d::Outflow, z_hi: Face3d::Outflow, ..Walls3d::all(Face3d::FreeSlip) },
    ] {
        let b = Smoke3dBoundaries {
            walls,
            obstacles: vec![Obstacle3d::Sphere { center: [0.5, 0.5, 0.5], radius: 0.2 }],
            inflow: None,
        };
        let smoke = Smoke3d::with_boundaries(grid, no_source(0.1, 0.0), b, BoxPressure::default()).unwrap();
        let p = smoke.project(&MacField3d::new(u.clone(), grid).unwrap()).unwrap();
        let d = rel_divergence(&p, &walls);
        eprintln!("{walls:?}: relative divergence {d:.2e}");
        assert!(d < 1e-12, "{d:e}");
        assert_eq!(blocked_max(&smoke, &p), 0.0);
    }
}

/// The largest |velocity| on a face touching a solid cell.
fn blocked_max(smoke: &Smoke3d, u: &MacField3d) -> f64 {
    let g = *smoke.grid();
    let Some(fluid) = smoke.fluid_mask() else { return 0.0 };
    let fluid = to_vec(fluid);
    let v = to_vec(u.values());
    let (n, nc) = ([g.nx, g.ny, g.nz], g.cells());
    let st = [1, n[0], n[0] * n[1]];
    let walls = smoke.boundaries().walls;
    let mut worst = 0.0f64;
    for b in 0..v.len() / (3 * nc) {
        for a in 0..3 {
            for m in 0..nc {
                let p = [m % n[0], (m / n[0]) % n[1], m / st[2]];
                // The face above cell m along a separates m and its upper neighbour.
                let up = if p[a] + 1 < n[a] {
                    Some(m + st[a])
                } else if walls.periodic(a) {
                    Some(m + st[a] - n[a] * st[a])
                } else {
                    None
                };
                let touches = fluid[m] == 0.0 || up.is_some_and(|q| fluid[q] == 0.0);
                // The face below a solid cell at the lower wall is the wall itself (0, not stored).
                if touches {
                    worst = worst.max(v[(b * 3 + a) * nc + m].abs());
                }
            }
        }
    }
    worst
}

/// The largest density in a solid cell.
fn solid_density_max(smoke: &Smoke3d, rho: &Tensor) -> f64 {
    let Some(fluid) = smoke.fluid_mask() else { return 0.0 };
    let fluid = to_vec(fluid);
    to_vec(rho)
        .iter()
        .enumerate()
        .filter(|(m, _)| fluid[m % fluid.len()] == 0.0)
        .map(|(_, r)| r.abs())
        .fold(0.0, f64::max)
}

/// Summary of a plume-onto-a-sphere run.
struct ObstacleRun {
    max_rel_div: f64,
    max_blocked: f64,
    max_solid_density: f64,
    above_fraction: f64,
    mass_error: f64,
    secs: f64,
}

fn plume_onto_sphere(n: usize, steps: usize, dtype: DType, density: Advection3d) -> ObstacleRun {
    let grid = Grid3d::cube(n, 1.0).unwrap();
    let cfg = Smoke3dConfig { density_advection: density, ..Smoke3dConfig::plume(&grid, grid.min_spacing()) };
    let (centre, radius) = ([0.5, 0.45, 0.5], 0.15);
    let b = Smoke3dBoundaries {
        walls: Walls3d::closed(),
        obstacles: vec![Obstacle3d::Sphere { center: centre, radius }],
        inflow: None,
    };
    let smoke = Smoke3d::with_boundaries(grid, cfg, b, BoxPressure::default()).unwrap();
    let mut s = smoke.rest(1, dtype).unwrap();
    let (mut max_rel_div, mut max_blocked, mut max_solid_density) = (0.0f64, 0.0f64, 0.0f64);
    let t0 = Instant::now();
    for _ in 0..steps {
        s = smoke.step(&s, None).unwrap();
        max_rel_div = max_rel_div.max(rel_divergence(&s.velocity, &Walls3d::closed()));
        max_blocked = max_blocked.max(blocked_max(&smoke, &s.velocity));
        max_solid_density = max_solid_density.max(solid_density_max(&smoke, &s.density));
    }
    let secs = t0.elapsed().as_secs_f64();
    let rho = to_vec(&s.density);
    let h = grid.spacing();
    let top = centre[1] + radius;
    let (mut total, mut above) = (0.0, 0.0);
    for (m, r) in rho.iter().enumerate() {
        total += r;
        if ((m / n) % n) as f64 * h[1] + 0.5 * h[1] > top {
            above += r;
        }
    }
    let mass = total * h[0] * h[1] * h[2];
    let injected = smoke.injected_per_step() * steps as f64;
    ObstacleRun {
        max_rel_div,
        max_blocked,
        max_solid_density,
        above_fraction: above / total,
        mass_error: (mass - injected).abs() / injected,
        secs,
    }
}

/// G3D-2's invariants at 16^3 for 60 steps (the fast form of the bar).
#[test]
fn plume_onto_a_sphere_keeps_solid_faces_and_cells_empty() {
    let r = plume_onto_sphere(16, 60, DType::F32, Advection3d::MacCormack);
    eprintln!(
        "16^3 f32 x 60: max rel div {:.2e}, max |u| on solid faces {:e}, max solid density {:e}, \
         density above the sphere {:.3}, {:.2} s",
        r.max_rel_div, r.max_blocked, r.max_solid_density, r.above_fraction, r.secs
    );
    assert!(r.max_rel_div <= 1e-5, "{:e}", r.max_rel_div);
    assert_eq!(r.max_blocked, 0.0);
    assert_eq!(r.max_solid_density, 0.0);
}

/// Conservative transport with an obstacle moves nothing through the solid faces: the mass is
/// what the source injected.
#[test]
fn conservative_density_around_an_obstacle_keeps_the_mass() {
    let r = plume_onto_sphere(12, 40, DType::F64, Advection3d::Conservative);
    eprintln!("12^3 f64 x 40 conservative: mass error {:.2e}, solid density {:e}", r.mass_error, r.max_solid_density);
    assert!(r.mass_error <= 1e-12, "{:e}", r.mass_error);
    assert_eq!(r.max_solid_density, 0.0);
    assert_eq!(r.max_blocked, 0.0);
}

/// Bar G3D-2: 32^3 f32, 300 steps (release: `cargo test --release -p pbdl-grid --test
/// smoke3d_boundaries -- --ignored`).
#[test]
#[ignore = "32^3 x 300 steps: run in release"]
fn g3d2_plume_onto_a_sphere_32() {
    let r = plume_onto_sphere(32, 300, DType::F32, Advection3d::MacCormack);
    eprintln!(
        "G3D-2 32^3 f32 x 300: max rel div {:.2e}, max |u| on solid faces {:e}, max solid density {:e}, \
         fraction of the density above the sphere's top {:.3}, {:.1} s ({:.1} ms/step incl. checks)",
        r.max_rel_div,
        r.max_blocked,
        r.max_solid_density,
        r.above_fraction,
        r.secs,
        1e3 * r.secs / 300.0
    );
    assert!(r.max_rel_div <= 1e-5, "{:e}", r.max_rel_div);
    assert_eq!(r.max_blocked, 0.0);
    assert_eq!(r.max_solid_density, 0.0);
    assert!(r.above_fraction > 0.01, "{}", r.above_fraction);
}

/// Bad boundaries are typed errors naming the face or the key.
#[test]
fn bad_boundaries_are_typed_errors() {
    let grid = Grid3d::cube(8, 1.0).unwrap();
    let plume = Smoke3dConfig::plume(&grid, 0.1);
    let build = |walls: Walls3d, obstacles: Vec<Obstacle3d>, cfg: &Smoke3dConfig, p: BoxPressure| {
        Smoke3d::with_boundaries(grid, cfg.clone(), Smoke3dBoundaries { walls, obstacles, inflow: None }, p)
    };
    let face = |r: pbdl_grid::Result<Smoke3d>| match r {
        Err(Error::Boundary { face, .. }) => face,
        other => panic!("expected a boundary error, got {other:?}"),
    };
    let field = |r: pbdl_grid::Result<Smoke3d>| match r {
        Err(Error::Invalid { field, .. }) => field,
        other => panic!("expected an invalid-field error, got {other:?}"),
    };
    let closed = Walls3d::closed();
    assert_eq!(face(build(Walls3d { x_lo: Face3d::Periodic, ..closed }, vec![], &plume, BoxPressure::Auto)), "x_hi");
    assert_eq!(face(build(Walls3d { y_lo: Face3d::Outflow, ..closed }, vec![], &plume, BoxPressure::Auto)), "y_lo");
    let on_source = Obstacle3d::Sphere { center: [0.5, 0.15, 0.5], radius: 0.1 };
    assert_eq!(field(build(closed, vec![on_source], &plume, BoxPressure::Auto)), "obstacles");
    let tiny = Obstacle3d::Sphere { center: [0.5, 0.5, 0.5], radius: 0.01 };
    assert_eq!(field(build(closed, vec![tiny], &plume, BoxPressure::Auto)), "obstacles");
    let sphere = Obstacle3d::Sphere { center: [0.5, 0.6, 0.5], radius: 0.2 };
    let cg = BoxPressure::Cg(CgSettings::default());
    assert_eq!(field(build(closed, vec![sphere], &plume, cg)), "pressure");
    // Conservative transport counts what leaves through an outflow face (G3D-3): it builds.
    let cons = Smoke3dConfig { density_advection: Advection3d::Conservative, ..plume.clone() };
    assert!(build(Walls3d { y_hi: Face3d::Outflow, ..closed }, vec![], &cons, BoxPressure::Auto).is_ok());
    // An inflow patch needs an outflow face, and must cover a cell.
    let patch = InflowPatch3d {
        face: InflowFace3d::YLo,
        shape: PatchShape3d::Disc { center: [0.3, 0.3], radius: 0.15 },
        velocity: 0.5,
        density: 1.0,
    };
    let with_inflow = |walls: Walls3d, patch: InflowPatch3d| {
        Smoke3d::with_boundaries(
            grid,
            plume.clone(),
            Smoke3dBoundaries { walls, obstacles: vec![], inflow: Some(patch) },
            BoxPressure::Auto,
        )
    };
    assert_eq!(field(with_inflow(closed, patch)), "inflow");
    let open_top = Walls3d { y_hi: Face3d::Outflow, ..closed };
    assert!(with_inflow(open_top, patch).is_ok());
    let tiny = InflowPatch3d { shape: PatchShape3d::Disc { center: [0.3, 0.3], radius: 0.01 }, ..patch };
    assert_eq!(field(with_inflow(open_top, tiny)), "inflow");
    let periodic_y = Walls3d { y_lo: Face3d::Periodic, y_hi: Face3d::Periodic, x_hi: Face3d::Outflow, ..closed };
    assert_eq!(face(with_inflow(periodic_y, patch)), "y_lo");
    // Free-slip walls keep the closed box's matrix, so CG works there.
    assert!(build(Walls3d::all(Face3d::FreeSlip), vec![], &plume, cg).is_ok());
}

mod scene {
    use pbdl_grid::scene::{Scene, SceneError};

    const OBSTACLE: &str = include_str!("../scenes/smoke3d_obstacle.toml");

    fn invalid_field(err: SceneError) -> String {
        match err {
            SceneError::Invalid { field, .. } => field,
            other => panic!("expected SceneError::Invalid, got {other:?}: {other}"),
        }
    }

    /// The built-in 3D scene (free-slip sides, open top, a sphere) runs and writes `[C, Z, Y, X]`.
    #[test]
    fn builtin_obstacle_scene_runs() {
        let mut sim = Scene::builtin("smoke3d_obstacle").unwrap().with_resolution(12).with_steps(20).build().unwrap();
        let ops = sim.operators().to_vec();
        assert!(ops.contains(&"grid3d.obstacles") && ops.contains(&"grid3d.pressure.sparse_cholesky"), "{ops:?}");
        let traj = sim.run(|_| {}).unwrap();
        let stacked = traj.stacked().unwrap();
        let rho = &stacked.iter().find(|(k, _)| k == "density").unwrap().1;
        assert_eq!(rho.dims()[1..], [1, 12, 12, 12]);
        let m = rho.max_all().unwrap().to_dtype(candle_core::DType::F64).unwrap().to_scalar::<f64>().unwrap();
        assert!(m.is_finite() && m > 0.0, "{m}");
    }

    /// Bad 3D boundary keys are typed errors naming the key.
    #[test]
    fn bad_3d_keys_name_the_key() {
        let with = |from: &str, to: &str| {
            assert!(OBSTACLE.contains(from), "{from}");
            OBSTACLE.replace(from, to)
        };
        let err = |text: String| {
            invalid_field(Scene::from_toml_str(&text, "x").and_then(|s| s.build().map(|_| ())).unwrap_err())
        };
        assert_eq!(
            err(with("x_lo = { kind = \"free_slip\" }", "x_lo = { kind = \"periodic\" }")),
            "physics.boundaries.x_hi"
        );
        assert_eq!(
            err(with("z_lo = { kind = \"free_slip\" }", "z_lo = { kind = \"outflow\" }")),
            "physics.boundaries_z.z_lo"
        );
        assert_eq!(
            err(with("y_lo = { kind = \"no_slip\" }", "y_lo = { kind = \"inflow\", velocity = [0.0, 1.0] }")),
            "physics.boundaries.y_lo"
        );
        assert_eq!(err(with("center = [0.5, 0.5, 0.5]", "center = [0.5, 0.15, 0.5]")), "physics.obstacles3d[0]");
        // An inflow patch without an outflow face.
        let patch = "[physics.inflow_patch]\nface = \"y_lo\"\nvelocity = 0.5\ndensity = 1.0\nshape = { kind = \"disc\", center = [0.3, 0.3], radius = 0.15 }\n";
        let closed = with("y_hi = { kind = \"outflow\" }", "y_hi = { kind = \"no_slip\" }");
        assert_eq!(err(format!("{closed}\n{patch}")), "physics.inflow_patch");
        // With the outflow top it builds.
        Scene::from_toml_str(&format!("{OBSTACLE}\n{patch}"), "x").unwrap().build().unwrap();
        // 3D keys in a 2D scene.
        let flat = with("nz = 32\n", "").replace("lz = 1.0\n", "");
        assert_eq!(err(flat), "physics.boundaries_z");
    }
}

/// Summary of an inflow / open-top run.
struct InflowRun {
    max_rel_div: f64,
    balance_error: f64,
    content: f64,
    inflow: f64,
    outflow: f64,
    injected: f64,
    secs: f64,
}

/// `||D u||_2 h / ||u||_2` over the cells that are neither solid nor inflow cells (an inflow
/// cell's faces are a wall, the inflow face and its neighbours: not a fluid cell).
fn fluid_rel_divergence(smoke: &Smoke3d, u: &MacField3d) -> f64 {
    let nc = u.grid().cells();
    let skip: Vec<bool> = {
        let f = smoke.fluid_mask().map(to_vec);
        let i = smoke.inflow_mask().map(to_vec);
        (0..nc).map(|m| f.as_ref().is_some_and(|f| f[m] == 0.0) || i.as_ref().is_some_and(|i| i[m] == 1.0)).collect()
    };
    rel_divergence_where(u, &smoke.boundaries().walls, &skip)
}

/// The G3D-3 scene: 16^3 unit box, free-slip sides, no-slip floor, an outflow top; a disc
/// inflow (radius 0.15, velocity 0.5, density 1) at the floor's centre; the plume's sphere
/// source; `dt = h`.
fn inflow_open_top(steps: usize, dtype: DType, density: Advection3d) -> InflowRun {
    let grid = Grid3d::cube(16, 1.0).unwrap();
    let cfg = Smoke3dConfig { density_advection: density, ..Smoke3dConfig::plume(&grid, grid.min_spacing()) };
    let walls = Walls3d { y_lo: Face3d::NoSlip, y_hi: Face3d::Outflow, ..Walls3d::all(Face3d::FreeSlip) };
    let inflow = InflowPatch3d {
        face: InflowFace3d::YLo,
        shape: PatchShape3d::Disc { center: [0.5, 0.5], radius: 0.15 },
        velocity: 0.5,
        density: 1.0,
    };
    let b = Smoke3dBoundaries { walls, obstacles: vec![], inflow: Some(inflow) };
    let smoke = Smoke3d::with_boundaries(grid, cfg, b, BoxPressure::default()).unwrap();
    let mut s = smoke.rest(1, dtype).unwrap();
    let (mut max_rel_div, mut inflow, mut outflow, mut injected) = (0.0f64, 0.0, 0.0, 0.0);
    let t0 = Instant::now();
    for _ in 0..steps {
        let (next, bal) = smoke.step_balance(&s).unwrap();
        s = next;
        injected += bal[0].source;
        inflow += bal[0].inflow;
        outflow += bal[0].outflow.unwrap_or(f64::NAN);
        max_rel_div = max_rel_div.max(fluid_rel_divergence(&smoke, &s.velocity));
    }
    let secs = t0.elapsed().as_secs_f64();
    let vol = grid.spacing().iter().product::<f64>();
    let content = to_vec(&s.density).iter().sum::<f64>() * vol;
    let balance_error = (content - (injected + inflow - outflow)).abs() / (injected + inflow);
    InflowRun { max_rel_div, balance_error, content, inflow, outflow, injected, secs }
}

/// Bar G3D-3: inflow through a floor patch, open top, 300 steps f32: divergence after every step
/// and (conservative density) the mass balance.
#[test]
fn g3d3_inflow_patch_and_open_top() {
    let r = inflow_open_top(300, DType::F32, Advection3d::Conservative);
    eprintln!(
        "G3D-3 16^3 f32 x 300 conservative: max rel div {:.2e}, content {:.6e} = injected {:.6e} + inflow {:.6e} - \
         outflow {:.6e}: relative balance error {:.2e}, {:.1} s",
        r.max_rel_div, r.content, r.injected, r.inflow, r.outflow, r.balance_error, r.secs
    );
    assert!(r.outflow > 0.0, "nothing left through the top: {}", r.outflow);
    assert!(r.max_rel_div <= 1e-5, "{:e}", r.max_rel_div);
    assert!(r.balance_error <= 1e-6, "{:e}", r.balance_error);
    // The same boundaries with MacCormack density (divergence only: no fluxes to count).
    let m = inflow_open_top(300, DType::F32, Advection3d::MacCormack);
    eprintln!("G3D-3 MacCormack: max rel div {:.2e}, {:.1} s", m.max_rel_div, m.secs);
    assert!(m.max_rel_div <= 1e-5, "{:e}", m.max_rel_div);
}

/// The inflow step is differentiable (the projection's backward is its linear part).
#[test]
fn inflow_step_gradients_match_finite_differences() {
    let grid = Grid3d::new(6, 5, 4, 1.2, 1.0, 0.9).unwrap();
    let cfg = Smoke3dConfig {
        dt: 0.08,
        nu: 0.02,
        viscosity: Viscosity3d::Implicit,
        advection: Advection3d::MacCormack,
        density_advection: Advection3d::MacCormack,
        buoyancy: 0.8,
        source: Some(SphereSource { centre: [0.6, 0.5, 0.45], radius: 0.25, rate: 1.0 }),
    };
    let inflow = InflowPatch3d {
        face: InflowFace3d::YLo,
        shape: PatchShape3d::Rect { lower: [0.2, 0.2], upper: [0.7, 0.6] },
        velocity: 0.7,
        density: 0.9,
    };
    let walls = Walls3d { y_hi: Face3d::Outflow, ..Walls3d::closed() };
    let b = Smoke3dBoundaries { walls, obstacles: vec![], inflow: Some(inflow) };
    let smoke = Smoke3d::with_boundaries(grid, cfg, b, BoxPressure::Cholesky).unwrap();
    let u0 = randn((1, 3, 4, 5, 6), 8, 0.5);
    let rho0 = randn((1, 1, 4, 5, 6), 9, 1.0).abs().unwrap();
    let f = |xs: &[Tensor]| -> candle_core::Result<Tensor> {
        let state = Smoke3dState { velocity: MacField3d::new(xs[0].clone(), grid)?, density: xs[1].clone() };
        let s = smoke.step(&state, None)?;
        Tensor::cat(&[s.velocity.values(), &s.density], 1)
    };
    let r = check_grad(f, &[u0, rho0], &GradCheckOptions { max_probes: 48, ..Default::default() }).unwrap();
    eprintln!("inflow step {:?}: max rel error {:.2e}", smoke.operators(), r.max_rel_error);
    r.ensure(TOL).unwrap();
}

/// Per-step time at 32^3 f32 (release, ignored; no bound: a measurement): the closed box, the
/// same with free-slip walls, with the G3D-2 sphere, and with the G3D-3 inflow patch and open top
/// (conservative density); the build time includes the Cholesky factorisation.
#[test]
#[ignore = "timing: run in release"]
fn step_time_32() {
    let grid = Grid3d::cube(32, 1.0).unwrap();
    let plume = Smoke3dConfig::plume(&grid, grid.min_spacing());
    let inflow = InflowPatch3d {
        face: InflowFace3d::YLo,
        shape: PatchShape3d::Disc { center: [0.5, 0.5], radius: 0.15 },
        velocity: 0.5,
        density: 1.0,
    };
    let cases = [
        ("closed box", plume.clone(), Smoke3dBoundaries::default()),
        (
            "free-slip walls",
            plume.clone(),
            Smoke3dBoundaries { walls: Walls3d::all(Face3d::FreeSlip), ..Default::default() },
        ),
        (
            "sphere obstacle",
            plume.clone(),
            Smoke3dBoundaries {
                obstacles: vec![Obstacle3d::Sphere { center: [0.5, 0.45, 0.5], radius: 0.15 }],
                ..Default::default()
            },
        ),
        (
            "inflow + open top, conservative",
            Smoke3dConfig { density_advection: Advection3d::Conservative, ..plume.clone() },
            Smoke3dBoundaries {
                walls: Walls3d { y_lo: Face3d::NoSlip, y_hi: Face3d::Outflow, ..Walls3d::all(Face3d::FreeSlip) },
                obstacles: vec![],
                inflow: Some(inflow),
            },
        ),
    ];
    for (name, cfg, b) in cases {
        let t0 = Instant::now();
        let smoke = Smoke3d::with_boundaries(grid, cfg, b, BoxPressure::default()).unwrap();
        let build = t0.elapsed().as_secs_f64();
        let mut s = smoke.rest(1, DType::F32).unwrap();
        for _ in 0..20 {
            s = smoke.step(&s, None).unwrap();
        }
        let steps = 60;
        let t1 = Instant::now();
        for _ in 0..steps {
            s = smoke.step(&s, None).unwrap();
        }
        let per = t1.elapsed().as_secs_f64() / steps as f64;
        eprintln!("32^3 f32 {name}: build {build:.2} s, {:.1} ms/step", 1e3 * per);
    }
}
