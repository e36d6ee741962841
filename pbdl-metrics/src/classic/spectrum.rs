//! Radially averaged energy spectrum of 1D, 2D and 3D fields, and a spectral error.
//!
//! A field `u_c(x)` on a periodic grid of `N = n_1 ... n_d` cells, with Fourier coefficients
//! `u_hat_c(m) = sum_x u_c(x) exp(-2 pi i sum_j m_j x_j / n_j)` (unnormalised DFT, `m_j` the
//! signed mode index along axis `j`), has the shell energy
//!
//! ```text
//! E(k) = sum over m with round(|m|) = k of  sum_c 0.5 |u_hat_c(m)|^2 / N^2,
//! ```
//!
//! summed over the channels (velocity components live in the channel axis, so `E` is the
//! kinetic-energy spectrum). By Parseval `sum_k E(k) = 0.5 mean_x sum_c u_c(x)^2`. Wavenumbers
//! are mode indices (a domain of unit length along every axis). Shells up to
//! `(min_j n_j - 1) / 2` are complete; higher shells only hold the corners of the mode box.
//!
//! The spectral error of a prediction `a` against a reference `b` is the log-spectral distance
//! over the complete shells `k = 1 ..= K` (the mean, `k = 0`, is left out):
//!
//! ```text
//! LSD = sqrt( mean_k log10( (E_a(k) + tau) / (E_b(k) + tau) )^2 ),  tau = 1e-12 max_k max(E_a, E_b),
//! ```
//!
//! 0 for equal spectra; 1 means the spectra differ by a factor of 10 on (root-mean-square) average.

use crate::{check, Error, Result};
use candle_core::{DType, Tensor};
use rayon::prelude::*;
use rustfft::{num_complex::Complex64, Fft, FftPlanner};
use std::sync::Arc;

/// The radially averaged energy spectrum of a batch of fields.
#[derive(Clone, Debug, PartialEq)]
pub struct Spectrum {
    /// Shell wavenumbers `0, 1, 2, ...` (mode indices).
    pub wavenumbers: Vec<f64>,
    /// `energy[sample][k]`: the energy in shell `k` of each batch entry.
    pub energy: Vec<Vec<f64>>,
    /// The last complete shell, `(min_j n_j - 1) / 2`.
    pub last_complete_shell: usize,
}

/// The energy spectrum of `field` `[batch, channel, spatial...]` (1 to 3 spatial axes), `f32` or
/// `f64`, computed in `f64` with an FFT. See the module docs for the definition.
///
/// Errors: a rank outside 3..=5, non-float, empty or non-finite input.
pub fn energy_spectrum(field: &Tensor) -> Result<Spectrum> {
    const OP: &str = "energy_spectrum";
    check::field_pair(OP, field, field, 1..=3)?;
    let dims = field.dims().to_vec();
    let (batch, channels, spatial) = (dims[0], dims[1], dims[2..].to_vec());
    let n_tot: usize = spatial.iter().product();
    // Shell of every flat spatial index.
    let mode = |j: usize, n: usize| -> f64 {
        if j <= n / 2 {
            j as f64
        } else {
            j as f64 - n as f64
        }
    };
    let shell: Vec<usize> = (0..n_tot)
        .map(|flat| {
            let mut rem = flat;
            let mut k2 = 0.0;
            for &n in spatial.iter().rev() {
                let m = mode(rem % n, n);
                k2 += m * m;
                rem /= n;
            }
            k2.sqrt().round() as usize
        })
        .collect();
    let n_shells = shell.iter().max().copied().unwrap_or(0) + 1;
    let mut planner = FftPlanner::<f64>::new();
    let plans: Vec<Arc<dyn Fft<f64>>> = spatial.iter().map(|&n| planner.plan_fft_forward(n)).collect();
    let values = field.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let norm = 0.5 / (n_tot as f64 * n_tot as f64);
    let energy: Vec<Vec<f64>> = (0..batch)
        .into_par_iter()
        .map(|b| {
            let mut e = vec![0.0; n_shells];
            for c in 0..channels {
                let start = (b * channels + c) * n_tot;
                let mut buf: Vec<Complex64> =
                    values[start..start + n_tot].iter().map(|&v| Complex64::new(v, 0.0)).collect();
                fft_nd(&mut buf, &spatial, &plans);
                for (z, &k) in buf.iter().zip(&shell) {
                    e[k] += z.norm_sqr() * norm;
                }
            }
            e
        })
        .collect();
    let last_complete_shell = (spatial.iter().min().copied().unwrap_or(1) - 1) / 2;
    Ok(Spectrum { wavenumbers: (0..n_shells).map(|k| k as f64).collect(), energy, last_complete_shell })
}

/// In-place unnormalised DFT of a dense row-major array with the given axis sizes.
fn fft_nd(buf: &mut [Complex64], dims: &[usize], plans: &[Arc<dyn Fft<f64>>]) {
    let total = buf.len();
    let mut line = Vec::new();
    for (axis, plan) in plans.iter().enumerate() {
        let n = dims[axis];
        let inner: usize = dims[axis + 1..].iter().product();
        if inner == 1 {
            plan.process(buf);
            continue;
        }
        line.resize(n, Complex64::new(0.0, 0.0));
        let outer = total / (n * inner);
        for o in 0..outer {
            for i in 0..inner {
                let base = o * n * inner + i;
                for (j, z) in line.iter_mut().enumerate() {
                    *z = buf[base + j * inner];
                }
                plan.process(&mut line);
                for (j, z) in line.iter().enumerate() {
                    buf[base + j * inner] = *z;
                }
            }
        }
    }
}

/// Log-spectral distance of `pred` against `target` per sample, over the complete shells (see the
/// module docs). Symmetric in its arguments; 0 for fields with equal spectra.
///
/// Errors: those of [`energy_spectrum`], mismatched shapes, and fields with fewer than 3 cells
/// along an axis (no complete shell beyond the mean).
pub fn spectral_error(pred: &Tensor, target: &Tensor) -> Result<Vec<f64>> {
    const OP: &str = "spectral_error";
    check::field_pair(OP, pred, target, 1..=3)?;
    let (sa, sb) = (energy_spectrum(pred)?, energy_spectrum(target)?);
    let kc = sa.last_complete_shell;
    if kc == 0 {
        return Err(Error::invalid(
            OP,
            "pred",
            format!(
                "shape {:?} has no complete wavenumber shell beyond k = 0; use at least 3 cells per axis",
                pred.dims()
            ),
        ));
    }
    Ok(sa
        .energy
        .iter()
        .zip(&sb.energy)
        .map(|(ea, eb)| {
            let peak = ea[1..=kc].iter().chain(&eb[1..=kc]).fold(f64::MIN_POSITIVE, |m, &v| m.max(v));
            let tau = 1e-12 * peak;
            let s: f64 = (1..=kc).map(|k| ((ea[k] + tau) / (eb[k] + tau)).log10().powi(2)).sum();
            (s / kc as f64).sqrt()
        })
        .collect())
}
