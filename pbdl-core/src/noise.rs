//! Seeded noise for initial conditions, data generation and samplers: independent streams from
//! one seed, and smooth periodic random fields (spectral, whole tensors; Perlin, point by point).
//!
//! | function | what it gives |
//! |---|---|
//! | [`stream_seed`] | the seed of stream `k` of a run seed (SplitMix64 finaliser): sampler steps, batch chunks and data items that must not share random numbers |
//! | [`power_law_noise`] | a periodic random field with Fourier amplitudes `1 / k^2` above a cut (PhiFlow's `Noise(smoothness=1)`), zero mean and unit variance per batch entry |
//! | [`perlin_1d`], [`perlin_2d`] | seeded periodic Perlin gradient noise, evaluated point by point in lattice units (the particle noise scenes' initial density and velocity) |
//!
//! Plain Gaussian and uniform tensors are [`crate::seed::randn`] and [`crate::seed::rand_uniform`].
//!
//! ```
//! use pbdl_core::noise::{power_law_noise, stream_seed};
//!
//! assert_ne!(stream_seed(7, 0), stream_seed(7, 1));
//! let f = power_law_noise(2, 1, 32, 16.0, stream_seed(7, 3))?;
//! assert_eq!(f.dims(), &[2, 1, 32, 32]);
//! let var = f.sqr()?.mean_all()?.to_scalar::<f64>()?;
//! assert!((var - 1.0).abs() < 1e-9);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

mod perlin;

pub use perlin::{perlin_1d, perlin_2d};

use crate::Result;
use candle_core::{DType, Device, Tensor};
use std::f64::consts::PI;

/// The seed of stream `stream` of `seed`: a SplitMix64 finaliser of `seed ^ stream * golden`, so
/// neighbouring streams give unrelated generators.
pub fn stream_seed(seed: u64, stream: u64) -> u64 {
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A periodic random field `[batch, channels, n, n]` (f64): complex Gaussian Fourier
/// coefficients with amplitude `1 / kappa^2` (`kappa` in periods per domain) where
/// `kappa^2 > min_kappa2` and zero below (a high-pass cut), the real part of the inverse
/// transform, scaled to zero mean and unit standard deviation per batch entry (over channels
/// and cells). The coefficients are drawn in f32.
pub fn power_law_noise(batch: usize, channels: usize, n: usize, min_kappa2: f64, seed: u64) -> Result<Tensor> {
    let dev = Device::Cpu;
    let freq = |k: usize| if k < n.div_ceil(2) { k as f64 } else { k as f64 - n as f64 };
    let w: Vec<f64> = (0..n * n)
        .map(|idx| {
            let k2 = freq(idx / n).powi(2) + freq(idx % n).powi(2);
            if k2 > min_kappa2 {
                1.0 / k2
            } else {
                0.0
            }
        })
        .collect();
    let w = Tensor::from_vec(w, (1, n, n), &dev)?;
    let (co, si): (Vec<f64>, Vec<f64>) = (0..n * n)
        .map(|idx| {
            let a = 2.0 * PI * ((idx / n) * (idx % n)) as f64 / n as f64;
            (a.cos(), a.sin())
        })
        .unzip();
    let co = Tensor::from_vec(co, (n, n), &dev)?;
    let si = Tensor::from_vec(si, (n, n), &dev)?;
    let m = batch * channels;
    // f32: the noise needs no more precision, and it dominates the cost of data generators.
    let coef = |seed: u64| -> Result<Tensor> {
        let c = crate::seed::randn((m, n, n), 0.0, 1.0, DType::F32, &dev, seed)?;
        Ok(c.broadcast_mul(&w.to_dtype(DType::F32)?)?)
    };
    let (cr, ci) = (coef(seed)?, coef(seed ^ 0x9e37_79b9_7f4a_7c15)?);
    let (co, si) = (co.to_dtype(DType::F32)?, si.to_dtype(DType::F32)?);
    let host = |t: &Tensor| -> Result<Vec<f32>> { Ok(t.flatten_all()?.to_vec1::<f32>()?) };
    let (cr, ci, co, si) = (host(&cr)?, host(&ci)?, host(&co)?, host(&si)?);
    // Re(E C E) with E = cos + i sin (symmetric): P + iQ = E C, then Re((P + iQ) E) = P cos - Q sin.
    let p = combine(&products(&co, &cr, m, n, true), &products(&si, &ci, m, n, true), -1.0);
    let q = combine(&products(&co, &ci, m, n, true), &products(&si, &cr, m, n, true), 1.0);
    let f = combine(&products(&co, &p, m, n, false), &products(&si, &q, m, n, false), -1.0);
    let f = Tensor::from_vec(f, (m, n, n), &dev)?.to_dtype(DType::F64)?;
    let f = f.reshape((batch, channels * n * n))?;
    let f = f.broadcast_sub(&f.mean_keepdim(1)?)?;
    let std = f.sqr()?.mean_keepdim(1)?.sqrt()?;
    Ok(f.broadcast_div(&std)?.reshape((batch, channels, n, n))?)
}

/// The `m` products of `n x n` f32 matrices `e * x_i` (`e_left`) or `x_i * e` with the shared
/// matrix `e`, on [`crate::matmul`]: parallel over the batch when the thread policy says the
/// whole is big enough, each product on one thread (a 64 x 64 product split over threads costs
/// more in wake-ups than it saves; the values do not depend on the split).
fn products(e: &[f32], x: &[f32], m: usize, n: usize, e_left: bool) -> Vec<f32> {
    use crate::matmul::{matmul, Mat, Threads};
    use rayon::prelude::*;
    let mut out = vec![0f32; m * n * n];
    let one = |(xi, oi): (&[f32], &mut [f32])| {
        let (a, b) = if e_left { (e, xi) } else { (xi, e) };
        matmul(oi, n, false, Mat::row_major(a, n), Mat::row_major(b, n), (n, n, n), 1.0, Threads::Serial);
    };
    if m > 1 && crate::threads::parallel(m * n * n) {
        x.par_chunks(n * n).zip(out.par_chunks_mut(n * n)).for_each(one);
    } else {
        x.chunks(n * n).zip(out.chunks_mut(n * n)).for_each(one);
    }
    out
}

/// `a + sign * b` elementwise in f32.
fn combine(a: &[f32], b: &[f32], sign: f32) -> Vec<f32> {
    a.iter().zip(b).map(|(x, y)| if sign < 0.0 { x - y } else { x + y }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_law_noise_has_no_power_below_the_cut_and_decays_as_k_to_the_minus_2() {
        // The field's own Fourier amplitudes: zero where kappa^2 <= cut, and the mean power
        // ratio between two shells follows |1/k^2|^2 = k^-4.
        let n = 32;
        let f = power_law_noise(4, 1, n, 4.5, 11).unwrap();
        let v: Vec<f64> = f.flatten_all().unwrap().to_vec1().unwrap();
        let power = |kx: usize, ky: usize| -> f64 {
            let mut s = 0.0;
            for b in 0..4 {
                let (mut re, mut im) = (0.0, 0.0);
                for y in 0..n {
                    for x in 0..n {
                        let a = -2.0 * PI * ((kx * x + ky * y) as f64) / n as f64;
                        let val = v[b * n * n + y * n + x];
                        re += val * a.cos();
                        im += val * a.sin();
                    }
                }
                s += re * re + im * im;
            }
            s
        };
        let total: f64 = v.iter().map(|x| x * x).sum::<f64>() * (n * n) as f64;
        // f32 coefficients: round-off leaves ~1e-14 of the power there; a mode above the cut
        // carries ~1e-3.
        let (p11, p20) = (power(1, 1) / total, power(2, 0) / total);
        assert!(p11 < 1e-10 && p20 < 1e-10, "below the cut: {p11:e} {p20:e}");
        // Shells at kappa^2 = 9 and 36: expected power ratio (36/9)^2 = 16 on average.
        let p3: f64 = [(3, 0), (0, 3)].iter().map(|&(a, b)| power(a, b)).sum();
        let p6: f64 = [(6, 0), (0, 6)].iter().map(|&(a, b)| power(a, b)).sum();
        let ratio = p3 / p6;
        assert!((2.0..130.0).contains(&ratio), "power ratio {ratio} should scatter around 16");
    }

    /// FNV-1a of the f64 bits of a field: a pin of its exact values.
    fn fingerprint(t: &Tensor) -> u64 {
        t.flatten_all()
            .unwrap()
            .to_vec1::<f64>()
            .unwrap()
            .iter()
            .fold(0xcbf2_9ce4_8422_2325u64, |h, v| (h ^ v.to_bits()).wrapping_mul(0x0100_0000_01b3))
    }

    /// The exact numbers of the metric data generator's noise (11 variants x 2 channels at
    /// 64^2, and a small odd case), recorded before the products moved off candle's matmul.
    #[test]
    fn power_law_noise_values_are_pinned() {
        let big = fingerprint(&power_law_noise(11, 2, 64, 16.4, 5).unwrap());
        let small = fingerprint(&power_law_noise(3, 1, 17, 2.0, 9).unwrap());
        assert_eq!((big, small), (0x1b65_7f30_25ff_7717, 0x5fd8_1352_3c63_bc84));
    }
}
