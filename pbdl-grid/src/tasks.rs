//! pbdl-grid's entries for `cargo xtask` (see `pbdl_core::registry`).
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
//! * stress `decaying_turbulence`, `decaying_taylor_green`: unforced flows stay finite and
//!   divergence-free and never gain energy; `kolmogorov`: the forced flow stays finite,
//!   divergence-free and bounded. Each check names the first step at which it broke.
//!
//! The smoke plume and the Karman street (tour renders, 10,000-step stress, Re = 1000) are not
//! registered yet: their scenes need the smoke and cylinder steppers.

use crate::burgers::cole_hopf_sine;
use crate::scene::{write_trajectory, Scene, Simulation, State};
use crate::{fd, Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
use candle_core::{DType, Device, Tensor};
use pbdl_core::bench::{median_seconds, BenchRow};
use pbdl_core::registry::{CrateTasks, Entry, StressCheck, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_core::viz::{self, PlotStyle, Series};
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
        ],
        bench: vec![
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
        ],
    }
}

fn rel_l2(a: &Tensor, b: &Tensor) -> candle_core::Result<f64> {
    let (a, b) = (a.to_dtype(DType::F64)?, b.to_dtype(DType::F64)?);
    Ok(((&a - &b)?.sqr()?.sum_all()?.to_scalar::<f64>()? / b.sqr()?.sum_all()?.to_scalar::<f64>()?).sqrt())
}

fn files_markdown(files: &[std::path::PathBuf], ctx: &TaskContext) -> String {
    files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "png" || e == "gif"))
        .map(|f| {
            let rel = f.strip_prefix(&ctx.out_dir).unwrap_or(f);
            format!("![{}]({})", rel.display(), f.display())
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

/// Ghia, Ghia & Shin (1982), J. Comput. Phys. 48(3):387-411, Tables I and II, Re = 100 column:
/// `(coordinate, value)` pairs, ascending.
/// A polyline `(coordinate, value)`.
type Line = Vec<(f64, f64)>;

fn ghia_re100() -> (Line, Line) {
    let parse = |text: &str| {
        let mut v: Vec<(f64, f64)> = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.starts_with('x') && !l.starts_with('y') && !l.trim().is_empty())
            .filter_map(|l| {
                let f: Vec<f64> = l.split(',').filter_map(|s| s.trim().parse().ok()).collect();
                (f.len() >= 2).then(|| (f[0], f[1]))
            })
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    };
    (
        parse(include_str!("../tests/data/ghia1982_u_vertical_centerline.csv")),
        parse(include_str!("../tests/data/ghia1982_v_horizontal_centerline.csv")),
    )
}

fn interp(pts: &[(f64, f64)], x: f64) -> f64 {
    let k = pts.windows(2).position(|w| x >= w[0].0 && x <= w[1].0).unwrap_or(pts.len() - 2);
    let (a, b) = (pts[k], pts[k + 1]);
    a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)
}

/// The cavity's centrelines: `u(0.5, y)` and `v(x, 0.5)` with the wall values at the ends, and
/// the max deviations from Ghia's Re = 100 points.
struct Centrelines {
    u: Line,
    v: Line,
    err_u: f64,
    err_v: f64,
}

fn centrelines(u: &MacField) -> TaskResult<Centrelines> {
    let g = u.grid();
    let n = g.nx;
    let vals = u.values().narrow(0, 0, 1)?.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let (nn, h) = (n * n, 1.0 / n as f64);
    // u on the face column x = 0.5 at the cell centres in y; v on the face row y = 0.5.
    let mut ul = vec![(0.0, 0.0)];
    ul.extend((0..n).map(|j| ((j as f64 + 0.5) * h, vals[j * n + n / 2 - 1])));
    ul.push((1.0, 1.0));
    let mut vl = vec![(0.0, 0.0)];
    vl.extend((0..n).map(|i| ((i as f64 + 0.5) * h, vals[nn + (n / 2 - 1) * n + i])));
    vl.push((1.0, 0.0));
    let (gu, gv) = ghia_re100();
    let err_u = gu.iter().map(|&(y, r)| (interp(&ul, y) - r).abs()).fold(0.0, f64::max);
    let err_v = gv.iter().map(|&(x, r)| (interp(&vl, x) - r).abs()).fold(0.0, f64::max);
    Ok(Centrelines { u: ul, v: vl, err_u, err_v })
}

/// Runs the cavity scene at `n^2` to its end time (t = 20, steady at Re = 100).
fn run_cavity(n: usize) -> TaskResult<(Simulation, crate::scene::Trajectory, f64)> {
    let mut sim = Scene::builtin("lid_driven_cavity")?.with_resolution(n).build()?;
    let t = Instant::now();
    let traj = sim.run(|_| {})?;
    Ok((sim, traj, t.elapsed().as_secs_f64()))
}

fn tour_cavity(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let n = if ctx.quick { 32 } else { 64 };
    let (sim, traj, seconds) = run_cavity(n)?;
    let State::Velocity(u) = sim.state() else { return Err("cavity is a velocity scene".into()) };
    let c = centrelines(u)?;
    let mut files = write_trajectory(&sim, &traj, &ctx.out_dir)?;
    let (gu, gv) = ghia_re100();
    let split =
        |p: &[(f64, f64)]| (p.iter().map(|q| q.0).collect::<Vec<_>>(), p.iter().map(|q| q.1).collect::<Vec<_>>());
    let series = [
        Series::new(format!("u(0.5, y), pbdl {n}^2"), split(&c.u).0, split(&c.u).1),
        Series::new("u(0.5, y), Ghia 1982", split(&gu).0, split(&gu).1),
        Series::new(format!("v(x, 0.5), pbdl {n}^2"), split(&c.v).0, split(&c.v).1),
        Series::new("v(x, 0.5), Ghia 1982", split(&gv).0, split(&gv).1),
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
    let markdown = format!(
        "{n}^2, f32, {steps} RK4 steps to t = {:.1} ({:.3} ms/step; operators: {}). Max |u - Ghia| on \
         the vertical centreline {:.4}, max |v - Ghia| on the horizontal one {:.4} (PhiFlow 3.4 \
         semi-Lagrangian at 64^2: 0.049 / 0.021). Ghia's points are joined by straight lines.\n\n{}",
        sim.time(),
        1e3 * seconds / steps as f64,
        sim.operators().join(", "),
        c.err_u,
        c.err_v,
        files_markdown(&files, ctx)
    );
    Ok(TourOutcome {
        rows: vec![TourRow {
            item: format!("lid_driven_cavity Re100 {n}^2 f32"),
            seconds,
            error: Some(c.err_u.max(c.err_v)),
            error_kind: "max centreline |u - Ghia|, |v - Ghia|".into(),
            note: format!("u {:.4}, v {:.4}; {steps} steps", c.err_u, c.err_v),
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
        crate::scene::Physics::Burgers1d { nu } => nu,
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
        let c = centrelines(u)?;
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
            error: Some(c.err_u.max(c.err_v)),
            error_kind: "max_centreline_abs_vs_ghia".into(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

/// Per-step invariant tracking for the stress entries.
struct Invariants {
    first_nonfinite: Option<u64>,
    first_div: Option<u64>,
    first_energy: Option<u64>,
    first_above_cap: Option<u64>,
    worst_div: f64,
    worst_growth: f64,
    energy0: f64,
    energy_last: f64,
    max_energy: f64,
    error: Option<String>,
}

fn energy(u: &MacField) -> candle_core::Result<f64> {
    Ok(0.5 * u.values().to_dtype(DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()? * u.grid().dx() * u.grid().dy())
}

/// Steps `sim` `steps` times, checking after each step: values finite, `max |div u| dx / max |u|`
/// below `div_bound`, and (when `decaying`) energy not above the previous step's by more than
/// `rel_tol`. A solver error (e.g. an unstable step) ends the run and is reported.
fn track(
    sim: &mut Simulation,
    steps: usize,
    decaying: bool,
    div_bound: f64,
    rel_tol: f64,
    energy_cap: f64,
) -> TaskResult<Invariants> {
    let State::Velocity(u) = sim.state() else { return Err("velocity scene expected".into()) };
    let e0 = energy(u)?;
    let mut inv = Invariants {
        first_nonfinite: None,
        first_div: None,
        first_energy: None,
        first_above_cap: None,
        worst_div: 0.0,
        worst_growth: f64::NEG_INFINITY,
        energy0: e0,
        energy_last: e0,
        max_energy: e0,
        error: None,
    };
    let mut prev = e0;
    for k in 1..=steps as u64 {
        if let Err(e) = sim.step() {
            inv.error = Some(format!("step {k}: {e}"));
            inv.first_nonfinite.get_or_insert(k);
            break;
        }
        let State::Velocity(u) = sim.state() else { unreachable!() };
        let m = u.max_abs()?;
        let e = energy(u)?;
        if !(m.is_finite() && e.is_finite()) {
            inv.first_nonfinite.get_or_insert(k);
            break;
        }
        let div = fd::divergence(u)?.into_values().abs()?.max_all()?.to_dtype(DType::F64)?.to_scalar::<f64>()?;
        let rel_div = div * u.grid().dx() / m.max(f64::MIN_POSITIVE);
        inv.worst_div = inv.worst_div.max(rel_div);
        if rel_div > div_bound {
            inv.first_div.get_or_insert(k);
        }
        let growth = (e - prev) / prev.max(f64::MIN_POSITIVE);
        inv.worst_growth = inv.worst_growth.max(growth);
        if decaying && growth > rel_tol {
            inv.first_energy.get_or_insert(k);
        }
        if e > energy_cap {
            inv.first_above_cap.get_or_insert(k);
        }
        inv.max_energy = inv.max_energy.max(e);
        inv.energy_last = e;
        prev = e;
    }
    Ok(inv)
}

fn checks(inv: &Invariants, steps: usize, decaying: bool, div_bound: f64, rel_tol: f64) -> Vec<StressCheck> {
    let mut out = vec![
        StressCheck {
            invariant: "values finite (and every step stable)".into(),
            passed: inv.first_nonfinite.is_none(),
            first_broken_step: inv.first_nonfinite,
            detail: inv.error.clone().unwrap_or_else(|| format!("{steps} steps")),
        },
        StressCheck {
            invariant: format!("max |div u| dx / max |u| <= {div_bound:.0e} after every step"),
            passed: inv.first_div.is_none(),
            first_broken_step: inv.first_div,
            detail: format!("worst {:.2e}", inv.worst_div),
        },
    ];
    if decaying {
        out.push(StressCheck {
            invariant: format!("energy never grows (relative step-to-step growth <= {rel_tol:.0e})"),
            passed: inv.first_energy.is_none(),
            first_broken_step: inv.first_energy,
            detail: format!(
                "energy {:.4e} -> {:.4e}; largest step-to-step change {:+.2e}",
                inv.energy0, inv.energy_last, inv.worst_growth
            ),
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
    let text = include_str!("../scenes/taylor_green.toml")
        .replace("nu = 0.01", "nu = 0.001")
        .replace("kind = \"taylor_green\"", "kind = \"random_modes\"\namplitude = 1.0\nmax_wavenumber = 4\nseed = 5");
    let mut sim = Scene::from_toml_str(&text, "decaying_turbulence")?.with_resolution(n).with_steps(steps).build()?;
    let inv = track(&mut sim, steps, true, DIV_BOUND_F32, ENERGY_TOL_F32, f64::INFINITY)?;
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
    let inv = track(&mut sim, steps, true, DIV_BOUND_F32, ENERGY_TOL_F32, f64::INFINITY)?;
    let mut c = checks(&inv, steps, true, DIV_BOUND_F32, ENERGY_TOL_F32);
    // The energy decays as exp(-4 nu t) (a discrete rate differs by O(dx^2)).
    let expect = (-4.0 * 0.01 * sim.time()).exp();
    let got = inv.energy_last / inv.energy0;
    let rate_err = (got - expect).abs() / expect;
    c.push(StressCheck {
        invariant: "energy decays at the analytic rate exp(-4 nu t) within 1%".into(),
        passed: rate_err < 0.01,
        first_broken_step: if rate_err < 0.01 { None } else { Some(steps as u64) },
        detail: format!("{n}^2 f32 t = {:.1}: E/E0 = {got:.5}, exp(-4 nu t) = {expect:.5}", sim.time()),
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
    let inv = track(&mut sim, steps, false, DIV_BOUND_F32, 0.0, 4.0 * laminar)?;
    let mut c = checks(&inv, steps, false, DIV_BOUND_F32, 0.0);
    c.push(StressCheck {
        invariant: "energy stays below 4x the laminar Kolmogorov energy".into(),
        passed: inv.first_above_cap.is_none(),
        first_broken_step: inv.first_above_cap,
        detail: format!("64^2 f32 t = {:.1}: max energy {:.3e}, laminar {:.3e}", sim.time(), inv.max_energy, laminar),
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
