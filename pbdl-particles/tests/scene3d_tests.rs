//! 3D scenes (`[dam_break_3d]`, `[block_drop_3d]`): the built-ins build and run, write `.npz`
//! trajectories with `[T, N, 3]` positions and velocities, restart through `--init`, and bad
//! keys are typed errors naming the key.

use pbdl_particles::scene::{self, InitState, Scene, Stepper};
use pbdl_particles::Error;

#[track_caller]
fn field_of(r: pbdl_particles::Result<Stepper>) -> String {
    match r {
        Err(Error::SceneField { field, .. }) => field,
        Err(e) => panic!("expected a SceneField error, got {e}"),
        Ok(_) => panic!("expected an error"),
    }
}

#[track_caller]
fn parse_field(text: &str) -> String {
    match Scene::from_toml_str(text, "test") {
        Err(Error::SceneField { field, .. }) => field,
        Err(e) => panic!("expected a SceneField error, got {e}"),
        Ok(_) => panic!("expected an error"),
    }
}

fn builtin_text(name: &str) -> &'static str {
    scene::BUILTIN.iter().find(|(n, _)| *n == name).unwrap().1
}

/// The built-in's text with the first line `key = ...` replaced by `key = value`.
fn with_key(name: &str, key: &str, value: &str) -> String {
    let prefix = format!("{key} = ");
    let mut done = false;
    let lines: Vec<String> = builtin_text(name)
        .lines()
        .map(|l| {
            if !done && l.starts_with(&prefix) {
                done = true;
                format!("{prefix}{value}")
            } else {
                l.to_string()
            }
        })
        .collect();
    assert!(done, "{name} has no `{key}`");
    lines.join("\n")
}

/// Builds the built-in for `frames` frames of a shortened interval, runs it, writes the
/// trajectory and checks the arrays' shapes; returns the stepper, the frames and the npz arrays.
fn run_and_write(
    sc: &Scene,
    dir: &std::path::Path,
) -> (Stepper, Vec<scene::Frame>, Vec<(String, candle_core::Tensor)>) {
    let mut sim = sc.build(0, None).unwrap();
    assert_eq!(sim.dim(), 3);
    let frames = scene::run_frames(sc, &mut sim, |_| {}).unwrap();
    assert_eq!(frames.len(), sc.frames + 1);
    let last = frames.last().unwrap();
    assert!((last.time - sc.t_end()).abs() < 1e-12, "t = {}", last.time);
    assert!(last.positions.iter().chain(&last.velocities).chain(&last.density).all(|v| v.is_finite()));
    let files = scene::write_trajectory(&sim, &frames, dir, &sc.name).unwrap();
    assert!(files[0].extension().is_some_and(|e| e == "npz"));
    #[cfg(feature = "viz")]
    assert!(files.iter().any(|f| f.extension().is_some_and(|e| e == "png")) && files.len() == 3, "{files:?}");
    let arrays = pbdl_core::io::read_npz(&files[0]).unwrap();
    let dims = |name: &str| arrays.iter().find(|(n, _)| n == name).unwrap().1.dims().to_vec();
    let (t, n) = (frames.len(), last.mass.len());
    assert!(n > 0);
    assert_eq!(dims("positions"), [t, n, 3]);
    assert_eq!(dims("velocities"), [t, n, 3]);
    assert_eq!(dims("density"), [t, n]);
    assert_eq!(dims("mass"), [t, n]);
    assert_eq!(dims("time"), [t]);
    let fixed = dims("fixed_positions");
    assert_eq!(fixed[1], 3);
    assert!(fixed[0] > 0);
    (sim, frames, arrays)
}

/// The built-in `dam_break_3d`: 3D WCSPH with walls, a short run with `[T, N, 3]` arrays, a
/// `--init` restart from the trajectory's last frame on the same solver, and the DFSPH variant.
#[test]
fn dam_break_3d_scene_runs_writes_and_restarts() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = Scene::builtin("dam_break_3d").unwrap().with_frames(2);
    sc.frame_dt = 0.005;
    let g = sc.dam_break_3d.unwrap().geometry;
    assert!((g.dx - 0.1).abs() < 1e-12, "coarse built-in: dx = a/10");
    let (sim, frames, arrays) = run_and_write(&sc, dir.path());
    assert_eq!(
        sim.operators(),
        [
            "tait_eos",
            "pressure_gradient",
            "continuity",
            "artificial_viscosity",
            "delta_sph_diffusion",
            "gravity",
            "wall_pressure_extrapolation"
        ]
    );
    let Stepper::Wcsph3d(s) = &sim else { panic!("not 3D WCSPH") };
    assert_eq!(s.n_fluid(), 10 * 20 * 5);
    assert_eq!(s.leaked(), 0);
    // Falling column: downward momentum.
    assert!(s.momentum()[1] < 0.0);

    // Restart from the last frame: the same fluid, the scene's walls.
    let init = InitState::from_arrays(&arrays).unwrap();
    assert_eq!(init.dim, 3);
    let Stepper::Wcsph3d(restart) = sc.build(0, Some(&init)).unwrap() else { panic!("restart not 3D WCSPH") };
    let last = frames.last().unwrap();
    let n = restart.n_fluid();
    assert_eq!(restart.x[..n].iter().flatten().copied().collect::<Vec<_>>(), last.positions);
    assert_eq!(restart.v.iter().flatten().copied().collect::<Vec<_>>(), last.velocities);
    assert_eq!(restart.rho[..n].to_vec(), last.density);
    assert_eq!(restart.x.len(), s.x.len());
    // 2D positions are refused, naming the field.
    let flat = InitState { dim: 2, positions: vec![0.1, 0.1, 0.2, 0.1], ..Default::default() };
    assert_eq!(field_of(sc.build(0, Some(&flat))), "init.positions");
    // Fluid outside the tank is refused.
    let outside = InitState { dim: 3, positions: vec![0.1, 0.1, 5.0], ..Default::default() };
    assert!(matches!(sc.build(0, Some(&outside)), Err(Error::OutsideDomain { .. })));

    // DFSPH: the same geometry with `solver = "dfsph"` (default parameters: `default_3d`).
    let text = with_key("dam_break_3d", "solver", "\"dfsph\"");
    let mut df = Scene::from_toml_str(&text, "df").unwrap().with_frames(1);
    df.frame_dt = 0.005;
    assert_eq!(df.dam_break_3d.unwrap().dfsph, pbdl_particles::dfsph::DfsphParams::default_3d());
    let (dsim, dframes, darrays) = run_and_write(&df, dir.path());
    assert!(dsim.operators().contains(&"divergence_solve_dfsph"), "{:?}", dsim.operators());
    let Stepper::Dfsph3d(ds) = &dsim else { panic!("not 3D DFSPH") };
    assert_eq!(ds.leaked(), 0);
    let dinit = InitState::from_arrays(&darrays).unwrap();
    let Stepper::Dfsph3d(drestart) = df.build(0, Some(&dinit)).unwrap() else { panic!("restart not 3D DFSPH") };
    let n = drestart.n_fluid();
    assert_eq!(drestart.x[..n].iter().flatten().copied().collect::<Vec<_>>(), dframes.last().unwrap().positions);
}

/// The built-in `block_drop_3d`: a falling cube with `[T, N, 3]` arrays.
#[test]
fn block_drop_3d_scene_runs_and_writes() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = Scene::builtin("block_drop_3d").unwrap().with_frames(2);
    sc.frame_dt = 0.004;
    let (sim, frames, _) = run_and_write(&sc, dir.path());
    assert!(sim.operators().contains(&"wall_pressure_extrapolation"));
    assert!(sim.operators().contains(&"gravity"));
    assert_eq!(frames[0].mass.len(), 8 * 8 * 8);
    // Free fall at first: every particle moves down.
    assert!(frames.last().unwrap().velocities.chunks(3).all(|v| v[1] < 0.0));
    // Two bodies, a block and a sphere, from an array of tables.
    let text = format!(
        "{}\n[[block_drop_3d.geometry.bodies]]\nvelocity = [1.0, 0.0, 0.0]\nshape = {{ sphere = {{ center = [0.5, 0.25, 0.5], radius = 0.15 }} }}\n",
        builtin_text("block_drop_3d")
    );
    let two = Scene::from_toml_str(&text, "two").unwrap();
    assert_eq!(two.block_drop_3d.as_ref().unwrap().geometry.bodies.len(), 2);
    let Stepper::Wcsph3d(s) = two.build(0, None).unwrap() else { panic!("not 3D WCSPH") };
    assert!(s.n_fluid() > 8 * 8 * 8);
}

/// Bad 3D scenes are typed errors naming the key.
#[test]
fn bad_3d_scenes_name_the_key() {
    let build = |text: &str| Scene::from_toml_str(text, "bad").unwrap().build(0, None);
    // IISPH has no 3D stepper.
    assert_eq!(field_of(build(&with_key("dam_break_3d", "solver", "\"iisph\""))), "dam_break_3d.solver");
    // Unknown keys, at every level.
    assert_eq!(parse_field(&builtin_text("dam_break_3d").replace("depth = 0.5", "depth = 0.5\nwidth = 1.0")), "width");
    assert_eq!(parse_field(&format!("{}\n[dam_break_3d.iisph]\nomega = 0.5\n", builtin_text("dam_break_3d"))), "iisph");
    assert_eq!(
        parse_field(&builtin_text("block_drop_3d").replace("\ndx = 0.05", "\ndx = 0.05\nspacing = 0.1")),
        "spacing"
    );
    assert_eq!(
        parse_field(
            &builtin_text("block_drop_3d")
                .replace("velocity = [0.0, 0.0, 0.0]", "velocity = [0.0, 0.0, 0.0]\nspin = 1.0")
        ),
        "spin"
    );
    // A missing body field.
    assert_eq!(parse_field(&builtin_text("block_drop_3d").replace("velocity = [0.0, 0.0, 0.0]\n", "")), "velocity");
    // Bad values.
    assert_eq!(field_of(build(&with_key("dam_break_3d", "dx", "-0.1"))), "dam_break_3d.geometry.dx");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "dx", "1e-5"))), "dam_break_3d.geometry.dx");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "dx", "0.5"))), "dam_break_3d.geometry.dx");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "g", "-9.81"))), "dam_break_3d.geometry.g");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "h_over_dx", "0.0"))), "dam_break_3d.wcsph.h_over_dx");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "alpha", "-1.0"))), "dam_break_3d.wcsph.alpha");
    assert_eq!(field_of(build(&with_key("dam_break_3d", "cfl", "2.0"))), "dam_break_3d.wcsph.cfl");
    let dfsph = |extra: &str| {
        let text = with_key("dam_break_3d", "solver", "\"dfsph\"");
        build(&format!("{text}\n[dam_break_3d.dfsph]\n{extra}\n"))
    };
    // The 2D omega diverges in 3D: refused, naming the key.
    assert_eq!(field_of(dfsph("omega = 0.5")), "dam_break_3d.dfsph.omega");
    assert_eq!(field_of(dfsph("cfl = 0.0")), "dam_break_3d.dfsph.cfl");
    assert_eq!(field_of(build(&with_key("block_drop_3d", "dx", "-0.05"))), "block_drop_3d.geometry.dx");
    assert_eq!(
        field_of(build(&with_key("block_drop_3d", "box_size", "[1.0, -1.0, 1.0]"))),
        "block_drop_3d.geometry.box_size"
    );
    assert_eq!(
        field_of(build(&with_key(
            "block_drop_3d",
            "shape",
            "{ block = { lo = [0.3, 0.5, 0.3], hi = [0.7, 1.9, 0.7] } }"
        ))),
        "block_drop_3d.geometry.bodies"
    );
    assert_eq!(field_of(build(&with_key("block_drop_3d", "delta", "-0.1"))), "block_drop_3d.wcsph.delta");
    // Two sections.
    let two = format!("{}\n[block_drop_3d]\n", builtin_text("dam_break_3d"));
    assert_eq!(parse_field(&two), "shock_tube");
}

/// A partial `[dam_break_3d.dfsph]` table keeps the 3D defaults for the keys it omits (the
/// 3D `omega`, not the 2D one that diverges in 3D); unknown keys in it are still named.
#[test]
fn partial_dfsph_table_keeps_the_3d_defaults() {
    let text = with_key("dam_break_3d", "solver", "\"dfsph\"");
    let sc = Scene::from_toml_str(&format!("{text}\n[dam_break_3d.dfsph]\ncfl = 0.3\n"), "p").unwrap();
    let p = sc.dam_break_3d.unwrap().dfsph;
    assert_eq!(p, pbdl_particles::dfsph::DfsphParams { cfl: 0.3, ..pbdl_particles::dfsph::DfsphParams::default_3d() });
    assert!(matches!(sc.build(0, None).unwrap(), Stepper::Dfsph3d(_)));
    assert_eq!(parse_field(&format!("{text}\n[dam_break_3d.dfsph]\nbogus = 1\n")), "bogus");
    assert_eq!(parse_field(&format!("{text}\n[dam_break_3d.dfsph]\ncfl = \"fast\"\n")), "cfl");
}
