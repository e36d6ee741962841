//! The pressure split of the 3D smoke step (what latent-space physics replaces on some steps):
//! `project_keep_pressure(step_unprojected(s)) == step(s)` (to round-off in f64; to the bit in
//! f32 and f64, since both run the same kernel), the kept pressure fed back through
//! `correct_with_pressure` gives the projection, the result is divergence-free, and a pressure of
//! the wrong shape is refused with a typed error.
//!
//! Bounds, stated before measuring: equality with the step `<= 1e-12 max|u|` in f64 (the kernel
//! is shared, so in fact 0) and exactly 0 in f32; the correction with the kept pressure equals
//! the projection exactly in f64 and to `1e-5 max|u|` in f32 (the kept pressure is rounded to
//! f32); divergence after the correction `||D u||_2 h / ||u||_2 < 1e-10` in f64 (sparse
//! Cholesky), and the unprojected velocity's is above `1e-4`.

use candle_core::{DType, Device, Tensor};
use pbdl_grid::grid3d::{fd, BoxPressure, Grid3d, MacField3d, Smoke3d, Smoke3dConfig, Smoke3dState};
use pbdl_grid::pressure::CgSettings;
use pbdl_grid::Error;

fn max_abs(t: &Tensor) -> f64 {
    t.to_dtype(DType::F64).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f64>().unwrap()
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    max_abs(&(a.to_dtype(DType::F64).unwrap() - b.to_dtype(DType::F64).unwrap()).unwrap())
}

fn l2(t: &Tensor) -> f64 {
    t.to_dtype(DType::F64).unwrap().sqr().unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap().sqrt()
}

fn rel_divergence(u: &MacField3d) -> f64 {
    l2(&fd::divergence(u).unwrap()) * u.grid().min_spacing() / l2(u.values()).max(f64::MIN_POSITIVE)
}

fn plume(grid: Grid3d, pressure: BoxPressure) -> Smoke3d {
    let mut cfg = Smoke3dConfig::plume(&grid, 0.5);
    cfg.buoyancy = 0.2;
    Smoke3d::new(grid, cfg, pressure).unwrap()
}

/// A moving plume state after `steps` steps from rest (batch 2, the second at another rate).
fn moving(f: &Smoke3d, dtype: DType, steps: usize) -> (Smoke3dState, Tensor) {
    let rate =
        Tensor::new(&[1.0f64, 0.5], &Device::Cpu).unwrap().reshape((2, 1, 1, 1, 1)).unwrap().to_dtype(dtype).unwrap();
    let mut s = f.rest(2, dtype).unwrap();
    for _ in 0..steps {
        s = f.step(&s, Some(&rate)).unwrap();
    }
    (s, rate)
}

#[test]
fn split_step_equals_the_step_and_the_kept_pressure_reproduces_the_projection_f64() {
    let g = Grid3d::new(10, 12, 8, 10.0, 12.0, 8.0).unwrap();
    for pressure in [BoxPressure::Cholesky, BoxPressure::Cg(CgSettings { rel_tol: 1e-10, ..CgSettings::default() })] {
        let f = plume(g, pressure);
        let (s, rate) = moving(&f, DType::F64, 8);
        let reference = f.step(&s, Some(&rate)).unwrap();
        let before = f.step_unprojected(&s, Some(&rate)).unwrap();
        let (projected, p) = f.project_keep_pressure(&before.velocity).unwrap();
        let scale = max_abs(reference.velocity.values());
        assert!(scale > 1e-3, "the plume must move ({scale})");
        let d = max_abs_diff(projected.values(), reference.velocity.values());
        assert!(d <= 1e-12 * scale, "split step differs from the step by {d}");
        assert_eq!(d, 0.0, "the split runs the step's kernel: expected bit equality");
        assert_eq!(max_abs_diff(&before.density, &reference.density), 0.0, "density differs");
        assert_eq!(p.dims(), [2, 1, 8, 12, 10]);
        assert_eq!(p.dtype(), DType::F64);
        assert!(max_abs(&p) > 0.0);
        // The kept pressure, given back, makes the same correction without a solve.
        let corrected = f.correct_with_pressure(&before.velocity, &p).unwrap();
        assert_eq!(max_abs_diff(corrected.values(), reference.velocity.values()), 0.0);
        // Divergence-free, while the unprojected velocity is not.
        assert!(rel_divergence(&corrected) < 1e-10, "{}", rel_divergence(&corrected));
        assert!(rel_divergence(&before.velocity) > 1e-4, "{}", rel_divergence(&before.velocity));
        // A zero pressure only zeroes the wall faces: the divergence stays.
        let zero = f.correct_with_pressure(&before.velocity, &p.zeros_like().unwrap()).unwrap();
        assert!(rel_divergence(&zero) > 1e-4);
    }
}

#[test]
fn split_step_equals_the_step_exactly_in_f32() {
    let g = Grid3d::cube(8, 8.0).unwrap();
    let f = plume(g, BoxPressure::default());
    let (mut s, rate) = moving(&f, DType::F32, 3);
    // Interval 1: every step through the split is the solver's run, to the bit.
    let mut reference = s.clone();
    for _ in 0..4 {
        reference = f.step(&reference, Some(&rate)).unwrap();
        let before = f.step_unprojected(&s, Some(&rate)).unwrap();
        let (velocity, p) = f.project_keep_pressure(&before.velocity).unwrap();
        assert_eq!(p.dtype(), DType::F32);
        let corrected = f.correct_with_pressure(&before.velocity, &p).unwrap();
        let scale = max_abs(velocity.values());
        assert!(max_abs_diff(corrected.values(), velocity.values()) <= 1e-5 * scale.max(1e-30));
        s = Smoke3dState { velocity, density: before.density };
        let a: Vec<f32> = s.velocity.values().flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f32> = reference.velocity.values().flatten_all().unwrap().to_vec1().unwrap();
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "velocity not bit-equal");
        assert_eq!(max_abs_diff(&s.density, &reference.density), 0.0);
    }
    assert!(rel_divergence(&s.velocity) < 1e-5);
}

#[test]
fn bad_pressure_and_velocity_are_refused_with_typed_errors() {
    let g = Grid3d::cube(8, 8.0).unwrap();
    let f = plume(g, BoxPressure::default());
    let (s, rate) = moving(&f, DType::F64, 1);
    let before = f.step_unprojected(&s, Some(&rate)).unwrap();
    for dims in [vec![1usize, 1, 8, 8, 8], vec![2, 2, 8, 8, 8], vec![2, 1, 8, 8, 7], vec![2, 8, 8, 8]] {
        let bad = Tensor::zeros(dims.clone(), DType::F64, &Device::Cpu).unwrap();
        let e = f.correct_with_pressure(&before.velocity, &bad).unwrap_err();
        assert!(matches!(e, Error::Shape { arg: "pressure", .. }), "{dims:?}: {e}");
    }
    let ints = Tensor::zeros((2, 1, 8, 8, 8), DType::U32, &Device::Cpu).unwrap();
    assert!(matches!(f.correct_with_pressure(&before.velocity, &ints), Err(Error::Invalid { .. })));
    // A velocity on another grid.
    let other = MacField3d::zeros(Grid3d::cube(6, 6.0).unwrap(), 1, DType::F64).unwrap();
    assert!(matches!(f.project_keep_pressure(&other), Err(Error::Invalid { .. })));
    assert!(f.step_unprojected(&Smoke3dState { velocity: other, density: s.density.clone() }, None).is_err());
}
