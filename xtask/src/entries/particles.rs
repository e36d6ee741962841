//! pbdl-particles' tour, bench and stress entries (see [`crate::registry`]).
//!
//! * tour: Sod's shock tube against the exact solution (PNG), the dam break (PNG + GIF) with
//!   the surge front against Martin & Moyce, the IISPH dam break (GIF) with its density error.
//! * bench: neighbour search throughput (100k points, ~40 neighbours, 2D/3D), Sod time against
//!   L1 error at several particle counts, one WCSPH and one IISPH dam-break step. The peers
//!   (SciPy, Open3D, PySPH) are measured by `bench/peers/particles_run.sh`; `cargo xtask bench`
//!   merges their rows.
//! * stress: the dam break to T = 10 (quick: T = 3) without NaN or leaked particles; strong
//!   shock tubes stay finite with positive density and energy; the IISPH dam break to T = 10
//!   with a converging pressure solve and at most 1% average density error.
//! * stress `acceptance`: the README's IISPH claim from its `#[ignore]`d test ([`crate::acceptance`]).

use crate::acceptance::AcceptanceTest;
use crate::bench_schema::{format_seconds, median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_core::viz::{self, ColorRange, FieldStyle, GifStyle, PlotStyle, Series};
use pbdl_particles::neighbors::{CellList, Domain, NeighborList};
use pbdl_particles::render;
use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::{DamBreak, Evolve, IisphParams, ShockTube, Sph1dParams, WcsphParams};
use std::time::Instant;

/// The entries of `pbdl-particles`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "particles",
        tour: vec![
            Entry {
                name: "sod",
                about: "Sod's shock tube with 1D SPH at t = 0.2 against the exact Riemann solution.",
                run: tour_sod,
            },
            Entry {
                name: "dam_break",
                about: "2D WCSPH dam break (H = 2a): particles as PNG/GIF, surge front against Martin & Moyce.",
                run: tour_dam_break,
            },
            Entry {
                name: "dam_break_iisph",
                about: "2D incompressible SPH (IISPH) dam break: average density error at a 0.1% solver tolerance.",
                run: tour_dam_break_iisph,
            },
        ],
        bench: vec![
            Entry {
                name: "neighbors",
                about: "Cell-list neighbour search, 100k points with ~40 neighbours, 2D and 3D.",
                run: bench_neighbors,
            },
            Entry {
                name: "sod",
                about: "Shock-tube set (Sod, Toro 1-5, gamma 5/3 colliding streams), N = 400 and 1600: SPH (defaults and constant viscosity) and the HLL reference, time against L1(rho).",
                run: bench_sod,
            },
            Entry {
                name: "wcsph_step",
                about: "One WCSPH dam-break step at dx = 0.05a (~1.8k particles).",
                run: bench_wcsph_step,
            },
            Entry {
                name: "dam_break_solvers",
                about: "Dam break to T = 2.28 (the last Martin & Moyce point in [1, 2.5]) with WCSPH, IISPH and DFSPH (issue-24 defaults) at dx = a/10, a/20, a/40 (a/10 quick): rollout time against the largest surge-front deviation from Martin & Moyce.",
                run: bench_dam_break_solvers,
            },
            Entry {
                name: "iisph_step",
                about: "One IISPH dam-break step at dx = 0.05a (pressure solve to 0.1% density error).",
                run: bench_iisph_step,
            },
        ],
        stress: vec![
            Entry {
                name: "dam_break_long",
                about: "Dam break to T = 10: finite, no particle leaves the tank.",
                run: stress_dam_break,
            },
            Entry {
                name: "dam_break_iisph_long",
                about: "IISPH dam break to T = 10: finite, pressure solve converges, density error <= 1%.",
                run: stress_dam_break_iisph,
            },
            Entry {
                name: "dt_limit",
                about: "WCSPH dam break with its CFL number 0.25 x 1..4 (the solver refuses larger steps) to T = 2 (1 quick): largest multiple that stays finite, tight and inside.",
                run: super::stability::particles_dt_limit,
            },
            Entry {
                name: "strong_shocks",
                about: "Strong shocks with moving end states (Toro 3-5, pressure ratios up to 1e5, u_L = 1): finite, positive density and energy.",
                run: stress_shocks,
            },
            Entry {
                name: "acceptance",
                about: "The README's IISPH no-leak-to-T = 10 claim: runs its #[ignore]d test in release (seconds; quick too).",
                run: stress_acceptance,
            },
        ],
    }
}

/// Martin & Moyce (1952) surge-front points (T, Z) for T in [1, 2.5].
fn mm_points() -> Vec<(f64, f64)> {
    martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)).collect()
}

fn tour_sod(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let n = if ctx.quick { 225 } else { 450 };
    let tube = ShockTube::sod();
    let exact = tube.exact()?;
    let t0 = Instant::now();
    let mut sim = tube.build(n, Sph1dParams::default())?;
    sim.run_until(0.2)?;
    let secs = t0.elapsed().as_secs_f64();
    let e = sim.l1_errors(0.0, 0.4, |x| exact.at(x, 0.0, 0.2));
    let xs: Vec<f64> = (0..=1000).map(|k| -0.5 + k as f64 / 1000.0).collect();
    let mut idx: Vec<usize> = (0..sim.n_mobile()).collect();
    idx.sort_by(|&a, &b| sim.x[a].total_cmp(&sim.x[b]));
    let mut files = Vec::new();
    for (name, f_exact, f_sph) in [
        ("rho", (|g: pbdl_particles::GasState| g.rho) as fn(pbdl_particles::GasState) -> f64, &sim.rho),
        ("p", |g: pbdl_particles::GasState| g.p, &sim.p),
        ("u", |g: pbdl_particles::GasState| g.u, &sim.v),
    ] {
        let series = vec![
            Series::new("exact", xs.clone(), xs.iter().map(|&x| f_exact(exact.at(x, 0.0, 0.2))).collect()),
            Series::new(
                format!("SPH, N = {n}"),
                idx.iter().map(|&i| sim.x[i]).collect(),
                idx.iter().map(|&i| f_sph[i]).collect(),
            ),
        ];
        let file = format!("particles_sod_{name}.png");
        viz::line_plot(
            ctx.out_dir.join(&file),
            &series,
            &PlotStyle {
                title: format!("Sod shock tube, t = 0.2: {name}"),
                x_label: "x".into(),
                y_label: name.into(),
                ..Default::default()
            },
        )?;
        files.push(file.into());
    }
    let rows = vec![TourRow {
        item: format!("Sod shock tube, 1D SPH, N = {n}, t = 0.2"),
        seconds: secs,
        error: Some(e.rho),
        error_kind: "L1(rho) over |x| < 0.4 vs exact".into(),
        note: format!("L1(u) {:.4}, L1(p) {:.4}, {} steps", e.u, e.p, sim.steps()),
    }];
    let markdown = format!(
        "Sod's shock tube with grad-h SPH (cubic spline, η = 1.2, Monaghan α = 1, β = 2), {n} equal-mass particles, t = 0.2, {} steps in {}: L1(ρ) = {:.4}, L1(u) = {:.4}, L1(p) = {:.4} over |x| < 0.4 (reference plain SPH: 0.0115 / 0.0073 at 225 / 450).\n\n![density](particles_sod_rho.png)\n",
        sim.steps(),
        format_seconds(secs),
        e.rho,
        e.u,
        e.p
    );
    Ok(TourOutcome { rows, files, markdown })
}

fn dam_break_frame(sim: &pbdl_particles::Wcsph, vmax: f64) -> render::Raster {
    let nf = sim.n_fluid();
    let values: Vec<f64> = (0..sim.x.len())
        .map(|i| if i < nf { (sim.v[i][0].powi(2) + sim.v[i][1].powi(2)).sqrt().min(vmax) } else { -1.0 })
        .collect();
    let [lo, hi] = sim.container();
    let margin = 4.0 * sim.physics().dx;
    let ppu = 60.0 / (hi[0] - lo[0]).max(1e-9) * 4.0;
    render::scatter(
        &sim.x,
        &values,
        [lo[0] - margin, lo[1] - margin],
        [hi[0] + margin, hi[1] + margin],
        ppu,
        0.5 * sim.physics().dx * ppu,
    )
}

fn tour_dam_break(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let scene = DamBreak::default();
    let t_end = if ctx.quick { 2.5 } else { 4.0 };
    let t0 = Instant::now();
    let mut sim = scene.build(WcsphParams::default())?;
    let vmax = (2.0 * scene.g * scene.height_ratio * scene.a).sqrt();
    let mut frames = Vec::new();
    let mut worst = 0.0f64;
    let mut k = 0;
    let mut big_t = 0.0;
    while big_t < t_end - 1e-9 {
        big_t = ((k + 1) as f64 * 0.1).min(t_end);
        // Stop at the measured times on the way.
        for &(tm, zm) in mm_points().iter().filter(|(tm, _)| *tm > big_t - 0.1 && *tm <= big_t) {
            sim.run_until(scene.physical_time(tm))?;
            worst = worst.max((sim.front() / scene.a / zm - 1.0).abs());
        }
        sim.run_until(scene.physical_time(big_t))?;
        let f = dam_break_frame(&sim, vmax);
        frames.push(f);
        k += 1;
    }
    let secs = t0.elapsed().as_secs_f64();
    let (h, w) = (frames[0].h, frames[0].w);
    let style = FieldStyle { range: ColorRange::Fixed(0.0, vmax), nan_color: [255, 255, 255], ..Default::default() };
    let last = frames.last().expect("frames");
    viz::field_to_png(ctx.out_dir.join("particles_dam_break.png"), &last.data, h, w, &style)?;
    let data: Vec<&[f64]> = frames.iter().map(|f| f.data.as_slice()).collect();
    viz::rollout_to_gif(
        ctx.out_dir.join("particles_dam_break.gif"),
        &data,
        h,
        w,
        &GifStyle { field: style, frame_delay_ms: 80, repeat: true },
    )?;
    let rows = vec![TourRow {
        item: format!(
            "dam break WCSPH, {} fluid + {} wall particles, T = {t_end}",
            sim.n_fluid(),
            sim.x.len() - sim.n_fluid()
        ),
        seconds: secs,
        error: Some(worst),
        error_kind: "max |Z/Z_MM - 1| of the surge front, T in [1, 2.5]".into(),
        note: format!("{} steps, {} leaked", sim.steps(), sim.leaked()),
    }];
    let markdown = format!(
        "Dam break (Martin & Moyce, H = 2a, dx = a/20), WCSPH with Tait EOS, Monaghan viscosity, δ-SPH and extrapolated-pressure walls: {} steps to T = {t_end} in {}; surge front within {:.1}% of the measurements for T in [1, 2.5]; {} particles left the tank. Colour: speed.\n\n![dam break](particles_dam_break.gif)\n",
        sim.steps(),
        format_seconds(secs),
        100.0 * worst,
        sim.leaked()
    );
    Ok(TourOutcome { rows, files: vec!["particles_dam_break.png".into(), "particles_dam_break.gif".into()], markdown })
}

fn tour_dam_break_iisph(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let scene = DamBreak::default();
    let params = IisphParams::default();
    let t_end = if ctx.quick { 2.5 } else { 4.0 };
    let t0 = Instant::now();
    let mut sim = scene.build_iisph(params)?;
    let vmax = (2.0 * scene.g * scene.height_ratio * scene.a).sqrt();
    let (mut frames, mut worst_comp, mut fronts) = (Vec::new(), 0.0f64, Vec::new());
    let mm_all = mm_points();
    let mut mm = mm_all.iter().filter(|p| p.0 <= t_end).peekable();
    let mut k = 1;
    while sim.time() < scene.physical_time(t_end) * (1.0 - 1e-12) {
        let big_t = (0.1 * k as f64).min(t_end);
        while let Some(&&(tm, zm)) = mm.peek() {
            if tm > big_t {
                break;
            }
            sim.run_until(scene.physical_time(tm))?;
            fronts.push((tm, sim.front() / scene.a, zm));
            mm.next();
        }
        sim.run_until(scene.physical_time(big_t))?;
        worst_comp = worst_comp.max(sim.average_compression()?);
        let nf = sim.n_fluid();
        let vals: Vec<f64> = (0..sim.x.len())
            .map(|i| if i < nf { (sim.v[i][0].powi(2) + sim.v[i][1].powi(2)).sqrt().min(vmax) } else { -1.0 })
            .collect();
        let [lo, hi] = sim.container();
        let margin = 4.0 * sim.dx();
        let ppu = 240.0 / (hi[0] - lo[0]).max(1e-9);
        frames.push(render::scatter(
            &sim.x,
            &vals,
            [lo[0] - margin, lo[1] - margin],
            [hi[0] + margin, hi[1] + margin],
            ppu,
            0.75 * sim.dx() * ppu,
        ));
        k += 1;
    }
    let secs = t0.elapsed().as_secs_f64();
    let (h, w) = (frames[0].h, frames[0].w);
    let style = FieldStyle { range: ColorRange::Fixed(-1.0, vmax), nan_color: [255, 255, 255], ..Default::default() };
    let data: Vec<&[f64]> = frames.iter().map(|f| f.data.as_slice()).collect();
    viz::rollout_to_gif(
        ctx.out_dir.join("particles_dam_break_iisph.gif"),
        &data,
        h,
        w,
        &GifStyle { field: style, frame_delay_ms: 80, repeat: true },
    )?;
    let front_text: Vec<String> = fronts
        .iter()
        .map(|(t, z, zm)| format!("T = {t:.2}: Z = {z:.2} vs {zm:.2} ({:+.0}%)", 100.0 * (z / zm - 1.0)))
        .collect();
    let rows = vec![TourRow {
        item: format!(
            "dam break IISPH, {} fluid particles, T = {t_end}, tolerance {:.0e}",
            sim.n_fluid(),
            params.tolerance
        ),
        seconds: secs,
        error: Some(worst_comp),
        error_kind: "max average compression mean(max(rho/rho0 - 1, 0)) of summation density".into(),
        note: format!(
            "{} steps, {} Jacobi iterations, {} leaked; wall fallback fired {} times (deepest crossing {:.2} dx)",
            sim.steps(),
            sim.total_iterations(),
            sim.leaked(),
            sim.wall_corrections(),
            sim.max_penetration() / sim.dx()
        ),
    }];
    let markdown = format!(
        "Dam break with implicit incompressible SPH (IISPH, relaxed Jacobi to an average density error of {:.1}%, extrapolated wall pressures plus an impermeable-wall fallback that puts the rare particle whose centre crosses the tank surface back on it, Wendland C2, no viscosity): {} steps ({} Jacobi iterations) to T = {t_end} in {}; average compression of the summation density at most {:.2}%. Surge front: {} (inviscid IISPH runs ahead of the measurements, more than WCSPH).\n\n![dam break IISPH](particles_dam_break_iisph.gif)\n",
        100.0 * params.tolerance,
        sim.steps(),
        sim.total_iterations(),
        format_seconds(secs),
        100.0 * worst_comp,
        front_text.join("; ")
    );
    Ok(TourOutcome { rows, files: vec!["particles_dam_break_iisph.gif".into()], markdown })
}

fn stress_dam_break_iisph(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let scene = DamBreak::default();
    let t_end = if ctx.quick { 3.0 } else { 10.0 };
    let mut sim = scene.build_iisph(IisphParams::default())?;
    let t_phys = scene.physical_time(t_end);
    let (mut broken, mut dens_at, mut max_comp, mut error) = (None, None, 0.0f64, None);
    while sim.time() < t_phys * (1.0 - 1e-14) {
        let dt = sim.stable_dt().min(t_phys - sim.time());
        if let Err(e) = sim.step(dt) {
            error = Some(e.to_string());
            broken = Some(sim.steps());
            break;
        }
        if sim.steps() % 20 == 0 {
            let c = sim.average_compression()?;
            max_comp = max_comp.max(c);
            if c > 0.01 {
                dens_at.get_or_insert(sim.steps());
            }
        }
    }
    let finite = sim.is_finite();
    Ok(vec![
        StressCheck {
            invariant: format!("IISPH dam break to T = {t_end}: finite, pressure solve converges every step"),
            passed: broken.is_none() && finite,
            first_broken_step: broken,
            detail: error
                .unwrap_or_else(|| format!("{} steps, {} Jacobi iterations", sim.steps(), sim.total_iterations())),
            measure: (broken.is_none() && finite).then_some(StressMeasure::StableSteps(sim.steps())),
        },
        StressCheck {
            invariant: "average density error (compression) stays below 1%".into(),
            passed: dens_at.is_none(),
            first_broken_step: dens_at,
            detail: format!("max {max_comp:.2e}; {} particle centres beyond the nominal wall surface", sim.leaked()),
            measure: None,
        },
    ])
}

/// Deterministic uniform points (a 64-bit LCG), no RNG dependency.
fn uniform_points<const D: usize>(n: usize, seed: u64) -> Vec<[f32; D]> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32
    };
    (0..n).map(|_| std::array::from_fn(|_| next())).collect()
}

fn neighbor_row<const D: usize>(n: usize, reps: usize, threads: usize) -> TaskResult<BenchRow> {
    let nf = n as f64;
    let radius = match D {
        2 => (40.0 / (std::f64::consts::PI * nf)).sqrt(),
        _ => (30.0 / (std::f64::consts::PI * nf)).cbrt(),
    } as f32;
    let pos = uniform_points::<D>(n, 42);
    let mut cells = CellList::new(Domain::bounded([0.0; D], [1.0; D]), radius)?;
    let mut nl = NeighborList::default();
    let secs = median_seconds(1, reps, || cells.neighbors(&pos, &mut nl).map(|_| nl.num_entries()).ok());
    Ok(BenchRow {
        case: format!("neighbor_search_{D}d"),
        method: "pbdl_cell_list".into(),
        size: format!("n{n}_k{:.0}", nl.num_entries() as f64 / nf),
        seconds: secs,
        unit: "full CSR lists".into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads,
    })
}

fn bench_neighbors(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let (n, reps) = if ctx.quick { (20_000, 3) } else { (100_000, 7) };
    Ok(vec![neighbor_row::<2>(n, reps, ctx.threads)?, neighbor_row::<3>(n, reps, ctx.threads)?])
}

/// The shock-tube set of issue 24 (Sod, Toro's tests 1-5, γ = 5/3 colliding streams) in tubes
/// fitted around their waves ([`ShockTube::fitted`]): a rollout of SPH with its defaults
/// (conductivity + Morris & Monaghan switch), of SPH with the round-1 constant viscosity, and of
/// the first-order HLL finite-volume reference with as many cells (`hll_fv`, an internal
/// comparison, not a peer), each with its L1(ρ) over the judged interval.
fn bench_sod(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    use pbdl_particles::{hll, GasState};
    let gas = |rho, u, p| GasState { rho, u, p };
    let cases = [
        ("sod", gas(1.0, 0.0, 1.0), gas(0.125, 0.0, 0.1), 1.4, 0.2),
        ("toro_1", gas(1.0, 0.75, 1.0), gas(0.125, 0.0, 0.1), 1.4, 0.2),
        ("toro_2_123", gas(1.0, -2.0, 0.4), gas(1.0, 2.0, 0.4), 1.4, 0.15),
        ("toro_3_left_blast", gas(1.0, 0.0, 1000.0), gas(1.0, 0.0, 0.01), 1.4, 0.012),
        ("toro_4_right_blast", gas(1.0, 0.0, 0.01), gas(1.0, 0.0, 100.0), 1.4, 0.035),
        ("toro_5_colliding_shocks", gas(5.99924, 19.5975, 460.894), gas(5.99242, -6.19633, 46.0950), 1.4, 0.035),
        ("colliding_gamma_5_3", gas(1.0, 0.5, 1.0), gas(0.25, -0.5, 0.2), 5.0 / 3.0, 0.15),
    ];
    let sizes: &[usize] = if ctx.quick { &[400] } else { &[400, 1600] };
    let mut rows = Vec::new();
    for (name, left, right, gamma, t) in cases {
        let fitted = ShockTube::fitted(left, right, gamma, t)?;
        let tube = fitted.tube;
        let exact = tube.exact()?;
        let (mid, half) = (0.5 * (fitted.judged.0 + fitted.judged.1), 0.5 * (fitted.judged.1 - fitted.judged.0));
        let reference = |x: f64| exact.at(x, 0.0, t);
        for &n in sizes {
            let row = |method: &str, secs: f64, err: f64| BenchRow {
                case: format!("shock_tube_{name}"),
                method: method.into(),
                size: format!("n{n}"),
                seconds: secs,
                unit: format!("rollout to t = {t}"),
                error: Some(err),
                error_kind: "l1_rho_judged_interval".into(),
                peer: false,
                threads: ctx.threads,
            };
            for (method, params) in [
                ("pbdl_sph1d_gradh", Sph1dParams::default()),
                ("pbdl_sph1d_const_visc", Sph1dParams::constant_viscosity()),
            ] {
                let mut err = f64::NAN;
                let secs = median_seconds(0, 1, || {
                    let mut sim = tube.build(n, params).ok()?;
                    sim.run_until(t).ok()?;
                    err = sim.l1_errors(mid, half, reference).rho;
                    Some(())
                });
                rows.push(row(method, secs, err));
            }
            let mut err = f64::NAN;
            let secs = median_seconds(0, if ctx.quick { 1 } else { 3 }, || {
                let fv = hll::solve(&tube, n, t, hll::DEFAULT_CFL).ok()?;
                err = fv.l1_errors(mid, half, reference).rho;
                Some(())
            });
            rows.push(row("hll_fv", secs, err));
        }
    }
    Ok(rows)
}

fn bench_wcsph_step(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let scene = DamBreak::default();
    let mut sim = scene.build(WcsphParams::default())?;
    sim.run_until(scene.physical_time(0.5))?;
    let secs = median_seconds(5, if ctx.quick { 20 } else { 200 }, || {
        let dt = sim.stable_dt().0;
        sim.step(dt).ok()
    });
    Ok(vec![BenchRow {
        case: "dam_break_2d_step".into(),
        method: "pbdl_wcsph".into(),
        size: format!("{}_particles_dx0.05", sim.x.len()),
        seconds: secs,
        unit: "step".into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads: ctx.threads,
    }])
}

/// Runs `sim` through Martin & Moyce's points in T in [1, 2.5] and returns the largest
/// `|Z / Z_MM - 1|` of its surge front (`front(sim)` in m).
fn worst_front_error<S: Evolve>(sim: &mut S, scene: &DamBreak, front: impl Fn(&S) -> f64) -> TaskResult<f64> {
    let mut worst = 0.0f64;
    for (big_t, z_mm) in mm_points() {
        sim.run_until(scene.physical_time(big_t))?;
        worst = worst.max((front(sim) / scene.a / z_mm - 1.0).abs());
    }
    Ok(worst)
}

fn bench_dam_break_solvers(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let dxs: &[(f64, &str)] =
        if ctx.quick { &[(0.1, "a/10")] } else { &[(0.1, "a/10"), (0.05, "a/20"), (0.025, "a/40")] };
    let mut rows = Vec::new();
    for &(dx, label) in dxs {
        let scene = DamBreak { dx, ..Default::default() };
        for method in ["pbdl_wcsph", "pbdl_iisph", "pbdl_dfsph"] {
            let t0 = Instant::now();
            let error = match method {
                "pbdl_wcsph" => worst_front_error(&mut scene.build(WcsphParams::default())?, &scene, |s| s.front())?,
                "pbdl_iisph" => {
                    worst_front_error(&mut scene.build_iisph(IisphParams::default())?, &scene, |s| s.front())?
                }
                _ => worst_front_error(&mut scene.build_dfsph(Default::default())?, &scene, |s| s.front())?,
            };
            rows.push(BenchRow {
                case: "dam_break_2d_front".into(),
                method: method.into(),
                size: format!("dx_{label}"),
                seconds: t0.elapsed().as_secs_f64(),
                unit: "build + rollout to T = 2.28 (one run)".into(),
                error: Some(error),
                error_kind: "max |Z/Z_MM - 1| of the surge front, T in [1, 2.5]".into(),
                peer: false,
                threads: ctx.threads,
            });
        }
    }
    Ok(rows)
}

fn bench_iisph_step(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let scene = DamBreak::default();
    let mut sim = scene.build_iisph(IisphParams::default())?;
    sim.run_until(scene.physical_time(0.5))?;
    let it0 = sim.total_iterations();
    let s0 = sim.steps();
    let secs = median_seconds(2, if ctx.quick { 10 } else { 100 }, || {
        let dt = sim.stable_dt();
        sim.step(dt).ok()
    });
    let iters = (sim.total_iterations() - it0) as f64 / (sim.steps() - s0).max(1) as f64;
    Ok(vec![BenchRow {
        case: "dam_break_2d_step".into(),
        method: format!("pbdl_iisph ({iters:.0} Jacobi iterations/step)"),
        size: format!("{}_particles_dx0.05", sim.x.len()),
        seconds: secs,
        unit: "step".into(),
        error: Some(sim.last_solve().density_error),
        error_kind: "average density error of the pressure solve".into(),
        peer: false,
        threads: ctx.threads,
    }])
}

fn stress_dam_break(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let scene = DamBreak::default();
    let t_end = if ctx.quick { 3.0 } else { 10.0 };
    let mut sim = scene.build(WcsphParams::default())?;
    let (mut nan_at, mut leak_at, mut dens_at) = (None, None, None);
    let mut max_dens = 0.0f64;
    let mut error = None;
    let t_phys = scene.physical_time(t_end);
    while sim.time() < t_phys * (1.0 - 1e-14) {
        let dt = sim.stable_dt().0.min(t_phys - sim.time());
        if let Err(e) = sim.step(dt) {
            error = Some(e.to_string());
            nan_at.get_or_insert(sim.steps());
            break;
        }
        if sim.steps() % 50 == 0 || sim.time() >= t_phys * (1.0 - 1e-14) {
            if !sim.is_finite() {
                nan_at.get_or_insert(sim.steps());
                break;
            }
            if sim.leaked() > 0 {
                leak_at.get_or_insert(sim.steps());
            }
            let d = sim.mean_density_error();
            max_dens = max_dens.max(d);
            if d > 0.05 {
                dens_at.get_or_insert(sim.steps());
            }
        }
    }
    Ok(vec![
        StressCheck {
            invariant: format!("dam break to T = {t_end}: values finite"),
            passed: nan_at.is_none(),
            first_broken_step: nan_at,
            detail: error.unwrap_or_else(|| format!("{} steps, t = {:.3} s", sim.steps(), sim.time())),
            measure: nan_at.is_none().then_some(StressMeasure::StableSteps(sim.steps())),
        },
        StressCheck {
            invariant: "no fluid particle leaves the tank".into(),
            passed: leak_at.is_none(),
            first_broken_step: leak_at,
            detail: format!("{} of {} outside at the end", sim.leaked(), sim.n_fluid()),
            measure: None,
        },
        StressCheck {
            invariant: "mean density error stays below 5%".into(),
            passed: dens_at.is_none(),
            first_broken_step: dens_at,
            detail: format!("max mean |rho/rho0 - 1| = {max_dens:.4}"),
            measure: None,
        },
    ])
}

/// Strong shocks with moving end states (issue 24, bar S3): Toro's tests 3-5, Toro 3 with
/// colliding end states, and Sod-like tubes with `u_L = 1` and pressure ratios 10, 1e3 and 1e5,
/// each in a tube fitted around its waves ([`ShockTube::fitted`]) and run with the SPH defaults
/// to its end time: the state stays finite with positive density and internal energy (hence
/// pressure).
fn stress_shocks(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    use pbdl_particles::GasState;
    let gas = |rho, u, p| GasState { rho, u, p };
    let n = if ctx.quick { 200 } else { 800 };
    let mut cases = vec![
        ("toro_3_left_blast", gas(1.0, 0.0, 1000.0), gas(1.0, 0.0, 0.01), 0.012),
        ("toro_4_right_blast", gas(1.0, 0.0, 0.01), gas(1.0, 0.0, 100.0), 0.035),
        ("toro_5_colliding_shocks", gas(5.99924, 19.5975, 460.894), gas(5.99242, -6.19633, 46.0950), 0.035),
        ("toro_3_colliding", gas(1.0, 1.0, 1000.0), gas(1.0, -1.0, 0.01), 0.012),
    ];
    for (name, ratio) in [("sod_moving_p1e1", 1e1), ("sod_moving_p1e3", 1e3), ("sod_moving_p1e5", 1e5)] {
        // p_L = 1, p_R = 1 / ratio, u_L = 1; the end time lets the fastest wave run 0.4.
        let (left, right) = (gas(1.0, 1.0, 1.0), gas(0.125, 0.0, 1.0 / ratio));
        let ex = pbdl_particles::riemann::solve(left, right, 1.4)?;
        let speed = (ex.u_star.abs() + left.sound_speed(1.4)).max(left.u + left.sound_speed(1.4));
        cases.push((name, left, right, 0.4 / speed));
    }
    let mut checks = Vec::new();
    for (k, (name, left, right, t_end)) in cases.into_iter().enumerate() {
        let tube = ShockTube::fitted(left, right, 1.4, t_end)?.tube;
        let ratio = left.p.max(right.p) / left.p.min(right.p);
        let mut sim = tube.build(n, Sph1dParams::default())?;
        let res = sim.run_until(t_end);
        let nm = sim.n_mobile();
        let ok = res.is_ok()
            && (0..nm).all(|i| {
                sim.rho[i] > 0.0 && sim.u[i] > 0.0 && sim.p[i] > 0.0 && sim.v[i].is_finite() && sim.x[i].is_finite()
            });
        let min_rho = sim.rho[..nm].iter().copied().fold(f64::INFINITY, f64::min);
        let min_p = sim.p[..nm].iter().copied().fold(f64::INFINITY, f64::min);
        checks.push(StressCheck {
            invariant: format!(
                "{name}: p ratio {ratio:.0e}, u_L = {}, u_R = {}: finite, positive density and energy",
                left.u, right.u
            ),
            passed: ok,
            first_broken_step: if ok { None } else { Some(sim.steps()) },
            detail: match res {
                Ok(steps) => format!(
                    "{steps} steps to t = {t_end:.4} at N = {n}, moving buffers {}; min rho {min_rho:.3e}, min p {min_p:.3e} (case {k})",
                    sim.moving_buffers()
                ),
                Err(e) => e.to_string(),
            },
            measure: if ok { Some(StressMeasure::StableSteps(sim.steps())) } else { None },
        });
    }
    Ok(checks)
}

/// The `#[ignore]`d tests behind the README's IISPH claim (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[AcceptanceTest {
    package: "pbdl-particles",
    file: "iisph_tests",
    test: "iisph_dam_break_to_t10_leaks_no_particle",
    claim: "IISPH dam break to T = 10: 0 leaked (checked every 0.1), average compression <= 1%, wall crossing < 0.5 dx",
    minutes: 0.2,
    env: &[],
}];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}
