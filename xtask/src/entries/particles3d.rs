//! pbdl-particles' 3D entries (crate name `particles3d`, see [`crate::registry`]):
//!
//! * tour `dam_break_3d`: the 3D WCSPH dam break (quasi-2D column spanning the tank's depth,
//!   dx = a/20 to T = 4; quick: a/8 to T = 2.5) drawn from the side (particles projected along
//!   the depth, the nearest on top) as PNG + GIF, with the surge front against Martin & Moyce.
//! * tour `liquid3d`: CConv-style 3D liquid scenes (blocks and balls dropped into a box, 0.05 m
//!   spacing, frames 0.02 s apart) written as `.npz` with JSON sidecars (quick: the tiny set).
//! * bench `wcsph3d_step`: one 3D dam-break step at several resolutions (rows in the shared
//!   schema, `peer: false`).
//! * bench `dfsph3d_step`: one 3D DFSPH dam-break step (`DamBreak3d::build_dfsph`,
//!   `DfsphParams::default_3d`) at the same resolutions, with the step's mean compression as
//!   its error (DFSPH's steps are ~10x longer in time than WCSPH's).
//! * stress `dam_break_3d_long`: the 3D dam break to T = 10 at dx = a/20 (quick: a/8 to T = 3),
//!   finite and with no particle outside the tank, checked every 0.1 T.
//! * stress `dfsph3d_dam_break_long`: the same for 3D DFSPH, plus the largest mean compression
//!   of the summation density (quick: a/8 to T = 3).
//! * stress `acceptance`: the README's bars 3D1 and 3D3 from their `#[ignore]`d tests
//!   ([`crate::acceptance`]).

use crate::acceptance::AcceptanceTest;
use crate::bench_schema::{format_seconds, median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, StressCheck, StressMeasure, TaskContext, TaskResult, TourOutcome, TourRow};
use pbdl_core::viz::{self, ColorRange, FieldStyle, GifStyle};
use pbdl_particles::dfsph::DfsphParams;
use pbdl_particles::liquid3d::Liquid3dConfig;
use pbdl_particles::render;
use pbdl_particles::validation::martin_moyce_1952;
use pbdl_particles::wcsph3d::{DamBreak3d, Wcsph3d, Wcsph3dParams};
use pbdl_particles::Evolve;
use std::time::Instant;

/// The 3D entries of `pbdl-particles`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "particles3d",
        tour: vec![
            Entry {
                name: "dam_break_3d",
                about: "3D WCSPH dam break (H = 2a, column spanning the tank's depth): side view PNG/GIF, surge front against Martin & Moyce.",
                run: tour_dam_break_3d,
            },
            Entry {
                name: "liquid3d",
                about: "CConv-style 3D liquid data: seeded block/ball drops into a box written as .npz with JSON sidecars.",
                run: tour_liquid3d,
            },
        ],
        bench: vec![
            Entry {
                name: "wcsph3d_step",
                about: "One 3D WCSPH dam-break step at several resolutions (dx = a/10, a/16, a/20; quick a/8, a/10).",
                run: bench_wcsph3d_step,
            },
            Entry {
                name: "dfsph3d_step",
                about: "One 3D DFSPH dam-break step (tolerance 0.1%) at dx = a/10, a/16, a/20 (quick a/8, a/10); error: mean compression of the summation density the step leaves.",
                run: bench_dfsph3d_step,
            },
        ],
        stress: vec![
            Entry {
                name: "dam_break_3d_long",
                about: "3D dam break to T = 10 at dx = a/20 (quick: a/8 to T = 3): finite, no particle leaves the tank (checked every 0.1 T).",
                run: stress_dam_break_3d,
            },
            Entry {
                name: "dfsph3d_dam_break_long",
                about: "3D DFSPH dam break to T = 10 at dx = a/20 (quick: a/8 to T = 3): finite, no particle leaves the tank (checked every 0.1 T), largest mean compression.",
                run: stress_dfsph3d_dam_break,
            },
            Entry {
                name: "acceptance",
                about: "The README's 3D1 and 3D3 bars: runs their #[ignore]d tests in release (front ~1.5 min, T = 10 several minutes, 3D DFSPH ~1 min; quick leaves out the T = 10 WCSPH run).",
                run: stress_acceptance,
            },
        ],
    }
}

/// The scene of the tour and stress entries: the default (dx = a/20) or a coarse a/8 column.
fn scene(quick: bool) -> DamBreak3d {
    if quick {
        DamBreak3d { dx: 0.125, ..DamBreak3d::default() }
    } else {
        DamBreak3d::default()
    }
}

/// A side view: fluid particles projected along the depth (far first, so the nearest paint on
/// top), coloured by speed up to `vmax`; wall particles outside the tank's side outline as -1.
fn side_view(sim: &Wcsph3d, vmax: f64) -> render::Raster {
    let nf = sim.n_fluid();
    let [lo, hi] = sim.container();
    let mut order: Vec<usize> = (0..nf).collect();
    order.sort_by(|&a, &b| sim.x[b][2].total_cmp(&sim.x[a][2]));
    let mut pos = Vec::new();
    let mut val = Vec::new();
    for i in nf..sim.x.len() {
        let p = sim.x[i];
        // Only the walls seen edge-on from the side (left, right, floor, lid), not the back plate.
        if p[0] < lo[0] || p[0] > hi[0] || p[1] < lo[1] || p[1] > hi[1] {
            pos.push([p[0], p[1]]);
            val.push(-1.0);
        }
    }
    for i in order {
        let v = sim.v[i];
        pos.push([sim.x[i][0], sim.x[i][1]]);
        val.push((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().min(vmax));
    }
    let dx = sim.physics().dx;
    let margin = 4.0 * dx;
    let ppu = 240.0 / (hi[0] - lo[0]).max(1e-9);
    render::scatter(&pos, &val, [lo[0] - margin, lo[1] - margin], [hi[0] + margin, hi[1] + margin], ppu, 0.6 * dx * ppu)
}

fn mm_points() -> Vec<(f64, f64)> {
    martin_moyce_1952().into_iter().filter(|p| (1.0..=2.5).contains(&p.0)).collect()
}

fn tour_dam_break_3d(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let scene = scene(ctx.quick);
    let t_end: f64 = if ctx.quick { 2.5 } else { 4.0 };
    let t0 = Instant::now();
    let mut sim = scene.build(Wcsph3dParams::default())?;
    let vmax = (2.0 * scene.g * scene.height_ratio * scene.a).sqrt();
    let mut frames = vec![side_view(&sim, vmax)];
    let mut fronts = Vec::new();
    let mut mm = mm_points().into_iter().peekable();
    for k in 1..=(t_end / 0.1).round() as usize {
        let big_t = 0.1 * k as f64;
        while let Some(&(tm, zm)) = mm.peek() {
            if tm > big_t {
                break;
            }
            sim.run_until(scene.physical_time(tm))?;
            fronts.push((tm, sim.front() / scene.a, zm));
            mm.next();
        }
        sim.run_until(scene.physical_time(big_t))?;
        frames.push(side_view(&sim, vmax));
    }
    let secs = t0.elapsed().as_secs_f64();
    let (h, w) = (frames[0].h, frames[0].w);
    let style = FieldStyle { range: ColorRange::Fixed(-1.0, vmax), nan_color: [255, 255, 255], ..Default::default() };
    let last = frames.last().ok_or("no frame")?;
    viz::field_to_png(ctx.out_dir.join("particles3d_dam_break.png"), &last.data, h, w, &style)?;
    let data: Vec<&[f64]> = frames.iter().map(|f| f.data.as_slice()).collect();
    viz::rollout_to_gif(
        ctx.out_dir.join("particles3d_dam_break.gif"),
        &data,
        h,
        w,
        &GifStyle { field: style, frame_delay_ms: 80, repeat: true },
    )?;
    let worst = fronts.iter().map(|(_, z, zm)| (z / zm - 1.0).abs()).fold(0.0f64, f64::max);
    let front_text: Vec<String> = fronts
        .iter()
        .map(|(t, z, zm)| format!("T = {t:.2}: Z = {z:.2} vs {zm:.2} ({:+.1}%)", 100.0 * (z / zm - 1.0)))
        .collect();
    let res = format!("dx = a/{:.0}", 1.0 / scene.dx);
    let rows = vec![TourRow {
        item: format!(
            "3D dam break WCSPH, {res}, {} fluid + {} wall particles, T = {t_end}",
            sim.n_fluid(),
            sim.x.len() - sim.n_fluid()
        ),
        seconds: secs,
        error: Some(worst),
        error_kind: "max |Z/Z_MM - 1| of the surge front, T in [1, 2.5]".into(),
        note: format!("{} steps, {} leaked", sim.steps(), sim.leaked()),
    }];
    let markdown = format!(
        "3D dam break (Martin & Moyce column, H = 2a, spanning the tank's depth {}a between free-slip side walls, {res}), 3D WCSPH with the parameter set fixed in `wcsph3d`'s docs before the comparison (round-1 2D defaults: Tait, Monaghan α = 0.15, δ-SPH 0.1, extrapolated-pressure wall layers): {} fluid particles, {} steps to T = {t_end} in {}; {} particles left the tank. Surge front: {} (README bar 3D1: 0..+10%, checked at dx = a/20 by the acceptance test). Side view, particles projected along the depth, colour: speed.\n\n![3D dam break](particles3d_dam_break.gif)\n",
        scene.depth,
        sim.n_fluid(),
        sim.steps(),
        format_seconds(secs),
        sim.leaked(),
        front_text.join("; ")
    );
    Ok(TourOutcome {
        rows,
        files: vec!["particles3d_dam_break.png".into(), "particles3d_dam_break.gif".into()],
        markdown,
    })
}

fn tour_liquid3d(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let cfg = if ctx.quick { Liquid3dConfig::tiny() } else { Liquid3dConfig::default() };
    let dir = ctx.out_dir.join("particles3d_liquid3d");
    let t0 = Instant::now();
    let files = cfg.generate(&dir)?;
    let secs = t0.elapsed().as_secs_f64();
    let mut particles = Vec::new();
    for f in &files {
        particles.push(pbdl_core::io::read_npz_array(f, "pos")?.dims()[1]);
    }
    let rows = vec![TourRow {
        item: format!(
            "CConv-style 3D liquid data, {} scenes x {} frames, spacing {} m, box {:?} m",
            cfg.scenes, cfg.frames, cfg.spacing, cfg.box_size
        ),
        seconds: secs,
        error: None,
        error_kind: String::new(),
        note: format!("fluid particles per scene {particles:?}, seed {}", cfg.seed),
    }];
    let markdown = format!(
        "CConv-style 3D liquid data: {} scenes of 1-3 fluid blocks and balls with random sizes, positions and initial velocities (seed {}) dropped into a {:?} m box, 3D WCSPH at {} m spacing, {} frames {} s apart, written as `scene_KKKK.npz` (`pos`, `vel` [frames, N, 3] f32; `box`, `box_normals` [M, 3], normals pointing into the box) plus JSON sidecars in {}; particles per scene {:?}.\n",
        cfg.scenes,
        cfg.seed,
        cfg.box_size,
        cfg.spacing,
        cfg.frames,
        cfg.frame_dt,
        format_seconds(secs),
        particles
    );
    let rel: Vec<std::path::PathBuf> =
        files.iter().filter_map(|f| f.strip_prefix(&ctx.out_dir).ok().map(|p| p.to_path_buf())).collect();
    Ok(TourOutcome { rows, files: rel, markdown })
}

fn bench_wcsph3d_step(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let resolutions: &[f64] = if ctx.quick { &[8.0, 10.0] } else { &[10.0, 16.0, 20.0] };
    let mut rows = Vec::new();
    for &per_a in resolutions {
        let scene = DamBreak3d { dx: 1.0 / per_a, ..DamBreak3d::default() };
        let mut sim = scene.build(Wcsph3dParams::default())?;
        // Let the column start to move so that the step is a typical one, not the rest state.
        for _ in 0..if ctx.quick { 5 } else { 50 } {
            let dt = sim.stable_dt().0;
            sim.step(dt)?;
        }
        let secs = median_seconds(2, if ctx.quick { 5 } else { 20 }, || {
            let dt = sim.stable_dt().0;
            sim.step(dt).ok()
        });
        rows.push(BenchRow {
            case: "dam_break_3d_step".into(),
            method: "pbdl_wcsph3d".into(),
            size: format!("{}f_{}w_dx_a{per_a:.0}", sim.n_fluid(), sim.x.len() - sim.n_fluid()),
            seconds: secs,
            unit: "step".into(),
            error: None,
            error_kind: String::new(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

/// What a long 3D dam-break run saw at its checks (every 0.1 T).
struct LongRun {
    /// Steps at the first non-finite state or solver error.
    nan_at: Option<u64>,
    /// Steps at the first check with a particle outside the tank.
    leak_at: Option<u64>,
    /// The solver's error, if one stopped the run.
    error: Option<String>,
    max_leaked: usize,
    /// The largest value of the run's density measure over the checks.
    max_density: f64,
}

/// Runs `sim` to `t_end` (dimensionless time of `scene`) in stops of 0.1 T, checking
/// finiteness, leaks and the largest `density(sim)`.
fn run_long<S: Evolve>(
    sim: &mut S,
    scene: &DamBreak3d,
    t_end: f64,
    is_finite: impl Fn(&S) -> bool,
    leaked: impl Fn(&S) -> usize,
    mut density: impl FnMut(&mut S) -> TaskResult<f64>,
) -> TaskResult<LongRun> {
    let mut run = LongRun { nan_at: None, leak_at: None, error: None, max_leaked: 0, max_density: 0.0 };
    for k in 1..=(t_end / 0.1).round() as usize {
        let big_t = 0.1 * k as f64;
        if let Err(e) = sim.run_until(scene.physical_time(big_t)) {
            run.error = Some(format!("T = {big_t:.1}: {e}"));
            run.nan_at.get_or_insert(sim.steps());
            break;
        }
        if !is_finite(sim) {
            run.nan_at.get_or_insert(sim.steps());
            break;
        }
        if leaked(sim) > 0 {
            run.leak_at.get_or_insert(sim.steps());
        }
        run.max_leaked = run.max_leaked.max(leaked(sim));
        run.max_density = run.max_density.max(density(sim)?);
    }
    Ok(run)
}

/// The two checks of a long run: finite values (`detail` when it finished), no leak.
fn long_run_checks(
    finite_invariant: String,
    leak_invariant: &str,
    run: LongRun,
    steps: u64,
    detail: String,
    leak_detail: String,
) -> Vec<StressCheck> {
    vec![
        StressCheck {
            invariant: finite_invariant,
            passed: run.nan_at.is_none(),
            first_broken_step: run.nan_at,
            detail: run.error.unwrap_or(detail),
            measure: run.nan_at.is_none().then_some(StressMeasure::StableSteps(steps)),
        },
        StressCheck {
            invariant: leak_invariant.into(),
            passed: run.leak_at.is_none() && run.nan_at.is_none(),
            first_broken_step: run.leak_at,
            detail: leak_detail,
            measure: None,
        },
    ]
}

fn stress_dam_break_3d(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let scene = scene(ctx.quick);
    let t_end: f64 = if ctx.quick { 3.0 } else { 10.0 };
    let mut sim = scene.build(Wcsph3dParams::default())?;
    let run = run_long(&mut sim, &scene, t_end, |s| s.is_finite(), |s| s.leaked(), |s| Ok(s.mean_density_error()))?;
    let res = format!("dx = a/{:.0}", 1.0 / scene.dx);
    let detail =
        format!("{} steps, t = {:.3} s, max mean |rho/rho0 - 1| = {:.4}", sim.steps(), sim.time(), run.max_density);
    let leak_detail = format!("at most {} of {} outside", run.max_leaked, sim.n_fluid());
    Ok(long_run_checks(
        format!("3D dam break ({res}) to T = {t_end}: values finite"),
        "no fluid particle leaves the tank (checked every 0.1 T)",
        run,
        sim.steps(),
        detail,
        leak_detail,
    ))
}

fn bench_dfsph3d_step(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let resolutions: &[f64] = if ctx.quick { &[8.0, 10.0] } else { &[10.0, 16.0, 20.0] };
    let mut rows = Vec::new();
    for &per_a in resolutions {
        let scene = DamBreak3d { dx: 1.0 / per_a, ..DamBreak3d::default() };
        let mut sim = scene.build_dfsph(DfsphParams::default_3d())?;
        // As for WCSPH: a moving column (T ~ 0.5 at a/20), not the rest state.
        for _ in 0..if ctx.quick { 3 } else { 20 } {
            let dt = sim.stable_dt();
            sim.step(dt)?;
        }
        let mut worst = 0.0f64;
        let secs = median_seconds(1, if ctx.quick { 3 } else { 10 }, || {
            let dt = sim.stable_dt();
            let r = sim.step(dt).ok();
            worst = worst.max(sim.last_solve().compression);
            r
        });
        rows.push(BenchRow {
            case: "dam_break_3d_step".into(),
            method: "pbdl_dfsph3d".into(),
            size: format!("{}f_{}w_dx_a{per_a:.0}", sim.n_fluid(), sim.x.len() - sim.n_fluid()),
            seconds: secs,
            unit: "step".into(),
            error: Some(worst),
            error_kind: "largest mean max(rho/rho0 - 1, 0) of the summation density over the timed steps".into(),
            peer: false,
            threads: ctx.threads,
        });
    }
    Ok(rows)
}

fn stress_dfsph3d_dam_break(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let scene = scene(ctx.quick);
    let t_end: f64 = if ctx.quick { 3.0 } else { 10.0 };
    let mut sim = scene.build_dfsph(DfsphParams::default_3d())?;
    let run = run_long(&mut sim, &scene, t_end, |s| s.is_finite(), |s| s.leaked(), |s| Ok(s.average_compression()?))?;
    let res = format!("dx = a/{:.0}", 1.0 / scene.dx);
    let per_step = |n: u64| n as f64 / sim.steps().max(1) as f64;
    let detail = format!(
        "{} steps, t = {:.3} s, {:.2} + {:.2} iterations per step, max mean compression (every 0.1 T) {:.2e}",
        sim.steps(),
        sim.time(),
        per_step(sim.total_iterations()),
        per_step(sim.total_divergence_iterations()),
        run.max_density
    );
    let leak_detail = format!(
        "at most {} of {} outside; {} wall-fallback corrections",
        run.max_leaked,
        sim.n_fluid(),
        sim.wall_corrections()
    );
    Ok(long_run_checks(
        format!("3D DFSPH dam break ({res}) to T = {t_end}: values finite"),
        "3D DFSPH: no fluid particle leaves the tank (checked every 0.1 T)",
        run,
        sim.steps(),
        detail,
        leak_detail,
    ))
}

/// The `#[ignore]`d tests behind the README's bars 3D1 and 3D3 (see [`crate::acceptance`]).
const ACCEPTANCE: &[AcceptanceTest] = &[
    AcceptanceTest {
        package: "pbdl-particles",
        file: "wcsph3d_tests",
        test: "dam_break_3d_front_within_band_of_martin_moyce",
        claim: "3D1: 3D WCSPH dam-break front (dx = a/20) within 0..+10% of Martin & Moyce for T in [1, 2.5]",
        minutes: 1.5,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-particles",
        file: "wcsph3d_tests",
        test: "dam_break_3d_to_t10_leaks_no_particle",
        claim: "3D1: 3D dam break (dx = a/20) to T = 10 finite with 0 leaked particles (checked every 0.1 T)",
        minutes: 6.0,
        env: &[],
    },
    AcceptanceTest {
        package: "pbdl-particles",
        file: "dfsph3d_tests",
        test: "bar_3d3_dam_break_dfsph_compression_leaks_and_front",
        claim: "3D3: 3D DFSPH dam break (dx = a/20, tolerance 0.1%): mean compression <= 0.1% (D1's measure), 0 leaked to T = 10; front reported",
        minutes: 1.0,
        env: &[],
    },
];

fn stress_acceptance(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    crate::acceptance::run_tests(ctx, ACCEPTANCE)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quick tour, bench and stress entries run (in seconds) and write their files; the
    /// acceptance entry is left to `cargo xtask stress particles3d --entry acceptance`.
    #[test]
    fn quick_entries_run() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: rayon::current_num_threads() };
        let tasks = tasks();
        assert_eq!(tasks.crate_name, "particles3d");
        for e in &tasks.tour {
            let out = (e.run)(&ctx).unwrap_or_else(|err| panic!("tour {}: {err}", e.name));
            assert!(!out.files.is_empty(), "{}", e.name);
            for f in &out.files {
                assert!(dir.path().join(f).exists(), "{} missing", f.display());
            }
        }
        for e in &tasks.bench {
            let rows = (e.run)(&ctx).unwrap();
            assert_eq!(rows.len(), 2);
            assert!(rows.iter().all(|r| r.seconds > 0.0 && !r.peer));
        }
        for name in ["dam_break_3d_long", "dfsph3d_dam_break_long"] {
            let long = tasks.stress.iter().find(|e| e.name == name).unwrap();
            for c in (long.run)(&ctx).unwrap() {
                assert!(c.passed, "{}: {}", c.invariant, c.detail);
            }
        }
    }
}
