//! Helpers shared by the convolution test files (`mod common;`); each file uses only some.
#![allow(dead_code)]

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed;

/// f32 agreement (with candle, or of two kernel paths): max |a - b| relative to max |b|.
pub const F32_TOL: f64 = 1e-5;
/// Finite-difference gradient checks in f64.
pub const GRAD_TOL: f64 = 1e-6;
/// f64 agreement (with a direct loop, or of two kernel paths).
pub const F64_TOL: f64 = 1e-12;

/// Standard-normal samples of `shape`, seeded.
pub fn randn(shape: &[usize], dtype: DType, seed: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, dtype, &Device::Cpu, seed).unwrap()
}

/// max |t| over all elements, in f64.
pub fn max_abs(t: &Tensor) -> f64 {
    t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap()
}

/// max |a - b| / max |b|.
pub fn rel_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.dims(), b.dims(), "shapes differ");
    max_abs(&(a - b).unwrap()) / max_abs(b).max(1e-30)
}
