//! Seeded randomness: every stochastic helper in pbdl takes an explicit seed.
//!
//! candle's own `Tensor::randn` draws from a thread-local generator that cannot be seeded on the
//! CPU, so pbdl code draws through these functions instead: same seed, same numbers.

use candle_core::{DType, Device, Shape, Tensor};
use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

/// A deterministic generator for `seed`.
pub fn rng(seed: u64) -> StdRng {
    StdRng::seed_from_u64(seed)
}

/// Standard-normal samples (mean `mean`, standard deviation `std`) of the given shape.
pub fn randn(
    shape: impl Into<Shape>,
    mean: f64,
    std: f64,
    dtype: DType,
    device: &Device,
    seed: u64,
) -> candle_core::Result<Tensor> {
    let shape = shape.into();
    let mut r = rng(seed);
    let data: Vec<f64> = (0..shape.elem_count())
        .map(|_| {
            let z: f64 = StandardNormal.sample(&mut r);
            mean + std * z
        })
        .collect();
    Tensor::from_vec(data, shape, device)?.to_dtype(dtype)
}

/// Uniform samples in `[lo, hi)` of the given shape.
pub fn rand_uniform(
    shape: impl Into<Shape>,
    lo: f64,
    hi: f64,
    dtype: DType,
    device: &Device,
    seed: u64,
) -> candle_core::Result<Tensor> {
    let shape = shape.into();
    let mut r = rng(seed);
    let data: Vec<f64> = (0..shape.elem_count()).map(|_| r.random_range(lo..hi)).collect();
    Tensor::from_vec(data, shape, device)?.to_dtype(dtype)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_numbers_other_seed_other_numbers() {
        let a = randn(100, 0.0, 1.0, DType::F64, &Device::Cpu, 7).unwrap().to_vec1::<f64>().unwrap();
        let b = randn(100, 0.0, 1.0, DType::F64, &Device::Cpu, 7).unwrap().to_vec1::<f64>().unwrap();
        let c = randn(100, 0.0, 1.0, DType::F64, &Device::Cpu, 8).unwrap().to_vec1::<f64>().unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        let mean = a.iter().sum::<f64>() / 100.0;
        assert!(mean.abs() < 0.4, "sample mean {mean} of 100 N(0,1) draws");
        let u = rand_uniform(1000, -2.0, 3.0, DType::F32, &Device::Cpu, 1).unwrap().to_vec1::<f32>().unwrap();
        assert!(u.iter().all(|&v| (-2.0..3.0).contains(&v)));
    }
}
