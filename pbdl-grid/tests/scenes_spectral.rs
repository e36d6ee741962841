//! The `navier_stokes_spectral` scene kind: operators, accuracy on Taylor-Green through the
//! scene, typed errors for keys it cannot take, and `set_fields` (`--init`) with cell-centred
//! velocities and with another scene's output.

use candle_core::{DType, Device, Tensor};
use pbdl_grid::scene::{Scene, SceneError, State};

const TGV: &str = include_str!("../scenes/taylor_green_spectral.toml");

fn invalid_field(err: SceneError) -> String {
    match err {
        SceneError::Invalid { field, .. } => field,
        other => panic!("expected SceneError::Invalid, got {other:?}: {other}"),
    }
}

fn vals(t: &Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap()
}

fn field(sim: &pbdl_grid::scene::Simulation, name: &str) -> Tensor {
    sim.fields().unwrap().into_iter().find(|(n, _)| n == name).unwrap().1
}

#[test]
fn taylor_green_through_the_scene_matches_the_exact_solution() {
    for (precision, bar) in [("f32", 2e-6), ("f64", 2e-9)] {
        let text = TGV.replace("[grid]", &format!("precision = \"{precision}\"\n[grid]"));
        let mut sim = Scene::from_toml_str(&text, "tgv").unwrap().with_resolution(32).build().unwrap();
        assert_eq!(
            sim.operators(),
            [
                "spectral.fft",
                "spectral.advection_dealiased_2/3",
                "spectral.viscosity_implicit",
                "time_stepping.imex_cn_rk4"
            ]
        );
        sim.run(|_| {}).unwrap();
        let t = sim.time();
        assert!((t - 1.0).abs() < 1e-12);
        let d = (-2.0f64 * 0.01 * t).exp();
        let u = vals(&field(&sim, "velocity"));
        let (n, h) = (32usize, std::f64::consts::TAU / 32.0);
        let (mut num, mut den) = (0.0, 0.0);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = ((i as f64 + 0.5) * h, (j as f64 + 0.5) * h);
                let (ue, ve) = (x.sin() * y.cos() * d, -x.cos() * y.sin() * d);
                num += (u[j * n + i] - ue).powi(2) + (u[n * n + j * n + i] - ve).powi(2);
                den += ue * ue + ve * ve;
            }
        }
        let err = (num / den).sqrt();
        println!("taylor_green_spectral 32^2 {precision}: rel L2 {err:.3e} in {} steps", sim.step_index());
        assert!(err < bar, "{precision}: {err:.3e}");
        // The MAC state is the face interpolation: kinetic energy as the centred one.
        let State::Velocity(mac) = sim.state() else { panic!("velocity state") };
        let e_mac: f64 = vals(mac.values()).iter().map(|v| v * v).sum();
        let e_c: f64 = u.iter().map(|v| v * v).sum();
        assert!((e_mac / e_c - 1.0).abs() < 1e-5, "{e_mac} vs {e_c}");
    }
}

#[test]
fn keys_the_spectral_kind_cannot_take_are_typed_errors() {
    let walls = TGV.replace(
        "nu = 0.01\n",
        "nu = 0.01\n[physics.boundaries]\nx_lo = { kind = \"no_slip\" }\nx_hi = { kind = \"no_slip\" }\ny_lo = { kind = \"periodic\" }\ny_hi = { kind = \"periodic\" }\n",
    );
    let e = Scene::from_toml_str(&walls, "walls").unwrap_err();
    assert_eq!(invalid_field(e), "physics.boundaries.x_lo");
    let euler = TGV.replace("cfl = 0.5", "cfl = 0.5\nscheme = \"forward_euler\"");
    let e = Scene::from_toml_str(&euler, "euler").unwrap().build().unwrap_err();
    assert_eq!(invalid_field(e), "time.scheme");
    let obstacle = format!("{TGV}\n[[obstacles]]\nkind = \"circle\"\ncenter = [3.0, 3.0]\nradius = 0.5\n");
    let e = Scene::from_toml_str(&obstacle, "obstacle").unwrap().build().unwrap_err();
    assert_eq!(invalid_field(e), "obstacles");
    let dt = TGV.replace("cfl = 0.5", "dt = 1.0");
    let e = Scene::from_toml_str(&dt, "dt").unwrap().build().unwrap_err();
    assert_eq!(invalid_field(e), "time.dt");
    let unknown = TGV.replace("nu = 0.01\n", "nu = 0.01\nviscosity = 2.0\n");
    assert!(matches!(Scene::from_toml_str(&unknown, "unknown").unwrap_err(), SceneError::Parse { .. }));
}

#[test]
fn init_takes_centred_velocity_and_other_scenes_output() {
    // A decaying-turbulence frame (32^2, f64) written as `velocity` [2, Y, X]: reading it back
    // gives the same state (the velocity is already divergence-free and resolved).
    let mut a = Scene::builtin("decaying_turbulence").unwrap().with_resolution(32).with_steps(5).build().unwrap();
    a.run(|_| {}).unwrap();
    let v = field(&a, "velocity");
    assert_eq!(v.dims(), [2, 32, 32]);
    let mut b = Scene::builtin("decaying_turbulence").unwrap().with_resolution(32).with_steps(5).build().unwrap();
    let used = b.set_fields(&[("velocity".into(), v.clone())]).unwrap();
    assert_eq!(used, ["velocity"]);
    let back = field(&b, "velocity");
    let d = vals(&(back - &v).unwrap()).iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(d < 1e-12, "round trip {d:.2e}");
    // The same frame stepped on: a continues, b restarts from a's frame; both take 5 more steps.
    a.run(|_| {}).unwrap_or_else(|e| panic!("{e}"));
    // Its velocity_mac alone (a trajectory [T, 2, Y, X]) also starts a spectral scene...
    let mac = field(&b, "velocity_mac").unsqueeze(0).unwrap();
    let mut c = Scene::builtin("decaying_turbulence").unwrap().with_resolution(32).with_steps(1).build().unwrap();
    assert_eq!(c.set_fields(&[("velocity_mac".into(), mac.clone())]).unwrap(), ["velocity_mac"]);
    let d = vals(&(field(&c, "velocity") - &v).unwrap()).iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(d < 1e-12, "faces -> centres {d:.2e}");
    // ...and a second-order `navier_stokes` scene on the same grid.
    let ns = include_str!("../scenes/taylor_green.toml").replace("[grid]", "precision = \"f64\"\n[grid]");
    let mut fv = Scene::from_toml_str(&ns, "fv").unwrap().with_resolution(32).build().unwrap();
    assert_eq!(fv.set_fields(&[("velocity_mac".into(), mac)]).unwrap(), ["velocity_mac"]);
    // No array it can read: the error lists what the file has.
    let e = c.set_fields(&[("density".into(), Tensor::zeros((32, 32), DType::F64, &Device::Cpu).unwrap())]);
    assert!(e.unwrap_err().to_string().contains("density"));
}

#[test]
fn decaying_turbulence_runs_finite_with_energy_decaying() {
    let mut sim = Scene::builtin("decaying_turbulence").unwrap().with_resolution(48).with_steps(60).build().unwrap();
    let energy = |sim: &pbdl_grid::scene::Simulation| vals(&field(sim, "velocity")).iter().map(|v| v * v).sum::<f64>();
    let mut last = energy(&sim);
    let mut checked = 0;
    sim.run_observed(|_, _| checked += 1).unwrap();
    assert_eq!(checked, 60);
    let e = energy(&sim);
    assert!(e.is_finite() && e < last, "{e} vs {last}");
    last = e;
    assert!(last > 0.5 * energy(&Scene::builtin("decaying_turbulence").unwrap().with_resolution(48).build().unwrap()));
}

#[test]
fn three_d_spectral_scene_runs_writes_and_reads_back() {
    // The 3D Taylor-Green vortex (Brachet et al. 1983) at 16^3 in f64: kinetic energy starts at
    // 1/8 (mean of (sin x cos y cos z)^2 + (cos x sin y cos z)^2) and only decays.
    let text = TGV
        .replace("nx = 64\nny = 64", "nx = 16\nny = 16\nnz = 16\nlz = 6.283185307179586")
        .replace("[grid]", "precision = \"f64\"\n[grid]")
        .replace("nu = 0.01", "nu = 0.05");
    let mut sim = Scene::from_toml_str(&text, "tgv3d").unwrap().build().unwrap();
    assert!(sim.operators().contains(&"spectral.leray_projection"), "{:?}", sim.operators());
    let energy = |sim: &pbdl_grid::scene::Simulation| {
        let v = vals(&field(sim, "velocity"));
        0.5 * v.iter().map(|x| x * x).sum::<f64>() / (16.0 * 16.0 * 16.0)
    };
    let e0 = energy(&sim);
    assert!((e0 - 0.125).abs() < 1e-12, "{e0}");
    let traj = sim.run(|_| {}).unwrap();
    let e1 = energy(&sim);
    println!("3D Taylor-Green 16^3: E {e0:.6} -> {e1:.6} in {} steps", sim.step_index());
    assert!(e1 < e0 && e1 > 0.5 * e0);
    let State::Velocity3d(u) = sim.state() else { panic!("3D velocity state") };
    assert_eq!(u.dims(), [1, 3, 16, 16, 16]);
    let stacked = traj.stacked().unwrap();
    let v = &stacked.iter().find(|(n, _)| n == "velocity").unwrap().1;
    assert_eq!(v.dims(), [traj.times.len(), 3, 16, 16, 16]);
    // --init with the trajectory (last frame) restarts from the same state.
    let mut b = Scene::from_toml_str(&text, "tgv3d").unwrap().build().unwrap();
    assert_eq!(b.set_fields(&[("velocity".into(), v.clone())]).unwrap(), ["velocity"]);
    let d =
        vals(&(field(&b, "velocity") - field(&sim, "velocity")).unwrap()).iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(d < 1e-13, "{d:.2e}");
    // Wrong size: a typed error naming the expected shape.
    let small = Tensor::zeros((3, 8, 16, 16), DType::F64, &Device::Cpu).unwrap();
    assert!(b.set_fields(&[("velocity".into(), small)]).unwrap_err().to_string().contains("[3, 16, 16, 16]"));
    // nz > 1 on a kind without a 3D form is refused.
    let e = Scene::from_toml_str(&text.replace("navier_stokes_spectral", "navier_stokes"), "x").unwrap_err();
    assert_eq!(invalid_field(e), "grid.nz");
    // Renders: the middle z slice.
    let dir = std::env::temp_dir().join(format!("pbdl_tgv3d_{}", std::process::id()));
    let files = pbdl_grid::scene::write_trajectory(&sim, &traj, &dir).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(files.iter().any(|f| f.to_string_lossy().ends_with("taylor_green_spectral.npz")), "{files:?}");
    #[cfg(feature = "viz")]
    assert!(files.iter().any(|f| f.to_string_lossy().ends_with("_vorticity.gif")), "{files:?}");
}
