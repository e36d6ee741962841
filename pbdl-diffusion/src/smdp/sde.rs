//! The toy SDE `dx = P(x) dt + g dW` and its seeded, batched Euler-Maruyama simulator.

use super::physics::{ScalarDrift, ToyDrift};
use crate::{Error, Result};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Paths are simulated in chunks of this many, each chunk with its own generator, so the numbers
/// do not depend on the number of threads.
const CHUNK: usize = 512;

/// A 1-D SDE with a toy drift, constant diffusion `g` and Euler-Maruyama step `dt` on `[0, t_end]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToySde {
    /// The drift `P(x)`.
    pub drift: ToyDrift,
    /// The diffusion coefficient `g`.
    pub g: f64,
    /// The time step.
    pub dt: f64,
    /// The end time `T`.
    pub t_end: f64,
}

/// Simulated paths, path-major: state `k` (time `k dt`) of path `p` is `data[p * (steps + 1) + k]`.
#[derive(Clone, Debug)]
pub struct Paths {
    /// Number of paths.
    pub n_paths: usize,
    /// Number of steps (each path holds `steps + 1` states).
    pub steps: usize,
    /// The time step.
    pub dt: f64,
    /// The states.
    pub data: Vec<f64>,
}

impl Paths {
    /// The states of path `p`, from `t = 0` to `t = T`.
    pub fn path(&self, p: usize) -> &[f64] {
        &self.data[p * (self.steps + 1)..(p + 1) * (self.steps + 1)]
    }
    /// State `k` of every path.
    pub fn at_step(&self, k: usize) -> Vec<f64> {
        (0..self.n_paths).map(|p| self.data[p * (self.steps + 1) + k]).collect()
    }
}

/// Mean and (population) standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n;
    (m, var.sqrt())
}

/// The generator of chunk `c` of a run seeded with `seed`.
pub(crate) fn chunk_rng(seed: u64, c: usize) -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(seed ^ (c as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0x2545_F491))
}

impl ToySde {
    /// The paper's toy problem: `P(x) = -7 sign(x) x^2`, `g = 0.03`, `dt = 0.02`, `T = 10`.
    pub fn paper_quadratic() -> Self {
        ToySde { drift: ToyDrift::quadratic(), g: 0.03, dt: 0.02, t_end: 10.0 }
    }
    /// The analytic check case: `P(x) = -0.5 x`, `g = 0.04`, `dt = 0.02`, `T = 10`.
    pub fn paper_affine() -> Self {
        ToySde { drift: ToyDrift::affine(), g: 0.04, dt: 0.02, t_end: 10.0 }
    }

    /// The same SDE with the finer step `dt / m` (for data resolved finer than the sampler's
    /// coarse steps, see [`super::sampler::CoarseSteps`]).
    pub fn refined(&self, m: usize) -> Self {
        ToySde { dt: self.dt / m.max(1) as f64, ..*self }
    }

    /// Number of steps `round(T / dt)`.
    pub fn steps(&self) -> usize {
        (self.t_end / self.dt).round() as usize
    }

    /// Rejects settings that cannot be simulated.
    pub fn validate(&self) -> Result<()> {
        self.drift.validate()?;
        let bad = |name, v: f64, hint| Err(Error::InvalidConfig { name, value: v.to_string(), hint });
        if !(self.g.is_finite() && self.g >= 0.0) {
            return bad("g", self.g, "use a finite, non-negative diffusion coefficient (0.03 in the paper)");
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt", self.dt, "use a positive time step (0.02 in the paper)");
        }
        if !(self.t_end.is_finite() && self.t_end >= self.dt) {
            return bad("t_end", self.t_end, "use an end time of at least one step (10 in the paper)");
        }
        Ok(())
    }

    /// One Euler-Maruyama step of every state in `x` (noise drawn from `rng`).
    fn step(&self, x: &mut [f64], rng: &mut impl rand::Rng) {
        let noise = self.g * self.dt.sqrt();
        for v in x.iter_mut() {
            let xi: f64 = StandardNormal.sample(rng);
            *v += self.dt * self.drift.drift(*v) + noise * xi;
        }
    }

    /// Simulates one path per start value in `x0` and keeps every state.
    pub fn simulate(&self, x0: &[f64], seed: u64) -> Result<Paths> {
        self.validate()?;
        let steps = self.steps();
        let mut data = vec![0.0; x0.len() * (steps + 1)];
        data.par_chunks_mut(CHUNK * (steps + 1)).enumerate().for_each(|(c, block)| {
            let mut rng = chunk_rng(seed, c);
            let n = block.len() / (steps + 1);
            let mut x: Vec<f64> = x0[c * CHUNK..c * CHUNK + n].to_vec();
            for k in 0..=steps {
                if k > 0 {
                    self.step(&mut x, &mut rng);
                }
                for (p, v) in x.iter().enumerate() {
                    block[p * (steps + 1) + k] = *v;
                }
            }
        });
        Ok(Paths { n_paths: x0.len(), steps, dt: self.dt, data })
    }

    /// The end states `x_T` of one path per start value (keeps no intermediate states).
    pub fn endpoints(&self, x0: &[f64], seed: u64) -> Result<Vec<f64>> {
        self.validate()?;
        let steps = self.steps();
        let mut out = x0.to_vec();
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, x)| {
            let mut rng = chunk_rng(seed, c);
            for _ in 0..steps {
                self.step(x, &mut rng);
            }
        });
        Ok(out)
    }
}

/// `n` start values alternating `+1, -1` (the toy's two-point initial distribution).
pub fn two_point_starts(n: usize) -> Vec<f64> {
    (0..n).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect()
}
