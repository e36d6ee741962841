//! pbdl-grid's entries for `cargo xtask` (see [`crate::registry`]).
//!
//! * tour `taylor_green`: the embedded Taylor-Green scene at 64^2 (f32) against the analytic
//!   decay; vorticity PNG + GIF.
//! * tour `lid_driven_cavity`: Re = 100 at 64^2 to t = 20 against Ghia, Ghia & Shin (1982);
//!   centreline plot against the Ghia points and the speed PNG.
//! * tour `burgers_1d`: viscous Burgers against the Cole-Hopf solution; line plot and space-time
//!   image.
//! * bench `taylor_green`: time per Navier-Stokes step against the relative L2 velocity error at
//!   t = 1 (f32, CFL 0.5, nu = 0.01), RK4 and SSP-RK3, 32^2 to 256^2 (32^2 and 64^2 when quick).
//! * bench `lid_driven_cavity`: time per step against the max centreline error vs Ghia at
//!   Re = 100, 64^2 and 128^2 (64^2 when quick).
//! * bench `abc_3d`: time per 3D Navier-Stokes RK4 step against the relative L2 error of the ABC
//!   flow at t = 1 (f32, CFL 0.5, nu = 0.01), 16^3 to 64^3 (16^3 and 32^3 when quick).
//! * stress `decaying_turbulence`, `decaying_taylor_green`: unforced flows stay finite and
//!   divergence-free and never gain energy; `kolmogorov`: the forced flow stays finite,
//!   divergence-free and bounded. Each check names the first step at which it broke.
//! * tour `smoke_plume`: the embedded plume scene (64 x 96, 400 MacCormack steps; 32 x 48 and 150
//!   steps when quick); density PNG + GIF, the density mass against what the source injected.
//! * tour `karman_street`: the embedded cylinder scene (Re = 100, 32 D x 32 D, blockage 1/32) at
//!   5 cells per diameter (4 and t = 90 when quick); vorticity PNG + GIF and the Strouhal number
//!   from a probe against Williamson's 0.165.
//! * stress `smoke_plume_long`: 10,000 plume steps at 128^2 (500 quick): finite, divergence
//!   bounded, density within [0, injected], speed bounded.
//! * stress `karman_re1000`: the cylinder scene at Re = 1000: finite, divergence bounded, speed
//!   bounded.
//! * stress `acceptance`: the README's cavity Re 1000, cylinder Strouhal and ABC 64^3 numbers
//!   from their `#[ignore]`d tests ([`crate::acceptance`]).

use crate::acceptance::AcceptanceTest;
use crate::bench_schema::{measured_peer, median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::{DType, Device, Tensor};
use pbdl_core::viz::{self, PlotStyle, Series};
use pbdl_grid::diagnostics::{strouhal_zero_crossings, track_invariants, InvariantBounds, InvariantReport};
use pbdl_grid::scalar_law::cole_hopf_sine;
use pbdl_grid::scene::{write_trajectory, Scene, Simulation, State};
use pbdl_grid::validation::{cavity_centrelines, GhiaTable};
use pbdl_grid::{fd, Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
use std::f64::consts::PI;
use std::time::Instant;

/// The entries of `pbdl-grid`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "grid",
        tour: vec![
            Entry {
                name: "taylor_green",
                about: "Taylor-Green vortex (embedded scene, 64^2, f32, t = 1) against the analytic decay; vorticity PNG + GIF.",
                run: tour_taylor_green,
            },
            Entry {
                name: "lid_driven_cavity",
                about: "Lid-driven cavity, Re = 100, 64^2, to steady state; centrelines against Ghia, Ghia & Shin (1982).",
                run: tour_cavity,
            },
            Entry {
                name: "burgers_1d",
                about: "1D viscous Burgers from -sin(pi x), 256 cells, t = 0.5, against the Cole-Hopf solution.",
                run: tour_burgers,
            },
            Entry {
                name: "smoke_plume",
                about: "Buoyant smoke plume (embedded scene, 64 x 96, 400 MacCormack steps); density PNG + GIF.",
                run: tour_smoke,
            },
            Entry {
                name: "decaying_turbulence",
                about: "Pseudo-spectral decaying turbulence (embedded scene, 128^2 f64, t = 10): vorticity PNG + GIF, energy budget against 2 nu int Z.",
                run: super::spectral::tour_decaying_turbulence,
            },
            Entry {
                name: "karman_street",
                about: "Flow past a cylinder at Re = 100 (blockage 1/32): vorticity PNG + GIF, Strouhal number vs Williamson (1996).",
                run: tour_karman,
            },
        ],
        bench: vec![
            Entry {
                name: "smoke3d",
                about: "3D smoke plume (f32, MacCormack, walled projection): time per step at 32^3, 64^3, 128^3 (16^3, 32^3 quick), divergence after the step.",
                run: super::smoke3d::bench_smoke3d,
            },
            Entry {
                name: "spectral",
                about: "Pseudo-spectral Navier-Stokes (f32, CN-RK4): Taylor-Green 32^2..256^2 vs analytic, decaying turbulence 64^2/128^2 vs 3x finer; JAX-CFD's spectral rows from bench/peers/run.sh.",
                run: super::spectral::bench_spectral,
            },
            Entry {
                name: "taylor_green",
                about:
                    "Taylor-Green vortex: time per Navier-Stokes step against the velocity error at t = 1, 32^2 to 256^2.",
                run: bench_taylor_green,
            },
            Entry {
                name: "lid_driven_cavity",
                about: "Lid-driven cavity Re = 100: time per step against the max centreline error vs Ghia, 64^2 and 128^2.",
                run: bench_cavity,
            },
            Entry {
                name: "abc_3d",
                about: "3D ABC flow (periodic, f32, RK4): time per step against the velocity error at t = 1, 16^3 to 64^3.",
                run: bench_abc_3d,
            },
        ],
        stress: vec![
            Entry {
                name: "decaying_turbulence",
                about: "Unforced random flow, nu = 1e-3, 2,000 steps (500 quick): finite, divergence-free, energy never grows.",
                run: stress_decaying_turbulence,
            },
            Entry {
                name: "decaying_taylor_green",
                about: "Taylor-Green vortex to t = 50 (10 quick): finite, divergence-free, energy never grows, decay rate exact.",
                run: stress_decaying_tgv,
            },
            Entry {
                name: "kolmogorov",
                about: "Forced Kolmogorov flow to t = 60 (10 quick) at 64^2: finite, divergence-free, energy bounded.",
                run: stress_kolmogorov,
            },
            Entry {
                name: "smoke_plume_long",
                about: "Smoke plume, 10,000 steps at 128^2 (500 quick): finite, divergence bounded, density in [0, injected].",
                run: stress_smoke,
            },
            Entry {
                name: "smoke3d_plume_64",
                about: "3D smoke plume, 2,000 steps at 64^3 f32 (~35 min; 200 at 16^3 quick): finite, divergence <= 1e-5 every step, mass reported.",
                run: super::smoke3d::stress_smoke3d,
            },
            Entry {
                name: "spectral_high_re",
                about: "Pseudo-spectral decaying turbulence at nu = 1e-5, 2,000 steps at 128^2 f32 (200 at 64^2 quick): finite, unforced energy never grows.",
                run: super::spectral::stress_spectral_high_re,
            },
            Entry {
                name: "dt_limit",
                about: "Taylor-Green RK4 at 1..16x the solver's stable step, unchecked, to t = 5 (64^2; 32^2 to t = 2 quick): largest multiple with error <= 5%.",
                run: super::stability::grid_dt_limit,
            },
            Entry {
                name: "karman_re1000",
                about: "Flow past a cylinder at Re = 1000 to t = 150 (t = 20 quick): finite, divergence bounded, speed bounded.",
                run: stress_karman,
            },
            Entry {
                name: "acceptance",
                about: "The README's cavity Re 1000, cylinder Strouhal and ABC 64^3 numbers: runs their #[ignore]d tests in release (about 8 min; all quick).",
                run: stress_acceptance,
            },
        ],
    }
}

fn rel_l2(a: &Tensor, b: &Tensor) -> candle_core::Result<f64> {
    let (a, b) = (a.to_dtype(DType::F64)?, b.to_dtype(DType::F64)?);
    Ok(((&a - &b)?.sqr()?.sum_all()?.to_scalar::<f64>()? / b.sqr()?.sum_all()?.to_scalar::<f64>()?).sqrt())
}

pub(crate) fn files_markdown(files: &[std::path::PathBuf], ctx: &TaskContext) -> String {
    files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "png" || e == "gif"))
        .map(|f| {
            // Relative to the entry's folder; the tour rewrites links relative to its report.
            let rel = f.strip_prefix(&ctx.out_dir).unwrap_or(f);
            format!("![{}]({})", rel.display(), rel.display())
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn tour_taylor_green(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let n = if ctx.quick { 32 } else { 64 };
    let mut sim = Scene::builtin("taylor_green")?.with_resolution(n).build()?;
    let t = Instant::now();
    let traj = sim.run(|_| {})?;
    let seconds = t.elapsed().as_secs_f64();
    let State::Velocity(u) = sim.state() else { return Err("taylor_green is a velocity scene".into()) };
    let d = (-2.0f64 * 0.01 * sim.time()).exp();
    let exact = MacField::from_fn(*u.grid(), Boundaries::periodic(), DType::F64, |x, y| {
        [x.sin() * y.cos() * d, -x.cos() * y.sin() * d]
    })?;
    let err = rel_l2(u.values(), exact.values())?;
    let files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let steps = sim.step_index();
    let markdown = format!(
        "{n}^2, f32, {steps} RK4 steps to t = {:.2} (operators: {}): relative L2 velocity error {err:.2e} against \
         `u = sin x cos y e^(-2 nu t)` in {seconds:.2} s ({:.3} ms/step).\n\n{}",
        sim.time(),
        sim.operators().join(", "),
        1e3 * seconds / steps as f64,
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("taylor_green {n}^2 f32, t = 1"),
            seconds,
            error: Some(err),
            error_kind: "rel_l2_vs_analytic".into(),
            note: format!("{steps} steps"),
        }],
        files,
        markdown,
    })
}

/// Runs the cavity scene at `n^2` to its end time (t = 20, steady at Re = 100).
fn run_cavity(n: usize) -> TaskResult<(Simulation, pbdl_grid::scene::Trajectory, f64)> {
    let mut sim = Scene::builtin("lid_driven_cavity")?.with_resolution(n).build()?;
    let t = Instant::now();
    let traj = sim.run(|_| {})?;
    Ok((sim, traj, t.elapsed().as_secs_f64()))
}

fn tour_cavity(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let n = if ctx.quick { 32 } else { 64 };
    let (sim, traj, seconds) = run_cavity(n)?;
    let State::Velocity(u) = sim.state() else { return Err("cavity is a velocity scene".into()) };
    let c = cavity_centrelines(u)?;
    let ghia = GhiaTable::for_reynolds(100.0)?;
    let (err_u, err_v) = c.max_errors(&ghia);
    let mut files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let (gu, gv) = (&ghia.u_vertical, &ghia.v_horizontal);
    let split =
        |p: &[(f64, f64)]| (p.iter().map(|q| q.0).collect::<Vec<_>>(), p.iter().map(|q| q.1).collect::<Vec<_>>());
    let series = [
        Series::new(format!("u(0.5, y), pbdl {n}^2"), split(&c.u).0, split(&c.u).1),
        Series::new("u(0.5, y), Ghia 1982", split(gu).0, split(gu).1),
        Series::new(format!("v(x, 0.5), pbdl {n}^2"), split(&c.v).0, split(&c.v).1),
        Series::new("v(x, 0.5), Ghia 1982", split(gv).0, split(gv).1),
    ];
    let png = ctx.out_dir.join("cavity_centrelines.png");
    let style = PlotStyle {
        title: format!("lid-driven cavity Re = 100, {n}^2 vs Ghia et al. (1982)"),
        x_label: "y (for u) / x (for v)".into(),
        y_label: "velocity".into(),
        ..Default::default()
    };
    viz::line_plot(&png, &series, &style)?;
    files.push(png);
    let steps = sim.step_index();
    // PhiFlow's error on the same case, only as measured by the peer script (never a quoted number).
    let bench_dir = ctx.out_dir.parent().and_then(|p| p.parent()).map(|p| p.join("bench"));
    let size = format!("{n}x{n}");
    let phiflow = match bench_dir.and_then(|d| measured_peer(&d, "grid", "lid_driven_cavity_re100", "phiflow", &size)) {
        Some((row, src)) => format!(
            "PhiFlow ({}, `{}`, measured {} by {}): max error {:.4}",
            src.versions,
            row.method,
            src.date,
            src.script,
            row.error.unwrap_or(f64::NAN)
        ),
        None => format!("PhiFlow at {n}^2: not measured here (`bench/peers/run.sh` measures it)"),
    };
    let markdown = format!(
        "{n}^2, f32, {steps} RK4 steps to t = {:.1} ({:.3} ms/step; operators: {}). Max |u - Ghia| on \
         the vertical centreline {:.4}, max |v - Ghia| on the horizontal one {:.4}. {phiflow}. Ghia's \
         points are joined by straight lines.\n\n{}",
        sim.time(),
        1e3 * seconds / steps as f64,
        sim.operators().join(", "),
        err_u,
        err_v,
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("lid_driven_cavity Re100 {n}^2 f32"),
            seconds,
            error: Some(err_u.max(err_v)),
            error_kind: "max centreline |u - Ghia|, |v - Ghia|".into(),
            note: format!("u {err_u:.4}, v {err_v:.4}; {steps} steps"),
        }],
        files,
        markdown,
    })
}

fn tour_burgers(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let mut sim = Scene::builtin("burgers_1d")?.build()?;
    let t = Instant::now();
    let traj = sim.run(|_| {})?;
    let seconds = t.elapsed().as_secs_f64();
    let State::Scalar(u) = sim.state() else { return Err("burgers_1d is a scalar scene".into()) };
    let g = sim.scene().grid;
    let dx = g.lx / g.nx as f64;
    let nu = match sim.scene().physics {
        pbdl_grid::scene::Physics::Burgers1d { nu } => nu,
        _ => return Err("burgers_1d physics".into()),
    };
    let exact: Vec<f64> =
        (0..g.nx).map(|i| cole_hopf_sine(g.origin[0] + (i as f64 + 0.5) * dx, sim.time(), nu)).collect();
    let exact = Tensor::from_vec(exact, u.shape(), &Device::Cpu)?;
    let err = rel_l2(u, &exact)?;
    let files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let markdown = format!(
        "{} cells, f64, {} RK4 steps to t = {:.2}, nu = 0.05/pi: relative L2 error {err:.2e} against the \
         Cole-Hopf solution (second order: `cargo test -p pbdl-grid --test burgers`).\n\n{}",
        g.nx,
        sim.step_index(),
        sim.time(),
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("burgers_1d {} cells f64, t = 0.5", g.nx),
            seconds,
            error: Some(err),
            error_kind: "rel_l2_vs_cole_hopf".into(),
            note: format!("{} steps", sim.step_index()),
        }],
        files,
        markdown,
    })
}

fn bench_cavity(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let sizes: &[usize] = if ctx.quick { &[64] } else { &[64, 128] };
    let mut rows = Vec::new();
    for &n in sizes {
        let (sim, _, _) = run_cavity(n)?;
        let State::Velocity(u) = sim.state() else { return Err("cavity is a velocity scene".into()) };
        let (err_u, err_v) = cavity_centrelines(u)?.max_errors(&GhiaTable::for_reynolds(100.0)?);
        let g = Grid::square(n, 1.0)?;
        let bc = Boundaries::lid_driven_cavity(1.0);
        let ns = NavierStokes::new(g, bc, NavierStokesConfig { nu: 0.01, dt: sim.dt(), scheme: Scheme::Rk4 })?;
        let reps = if ctx.quick { 20 } else { 100 };
        let seconds = median_seconds(5, reps, || ns.step(u).expect("stable step"));
        rows.push(BenchRow {
            case: "lid_driven_cavity_re100".into(),
            method: "pbdl_fv_rk4".into(),
            size: format!("{n}x{n}"),
            seconds,
            unit: "step".into(),
            error: Some(err_u.max(err_v)),
            error_kind: "max_centreline_abs_vs_ghia".into(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

/// Speed cap of the stress runs (5 U for the unit-inflow cylinder; the other flows stay far below).
const SPEED_CAP: f64 = 5.0;

/// Steps `sim` with the stress entries' bounds (see [`track_invariants`]).
fn track(
    sim: &mut Simulation,
    steps: usize,
    decaying: bool,
    energy_growth: f64,
    energy_cap: f64,
) -> TaskResult<InvariantReport> {
    let bounds =
        InvariantBounds { divergence: DIV_BOUND_F32, decaying, energy_growth, energy_cap, speed_cap: SPEED_CAP };
    Ok(track_invariants(sim, steps, &bounds)?)
}

fn checks(inv: &InvariantReport, steps: usize, decaying: bool, div_bound: f64, rel_tol: f64) -> Vec<StressCheck> {
    let mut out = vec![
        StressCheck {
            invariant: "values finite (and every step stable)".into(),
            passed: inv.first_nonfinite.is_none(),
            first_broken_step: inv.first_nonfinite,
            detail: inv.error.clone().unwrap_or_else(|| format!("{steps} steps")),
            measure: inv.first_nonfinite.is_none().then_some(StressMeasure::StableSteps(steps as u64)),
        },
        StressCheck {
            invariant: format!("max |div u| dx / max |u| <= {div_bound:.0e} after every step"),
            passed: inv.first_divergence.is_none(),
            first_broken_step: inv.first_divergence,
            detail: format!("worst {:.2e}", inv.worst_divergence),
            measure: None,
        },
    ];
    if decaying {
        out.push(StressCheck {
            invariant: format!("energy never grows (relative step-to-step growth <= {rel_tol:.0e})"),
            passed: inv.first_energy_growth.is_none(),
            first_broken_step: inv.first_energy_growth,
            detail: format!(
                "energy {:.4e} -> {:.4e}; largest step-to-step change {:+.2e}",
                inv.energy_start, inv.energy_last, inv.worst_growth
            ),
            measure: None,
        });
    }
    out
}

/// f32 divergence bound: the projection leaves round-off `~ 1e-7 |u| / dx` per step; 1e-4 is
/// three orders above that and far below any real loss of incompressibility.
const DIV_BOUND_F32: f64 = 1e-4;
/// f32 energy round-off per step (the energy sum has ~1e-7 relative error).
const ENERGY_TOL_F32: f64 = 1e-6;

fn stress_decaying_turbulence(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (n, steps) = if ctx.quick { (64, 500) } else { (128, 2000) };
    let text = include_str!("../../../pbdl-grid/scenes/taylor_green.toml")
        .replace("nu = 0.01", "nu = 0.001")
        .replace("kind = \"taylor_green\"", "kind = \"random_modes\"\namplitude = 1.0\nmax_wavenumber = 4\nseed = 5");
    let mut sim = Scene::from_toml_str(&text, "decaying_turbulence")?.with_resolution(n).with_steps(steps).build()?;
    let inv = track(&mut sim, steps, true, ENERGY_TOL_F32, f64::INFINITY)?;
    let mut c = checks(&inv, steps, true, DIV_BOUND_F32, ENERGY_TOL_F32);
    for x in &mut c {
        x.detail = format!("{n}^2 f32, nu = 1e-3, dt = {:.3e}: {}", sim.dt(), x.detail);
    }
    Ok(c)
}

fn stress_decaying_tgv(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let (n, t_end) = if ctx.quick { (32, 10.0) } else { (64, 50.0) };
    let mut sim = Scene::builtin("taylor_green")?.with_resolution(n).build()?;
    let steps = (t_end / sim.dt()).round() as usize;
    let inv = track(&mut sim, steps, true, ENERGY_TOL_F32, f64::INFINITY)?;
    let mut c = checks(&inv, steps, true, DIV_BOUND_F32, ENERGY_TOL_F32);
    // The energy decays as exp(-4 nu t) (a discrete rate differs by O(dx^2)).
    let expect = (-4.0 * 0.01 * sim.time()).exp();
    let got = inv.energy_last / inv.energy_start;
    let rate_err = (got - expect).abs() / expect;
    c.push(StressCheck {
        invariant: "energy decays at the analytic rate exp(-4 nu t) within 1%".into(),
        passed: rate_err < 0.01,
        first_broken_step: if rate_err < 0.01 { None } else { Some(steps as u64) },
        detail: format!("{n}^2 f32 t = {:.1}: E/E0 = {got:.5}, exp(-4 nu t) = {expect:.5}", sim.time()),
        measure: None,
    });
    Ok(c)
}

fn stress_kolmogorov(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let mut sim = Scene::builtin("kolmogorov")?.with_resolution(64).build()?;
    let t_end = if ctx.quick { 10.0 } else { 60.0 };
    let steps = (t_end / sim.dt()).round() as usize;
    // The laminar Kolmogorov state u = A / (nu k^2 + drag) sin(k y) bounds the energy of the
    // forced, dragged flow in practice; allow 4x.
    let (a, k, nu, drag) = (1.0f64, 4.0f64, 0.01f64, 0.1f64);
    let ul = a / (nu * k * k + drag);
    let laminar = 0.25 * ul * ul * (2.0 * PI) * (2.0 * PI);
    let inv = track(&mut sim, steps, false, 0.0, 4.0 * laminar)?;
    let mut c = checks(&inv, steps, false, DIV_BOUND_F32, 0.0);
    c.push(StressCheck {
        invariant: "energy stays below 4x the laminar Kolmogorov energy".into(),
        passed: inv.first_above_energy_cap.is_none(),
        first_broken_step: inv.first_above_energy_cap,
        detail: format!("64^2 f32 t = {:.1}: max energy {:.3e}, laminar {:.3e}", sim.time(), inv.max_energy, laminar),
        measure: None,
    });
    Ok(c)
}

fn bench_taylor_green(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let sizes: &[usize] = if ctx.quick { &[32, 64] } else { &[32, 64, 128, 256] };
    let nu = 0.01;
    let mut rows = Vec::new();
    for scheme in [Scheme::Rk4, Scheme::SspRk3] {
        for &n in sizes {
            let grid = Grid::square(n, 2.0 * PI)?;
            let bc = Boundaries::periodic();
            let probe = NavierStokes::new(grid, bc, NavierStokesConfig { nu, dt: 1e-9, scheme })?;
            // CFL 0.5 on |u|max = 1, reduced where the scheme's stability limit requires it.
            let dt_max = (0.5 * grid.dx()).min(probe.stable_time_step([1.0, 1.0]));
            let steps = (1.0 / dt_max).ceil() as usize;
            let ns = NavierStokes::new(grid, bc, NavierStokesConfig { nu, dt: 1.0 / steps as f64, scheme })?;
            let field = |t: f64| {
                let d = (-2.0 * nu * t).exp();
                move |x: f64, y: f64| [x.sin() * y.cos() * d, -x.cos() * y.sin() * d]
            };
            let u0 = MacField::from_fn(grid, bc, DType::F32, field(0.0))?;
            let mut u = u0.clone();
            for _ in 0..steps {
                u = ns.step(&u)?;
            }
            let exact = MacField::from_fn(grid, bc, DType::F64, field(1.0))?.into_values();
            let got = u.values().to_dtype(DType::F64)?;
            let err = ((&got - &exact)?.sqr()?.sum_all()?.to_scalar::<f64>()?
                / exact.sqr()?.sum_all()?.to_scalar::<f64>()?)
            .sqrt();
            let reps = if ctx.quick { 10 } else { (2000 / n).max(10) };
            let seconds = median_seconds(3, reps, || ns.step(&u0).expect("stable step"));
            rows.push(BenchRow {
                case: "taylor_green".into(),
                method: format!("pbdl_fv_{}", format!("{scheme:?}").to_lowercase()),
                size: format!("{n}x{n}"),
                seconds,
                unit: "step".into(),
                error: Some(err),
                error_kind: "rel_l2_vs_analytic".into(),
                peer: false,
                threads: ctx.threads,
            });
        }
    }
    Ok(rows)
}

/// 3D ABC flow on `[0, 2 pi]^3` (A = B = C = 1, nu = 0.01), f32, RK4, CFL 0.5 on the largest
/// component (2): time per `NavierStokes3d` step against the relative L2 error at t = 1 over all
/// faces, 16^3, 32^3 and 64^3 (64^3 only when not quick).
fn bench_abc_3d(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    use pbdl_grid::grid3d::{abc::abc_flow, Grid3d, NavierStokes3d, NavierStokes3dConfig};
    let sizes: &[usize] = if ctx.quick { &[16, 32] } else { &[16, 32, 64] };
    let (nu, coef) = (0.01, [1.0, 1.0, 1.0]);
    let mut rows = Vec::new();
    for &n in sizes {
        let grid = Grid3d::cube(n, 2.0 * PI)?;
        let steps = (1.0 / (0.5 * grid.min_spacing() / 2.0)).ceil() as usize;
        let ns = NavierStokes3d::new(grid, NavierStokes3dConfig { nu, dt: 1.0 / steps as f64, scheme: Scheme::Rk4 })?;
        let u0 = abc_flow(grid, coef, nu, 0.0, DType::F32)?;
        let mut u = u0.clone();
        for _ in 0..steps {
            u = ns.step(&u)?;
        }
        let exact = abc_flow(grid, coef, nu, 1.0, DType::F64)?;
        let err = rel_l2(u.values(), exact.values())?;
        let reps = if ctx.quick { 5 } else { (1280 / n).max(10) };
        let seconds = median_seconds(2, reps, || ns.step(&u0).expect("stable step"));
        rows.push(BenchRow {
            case: "abc_3d".into(),
            method: "pbdl_fv_rk4".into(),
            size: format!("{n}x{n}x{n}"),
            seconds,
            unit: "step".into(),
            error: Some(err),
            error_kind: "rel_l2_vs_analytic".into(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

fn scalar_sum(t: &Tensor) -> candle_core::Result<f64> {
    t.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()
}

fn min_max(t: &Tensor) -> candle_core::Result<(f64, f64)> {
    let t = t.to_dtype(DType::F64)?;
    Ok((t.min_all()?.to_scalar::<f64>()?, t.max_all()?.to_scalar::<f64>()?))
}

/// The smoke scene's source: `(rate, cells covered)`.
fn smoke_source(sim: &Simulation) -> TaskResult<(f64, f64)> {
    let pbdl_grid::scene::Physics::Smoke { source, .. } = sim.scene().physics else {
        return Err("smoke_plume is a smoke scene".into());
    };
    let g = sim.scene().grid;
    let (dx, dy) = (g.lx / g.nx as f64, g.ly / g.ny as f64);
    let mut cells = 0.0;
    for j in 0..g.ny {
        for i in 0..g.nx {
            let (x, y) = (g.origin[0] + (i as f64 + 0.5) * dx, g.origin[1] + (j as f64 + 0.5) * dy);
            if (x - source.center[0]).powi(2) + (y - source.center[1]).powi(2) <= source.radius * source.radius {
                cells += 1.0;
            }
        }
    }
    Ok((source.rate, cells))
}

fn tour_smoke(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let mut scene = Scene::builtin("smoke_plume")?;
    if ctx.quick {
        scene = scene.with_resolution(32).with_steps(150);
    }
    let mut sim = scene.build()?;
    let t = Instant::now();
    let traj = sim.run(|_| {})?;
    let seconds = t.elapsed().as_secs_f64();
    let (Some(rho), Some(u)) = (sim.state().density(), sim.state().velocity()) else {
        return Err("smoke_plume has a density and a velocity".into());
    };
    // Mass: the source adds dt * rate to each covered cell every step; the closed box and the
    // zero-gradient density keep it all (up to MacCormack's non-conservation).
    let (rate, cells) = smoke_source(&sim)?;
    let injected = sim.step_index() as f64 * sim.dt() * rate * cells;
    let mass = scalar_sum(rho.values())?;
    let mass_err = (mass - injected).abs() / injected;
    let (lo, hi) = min_max(rho.values())?;
    let g = sim.scene().grid;
    let vals = rho.values().to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let centre_y = vals.iter().enumerate().map(|(k, r)| r * ((k / g.nx) as f64 + 0.5)).sum::<f64>() / mass.max(1e-300)
        * g.ly
        / g.ny as f64;
    let div = fd::divergence(u)?.into_values().abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
    let umax = u.max_abs()?;
    let files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let steps = sim.step_index();
    let markdown = format!(
        "{}x{}, f32, {steps} steps of dt = {:.3e} to t = {:.2} (operators: {}) in {seconds:.2} s ({:.3} ms/step). \
         Density in [{lo:.2e}, {hi:.3}], mass {mass:.4} against {injected:.4} injected (relative difference \
         {mass_err:.2e}: MacCormack with its limiter is not exactly conservative); density centre of mass at \
         y = {centre_y:.3} (source at y = 0.15); max |u| = {umax:.3}, max |div u| dx / max |u| = {:.1e}.\n\n{}",
        g.nx,
        g.ny,
        sim.dt(),
        sim.time(),
        sim.operators().join(", "),
        1e3 * seconds / steps as f64,
        div * g.lx / g.nx as f64 / umax.max(1e-300),
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("smoke_plume {}x{} f32, {steps} steps", g.nx, g.ny),
            seconds,
            error: Some(mass_err),
            error_kind: "rel |density mass - injected|".into(),
            note: format!("centre of mass y = {centre_y:.3}, max |u| {umax:.3}"),
        }],
        files,
        markdown,
    })
}

/// Williamson (1996), Annu. Rev. Fluid Mech. 28:477-539: unconfined cylinder, Re = 100.
const ST_WILLIAMSON: f64 = 0.165;

/// The first circle of a cylinder scene: `(centre, diameter)`.
fn first_circle(scene: &Scene) -> TaskResult<([f64; 2], f64)> {
    scene
        .obstacles
        .iter()
        .find_map(|o| match *o {
            pbdl_grid::scene::Obstacle::Circle { center, radius } => {
                Some(([center[0] - scene.grid.origin[0], center[1] - scene.grid.origin[1]], 2.0 * radius))
            }
            _ => None,
        })
        .ok_or_else(|| "the cylinder scene has no circle".into())
}

fn tour_karman(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let mut scene = Scene::builtin("cylinder")?;
    // Quick mode: 4 cells/D to t = 90 (3 cells/D does not shed by t = 60).
    let cells_per_d = if ctx.quick { 4 } else { KARMAN_CELLS_PER_D };
    let (centre, d) = first_circle(&scene)?;
    let n = (scene.grid.lx / d * cells_per_d as f64).round() as usize;
    scene = scene.with_resolution(n);
    if ctx.quick {
        scene.time.t_end = Some(90.0);
        scene.time.frames = 31;
    }
    let mut sim = scene.build()?;
    let grid = *sim.grid().ok_or("cylinder is 2D")?;
    let pbdl_grid::scene::Physics::Cylinder { inflow, nu, .. } = sim.scene().physics else {
        return Err("cylinder physics".into());
    };
    // Probe: the v face nearest to 1.5 D behind the cylinder on its axis.
    let pi = ((centre[0] + 1.5 * d) / grid.dx() - 0.5).round() as usize;
    let pj = (centre[1] / grid.dy() - 1.0).round() as usize;
    let idx = grid.cells() + pj * grid.nx + pi;
    let mut signal = Vec::with_capacity(sim.steps());
    let t = Instant::now();
    let mut probe_err = None;
    let traj = sim.run_observed(|s, _| {
        let v = s
            .velocity()
            .map(|u| u.values().flatten_all().and_then(|f| f.get(idx)).and_then(|x| x.to_dtype(DType::F64)))
            .and_then(|r| r.ok())
            .and_then(|x| x.to_scalar::<f64>().ok());
        match v {
            Some(v) => signal.push(v),
            None => probe_err = Some("probe read failed"),
        }
    })?;
    let seconds = t.elapsed().as_secs_f64();
    if let Some(e) = probe_err {
        return Err(e.into());
    }
    let (st, periods) = strouhal_zero_crossings(&signal, sim.dt(), d, inflow);
    let rel = (st - ST_WILLIAMSON).abs() / ST_WILLIAMSON;
    let tail = &signal[2 * signal.len() / 3..];
    let amp = tail.iter().cloned().fold(f64::MIN, f64::max) - tail.iter().cloned().fold(f64::MAX, f64::min);
    let files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let steps = sim.step_index();
    let blockage = d / grid.ly;
    let re = inflow * d / nu;
    let markdown = format!(
        "Re = {re:.0}, {}x{} ({cells_per_d} cells per diameter), f32, {steps} steps of dt = {:.3e} to t = {:.0} D/U \
         (operators: {}) in {seconds:.2} s ({:.3} ms/step). Transverse velocity 1.5 D behind the cylinder: \
         peak-to-peak {amp:.3} U over the last third; Strouhal number {st:.4} from {periods} periods in the \
         second half, against Williamson's (1996) 0.165 for the unconfined cylinder: {:.1}% off. Blockage \
         D/H = 1/{:.0} (free-slip walls 16 D from the axis), a staircase cylinder. The accuracy test \
         (`cargo test -p pbdl-grid --test cylinder -- --ignored`, 8 cells/D, central flux form + RK4) asks for 5%.\n\n{}",
        grid.nx,
        grid.ny,
        sim.dt(),
        sim.time(),
        sim.operators().join(", "),
        1e3 * seconds / steps as f64,
        100.0 * rel,
        1.0 / blockage,
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("karman_street Re{re:.0} {}x{} f32 ({cells_per_d} cells/D)", grid.nx, grid.ny),
            seconds,
            error: Some(rel),
            error_kind: "rel |St - 0.165| (Williamson 1996)".into(),
            note: format!("St = {st:.4}, {periods} periods, blockage D/H = 1/{:.0}", 1.0 / blockage),
        }],
        files,
        markdown,
    })
}

/// Cells per cylinder diameter of the full tour's Karman street. Measured on this 2-core machine
/// (central flux form + RK4, CFL 0.7 on 1.5 U, t = 120 D/U; St against 0.165): 4 cells/D
/// (128^2): St = 0.1580 in 4.4 s; 5 cells/D (160^2): 0.1693 in 15 s; 6 cells/D (192^2): 0.1643
/// in 40 s (the masked sparse Cholesky solve dominates and grows much faster than the cell
/// count). MacCormack at CFL 1.5 damps the wake: 0.143 / 0.148 / 0.156 at 4 / 6 / 8 cells/D.
const KARMAN_CELLS_PER_D: usize = 5;

fn stress_smoke(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let steps = if ctx.quick { 500 } else { 10_000 };
    // A square 128^2 version of the embedded plume.
    let text = include_str!("../../../pbdl-grid/scenes/smoke_plume.toml")
        .replace("ny = 96", "ny = 64")
        .replace("ly = 1.5", "ly = 1.0");
    let mut sim = Scene::from_toml_str(&text, "smoke_plume_long")?.with_resolution(128).with_steps(steps).build()?;
    let (rate, _) = smoke_source(&sim)?;
    let g = *sim.grid().ok_or("2D")?;
    let (mut first_nonfinite, mut first_div, mut first_rho, mut first_speed) = (None, None, None, None);
    let (mut worst_div, mut rho_lo, mut rho_hi, mut umax_seen) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut error = None;
    // Speed bound: free fall of the densest fluid over the box height, sqrt(2 beta rho_max H),
    // far above anything the plume reaches; density bound: what the source can put in one cell.
    for k in 1..=steps as u64 {
        if let Err(e) = sim.step() {
            error = Some(format!("step {k}: {e}"));
            first_nonfinite.get_or_insert(k);
            break;
        }
        let (Some(u), Some(rho)) = (sim.state().velocity(), sim.state().density()) else {
            return Err("smoke state".into());
        };
        let m = u.max_abs()?;
        let (lo, hi) = min_max(rho.values())?;
        if !(m.is_finite() && lo.is_finite() && hi.is_finite()) {
            first_nonfinite.get_or_insert(k);
            break;
        }
        let div = fd::divergence(u)?.into_values().abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        let rel = div * g.dx() / m.max(f64::MIN_POSITIVE);
        worst_div = worst_div.max(rel);
        if rel > DIV_BOUND_F32 {
            first_div.get_or_insert(k);
        }
        let injected_max = k as f64 * sim.dt() * rate;
        rho_lo = rho_lo.min(lo);
        rho_hi = rho_hi.max(hi);
        if lo < -1e-4 * injected_max || hi > injected_max * (1.0 + 1e-4) {
            first_rho.get_or_insert(k);
        }
        umax_seen = umax_seen.max(m);
        let bound = (2.0 * injected_max * g.ly).sqrt().max(1.0);
        if m > bound {
            first_speed.get_or_insert(k);
        }
    }
    let detail = |s: String| format!("128^2 f32, dt = {:.3e}, t = {:.1}: {s}", sim.dt(), sim.time());
    Ok(vec![
        StressCheck {
            invariant: "values finite (and every step succeeds)".into(),
            passed: first_nonfinite.is_none(),
            first_broken_step: first_nonfinite,
            detail: detail(error.unwrap_or_else(|| format!("{steps} steps"))),
            measure: first_nonfinite.is_none().then_some(StressMeasure::StableSteps(steps as u64)),
        },
        StressCheck {
            invariant: format!("max |div u| dx / max |u| <= {DIV_BOUND_F32:.0e} after every step"),
            passed: first_div.is_none(),
            first_broken_step: first_div,
            detail: detail(format!("worst {worst_div:.2e}")),
            measure: None,
        },
        StressCheck {
            invariant: "density within [0, rate t] (limited MacCormack stays bounded)".into(),
            passed: first_rho.is_none(),
            first_broken_step: first_rho,
            detail: detail(format!("density range seen [{rho_lo:.3e}, {rho_hi:.4}]")),
            measure: None,
        },
        StressCheck {
            invariant: "max |u| <= sqrt(2 beta rate t H) (free fall of the densest possible smoke)".into(),
            passed: first_speed.is_none(),
            first_broken_step: first_speed,
            detail: detail(format!("largest max |u| {umax_seen:.3}")),
            measure: None,
        },
    ])
}

fn stress_karman(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let text = include_str!("../../../pbdl-grid/scenes/cylinder.toml").replace("nu = 0.01", "nu = 0.001");
    let t_end = if ctx.quick { 20.0 } else { 150.0 };
    let mut scene = Scene::from_toml_str(&text, "karman_re1000")?;
    scene.time.t_end = Some(t_end);
    let mut sim = scene.build()?;
    let steps = sim.steps();
    let inv = track(&mut sim, steps, false, 0.0, f64::INFINITY)?;
    let mut c = checks(&inv, steps, false, DIV_BOUND_F32, 0.0);
    // Speed: potential flow peaks at 2 U on the cylinder; allow 5 U.
    let first_fast = inv.first_too_fast;
    c.push(StressCheck {
        invariant: "max |u| <= 5 U".into(),
        passed: first_fast.is_none(),
        first_broken_step: first_fast,
        detail: format!("largest max |u| {:.3}", inv.max_speed),
        measure: None,
    });
    let g = sim.scene().grid;
    for x in &mut c {
        x.detail =
            format!("Re = 1000, {}x{} f32, dt = {:.3e}, t = {:.0}: {}", g.nx, g.ny, sim.dt(), sim.time(), x.detail);
    }
    Ok(c)
}

/// The `#[ignore]`d tests behind the README's grid numbers (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[
    AcceptanceTest {
        package: "pbdl-grid",
        file: "cavity",
        test: "cavity_re1000_128_matches_ghia_within_003",
        claim: "cavity Re 1000 at 128^2: max |u,v - Ghia| <= 0.03",
        minutes: 1.5,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-grid",
        file: "cylinder",
        test: "cylinder_strouhal_number_matches_williamson",
        claim: "cylinder wake Re 100, 8 cells/D: |St - 0.165| <= 5%, >= 10 periods",
        minutes: 5.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-grid",
        file: "ns3d",
        test: "abc_flow_64_cubed",
        claim: "ABC flow 32^3 -> 64^3: order in [1.9, 2.1], divergence at round-off",
        minutes: 0.5,
        env: &[],
    },
];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}
