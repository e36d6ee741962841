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
    draw(shape.into(), dtype, device, seed, |r| {
        let z: f64 = StandardNormal.sample(r);
        mean + std * z
    })
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
    draw(shape.into(), dtype, device, seed, |r| r.random_range(lo..hi))
}

/// A tensor of `shape` whose elements, in row-major order, are `sample` drawn in `f64` from
/// [`rng`]`(seed)` and then converted to `dtype`.
fn draw(
    shape: Shape,
    dtype: DType,
    device: &Device,
    seed: u64,
    mut sample: impl FnMut(&mut StdRng) -> f64,
) -> candle_core::Result<Tensor> {
    let mut r = rng(seed);
    let data: Vec<f64> = (0..shape.elem_count()).map(|_| sample(&mut r)).collect();
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
