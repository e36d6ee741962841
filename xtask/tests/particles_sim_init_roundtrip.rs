//! `cargo xtask sim particles` on a shock tube with moving ends: the trajectory holds pressure,
//! internal energy and smoothing length, and its last frame read back with `--init` continues
//! the run (the restart's first frame is the file's last; one more frame matches the
//! uninterrupted run).

use candle_core::Tensor;
use std::path::Path;
use std::process::Command;

fn xtask(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().unwrap();
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// A small Toro-1-like tube (`u_L = 0.75`) with `frames` frames of 0.01.
fn scene(dir: &Path, frames: usize) -> String {
    let text = format!(
        r#"name = "moving_tube"
frames = {frames}
frame_dt = 0.01

[shock_tube]
n = 120
left = {{ rho = 1.0, u = 0.75, p = 1.0 }}
right = {{ rho = 0.125, u = -0.2, p = 0.1 }}
gamma = 1.4
x_lo = -0.5
x_hi = 0.5
x0 = 0.0
"#
    );
    let path = dir.join(format!("moving_tube_{frames}.toml"));
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn arrays(path: &Path) -> Vec<(String, Tensor)> {
    pbdl_core::io::read_npz(path).unwrap()
}

/// Frame `k` (negative: from the end) of the `[T, N]` or `[T, N, 1]` array `name`.
fn frame(arrays: &[(String, Tensor)], name: &str, k: isize) -> Vec<f64> {
    let t = &arrays.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no `{name}`")).1;
    let frames = t.dim(0).unwrap() as isize;
    let k = if k < 0 { frames + k } else { k };
    t.get(k as usize).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap()
}

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs() / scale))
}

#[test]
fn shock_tube_output_has_p_e_h_and_restarts_with_init() {
    let dir = tempfile::tempdir().unwrap();
    let (two, three, rest) = (dir.path().join("two"), dir.path().join("three"), dir.path().join("rest"));
    xtask(&["sim", "particles", &scene(dir.path(), 2), "--out", two.to_str().unwrap()]);
    xtask(&["sim", "particles", &scene(dir.path(), 3), "--out", three.to_str().unwrap()]);
    let first = two.join("moving_tube_seed0.npz");
    let a = arrays(&first);
    for name in ["positions", "velocities", "density", "mass", "pressure", "internal_energy", "smoothing_length"] {
        let t = &a.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no `{name}` in the trajectory")).1;
        assert_eq!(t.dim(0).unwrap(), 3, "{name}: {:?}", t.dims());
    }
    // P = (γ - 1) ρ e, per particle.
    let (rho, p, e) = (frame(&a, "density", -1), frame(&a, "pressure", -1), frame(&a, "internal_energy", -1));
    let eos: Vec<f64> = rho.iter().zip(&e).map(|(r, e)| 0.4 * r * e).collect();
    assert!(max_rel(&p, &eos) < 1e-12);

    // Restart from the last frame and run one more frame.
    xtask(&[
        "sim",
        "particles",
        &scene(dir.path(), 1),
        "--init",
        first.to_str().unwrap(),
        "--out",
        rest.to_str().unwrap(),
    ]);
    let b = arrays(&rest.join("moving_tube_seed0.npz"));
    // The restart's first frame is the file's last: positions, velocities, masses and energies
    // exactly; density, pressure and smoothing length re-solved from them to round-off.
    for name in ["positions", "velocities", "mass", "internal_energy", "viscosity_alpha"] {
        assert_eq!(frame(&a, name, -1), frame(&b, name, 0), "{name}");
    }
    for name in ["density", "pressure", "smoothing_length"] {
        let d = max_rel(&frame(&a, name, -1), &frame(&b, name, 0));
        assert!(d < 1e-9, "{name}: restart differs by {d:.2e}");
    }
    let c = arrays(&three.join("moving_tube_seed0.npz"));
    // The buffers restart where the run had moved them (`fixed_positions`), and after one more
    // frame they are where the uninterrupted run's are.
    let fixed = |arrays: &[(String, Tensor)]| {
        let t = &arrays.iter().find(|(n, _)| n == "fixed_positions").expect("fixed_positions").1;
        t.flatten_all().unwrap().to_vec1::<f64>().unwrap()
    };
    let d = max_rel(&fixed(&c), &fixed(&b));
    assert!(d < 1e-12, "buffers differ by {d:.2e}");
    for name in ["positions", "velocities", "density", "pressure"] {
        let d = max_rel(&frame(&c, name, -1), &frame(&b, name, -1));
        eprintln!("{name}: restart vs uninterrupted after one more frame: {d:.2e}");
        assert!(d < 1e-3, "{name}: restart differs from the uninterrupted run by {d:.2e}");
    }
}

/// `sim particles` on a short 3D block drop (a `[block_drop_3d]` file): `[T, N, 3]` positions
/// and velocities, and `--init` from its last frame starts the next run there.
#[test]
fn block_drop_3d_writes_3d_arrays_and_restarts_with_init() {
    let dir = tempfile::tempdir().unwrap();
    let text = r#"name = "drop3d"
frames = 2
frame_dt = 0.004

[block_drop_3d.geometry]
box_size = [1.0, 1.0, 1.0]
dx = 0.1
g = 9.81
rho0 = 1000.0
c0_factor = 10.0

[[block_drop_3d.geometry.bodies]]
velocity = [0.5, 0.0, 0.0]
shape = { block = { lo = [0.3, 0.4, 0.3], hi = [0.7, 0.8, 0.7] } }
"#;
    let path = dir.path().join("drop3d.toml");
    std::fs::write(&path, text).unwrap();
    let (first, rest) = (dir.path().join("first"), dir.path().join("rest"));
    xtask(&["sim", "particles", path.to_str().unwrap(), "--out", first.to_str().unwrap()]);
    let npz = first.join("drop3d_seed0.npz");
    let a = arrays(&npz);
    let dims = |a: &[(String, Tensor)], name: &str| a.iter().find(|(n, _)| n == name).unwrap().1.dims().to_vec();
    assert_eq!(dims(&a, "positions"), [3, 64, 3]);
    assert_eq!(dims(&a, "velocities"), [3, 64, 3]);
    assert_eq!(dims(&a, "density"), [3, 64]);
    assert_eq!(dims(&a, "mass"), [3, 64]);
    xtask(&[
        "sim",
        "particles",
        path.to_str().unwrap(),
        "--init",
        npz.to_str().unwrap(),
        "--out",
        rest.to_str().unwrap(),
    ]);
    let b = arrays(&rest.join("drop3d_seed0.npz"));
    assert_eq!(frame(&b, "positions", 0), frame(&a, "positions", -1));
    assert_eq!(frame(&b, "velocities", 0), frame(&a, "velocities", -1));
}
