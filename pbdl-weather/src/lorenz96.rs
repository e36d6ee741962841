//! Lorenz-96 (Lorenz 1996): the unit-test tier of stand-in weather.
//!
//! `dx_k/dt = (x_{k+1} - x_{k-2}) x_{k-1} - x_k + F`, cyclic in k; with K = 40 and F = 8 the
//! system is chaotic, and one time unit is about 5 days of atmospheric error growth, so
//! `dt = 0.05` stands for 6 hours. Trajectories come out as [`Field`]s on a 1 x K "grid"
//! (one latitude at the equator, weight 1), so that every WeatherBench score and baseline
//! applies unchanged.

use crate::error::{Error, Result};
use crate::field::{Field, Values};
use crate::grid::LatLonGrid;
use crate::time::Seconds;
use rand::Rng;

/// The Lorenz-96 system.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lorenz96 {
    /// Number of variables K (at least 4).
    pub k: usize,
    /// Forcing F.
    pub forcing: f64,
    /// Time step in model time units (0.05 = 6 h).
    pub dt: f64,
}

impl Default for Lorenz96 {
    fn default() -> Self {
        Self { k: 40, forcing: 8.0, dt: 0.05 }
    }
}

impl Lorenz96 {
    /// The tendency `dx/dt` into `out`.
    pub fn tendency(&self, x: &[f64], out: &mut [f64]) {
        let k = x.len();
        for i in 0..k {
            let (ip1, im1, im2) = ((i + 1) % k, (i + k - 1) % k, (i + k - 2) % k);
            out[i] = (x[ip1] - x[im2]) * x[im1] - x[i] + self.forcing;
        }
    }

    /// One classical RK4 step of `dt`, in place.
    pub fn step(&self, x: &mut [f64]) {
        let k = x.len();
        let (mut k1, mut k2, mut k3, mut k4, mut tmp) =
            (vec![0.0; k], vec![0.0; k], vec![0.0; k], vec![0.0; k], vec![0.0; k]);
        self.tendency(x, &mut k1);
        for i in 0..k {
            tmp[i] = x[i] + 0.5 * self.dt * k1[i];
        }
        self.tendency(&tmp, &mut k2);
        for i in 0..k {
            tmp[i] = x[i] + 0.5 * self.dt * k2[i];
        }
        self.tendency(&tmp, &mut k3);
        for i in 0..k {
            tmp[i] = x[i] + self.dt * k3[i];
        }
        self.tendency(&tmp, &mut k4);
        for i in 0..k {
            x[i] += self.dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }

    /// `n_steps` states after a spin-up of `spinup` steps from `F` plus a seeded perturbation,
    /// one every `dt`, stamped every 6 hours from 2000-01-01 as a field named `x`.
    pub fn trajectory(&self, seed: u64, spinup: usize, n_steps: usize) -> Result<Field> {
        if self.k < 4 || !(self.dt > 0.0 && self.dt.is_finite()) || !self.forcing.is_finite() {
            return Err(Error::InvalidArgument(format!(
                "Lorenz-96 needs K >= 4 and dt > 0 (got K = {}, dt = {})",
                self.k, self.dt
            )));
        }
        let mut rng = pbdl_core::seed::rng(seed);
        let mut x: Vec<f64> = (0..self.k).map(|_| self.forcing + 0.01 * (rng.random::<f64>() - 0.5)).collect();
        for _ in 0..spinup {
            self.step(&mut x);
        }
        let mut values = Vec::with_capacity(n_steps * self.k);
        for _ in 0..n_steps {
            values.extend_from_slice(&x);
            self.step(&mut x);
        }
        let start: Seconds = 946_684_800; // 2000-01-01
        let times = (0..n_steps as i64).map(|t| start + 6 * 3600 * t).collect();
        let lon = (0..self.k).map(|i| i as f64 * 360.0 / self.k as f64).collect();
        Field::new("x", Some(times), LatLonGrid { lat: vec![0.0], lon }, Values::F64(values))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rk4_converges_at_fourth_order() {
        // Integrate to t = 0.4 with dt and dt/2 and dt/4 from a fixed state; error ratio ~ 16.
        let base = Lorenz96::default();
        let x0: Vec<f64> = (0..40).map(|i| 8.0 + (i as f64 * 0.7).sin()).collect();
        let run = |dt: f64| {
            let m = Lorenz96 { dt, ..base };
            let mut x = x0.clone();
            for _ in 0..(0.4 / dt).round() as usize {
                m.step(&mut x);
            }
            x
        };
        let reference = run(0.0005);
        let err = |dt: f64| run(dt).iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        let (e1, e2) = (err(0.02), err(0.01));
        let order = (e1 / e2).log2();
        assert!((3.7..4.3).contains(&order), "observed order {order} (errors {e1:e}, {e2:e})");
    }

    #[test]
    fn the_attractor_has_the_published_mean_and_spread() {
        // For K = 40, F = 8 the climatological mean is about 2.3 and the standard deviation
        // about 3.6 (Lorenz and Emanuel 1998).
        let f = Lorenz96::default().trajectory(1, 2000, 4000).unwrap();
        let v = f.values.to_f64();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        assert!((2.1..2.5).contains(&mean), "mean {mean}");
        assert!((3.4..3.8).contains(&sd), "sd {sd}");
    }
}
