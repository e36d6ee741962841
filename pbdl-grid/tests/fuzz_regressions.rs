//! Regressions from `cargo xtask stress fuzz` (targets grid_scene and grid_init): each input
//! panicked or overflowed before its fix and must now give a typed error.

use candle_core::{DType, Device, Tensor};
use pbdl_grid::scene::{Scene, SceneError};

fn taylor_green_16() -> Scene {
    Scene::builtin("taylor_green").unwrap().with_resolution(16).with_steps(1)
}

/// `--init` with a trajectory of zero frames (`[0, 2, Y, X]`) used `T - 1` (underflow).
#[test]
fn init_trajectory_without_frames_is_a_typed_error() {
    let mut sim = taylor_green_16().build().unwrap();
    let empty = Tensor::zeros((0, 2, 16, 16), DType::F32, &Device::Cpu).unwrap();
    match sim.set_fields(&[("velocity".to_string(), empty)]) {
        Err(SceneError::Invalid { reason, .. }) => assert!(reason.contains("no frames"), "{reason}"),
        other => panic!("expected SceneError::Invalid, got {other:?}"),
    }
}

/// An init field with no cells (`[2, 0, 16]`) reached the max/resample of an empty tensor.
#[test]
fn empty_init_field_is_a_typed_error() {
    let mut sim = taylor_green_16().build().unwrap();
    let empty = Tensor::zeros((2, 0, 16), DType::F32, &Device::Cpu).unwrap();
    match sim.set_fields(&[("velocity".to_string(), empty)]) {
        Err(SceneError::Invalid { reason, .. }) => assert!(reason.contains("empty"), "{reason}"),
        other => panic!("expected SceneError::Invalid, got {other:?}"),
    }
    let mut heat = Scene::builtin("heat").unwrap().with_resolution(16).build().unwrap();
    let empty = Tensor::zeros((3, 1, 0, 16), DType::F64, &Device::Cpu).unwrap();
    assert!(matches!(heat.set_fields(&[("temperature".to_string(), empty)]), Err(SceneError::Invalid { .. })));
}

/// `max_wavenumber = 4294967295` overflowed `a * a + b * b` (i32) and would have evaluated
/// ~10^19 modes per cell.
#[test]
fn huge_random_mode_wavenumber_is_a_typed_error() {
    let (_, text) = pbdl_grid::scene::BUILTIN.iter().find(|(n, _)| *n == "kolmogorov").unwrap();
    let text = text.replace("max_wavenumber = 4", "max_wavenumber = 4294967295");
    assert!(text.contains("4294967295"));
    match Scene::from_toml_str(&text, "fuzz.toml") {
        Err(SceneError::Invalid { field, .. }) => assert_eq!(field, "init.max_wavenumber"),
        other => panic!("expected SceneError::Invalid, got {other:?}"),
    }
}

/// A grid whose cell count overflows `usize` is refused by validation.
#[test]
fn overflowing_cell_count_is_a_typed_error() {
    let (_, text) = pbdl_grid::scene::BUILTIN.iter().find(|(n, _)| *n == "heat").unwrap();
    let text = text.replace("nx = 64", "nx = 9223372036854775807");
    match Scene::from_toml_str(&text, "fuzz.toml") {
        Err(SceneError::Invalid { field, .. }) => assert_eq!(field, "grid"),
        other => panic!("expected SceneError::Invalid, got {other:?}"),
    }
}
