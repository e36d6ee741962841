//! Time-step limits: each simulator run at growing multiples of its own time step over a fixed
//! horizon, to find the largest multiple that still gives a usable answer. Stress entries
//! `dt_limit` of pbdl-grid, pbdl-particles and pbdl-weather (registered in their modules).
//!
//! A multiple passes when the run finishes, stays finite and meets the entry's accuracy bound;
//! "refused" (the solver's own time-step check rejects it) counts as not passing. The sweep
//! stops at the first failure; the summary check reports the largest multiple before it.

use crate::registry::{StressCheck, StressMeasure, TaskContext, TaskResult};
use candle_core::DType;
use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
use pbdl_particles::{DamBreak, WcsphParams};
use pbdl_weather::standin::{run_streaming, ClimateConfig};
use std::f64::consts::PI;

/// The multiples tried, in order.
const MULTIPLES: [f64; 8] = [1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 16.0];

/// One multiple's outcome: passed, and what was measured.
type Outcome = (bool, String);

/// Runs `run(m)` for each multiple in order and stops after the first that fails: a limit
/// is found, larger multiples would only fail longer.
fn sweep(
    multiples: impl IntoIterator<Item = f64>,
    mut run: impl FnMut(f64) -> TaskResult<Outcome>,
) -> TaskResult<Vec<(f64, Outcome)>> {
    let mut outcomes = Vec::new();
    for m in multiples {
        let outcome = run(m)?;
        let failed = !outcome.0;
        outcomes.push((m, outcome));
        if failed {
            break;
        }
    }
    Ok(outcomes)
}

/// Turns per-multiple outcomes into one check each plus the summary.
fn summarize(what: &str, bar: &str, outcomes: Vec<(f64, Outcome)>) -> Vec<StressCheck> {
    let mut checks: Vec<StressCheck> = outcomes
        .iter()
        .map(|(m, (ok, detail))| StressCheck {
            invariant: format!("{what} at {m} x its time step: {bar}"),
            passed: *ok,
            first_broken_step: None,
            detail: detail.clone(),
            measure: None,
        })
        .collect();
    // Failing at large multiples is the point of the sweep; the verdict is on the default step.
    for c in checks.iter_mut().skip(1) {
        if !c.passed {
            c.detail = format!("limit found (not a failure of the entry): {}", c.detail);
            c.passed = true;
        }
    }
    let largest = outcomes.iter().take_while(|(_, (ok, _))| *ok).last().map(|(m, _)| *m);
    checks.push(StressCheck {
        invariant: format!("{what}: largest stable dt multiple ({bar})"),
        passed: largest.is_some(),
        first_broken_step: None,
        detail: match largest {
            Some(m) => format!("largest stable dt multiple: {m}"),
            None => "the default time step itself fails".into(),
        },
        measure: largest.map(StressMeasure::DtMultiple),
    });
    checks
}

/// pbdl-grid: the Taylor-Green vortex (f32, RK4, nu = 0.01) to t = 5 at the multiple times the
/// solver's own stable step for |u| = 1 (`NavierStokes::stable_time_step`), stepped with
/// `step_unchecked` so that the sweep sees the scheme, not the solver's refusal (which the
/// detail reports); passes when finite and within 5% (relative L2) of the exact solution.
pub fn grid_dt_limit(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (n, t_end) = if ctx.quick { (32, 2.0) } else { (64, 5.0) };
    let nu = 0.01;
    let grid = Grid::square(n, 2.0 * PI)?;
    let bc = Boundaries::periodic();
    let probe = NavierStokes::new(grid, bc, NavierStokesConfig { nu, dt: 1e-9, scheme: Scheme::Rk4 })?;
    let dt0 = probe.stable_time_step([1.0, 1.0]);
    let exact = |t: f64| {
        let d = (-2.0 * nu * t).exp();
        move |x: f64, y: f64| [x.sin() * y.cos() * d, -x.cos() * y.sin() * d]
    };
    let outcomes = sweep(MULTIPLES, |m| {
        let steps = (t_end / (m * dt0)).ceil() as usize;
        let dt = t_end / steps as f64;
        // The constructor refuses a step beyond the scheme's diffusion limit (velocity-free).
        let ns = match NavierStokes::new(grid, bc, NavierStokesConfig { nu, dt, scheme: Scheme::Rk4 }) {
            Ok(ns) => ns,
            Err(e) => return Ok((false, format!("dt {dt:.3e}: refused by the solver: {e}"))),
        };
        let mut u = MacField::from_fn(grid, bc, DType::F32, exact(0.0))?;
        let checked = if ns.check(&u).is_ok() { "accepted" } else { "refused" };
        let mut failed = None;
        for k in 1..=steps {
            u = ns.step_unchecked(&u)?;
            if (k % 10 == 0 || k == steps) && !u.max_abs()?.is_finite() {
                failed = Some(k);
                break;
            }
        }
        let outcome = match failed {
            Some(k) => (false, format!("dt {dt:.3e}: non-finite at step {k} (solver's own check: {checked})")),
            None => {
                let want = MacField::from_fn(grid, bc, DType::F64, exact(t_end))?;
                let (a, b) = (u.values().to_dtype(DType::F64)?, want.values().clone());
                let err =
                    ((&a - &b)?.sqr()?.sum_all()?.to_scalar::<f64>()? / b.sqr()?.sum_all()?.to_scalar::<f64>()?).sqrt();
                let ok = err.is_finite() && err <= 0.05;
                (
                    ok,
                    format!(
                        "{n}^2, dt {dt:.3e}, {steps} steps: rel. L2 error {err:.2e} (solver's own check: {checked})"
                    ),
                )
            }
        };
        Ok(outcome)
    })?;
    Ok(summarize("Taylor-Green RK4", "finite, rel. L2 error <= 5% at t_end", outcomes))
}

/// pbdl-particles: the WCSPH dam break (dx = a/20) to T = 2 with its CFL number (0.25 by
/// default, on the sound speed) times the multiple, up to the largest the solver accepts (1.0);
/// the solver refuses any step above its stable step, so the sweep moves the CFL number itself.
/// Passes when finite, no fluid particle outside the tank and the mean density error below 5%
/// at every check.
pub fn particles_dt_limit(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let t_end = if ctx.quick { 1.0 } else { 2.0 };
    let scene = DamBreak::default();
    let base = WcsphParams::default();
    let outcomes = sweep(MULTIPLES.into_iter().filter(|m| base.cfl * m <= 1.0), |m| {
        let mut sim = scene.build(WcsphParams { cfl: base.cfl * m, ..base })?;
        let t_phys = scene.physical_time(t_end);
        let mut outcome = None;
        let mut worst = 0.0f64;
        while sim.time() < t_phys * (1.0 - 1e-14) {
            let dt = sim.stable_dt().0.min(t_phys - sim.time());
            if let Err(e) = sim.step(dt) {
                outcome = Some((false, format!("step {}: {e}", sim.steps())));
                break;
            }
            if sim.steps() % 20 == 0 {
                if !sim.is_finite() {
                    outcome = Some((false, format!("non-finite at step {}", sim.steps())));
                    break;
                }
                worst = worst.max(sim.mean_density_error());
                if sim.leaked() > 0 || worst > 0.05 {
                    outcome = Some((
                        false,
                        format!("step {}: {} outside, mean density error {worst:.3}", sim.steps(), sim.leaked()),
                    ));
                    break;
                }
            }
        }
        let outcome = outcome.unwrap_or_else(|| {
            let ok = sim.is_finite() && sim.leaked() == 0 && worst <= 0.05;
            (
                ok,
                format!(
                    "CFL {}: {} steps to T = {t_end}: mean density error max {worst:.4}, {} outside",
                    base.cfl * m,
                    sim.steps(),
                    sim.leaked()
                ),
            )
        });
        Ok(outcome)
    })?;
    Ok(summarize("WCSPH dam break", "finite, no leak, mean density error <= 5%", outcomes))
}

/// pbdl-weather: the stand-in climate (spectral shallow water) for 60 days after a 10-day
/// spin-up with the multiple times its 1200 s step (multiples that divide the 6-hour output
/// interval); passes when it stays finite and z500 / t850 in the plausible ranges of the
/// years-long stress entry.
pub fn weather_dt_limit(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let days = if ctx.quick { 20.0 } else { 60.0 };
    let outcomes = sweep([1.0, 1.5, 2.0, 3.0, 4.5, 6.0, 9.0, 18.0], |m| {
        let cfg = ClimateConfig::default();
        let cfg = ClimateConfig { dt: cfg.dt * m, ..cfg };
        let (mut z, mut t) = ((f64::MAX, f64::MIN), (f64::MAX, f64::MIN));
        let result = run_streaming(
            &cfg,
            0,
            10.0,
            days,
            |_| {},
            |o| {
                for &v in o.z {
                    z = (z.0.min(v), z.1.max(v));
                }
                for &v in o.t {
                    t = (t.0.min(v), t.1.max(v));
                }
                Ok(())
            },
        );
        let outcome = match result {
            Err(e) => (false, format!("dt {:.0} s: {e}", cfg.dt)),
            Ok(_) => {
                let ok = z.0 >= 2.0e4 && z.1 <= 8.0e4 && t.0 >= 150.0 && t.1 <= 350.0;
                (ok, format!("dt {:.0} s, {days} days: z {:.0}..{:.0}, t {:.1}..{:.1}", cfg.dt, z.0, z.1, t.0, t.1))
            }
        };
        Ok(outcome)
    })?;
    Ok(summarize("stand-in climate", "finite, z in 2e4..8e4, t in 150..350 K", outcomes))
}
