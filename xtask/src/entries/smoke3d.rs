//! pbdl-grid's 3D smoke plume ([`Smoke3d`]) in `cargo xtask` (registered with the grid entries):
//!
//! * bench `smoke3d`: time per plume step (f32, MacCormack, inviscid, walled projection) at
//!   32^3, 64^3 and 128^3 (16^3 and 32^3 quick), measured on a plume that has risen for a few
//!   steps; the error column is the relative divergence `||D u||_2 h / ||u||_2` after the step.
//! * stress `smoke3d_plume_64`: 2,000 steps at 64^3 in f32 (about 35 min on 2 cores; 200 steps
//!   at 16^3 quick): finite, divergence below 1e-5 at every step, and the density mass against
//!   the injected mass reported (MacCormack does not conserve it).

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{StressCheck, StressMeasure, TaskContext, TaskResult};
use candle_core::DType;
use pbdl_grid::grid3d::smoke::{Smoke3d, Smoke3dConfig, Smoke3dState};
use pbdl_grid::grid3d::{fd, BoxPressure, Grid3d};

fn l2(t: &candle_core::Tensor) -> TaskResult<f64> {
    Ok(t.to_dtype(DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()?.sqrt())
}

fn rel_divergence(s: &Smoke3dState) -> TaskResult<f64> {
    let u = &s.velocity;
    let norm = l2(u.values())?;
    Ok(if norm == 0.0 { 0.0 } else { l2(&fd::divergence(u)?)? * u.grid().min_spacing() / norm })
}

/// The unit-cube plume at `n^3`, dt from CFL 0.5 on speed 1.
fn plume(n: usize) -> TaskResult<Smoke3d> {
    let grid = Grid3d::cube(n, 1.0)?;
    let dt = 0.5 * grid.min_spacing();
    Ok(Smoke3d::new(grid, Smoke3dConfig::plume(&grid, dt), BoxPressure::default())?)
}

/// The `smoke3d` bench rows (see the module docs).
pub fn bench_smoke3d(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let sizes: &[usize] = if ctx.quick { &[16, 32] } else { &[32, 64, 128] };
    let mut rows = Vec::new();
    for &n in sizes {
        let smoke = plume(n)?;
        let mut s = smoke.rest(1, DType::F32)?;
        for _ in 0..3 {
            s = smoke.step(&s, None)?;
        }
        let after = smoke.step(&s, None)?;
        let div = rel_divergence(&after)?;
        let reps = match n {
            0..=32 => 5,
            33..=64 => 3,
            _ => 1,
        };
        let seconds = median_seconds(0, reps, || smoke.step(&s, None).expect("plume step"));
        rows.push(BenchRow {
            case: "smoke3d_plume".into(),
            method: "pbdl_smoke3d_maccormack".into(),
            size: format!("{n}x{n}x{n}"),
            seconds,
            unit: "step".into(),
            error: Some(div),
            error_kind: "rel_divergence_after_step".into(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

/// The `smoke3d_plume_64` stress checks (see the module docs).
pub fn stress_smoke3d(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (n, steps) = if ctx.quick { (16, 200) } else { (64, 2000) };
    let smoke = plume(n)?;
    let mut s = smoke.rest(1, DType::F32)?;
    let (mut done, mut first_bad_div, mut worst_div, mut first_nan) = (0usize, None, 0.0f64, None);
    let progress = pbdl_core::train::Progress::new(steps as u64);
    for k in 1..=steps {
        match smoke.step(&s, None) {
            Ok(next) => s = next,
            Err(_) => {
                first_nan = Some(k as u64);
                break;
            }
        }
        let div = rel_divergence(&s)?;
        if !div.is_finite() {
            first_nan = Some(k as u64);
            break;
        }
        if div > 1e-5 {
            first_bad_div.get_or_insert(k as u64);
        }
        worst_div = worst_div.max(div);
        done = k;
        progress.set_position(k as u64);
    }
    progress.finish();
    let [dx, dy, dz] = smoke.grid().spacing();
    let mass = s.density.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()? * dx * dy * dz;
    let injected = smoke.injected_per_step() * done as f64;
    Ok(vec![
        StressCheck {
            invariant: format!("3D plume {n}^3 f32: finite for {steps} steps"),
            passed: first_nan.is_none() && done == steps,
            first_broken_step: first_nan,
            detail: format!("{done} of {steps} steps; density mass {mass:.4e} vs injected {injected:.4e} (MacCormack does not conserve it)"),
            measure: Some(StressMeasure::StableSteps(done as u64)),
        },
        StressCheck {
            invariant: "relative divergence ||D u|| h / ||u|| <= 1e-5 after every step".into(),
            passed: first_bad_div.is_none(),
            first_broken_step: first_bad_div,
            detail: format!("largest {worst_div:.2e}"),
            measure: None,
        },
    ])
}
