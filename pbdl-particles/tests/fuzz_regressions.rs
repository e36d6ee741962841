//! Regressions from `cargo xtask stress fuzz` (targets particles_scene and particles_init): each
//! input panicked, overflowed or ran without bound before its fix and must now give a typed error.

use candle_core::{DType, Device, Tensor};
use pbdl_particles::scene::{InitState, Scene, BUILTIN};
use pbdl_particles::Error;

fn builtin_text(name: &str) -> &'static str {
    BUILTIN.iter().find(|(n, _)| *n == name).map(|(_, t)| *t).unwrap()
}

/// The field named by a `SceneField` error of building `text` (parse and build).
fn scene_field_error(text: &str) -> String {
    let result = Scene::from_toml_str(text, "fuzz.toml").and_then(|s| s.build(0, None).map(|_| ()));
    match result {
        Err(Error::SceneField { field, .. }) => field,
        other => panic!("expected Error::SceneField, got {other:?}"),
    }
}

/// `--init` with a zero-frame trajectory `[0, n, d]` used `T - 1` (underflow).
#[test]
fn init_trajectory_without_frames_is_a_typed_error() {
    let pos = Tensor::zeros((0, 4, 2), DType::F64, &Device::Cpu).unwrap();
    match InitState::from_arrays(&[("positions".to_string(), pos)]) {
        Err(Error::SceneField { reason, .. }) => assert!(reason.contains("no frames"), "{reason}"),
        other => panic!("expected Error::SceneField, got {other:?}"),
    }
}

/// `--init` with no particles (`[0, 2]`) or zero-dimensional ones (`[4, 0]`).
#[test]
fn init_without_particles_is_a_typed_error() {
    for shape in [(0usize, 2usize), (4, 0)] {
        let pos = Tensor::zeros(shape, DType::F64, &Device::Cpu).unwrap();
        match InitState::from_arrays(&[("positions".to_string(), pos)]) {
            Err(Error::SceneField { reason, .. }) => assert!(reason.contains("no particles"), "{reason}"),
            other => panic!("expected Error::SceneField for {shape:?}, got {other:?}"),
        }
    }
}

/// Bad values after keys with multi-byte characters (the key lookup of the error message
/// sliced inside such a character; a unit test in `scene/mod.rs` pins the exact case).
#[test]
fn bad_values_after_multibyte_characters_are_typed_errors() {
    for text in ["xé= !", "#\u{fffd}= [", "name = \"é\"\nframes = é= 1\n", "\u{fffd}= nan x"] {
        assert!(Scene::from_toml_str(text, "fuzz.toml").is_err(), "{text:?}");
    }
}

/// Noise octaves beyond the bits of `usize` shifted with overflow (`base_cells << octave`).
#[test]
fn too_many_noise_octaves_is_a_typed_error() {
    let text = builtin_text("periodic_2d_box").replace("octaves = 3", "octaves = 70");
    assert!(text.contains("octaves = 70"));
    assert_eq!(scene_field_error(&text), "periodic_2d.octaves");
    let text = builtin_text("periodic_1d_noise").replace("octaves = 4", "octaves = 70");
    assert!(text.contains("octaves = 70"));
    assert_eq!(scene_field_error(&text), "periodic_1d.octaves");
}

/// `h_over_dx` / `eta` of 2^32 or 2^63: the lattice sum overflowed (IISPH) and walls or ghosts as
/// thick as the kernel support ran out of memory (WCSPH, 1D SPH).
#[test]
fn huge_smoothing_lengths_are_typed_errors() {
    let cases = [
        ("dam_break_iisph", "h_over_dx = 1.385", "h_over_dx = 9223372036854775807", "dam_break.iisph.h_over_dx"),
        ("dam_break", "h_over_dx = 1.3", "h_over_dx = 4294967295", "dam_break.wcsph.h_over_dx"),
        ("shock_tube", "eta = 1.2", "eta = 4294967295", "shock_tube.sph.eta"),
    ];
    for (scene, from, to, field) in cases {
        let text = builtin_text(scene).replace(from, to);
        assert!(text.contains(to), "{scene}: `{from}` not in the built-in scene");
        assert_eq!(scene_field_error(&text), field);
    }
}

/// A tank of `a = 1e308` metres overflowed to infinite lengths (an unbounded cell list).
#[test]
fn overflowing_tank_size_is_a_typed_error() {
    let text = builtin_text("dam_break_iisph").replace("\na = 1.0", "\na = 1e308");
    assert!(text.contains("\na = 1e308"));
    assert_eq!(scene_field_error(&text), "dam_break.geometry.a");
}

/// IISPH dam break with `h_over_dx = 0.005` (the fuzzer's over-memory input, 312 bytes): the
/// neighbour grid, sized by the support, asked for tens of millions of cells.
#[test]
fn tiny_smoothing_length_is_a_typed_error() {
    let text = "name = \"tiny_h\"\nframes = 25\nframe_dt = 0.02\n\n[dam_break]\nsolver = \"iisph\"\n\n\
                [dam_break.iisph]\nh_over_dx = 0.005\n";
    assert_eq!(scene_field_error(text), "dam_break.iisph.h_over_dx");
    assert!(pbdl_particles::DamBreak::default()
        .build(pbdl_particles::WcsphParams { h_over_dx: 0.005, ..Default::default() })
        .is_err());
}
