//! pbdl-grid's pseudo-spectral solver in `cargo xtask` (registered with the grid entries):
//!
//! * bench `spectral`: time per step of [`SpectralNavierStokes`] (fast path, f32, CN-RK4)
//!   against its error, on the cases of `bench/peers/grid_peers.py`'s JAX-CFD spectral rows:
//!   the Taylor-Green vortex to t = 1 (CFL 0.5 on |u| = 1, nu = 0.01, relative L2 velocity error
//!   against the analytic decay) at 32^2 to 256^2, and decaying turbulence from the smooth
//!   vorticity `omega_0` below to t = 1 (nu = 1e-3, CFL 0.5 on |u| = 3, relative L2 vorticity
//!   error against the same solver at 3x the resolution and a 3x shorter step in f64) at 64^2 and
//!   128^2; and the 3D ABC flow ([`SpectralNavierStokes3d`]) to t = 1 at 16^3 to 64^3 against the
//!   analytic decay, next to the finite-volume `abc_3d` rows.
//! * tour `decaying_turbulence`: the embedded scene (128^2 f64, 64^2 quick) to t = 10: vorticity
//!   PNG + GIF, and the energy budget `E(t)` against `E(0) - 2 nu int Z dt` (plot).
//! * stress `spectral_high_re`: decaying turbulence at nu = 1e-5 (Re ~ 1e5 on the box) for 2,000
//!   steps at 128^2, f32: finite, energy never grows.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::viz::{self, PlotStyle, Series};
use pbdl_grid::scene::{write_trajectory, Scene};
use pbdl_grid::spectral::{ImexScheme, SpectralConfig, SpectralNavierStokes, SpectralNavierStokes3d, SpectralState};
use pbdl_grid::Grid;
use std::f64::consts::PI;

/// The initial vorticity of the decaying-turbulence case (also in grid_peers.py): smooth, every
/// Fourier mode present, zero mean after subtracting it.
pub fn decaying_vorticity(x: f64, y: f64) -> f64 {
    (1.5 * x.cos() + (y + 0.3).sin()).exp() - (1.2 * (x - 2.0 * y).sin()).exp() + (3.0 * x + y).cos()
}

fn solver(n: usize, nu: f64, dt: f64) -> TaskResult<SpectralNavierStokes> {
    Ok(SpectralNavierStokes::new(
        Grid::square(n, 2.0 * PI)?,
        SpectralConfig { nu, dt, scheme: ImexScheme::CnRk4, drag: 0.0 },
    )?)
}

/// The decaying-turbulence state on `n^2` cell centres in `dtype`.
fn decaying_state(ns: &SpectralNavierStokes, dtype: DType) -> TaskResult<SpectralState> {
    let g = *ns.grid();
    let mut w: Vec<f64> = (0..g.cells())
        .map(|k| {
            decaying_vorticity((k % g.nx) as f64 * g.dx() + 0.5 * g.dx(), (k / g.nx) as f64 * g.dy() + 0.5 * g.dy())
        })
        .collect();
    let mean = w.iter().sum::<f64>() / w.len() as f64;
    w.iter_mut().for_each(|v| *v -= mean);
    let t = Tensor::from_vec(w, (g.ny, g.nx), &Device::Cpu)?.to_dtype(dtype)?;
    Ok(ns.state_from_vorticity(&t, [0.0, 0.0])?)
}

fn vorticity_f64(ns: &SpectralNavierStokes, s: &SpectralState) -> TaskResult<Vec<f64>> {
    Ok(ns.vorticity(s)?.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?)
}

/// `(steps, dt)`: a whole number of steps to `t_end` at CFL 0.5 on `speed`.
fn steps_to(t_end: f64, n: usize, speed: f64) -> (usize, f64) {
    let dx = 2.0 * PI / n as f64;
    let steps = (t_end / (0.5 * dx / speed)).ceil() as usize;
    (steps, t_end / steps as f64)
}

/// The `spectral` bench rows (see the module docs).
pub fn bench_spectral(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let mut rows = Vec::new();
    let row = |case: &str, n: usize, seconds: f64, error: f64, kind: &str| BenchRow {
        case: case.into(),
        method: "pbdl_spectral_cn_rk4".into(),
        size: format!("{n}x{n}"),
        seconds,
        unit: "step".into(),
        error: Some(error),
        error_kind: kind.into(),
        peer: false,
        threads: ctx.threads,
    };
    let sizes: &[usize] = if ctx.quick { &[32, 64] } else { &[32, 64, 128, 256] };
    let nu = 0.01;
    for &n in sizes {
        let (steps, dt) = steps_to(1.0, n, 1.0);
        let ns = solver(n, nu, dt)?;
        let tg =
            |amp: f64| ns.sample_velocity(DType::F32, move |x, y| [x.sin() * y.cos() * amp, -x.cos() * y.sin() * amp]);
        let s0 = ns.state_from_velocity(&tg(1.0)?)?;
        let mut s = s0.clone();
        ns.advance(&mut s, steps)?;
        let exact = tg((-2.0 * nu).exp())?.to_dtype(DType::F64)?;
        let got = ns.velocity(&s)?.to_dtype(DType::F64)?;
        let err = ((&got - &exact)?.sqr()?.sum_all()?.to_scalar::<f64>()?
            / exact.sqr()?.sum_all()?.to_scalar::<f64>()?)
        .sqrt();
        let reps = if ctx.quick { 10 } else { (4000 / n).max(10) };
        let mut timed = s0.clone();
        let seconds = median_seconds(3, reps, || ns.advance(&mut timed, 1).expect("stable step"));
        rows.push(row("taylor_green", n, seconds, err, "rel_l2_vs_analytic"));
    }
    let sizes: &[usize] = if ctx.quick { &[32] } else { &[64, 128] };
    let nu = 1e-3;
    for &n in sizes {
        let (steps, dt) = steps_to(1.0, n, 3.0);
        let ns = solver(n, nu, dt)?;
        let s0 = decaying_state(&ns, DType::F32)?;
        let mut s = s0.clone();
        ns.advance(&mut s, steps)?;
        let got = vorticity_f64(&ns, &s)?;
        // The reference at 3x the resolution needs a 3x shorter step (its largest wavenumber is
        // 3x larger), which also makes its time error 9x (CN) to 81x (RK4) smaller.
        let fine = solver(3 * n, nu, dt / 3.0)?;
        let mut r = decaying_state(&fine, DType::F64)?;
        fine.advance(&mut r, 3 * steps)?;
        let reference = vorticity_f64(&fine, &r)?;
        let (mut num, mut den) = (0.0, 0.0);
        for j in 0..n {
            for i in 0..n {
                let f = reference[(3 * j + 1) * 3 * n + 3 * i + 1];
                num += (got[j * n + i] - f).powi(2);
                den += f * f;
            }
        }
        let reps = if ctx.quick { 10 } else { (4000 / n).max(10) };
        let mut timed = s0.clone();
        let seconds = median_seconds(3, reps, || ns.advance(&mut timed, 1).expect("stable step"));
        rows.push(row("decaying_turbulence", n, seconds, (num / den).sqrt(), "rel_l2_vorticity_vs_3x_finer"));
    }
    // 3D: the ABC flow (A = B = C = 1, nu = 0.01) to t = 1, CFL 0.5 on its largest component
    // (2), as the `abc_3d` rows of the finite-volume solver.
    let sizes: &[usize] = if ctx.quick { &[16] } else { &[16, 32, 64] };
    for &n in sizes {
        let (steps, dt) = steps_to(1.0, n, 2.0);
        let grid = pbdl_grid::grid3d::Grid3d::cube(n, 2.0 * PI)?;
        let ns =
            SpectralNavierStokes3d::new(grid, SpectralConfig { nu: 0.01, dt, scheme: ImexScheme::CnRk4, drag: 0.0 })?;
        let abc = |d: f64| {
            ns.sample_velocity(DType::F32, move |x, y, z| {
                [d * (z.sin() + y.cos()), d * (x.sin() + z.cos()), d * (y.sin() + x.cos())]
            })
        };
        let s0 = ns.state_from_velocity(&abc(1.0)?)?;
        let mut s = s0.clone();
        ns.advance(&mut s, steps)?;
        let exact = abc((-0.01f64).exp())?.to_dtype(DType::F64)?;
        let got = ns.velocity(&s)?.to_dtype(DType::F64)?;
        let err = ((&got - &exact)?.sqr()?.sum_all()?.to_scalar::<f64>()?
            / exact.sqr()?.sum_all()?.to_scalar::<f64>()?)
        .sqrt();
        let reps = if ctx.quick { 3 } else { (256 / n).max(3) };
        let mut timed = s0.clone();
        let seconds = median_seconds(1, reps, || ns.advance(&mut timed, 1).expect("stable step"));
        let mut r = row("abc_3d", n, seconds, err, "rel_l2_vs_analytic");
        r.size = format!("{n}x{n}x{n}");
        rows.push(r);
    }
    Ok(rows)
}

/// The `spectral_high_re` stress checks (see the module docs).
pub fn stress_spectral_high_re(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (n, steps) = if ctx.quick { (64, 200) } else { (128, 2000) };
    let (_, dt) = steps_to(1.0, n, 3.0);
    let ns = solver(n, 1e-5, dt)?;
    let mut s = decaying_state(&ns, DType::F32)?;
    let e0 = ns.energy(&s)?;
    let (mut prev, mut grew, mut worst_growth, mut finite_steps) = (e0, 0usize, 0.0f64, 0usize);
    let mut first_grew = None;
    for k in 0..steps {
        if ns.advance(&mut s, 1).is_err() {
            break;
        }
        let e = ns.energy(&s)?;
        if !e.is_finite() {
            break;
        }
        finite_steps += 1;
        // f32 sums: growth below 1e-6 relative is round-off of the energy itself.
        if e > prev * (1.0 + 1e-6) {
            grew += 1;
            first_grew.get_or_insert(k as u64 + 1);
            worst_growth = worst_growth.max(e / prev - 1.0);
        }
        prev = e;
    }
    let three_d = stress_3d(ctx)?;
    Ok(vec![
        three_d,
        StressCheck {
            invariant: format!("finite for {steps} steps at nu = 1e-5, {n}^2 f32"),
            passed: finite_steps == steps,
            first_broken_step: (finite_steps < steps).then_some(finite_steps as u64 + 1),
            detail: format!("{finite_steps} of {steps} steps finite; energy {e0:.4e} -> {prev:.4e}"),
            measure: Some(StressMeasure::StableSteps(finite_steps as u64)),
        },
        StressCheck {
            invariant: "unforced energy never grows (beyond 1e-6 relative per step)".into(),
            passed: grew == 0,
            first_broken_step: first_grew,
            detail: format!("{grew} steps grew; largest relative growth {worst_growth:.2e}"),
            measure: None,
        },
    ])
}

/// The `decaying_turbulence` tour entry (see the module docs).
pub fn tour_decaying_turbulence(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let n = if ctx.quick { 64 } else { 128 };
    let mut sim = Scene::builtin("decaying_turbulence")?.with_resolution(n).build()?;
    let nu = 1e-3;
    let g = *sim.grid().ok_or("decaying_turbulence is a 2D scene")?;
    // Energy and enstrophy of the centred velocity and vorticity after every step.
    let budget = |sim: &pbdl_grid::scene::Simulation| -> TaskResult<(f64, f64)> {
        let f = sim.fields()?;
        let get = |name: &str| -> TaskResult<Vec<f64>> {
            let t = &f.iter().find(|(k, _)| k == name).ok_or("missing field")?.1;
            Ok(t.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?)
        };
        let cells = g.cells() as f64;
        let e = 0.5 * get("velocity")?.iter().map(|v| v * v).sum::<f64>() / cells;
        let z = 0.5 * get("vorticity")?.iter().map(|v| v * v).sum::<f64>() / cells;
        Ok((e, z))
    };
    let (e0, z0) = budget(&sim)?;
    let (mut times, mut energy, mut predicted) = (vec![0.0], vec![e0], vec![e0]);
    let (mut z_prev, mut integral) = (z0, 0.0);
    let started = std::time::Instant::now();
    let traj = sim.run(|_| {})?;
    let seconds = started.elapsed().as_secs_f64();
    // The budget from the recorded frames would be too coarse: rerun with a probe per step.
    let mut probe = Scene::builtin("decaying_turbulence")?.with_resolution(n).build()?;
    let steps = probe.steps();
    for _ in 0..steps {
        probe.step()?;
        let (e, z) = budget(&probe)?;
        integral += 0.5 * (z + z_prev) * probe.dt();
        z_prev = z;
        times.push(probe.time());
        energy.push(e);
        predicted.push(e0 - 2.0 * nu * integral);
    }
    let mut files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let png = ctx.out_dir.join("energy_budget.png");
    let style = PlotStyle {
        title: format!("decaying turbulence {n}^2: energy budget"),
        x_label: "t".into(),
        y_label: "kinetic energy".into(),
        ..Default::default()
    };
    viz::line_plot(
        &png,
        &[
            Series::new("E(t)", times.clone(), energy.clone()),
            Series::new("E(0) - 2 nu int Z dt", times, predicted.clone()),
        ],
        &style,
    )?;
    files.push(png);
    let (e1, p1) = (*energy.last().unwrap_or(&e0), *predicted.last().unwrap_or(&e0));
    let gap = (e1 - p1).abs() / (e0 - e1).abs().max(f64::MIN_POSITIVE);
    let links = super::grid::files_markdown(&files, ctx);
    let markdown = format!(
        "Pseudo-spectral decaying turbulence, {n}^2 f64, nu = 1e-3, {steps} steps to t = {:.1} in {seconds:.2} s \
         (operators: {}). Energy {e0:.5} -> {e1:.5}; the budget E(0) - 2 nu int Z dt gives {p1:.5} \
         (off by {gap:.1e} of the energy lost: time-stepping and trapezoid error).\n\n{links}",
        sim.time(),
        sim.operators().join(", ")
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("decaying_turbulence {n}^2 f64, t = 10"),
            seconds,
            error: Some(gap),
            error_kind: "energy_budget_rel_gap".into(),
            note: format!("{steps} steps"),
        }],
        files,
        markdown,
    })
}

/// 3D Taylor-Green at nu = 1e-4 (Re = 10^4 on the box), f32: unforced energy never grows and the
/// run stays finite.
fn stress_3d(ctx: &TaskContext) -> TaskResult<StressCheck> {
    let (n, steps) = if ctx.quick { (16, 50) } else { (32, 500) };
    let grid = pbdl_grid::grid3d::Grid3d::cube(n, 2.0 * PI)?;
    let (_, dt) = steps_to(1.0, n, 1.0);
    let ns = SpectralNavierStokes3d::new(grid, SpectralConfig { nu: 1e-4, dt, scheme: ImexScheme::CnRk4, drag: 0.0 })?;
    let u0 =
        ns.sample_velocity(DType::F32, |x, y, z| [x.sin() * y.cos() * z.cos(), -x.cos() * y.sin() * z.cos(), 0.0])?;
    let mut s = ns.state_from_velocity(&u0)?;
    let (mut prev, mut first_bad, mut done) = (ns.energy(&s)?, None, 0usize);
    for k in 0..steps {
        if ns.advance(&mut s, 1).is_err() {
            first_bad.get_or_insert(k as u64 + 1);
            break;
        }
        let e = ns.energy(&s)?;
        if !e.is_finite() || e > prev * (1.0 + 1e-6) {
            first_bad.get_or_insert(k as u64 + 1);
        }
        prev = e;
        done += 1;
    }
    Ok(StressCheck {
        invariant: format!("3D Taylor-Green nu = 1e-4, {n}^3 f32, {steps} steps: finite, energy never grows"),
        passed: first_bad.is_none() && done == steps,
        first_broken_step: first_bad,
        detail: format!("{done} of {steps} steps; final energy {prev:.5e} (start 0.125)"),
        measure: Some(StressMeasure::StableSteps(done as u64)),
    })
}
