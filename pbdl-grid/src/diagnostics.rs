//! Flow diagnostics: kinetic energy, incompressibility, shedding frequency, and a tracker that
//! steps a [`Simulation`] and records the first step at which an invariant breaks.
//!
//! # Shedding frequency: which estimator
//!
//! Two estimators turn a probe signal sampled every `dt` into a frequency or a Strouhal number
//! `St = f d / u`:
//!
//! - [`strouhal_zero_crossings`]: the mean period between upward zero crossings (about the
//!   mean, linearly interpolated) over the signal's second half, which it treats as past the
//!   start-up. Cheap (one pass, no allocation beyond the crossings) and very accurate on a clean
//!   single-frequency probe, but it needs several periods (at least 3 crossings in the second
//!   half, else NaN), and noise or a second tone adds spurious crossings.
//! - [`strouhal_spectral_peak`] (from [`dominant_frequency`]): the peak of the amplitude spectrum
//!   of the whole signal (mean removed, Hann window, zero-padded to
//!   `P = (16 n).next_power_of_two()`), refined by a parabola through the peak bin and its
//!   neighbours. Use it for noisy or multi-frequency signals (e.g. sampled model rollouts): it
//!   picks the strongest tone. Bin spacing is `1 / (P dt)`, the parabola refines within a bin,
//!   and the band below about two cycles per record is skipped (window leakage of the mean).
//!   NaN for fewer than 8 samples or a constant signal.
//!
//! ```
//! use pbdl_grid::diagnostics::{strouhal_spectral_peak, strouhal_zero_crossings};
//!
//! // A clean 0.2 Hz probe sampled at dt = 0.05 for 100 s; d = 1, u = 2, so St = 0.1.
//! let tau = 2.0 * std::f64::consts::PI;
//! let clean: Vec<f64> = (0..2000).map(|k| (tau * 0.2 * k as f64 * 0.05).sin()).collect();
//! let (st, periods) = strouhal_zero_crossings(&clean, 0.05, 1.0, 2.0);
//! assert!((st - 0.1).abs() < 1e-4 && periods == 8, "{st} {periods}");
//! assert!((strouhal_spectral_peak(&clean, 0.05, 1.0, 2.0) - 0.1).abs() < 1e-3);
//!
//! // A weaker 0.7 Hz tone on top adds zero crossings; the spectral peak still finds 0.2 Hz.
//! let mixed: Vec<f64> =
//!     (0..2000).map(|k| k as f64 * 0.05).map(|t| (tau * 0.2 * t).sin() + 0.3 * (tau * 0.7 * t).sin()).collect();
//! assert!((strouhal_spectral_peak(&mixed, 0.05, 1.0, 2.0) - 0.1).abs() < 1e-3);
//! assert!((strouhal_zero_crossings(&mixed, 0.05, 1.0, 2.0).0 - 0.1).abs() > 0.02);
//! ```
//!
//! ```
//! use pbdl_grid::diagnostics::{kinetic_energy, relative_divergence};
//! use pbdl_grid::{Boundaries, Grid, MacField};
//!
//! let grid = Grid::square(32, 2.0 * std::f64::consts::PI)?;
//! let u = MacField::from_fn(grid, Boundaries::periodic(), candle_core::DType::F64, |x, y| {
//!     [x.sin() * y.cos(), -x.cos() * y.sin()]
//! })?;
//! // Taylor-Green: energy (1/2) |u|^2 integrated over the box = pi^2, and divergence-free.
//! assert!((kinetic_energy(&u)? - std::f64::consts::PI.powi(2)).abs() < 1e-9);
//! assert!(relative_divergence(&u)? < 1e-12);
//! # Ok::<(), pbdl_grid::Error>(())
//! ```

use crate::scene::Simulation;
use crate::{fd, MacField, Result};
use candle_core::DType;
use realfft::RealFftPlanner;

/// Kinetic energy `1/2 sum |u|^2 dx dy` over the MAC faces of every batch entry.
pub fn kinetic_energy(u: &MacField) -> Result<f64> {
    Ok(0.5 * u.values().to_dtype(DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()? * u.grid().dx() * u.grid().dy())
}

/// `max |div u| dx / max |u|`: the divergence relative to what one cell's worth of velocity
/// difference would give (round-off `~1e-7` in f32 after a projection).
pub fn relative_divergence(u: &MacField) -> Result<f64> {
    let div = fd::divergence(u)?.into_values().abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
    Ok(div * u.grid().dx() / u.max_abs()?.max(f64::MIN_POSITIVE))
}

/// Strouhal number `St = d / (period u)` from the upward zero crossings (about the mean) of a
/// probe signal sampled every `dt`, over its second half (the first is the start-up);
/// `(St, periods counted)`, `(NaN, 0)` with fewer than 3 crossings.
pub fn strouhal_zero_crossings(signal: &[f64], dt: f64, d: f64, u: f64) -> (f64, usize) {
    let half = &signal[signal.len() / 2..];
    let mean = half.iter().sum::<f64>() / half.len().max(1) as f64;
    let mut cross = Vec::new();
    for k in 1..half.len() {
        let (a, b) = (half[k - 1] - mean, half[k] - mean);
        if a < 0.0 && b >= 0.0 {
            cross.push((k - 1) as f64 + a / (a - b));
        }
    }
    if cross.len() < 3 {
        return (f64::NAN, 0);
    }
    let period = (cross[cross.len() - 1] - cross[0]) / (cross.len() - 1) as f64 * dt;
    (d / (period * u), cross.len() - 1)
}

/// The dominant frequency of a signal sampled every `dt`: the mean is removed, a Hann window
/// applied, the series zero-padded 16x (to a power of two), and the peak of the amplitude
/// spectrum (ignoring the band below about two cycles per record) refined by a parabola through
/// its neighbours. NaN for fewer than 8 samples or a constant signal. See the
/// [module docs](crate::diagnostics) for when to prefer [`strouhal_zero_crossings`].
///
/// ```
/// // 0.173 Hz sampled at 10 Hz for 100 s: within 0.2% (bin spacing 1 / (16384 * 0.1) Hz).
/// let s: Vec<f64> = (0..1000).map(|k| (2.0 * std::f64::consts::PI * 0.173 * k as f64 * 0.1).sin()).collect();
/// let f = pbdl_grid::diagnostics::dominant_frequency(&s, 0.1);
/// assert!((f - 0.173).abs() / 0.173 < 2e-3, "{f}");
/// ```
pub fn dominant_frequency(signal: &[f64], dt: f64) -> f64 {
    let n = signal.len();
    if n < 8 {
        return f64::NAN;
    }
    let m = signal.iter().sum::<f64>() / n as f64;
    let pad = (16 * n).next_power_of_two();
    let mut buf = vec![0.0f64; pad];
    for (k, &x) in signal.iter().enumerate() {
        let w = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * k as f64 / (n - 1) as f64).cos();
        buf[k] = (x - m) * w;
    }
    let fft = RealFftPlanner::<f64>::new().plan_fft_forward(pad);
    let mut spec = fft.make_output_vec();
    if fft.process(&mut buf, &mut spec).is_err() {
        return f64::NAN;
    }
    let amp: Vec<f64> = spec.iter().map(|c| c.norm()).collect();
    // Skip the lowest bins, about two cycles per record (window leakage of the removed mean).
    let lo = (pad / n).max(1) * 2;
    let (mut best, mut arg) = (0.0, 0);
    for (k, &a) in amp.iter().enumerate().skip(lo) {
        if a > best {
            best = a;
            arg = k;
        }
    }
    if best <= 1e-12 || arg + 1 >= amp.len() {
        return f64::NAN;
    }
    let (a, b, c) = (amp[arg - 1], amp[arg], amp[arg + 1]);
    let den = a - 2.0 * b + c;
    let shift = if den.abs() > 0.0 { 0.5 * (a - c) / den } else { 0.0 };
    (arg as f64 + shift) / (pad as f64 * dt)
}

/// Strouhal number `St = f d / u` with `f` the [`dominant_frequency`] (spectral peak) of a
/// probe signal sampled every `dt` over its whole length; NaN where that is NaN.
pub fn strouhal_spectral_peak(signal: &[f64], dt: f64, d: f64, u: f64) -> f64 {
    dominant_frequency(signal, dt) * d / u
}

/// Bounds checked after every step by [`track_invariants`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InvariantBounds {
    /// Largest allowed [`relative_divergence`].
    pub divergence: f64,
    /// Whether the flow should not gain energy (unforced, no inflow).
    pub decaying: bool,
    /// Largest allowed relative step-to-step energy growth when `decaying`.
    pub energy_growth: f64,
    /// Largest allowed kinetic energy (`f64::INFINITY` for none).
    pub energy_cap: f64,
    /// Largest allowed `max |u|`.
    pub speed_cap: f64,
}

/// What [`track_invariants`] saw: the first step (counting from 1) at which each invariant
/// broke, and the extremes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InvariantReport {
    /// First step with a non-finite value or a solver error (e.g. an unstable step).
    pub first_nonfinite: Option<u64>,
    /// First step above [`InvariantBounds::divergence`].
    pub first_divergence: Option<u64>,
    /// First step whose energy grew by more than [`InvariantBounds::energy_growth`] (decaying flows).
    pub first_energy_growth: Option<u64>,
    /// First step above [`InvariantBounds::energy_cap`].
    pub first_above_energy_cap: Option<u64>,
    /// First step with `max |u|` above [`InvariantBounds::speed_cap`].
    pub first_too_fast: Option<u64>,
    /// Largest relative divergence seen.
    pub worst_divergence: f64,
    /// Largest relative step-to-step energy change seen.
    pub worst_growth: f64,
    /// Energy at the start.
    pub energy_start: f64,
    /// Energy after the last step.
    pub energy_last: f64,
    /// Largest energy seen.
    pub max_energy: f64,
    /// Largest `max |u|` seen.
    pub max_speed: f64,
    /// The solver's error, if one ended the run.
    pub error: Option<String>,
}

/// Steps a velocity scene `steps` times and checks after each step: values finite, the
/// relative divergence, energy growth (when decaying), the energy and speed caps. A solver
/// error ends the run and is reported (not returned), as is the first non-finite value.
pub fn track_invariants(sim: &mut Simulation, steps: usize, bounds: &InvariantBounds) -> Result<InvariantReport> {
    let Some(u) = sim.state().velocity() else {
        return Err(crate::Error::Invalid {
            field: "scene",
            reason: "invariant tracking needs a velocity scene".into(),
        });
    };
    let e0 = kinetic_energy(u)?;
    let mut rep = InvariantReport {
        worst_growth: f64::NEG_INFINITY,
        energy_start: e0,
        energy_last: e0,
        max_energy: e0,
        ..Default::default()
    };
    let mut prev = e0;
    for k in 1..=steps as u64 {
        if let Err(e) = sim.step() {
            rep.error = Some(format!("step {k}: {e}"));
            rep.first_nonfinite.get_or_insert(k);
            break;
        }
        let Some(u) = sim.state().velocity() else { break };
        let m = u.max_abs()?;
        let e = kinetic_energy(u)?;
        rep.max_speed = rep.max_speed.max(m);
        if m > bounds.speed_cap {
            rep.first_too_fast.get_or_insert(k);
        }
        if !(m.is_finite() && e.is_finite()) {
            rep.first_nonfinite.get_or_insert(k);
            break;
        }
        let rel_div = relative_divergence(u)?;
        rep.worst_divergence = rep.worst_divergence.max(rel_div);
        if rel_div > bounds.divergence {
            rep.first_divergence.get_or_insert(k);
        }
        let growth = (e - prev) / prev.max(f64::MIN_POSITIVE);
        rep.worst_growth = rep.worst_growth.max(growth);
        if bounds.decaying && growth > bounds.energy_growth {
            rep.first_energy_growth.get_or_insert(k);
        }
        if e > bounds.energy_cap {
            rep.first_above_energy_cap.get_or_insert(k);
        }
        rep.max_energy = rep.max_energy.max(e);
        rep.energy_last = e;
        prev = e;
    }
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strouhal_of_a_sine_is_its_frequency() {
        // f = 0.2 with d = u = 1 sampled at dt = 0.01 over 100 time units.
        let s: Vec<f64> = (0..10_000).map(|k| (2.0 * std::f64::consts::PI * 0.2 * k as f64 * 0.01).sin()).collect();
        let (st, periods) = strouhal_zero_crossings(&s, 0.01, 1.0, 1.0);
        assert!((st - 0.2).abs() < 1e-6, "{st}");
        assert_eq!(periods, 9);
        assert!(strouhal_zero_crossings(&[1.0; 10], 0.1, 1.0, 1.0).0.is_nan());
    }

    #[test]
    fn dominant_frequency_of_a_sine() {
        // 0.173 Hz sampled at 10 Hz for 100 s: the peak lands within 0.2% (resolution 0.01 Hz).
        let s: Vec<f64> =
            (0..1000).map(|k| (2.0 * std::f64::consts::PI * 0.173 * k as f64 * 0.1).sin() + 0.3).collect();
        let f = dominant_frequency(&s, 0.1);
        assert!((f - 0.173).abs() / 0.173 < 2e-3, "f = {f}");
        assert!(dominant_frequency(&[1.0; 100], 0.1).is_nan());
    }

    #[test]
    fn dominant_frequency_pinned_bits() {
        // Exact f64 bits of the estimator on a sine with offset, a two-tone signal with offset,
        // a noisy sine (deterministic LCG noise) and a 9-sample record: refactors must keep them.
        let tau = 2.0 * std::f64::consts::PI;
        let sine: Vec<f64> = (0..1000).map(|k| (tau * 0.173 * k as f64 * 0.1).sin() + 0.3).collect();
        let two: Vec<f64> = (0..777)
            .map(|k| {
                let t = k as f64 * 0.05;
                (tau * 0.9 * t).sin() + 0.4 * (tau * 2.3 * t + 0.7).cos() - 1.5
            })
            .collect();
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let noisy: Vec<f64> = (0..513)
            .map(|k| {
                state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                let r = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                (tau * 0.31 * k as f64 * 0.2).sin() + 0.8 * r
            })
            .collect();
        let short: Vec<f64> = (0..9).map(|k| (k as f64 * 1.3).cos()).collect();
        let cases = [
            (&sine, 0.1, 0x3fc6_24dc_ec7b_291c_u64),
            (&two, 0.05, 0x3fec_cccc_8c5b_82f5),
            (&noisy, 0.2, 0x3fd3_d533_2b8a_5c8a),
            (&short, 0.1, 0x4000_6c61_9a93_911e),
        ];
        for (s, dt, bits) in cases {
            let f = dominant_frequency(s, dt);
            assert_eq!(f.to_bits(), bits, "n = {}: {f}", s.len());
            // The Strouhal form is `f d / u`, evaluated left to right (as the ACDM metric did).
            assert_eq!(strouhal_spectral_peak(s, dt, 0.7, 1.3).to_bits(), (f * 0.7 / 1.3).to_bits());
        }
    }
}
