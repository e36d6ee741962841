//! Flow diagnostics: kinetic energy, incompressibility, shedding frequency, and a tracker that
//! steps a [`Simulation`] and records the first step at which an invariant breaks.
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
}
