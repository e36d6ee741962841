//! The heat-equation physics of SMDP's inverse problem: a spectral heat step as a differentiable
//! candle op, Gaussian random fields with power spectrum `P(k) ~ k^-4`, the noisy forward
//! simulation, and the metrics (MSE of the re-simulated reconstruction, spectral error).
//!
//! The heat step multiplies each Fourier mode by `exp(-|k|^2 dt)`, `k` the integer frequency
//! (the index distance from the centre of the shifted spectrum). It is linear with a real, even
//! multiplier, so it is self-adjoint: its vector-Jacobian product is the same step applied to the
//! output gradient.

use super::physics::PhysicsDrift;
use crate::{Error, Result};
use candle_core::{DType, Device, Shape, Tensor};
use pbdl_core::op::{apply1, Kernel1, Op1};
use pbdl_core::Real;
use rand_distr::{Distribution, StandardNormal};
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// Signed integer frequency of FFT index `i` on an axis of length `n` (`-n/2 .. n/2 - 1`).
fn freq(i: usize, n: usize) -> f64 {
    if i < n.div_ceil(2) {
        i as f64
    } else {
        i as f64 - n as f64
    }
}

/// In-place 2-D FFT of an `h x w` row-major complex image (unnormalised both ways).
fn fft2(planner: &mut FftPlanner<f64>, data: &mut [Complex<f64>], h: usize, w: usize, inverse: bool) {
    let (row, col) = if inverse {
        (planner.plan_fft_inverse(w), planner.plan_fft_inverse(h))
    } else {
        (planner.plan_fft_forward(w), planner.plan_fft_forward(h))
    };
    row.process(data);
    let mut column = vec![Complex::new(0.0, 0.0); h];
    for x in 0..w {
        for y in 0..h {
            column[y] = data[y * w + x];
        }
        col.process(&mut column);
        for y in 0..h {
            data[y * w + x] = column[y];
        }
    }
}

/// The spectral heat step `x -> IFFT(FFT(x) exp(-|k|^2 dt))` over the last two axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatStep {
    /// Time step (the diffusivity is 1).
    pub dt: f64,
}

impl Kernel1 for HeatStep {
    fn name(&self) -> &'static str {
        "heat_step"
    }
    fn output_shape(&self, input: &Shape) -> candle_core::Result<Shape> {
        if input.rank() < 2 {
            candle_core::bail!("heat_step: input of shape {input:?} needs at least two (y, x) axes");
        }
        Ok(input.clone())
    }
    fn forward<T: Real>(&self, x: &[T], shape: &Shape, out: &mut [T]) -> candle_core::Result<()> {
        let dims = shape.dims();
        let (h, w) = (dims[dims.len() - 2], dims[dims.len() - 1]);
        if h * w == 0 {
            return Ok(());
        }
        let mult: Vec<f64> = (0..h * w)
            .map(|i| {
                let (ky, kx) = (freq(i / w, h), freq(i % w, w));
                (-(kx * kx + ky * ky) * self.dt).exp() / (h * w) as f64
            })
            .collect();
        let mut planner = FftPlanner::new();
        let mut buf = vec![Complex::new(0.0, 0.0); h * w];
        for (xi, oi) in x.chunks(h * w).zip(out.chunks_mut(h * w)) {
            for (b, v) in buf.iter_mut().zip(xi) {
                *b = Complex::new(candle_core::WithDType::to_f64(*v), 0.0);
            }
            fft2(&mut planner, &mut buf, h, w, false);
            for (b, m) in buf.iter_mut().zip(&mult) {
                *b *= *m;
            }
            fft2(&mut planner, &mut buf, h, w, true);
            for (o, b) in oi.iter_mut().zip(&buf) {
                *o = T::from_f64(b.re);
            }
        }
        Ok(())
    }
}

impl Op1 for HeatStep {
    fn backward(&self, _x: &Tensor, _y: &Tensor, grad_y: &Tensor) -> candle_core::Result<Tensor> {
        // Self-adjoint; applying the op (not its kernel) keeps higher derivatives available.
        apply1(grad_y, *self)
    }
}

/// Applies the spectral heat step of length `dt` to the last two axes of `x`.
pub fn heat_step(x: &Tensor, dt: f64) -> Result<Tensor> {
    if !(dt.is_finite() && dt >= 0.0) {
        return Err(Error::InvalidConfig { name: "dt", value: dt.to_string(), hint: "use a finite time step >= 0" });
    }
    Ok(apply1(x, HeatStep { dt })?)
}

/// The heat equation as SMDP physics: the increment of one step is `heat_step(x) - x`, so the
/// inverse step is `2 x - heat_step(x)`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeatPhysics;

impl PhysicsDrift for HeatPhysics {
    fn increment(&self, x: &Tensor, _t: f64, dt: f64) -> Result<Tensor> {
        Ok((heat_step(x, dt)? - x)?)
    }
}

/// The paper's heat problem settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatProblem {
    /// Grid side (32).
    pub n: usize,
    /// Time step (0.01).
    pub dt: f64,
    /// End time (0.2).
    pub t1: f64,
    /// Diffusion `g` of the SDE (0.1).
    pub g: f64,
}

impl Default for HeatProblem {
    fn default() -> Self {
        HeatProblem { n: 32, dt: 0.01, t1: 0.2, g: 0.1 }
    }
}

impl HeatProblem {
    /// Number of steps `round(t1 / dt)`.
    pub fn steps(&self) -> usize {
        (self.t1 / self.dt).round() as usize
    }

    /// Rejects settings that cannot be simulated.
    pub fn validate(&self) -> Result<()> {
        let bad = |name, v: String, hint| Err(Error::InvalidConfig { name, value: v, hint });
        if self.n < 4 {
            return bad("n", self.n.to_string(), "use a grid side of at least 4 (32 in the paper)");
        }
        if !(self.dt > 0.0 && self.dt.is_finite() && self.t1 >= self.dt && self.t1.is_finite()) {
            return bad("dt/t1", format!("{}/{}", self.dt, self.t1), "use 0 < dt <= t1 (0.01 and 0.2 in the paper)");
        }
        if !(self.g >= 0.0 && self.g.is_finite()) {
            return bad("g", self.g.to_string(), "use a finite g >= 0 (0.1 in the paper)");
        }
        Ok(())
    }

    /// `count` Gaussian random fields `[count, 1, n, n]` with power spectrum `|k|^-4` (zero
    /// mean), scaled so that the expected pixel variance is 1.
    pub fn random_fields(&self, count: usize, dtype: DType, seed: u64) -> Result<Tensor> {
        self.validate()?;
        let n = self.n;
        let amp: Vec<f64> = (0..n * n)
            .map(|i| {
                let k2 = freq(i / n, n).powi(2) + freq(i % n, n).powi(2);
                if k2 == 0.0 {
                    0.0
                } else {
                    1.0 / k2
                }
            })
            .collect();
        // Re(IFFT(z A)) with E|z|^2 = 2 has pixel variance sum(A^2) / n^4.
        let scale = (n * n) as f64 / amp.iter().map(|a| a * a).sum::<f64>().sqrt();
        let mut rng = super::sde::chunk_rng(seed, 77);
        let mut planner = FftPlanner::new();
        let mut data = Vec::with_capacity(count * n * n);
        let mut buf = vec![Complex::new(0.0, 0.0); n * n];
        for _ in 0..count {
            for (b, a) in buf.iter_mut().zip(&amp) {
                let (re, im): (f64, f64) = (StandardNormal.sample(&mut rng), StandardNormal.sample(&mut rng));
                *b = Complex::new(re, im) * (a * scale / (n * n) as f64);
            }
            fft2(&mut planner, &mut buf, n, n, true);
            data.extend(buf.iter().map(|c| c.re));
        }
        Ok(Tensor::from_vec(data, (count, 1, n, n), &Device::Cpu)?.to_dtype(dtype)?)
    }

    /// The noisy forward simulation `x <- heat_step(x) + g sqrt(dt) xi` from `x0`; returns all
    /// `steps + 1` states.
    pub fn simulate(&self, x0: &Tensor, seed: u64) -> Result<Vec<Tensor>> {
        self.validate()?;
        let noise = self.g * self.dt.sqrt();
        let mut states = vec![x0.clone()];
        let mut x = x0.clone();
        for k in 0..self.steps() {
            let xi = pbdl_core::seed::randn(x.shape(), 0.0, noise, x.dtype(), x.device(), seed.wrapping_add(k as u64))?;
            x = (heat_step(&x, self.dt)? + xi)?;
            states.push(x.clone());
        }
        Ok(states)
    }

    /// The noise-free forward simulation over `[0, t1]` (one spectral step of length `t1`).
    pub fn forward_clean(&self, x: &Tensor) -> Result<Tensor> {
        heat_step(x, self.steps() as f64 * self.dt)
    }
}

/// Radially averaged power spectrum `|FFT(x)|^2` of one `n x n` field, bins `round(|k|)` for
/// `k = 0 .. n/2`.
pub fn radial_power_spectrum(field: &[f64], n: usize) -> Vec<f64> {
    let mut buf: Vec<Complex<f64>> = field.iter().map(|&v| Complex::new(v, 0.0)).collect();
    fft2(&mut FftPlanner::new(), &mut buf, n, n, false);
    let bins = n / 2 + 1;
    let (mut sum, mut count) = (vec![0.0; bins], vec![0usize; bins]);
    for (i, c) in buf.iter().enumerate() {
        let k = (freq(i / n, n).powi(2) + freq(i % n, n).powi(2)).sqrt().round() as usize;
        if k < bins {
            sum[k] += c.norm_sqr();
            count[k] += 1;
        }
    }
    sum.iter().zip(&count).map(|(s, &c)| s / c.max(1) as f64).collect()
}

/// Spectral error of fields `pred` against `truth` (`[b, 1, n, n]`): per field the mean over
/// `k = 1..=k_max` of `|log P_pred(k) - log P_truth(k)|`, averaged over the fields.
pub fn spectral_error(pred: &Tensor, truth: &Tensor, k_max: usize) -> Result<f64> {
    if pred.dims() != truth.dims() || pred.rank() != 4 {
        return Err(Error::shape("spectral_error fields", truth.dims(), pred.dims()));
    }
    let n = pred.dim(3)?;
    let p = pred.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let t = truth.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let mut total = 0.0;
    let fields = p.len() / (n * n);
    for (a, b) in p.chunks(n * n).zip(t.chunks(n * n)) {
        let (sa, sb) = (radial_power_spectrum(a, n), radial_power_spectrum(b, n));
        let km = k_max.min(sa.len() - 1);
        total += (1..=km).map(|k| (sa[k].ln() - sb[k].ln()).abs()).sum::<f64>() / km as f64;
    }
    Ok(total / fields.max(1) as f64)
}

/// Mean squared difference of two tensors of one shape.
pub fn mse(a: &Tensor, b: &Tensor) -> Result<f64> {
    if a.dims() != b.dims() {
        return Err(Error::shape("mse operands", b.dims(), a.dims()));
    }
    Ok((a - b)?.sqr()?.mean_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pbdl_core::{check_grad, GradCheckOptions};

    /// A single Fourier mode cos(2 pi (kx x + ky y) / n) decays by exactly exp(-(kx^2 + ky^2) dt).
    #[test]
    fn single_modes_decay_by_exp_minus_k_squared_dt() {
        let n = 32;
        let dt = 0.01;
        for &(kx, ky) in &[(1usize, 0usize), (0, 3), (5, 7), (16, 0), (11, 16)] {
            let f: Vec<f64> = (0..n * n)
                .map(|i| {
                    let (y, x) = ((i / n) as f64, (i % n) as f64);
                    (2.0 * std::f64::consts::PI * (kx as f64 * x + ky as f64 * y) / n as f64).cos()
                })
                .collect();
            let t = Tensor::from_vec(f.clone(), (1, 1, n, n), &Device::Cpu).unwrap();
            let out = heat_step(&t, dt).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
            let decay = (-((kx * kx + ky * ky) as f64) * dt).exp();
            let err = out.iter().zip(&f).map(|(o, v)| (o - decay * v).abs()).fold(0.0, f64::max);
            assert!(err < 1e-6, "mode ({kx},{ky}): max error {err}");
        }
    }

    #[test]
    fn heat_step_gradient_matches_finite_differences() {
        let x = pbdl_core::seed::randn((2, 1, 8, 6), 0.0, 1.0, DType::F64, &Device::Cpu, 3).unwrap();
        // Squared output so the cotangent depends on the input.
        let rep =
            check_grad(|xs| apply1(&xs[0], HeatStep { dt: 0.05 })?.sqr(), &[x], &GradCheckOptions::default()).unwrap();
        assert!(rep.max_rel_error < 1e-6, "{rep:?}");
    }

    #[test]
    fn random_fields_have_unit_variance_and_a_k_minus_4_spectrum() {
        let p = HeatProblem::default();
        let x = p.random_fields(400, DType::F64, 1).unwrap();
        let v = x.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        let var = v.iter().map(|a| a * a).sum::<f64>() / v.len() as f64;
        assert!((var - 1.0).abs() < 0.1, "variance {var}");
        let mut spec = [0.0; 17];
        for f in v.chunks(32 * 32) {
            for (s, a) in spec.iter_mut().zip(radial_power_spectrum(f, 32)) {
                *s += a;
            }
        }
        // log P(2k) - log P(k) = -4 log 2 for a k^-4 spectrum (bins average over rings).
        for k in [2usize, 4, 6] {
            let slope = (spec[2 * k].ln() - spec[k].ln()) / 2f64.ln();
            assert!((slope + 4.0).abs() < 0.4, "k {k}: slope {slope}");
        }
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        assert!(heat_step(&Tensor::zeros(4, DType::F64, &Device::Cpu).unwrap(), 0.1).is_err());
        assert!(heat_step(&Tensor::zeros((4, 4), DType::F64, &Device::Cpu).unwrap(), -1.0).is_err());
        let e = HeatProblem { n: 2, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("grid side"), "{e}");
    }
}
