//! The `smoke` scene in 3D (`grid.nz > 1`): builds on the 3D plume stepper, rises, writes
//! `[T, C, Z, Y, X]` fields, reads them back, and refuses what has no 3D form with typed errors.

use pbdl_grid::scene::{Scene, SceneError, State};

const PLUME: &str = include_str!("../scenes/smoke_plume.toml");

fn plume3d(extra: &str) -> String {
    PLUME
        .replace("nx = 64\nny = 96", "nx = 16\nny = 24\nnz = 16\nlz = 1.0")
        .replace("steps = 400", "steps = 100")
        .replace("[physics]\n", &format!("[physics]\n{extra}"))
}

fn field(sim: &pbdl_grid::scene::Simulation, name: &str) -> candle_core::Tensor {
    sim.fields().unwrap().into_iter().find(|(n, _)| n == name).unwrap().1
}

fn invalid_field(err: SceneError) -> String {
    match err {
        SceneError::Invalid { field, .. } => field,
        other => panic!("expected SceneError::Invalid, got {other:?}: {other}"),
    }
}

#[test]
fn three_d_plume_scene_rises_and_round_trips() {
    let mut sim = Scene::from_toml_str(&plume3d(""), "plume3d").unwrap().build().unwrap();
    println!("3D plume operators {:?}, dt {:.3e}", sim.operators(), sim.dt());
    assert!(sim.operators().iter().any(|o| o.contains("buoyancy")), "{:?}", sim.operators());
    let traj = sim.run(|_| {}).unwrap();
    let rho = field(&sim, "density");
    assert_eq!(rho.dims(), [1, 16, 24, 16]);
    assert_eq!(field(&sim, "velocity").dims(), [3, 16, 24, 16]);
    // The plume rises: the density's centre of mass is above the source (y = 0.15).
    let r: Vec<f64> = rho.to_dtype(candle_core::DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap();
    let (mut m, mut my) = (0.0, 0.0);
    for (i, v) in r.iter().enumerate() {
        let j = (i / 16) % 24;
        m += v;
        my += v * (j as f64 + 0.5) * 1.5 / 24.0;
    }
    let com_y = my / m;
    println!("after {} steps: density sum {m:.4}, centre of mass y {com_y:.3} (source 0.15)", sim.step_index());
    assert!(m > 0.0 && com_y > 0.2, "{com_y}");
    let State::Smoke3d(s) = sim.state() else { panic!("3D smoke state") };
    assert_eq!(s.density.dims(), [1, 1, 16, 24, 16]);
    let stacked = traj.stacked().unwrap();
    let get = |n: &str| stacked.iter().find(|(k, _)| k == n).unwrap().1.clone();
    assert_eq!(get("density").dims()[1..], [1, 16, 24, 16]);
    // --init from the trajectory restores density and velocity.
    let mut b = Scene::from_toml_str(&plume3d(""), "plume3d").unwrap().build().unwrap();
    let used =
        b.set_fields(&[("density".into(), get("density")), ("velocity_mac".into(), get("velocity_mac"))]).unwrap();
    assert_eq!(used, ["density", "velocity_mac"]);
    let d = (field(&b, "density") - &rho).unwrap().abs().unwrap().max_all().unwrap();
    assert_eq!(d.to_dtype(candle_core::DType::F64).unwrap().to_scalar::<f64>().unwrap(), 0.0);
}

#[test]
fn what_has_no_3d_form_is_a_typed_error() {
    let e = Scene::from_toml_str(&plume3d("advection = \"central_rk4\"\n"), "x").unwrap().build().unwrap_err();
    assert_eq!(invalid_field(e), "physics.advection");
    // Free-slip, periodic and outflow faces have a 3D form now (issue 23, tests/smoke3d_boundaries.rs);
    // a moving wall does not.
    let walls = "[physics.boundaries]\nx_lo = { kind = \"moving_wall\", velocity = 1.0 }\nx_hi = { kind = \"no_slip\" }\ny_lo = { kind = \"no_slip\" }\ny_hi = { kind = \"no_slip\" }\n";
    let text = format!("{}\n{walls}", plume3d(""));
    let e = Scene::from_toml_str(&text, "x").unwrap().build().unwrap_err();
    assert_eq!(invalid_field(e), "physics.boundaries.x_lo");
    // Conservative density transport has a 3D form now (grid3d::conservative); it builds.
    let sim = Scene::from_toml_str(&plume3d("density_advection = \"conservative\"\n"), "x").unwrap().build().unwrap();
    assert!(sim.operators().iter().any(|o| o.contains("conservative")), "{:?}", sim.operators());
    let obstacle = format!("{}\n[[obstacles]]\nkind = \"circle\"\ncenter = [0.5, 0.8]\nradius = 0.1\n", plume3d(""));
    // A 2D obstacle is extruded through the depth in 3D (issue 23): it builds.
    let sim = Scene::from_toml_str(&obstacle, "x").unwrap().build().unwrap();
    assert!(sim.operators().contains(&"grid3d.obstacles"), "{:?}", sim.operators());
}

#[test]
fn three_d_grids_beyond_memory_are_refused_before_allocating() {
    let huge = plume3d("").replace("nz = 16", "nz = 4000000");
    let e = Scene::from_toml_str(&huge, "huge").unwrap_err();
    assert_eq!(invalid_field(e), "grid");
}
