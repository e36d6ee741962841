//! SMDP's `cargo xtask` entries.
//!
//! * tour: the toy's forward simulator against the digest's statistics, a short training of the
//!   score network, reverse-SDE/ODE trajectories and the posterior against the digest's table
//!   (PNG plots).
//! * bench: simulator paths per second, 1-step and multi-step updates, the spectral heat step.
//! * stress: long forward integrations, the explicit-Euler stability limit, reverse samplers
//!   over the whole horizon, and the heat step's energy decay and mean conservation.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{Entry, StressCheck, TaskContext, TaskResult, TourOutcome, TourRow};
use candle_core::DType;
use pbdl_core::viz::{line_plot, PlotStyle, Series};
use pbdl_diffusion::smdp::analytic::QUADRATIC_POSTERIOR_DT002;
use pbdl_diffusion::smdp::experts::SplitExpertRecipe;
use pbdl_diffusion::smdp::heat::{heat_step, HeatProblem};
use pbdl_diffusion::smdp::loss::{graded_one_step_loss, multi_step_loss, one_step_loss, LossWorkspace};
use pbdl_diffusion::smdp::mlp::{paper_adam, ScoreMlp};
use pbdl_diffusion::smdp::sampler::{
    hit_rates_with, posterior_plus_with, sample_trajectories, sample_trajectories_with, trajectory_times, Sampler,
};
use pbdl_diffusion::smdp::sde::{mean_std, two_point_starts, ToySde};
use pbdl_diffusion::smdp::toy::{train_toy, TimeSampling, ToyTrainConfig};
use std::time::Instant;

/// Tour, bench and stress entries of this part.
pub type Entries = (Vec<Entry<TourOutcome>>, Vec<Entry<Vec<BenchRow>>>, Vec<Entry<Vec<StressCheck>>>);

/// This part's entries.
pub fn entries() -> Entries {
    (
        vec![Entry {
            name: "smdp_toy",
            about: "SMDP toy: simulator statistics, a short score training, reverse-SDE/ODE trajectories and the posterior P(+1|y).",
            run: tour_toy,
        }],
        vec![Entry {
            name: "smdp",
            about: "SMDP: toy simulator, 1-step and multi-step updates of the score MLP, spectral heat step.",
            run: bench_smdp,
        }],
        vec![Entry {
            name: "smdp_long",
            about: "SMDP: long SDE/ODE integrations stay finite; the explicit-Euler stability limit; heat step energy decays.",
            run: stress_smdp,
        }],
    )
}

fn tour_toy(ctx: &TaskContext) -> TaskResult<TourOutcome> {
    let sde = ToySde::paper_quadratic();
    let mut rows = vec![];
    let t0 = Instant::now();
    let n_paths = if ctx.quick { 20_000 } else { 200_000 };
    let (m, s) = mean_std(&sde.endpoints(&vec![1.0; n_paths], 11)?);
    rows.push(TourRow {
        item: format!("forward SDE, {n_paths} paths from +1"),
        seconds: t0.elapsed().as_secs_f64(),
        error: Some((m - 0.0036).abs().max((s - 0.0351).abs())),
        error_kind: "max |mean - 0.0036|, |std - 0.0351| (digest)".into(),
        note: format!("mean {m:.5}, std {s:.5}"),
    });

    // The two time-split experts on data refined 8x, sampled on the graded grid (the recipe that
    // passes the acceptance at 600k updates per expert; here a short run).
    let updates = if ctx.quick { [3000, 2000, 0] } else { [20_000, 20_000, 5_000] };
    let recipe = SplitExpertRecipe { updates, ..SplitExpertRecipe::quadratic() };
    let (net, reps) = recipe.train(&sde, 0)?;
    let fine = recipe.data_sde(&sde);
    let opts = recipe.sampler_options();
    let total: usize = updates.iter().sum();
    rows.push(TourRow {
        item: format!("two score MLPs (t < {} and above), {total} updates each (batch 256)", recipe.split),
        seconds: reps[0].seconds.max(reps[1].seconds),
        error: reps[0].losses.last().map(|l| l.1),
        error_kind: "final 1-step loss of the near expert".into(),
        note: format!("{} parameters each; data at dt / {}", net.near.num_params(), recipe.stride),
    });

    let t0 = Instant::now();
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
    let per_bin = if ctx.quick { 300 } else { 2000 };
    let post = posterior_plus_with(&fine, &net, &ys, per_bin, opts, 5)?;
    let worst = post.iter().zip(&QUADRATIC_POSTERIOR_DT002).map(|(p, r)| (p - r.1).abs()).fold(0.0, f64::max);
    rows.push(TourRow {
        item: format!("reverse-SDE posterior, {per_bin} samples per bin"),
        seconds: t0.elapsed().as_secs_f64(),
        error: Some(worst),
        error_kind: "max |P(+1|y) - digest table| (dt = 0.02)".into(),
        note: format!("{post:.3?}"),
    });
    let t0 = Instant::now();
    let hits = hit_rates_with(&fine, &net, 1000, 0.01, opts, 6)?;
    rows.push(TourRow {
        item: "hit rates, 1000 start points in [-0.1, 0.1]".into(),
        seconds: t0.elapsed().as_secs_f64(),
        error: None,
        error_kind: String::new(),
        note: format!(
            "ODE {:.1}%, SDE {:.1}% within 1% of +-1; ODE keeps sign {:.1}%",
            100.0 * hits.ode_hits,
            100.0 * hits.sde_hits,
            100.0 * hits.ode_sign_kept
        ),
    });

    // Trajectories: a few start points, both samplers, x against t.
    let y: Vec<f64> = (0..8).map(|i| -0.07 + 0.02 * i as f64).collect();
    let mut series = vec![];
    let ts = trajectory_times(&fine, opts);
    for (sampler, label) in [(Sampler::ProbabilityFlow, "ODE"), (Sampler::ReverseSde, "SDE")] {
        let traj = sample_trajectories_with(&fine, &net, &y, sampler, opts, 3)?;
        for i in [1usize, 6] {
            // A poorly trained score lets the unstable reverse physics (x' = +lambda x^2 backward)
            // run away: clip for display; the hit rates above say how often that happens.
            let xs = traj.iter().map(|s| if s[i].is_finite() { s[i].clamp(-1.5, 1.5) } else { 1.5f64.copysign(s[i]) });
            series.push(Series::new(format!("{label} from y = {:+.2}", y[i]), ts.clone(), xs.collect()));
        }
    }
    let fwd = sde.simulate(&two_point_starts(2), 4)?;
    let ts: Vec<f64> = (0..=fwd.steps).map(|k| k as f64 * sde.dt).collect();
    series.push(Series::new("forward SDE from +1", ts.clone(), fwd.path(0).to_vec()));
    series.push(Series::new("forward SDE from -1", ts, fwd.path(1).to_vec()));
    let traj_png = ctx.out_dir.join("smdp_toy_trajectories.png");
    let style = |title: &str, x: &str, y: &str| PlotStyle {
        title: title.into(),
        x_label: x.into(),
        y_label: y.into(),
        ..Default::default()
    };
    line_plot(
        &traj_png,
        &series,
        &style("SMDP toy: forward paths, reverse ODE/SDE samples (clipped to +-1.5)", "t", "x"),
    )?;

    let post_png = ctx.out_dir.join("smdp_toy_posterior.png");
    let yf: Vec<f64> = (0..=20).map(|i| -0.1 + 0.01 * i as f64).collect();
    let post_fine = posterior_plus_with(&fine, &net, &yf, per_bin / 2, opts, 8)?;
    line_plot(
        &post_png,
        &[
            Series::new("reverse SDE (learned scores)", yf, post_fine),
            Series::new("digest Monte Carlo, dt = 0.02", ys, QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.1).collect()),
        ],
        &style("SMDP toy: posterior P(x0 = +1 | x_T = y)", "y", "P(+1 | y)"),
    )?;

    let markdown = format!(
        "### SMDP toy\n\nForward SDE x_T from +1: mean {m:.5}, std {s:.5} (digest: 0.0036, 0.0351). \
         Two time-split score MLPs (`experts::SplitExpertRecipe`, data refined {}x, graded sampler grid) trained \
         for {total} updates each in {:.1} s (the acceptance run uses 600k). Posterior max deviation from the digest \
         table {worst:.3}; hits ODE {:.1}%, SDE {:.1}%.\n\n![trajectories](smdp_toy_trajectories.png)\n\n\
         ![posterior](smdp_toy_posterior.png)\n",
        recipe.stride,
        reps[0].seconds.max(reps[1].seconds),
        100.0 * hits.ode_hits,
        100.0 * hits.sde_hits
    );
    Ok(TourOutcome { rows, files: vec![traj_png, post_png], markdown })
}

fn bench_row(case: &str, size: &str, seconds: f64, unit: &str, threads: usize) -> BenchRow {
    BenchRow {
        case: case.into(),
        method: "pbdl".into(),
        size: size.into(),
        seconds,
        unit: unit.into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads,
    }
}

fn bench_smdp(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let reps = if ctx.quick { 3 } else { 10 };
    let sde = ToySde::paper_quadratic();
    let mut rows = vec![];
    let n = if ctx.quick { 10_000 } else { 100_000 };
    let x0 = vec![1.0; n];
    let sec = median_seconds(1, reps, || sde.endpoints(&x0, 1));
    let (m, s) = mean_std(&sde.endpoints(&x0, 1)?);
    let mut row = bench_row("smdp_toy_forward_sde", &format!("{n}_paths_500_steps"), sec, "call", ctx.threads);
    row.error = Some((m - 0.0036).abs().max((s - 0.0351).abs()));
    row.error_kind = "max_abs_dev_from_digest_mean_std".into();
    rows.push(row);

    let net = ScoreMlp::paper(0);
    let paths = sde.simulate(&two_point_starts(256), 2)?;
    let x: Vec<f64> = (0..256).map(|p| paths.path(p)[1 + p % 400]).collect();
    let t: Vec<f64> = (0..256).map(|p| (1 + p % 400) as f64 * sde.dt).collect();
    let prev: Vec<f64> = (0..256).map(|p| paths.path(p)[p % 400]).collect();
    let mut ws = LossWorkspace::default();
    let mut grad = vec![0.0; net.num_params()];
    let mut work = net.clone();
    let mut adam = paper_adam(net.num_params(), 1e-4);
    let sec = median_seconds(3, reps * 10, || {
        grad.fill(0.0);
        let l = one_step_loss(&work, &sde.drift, sde.dt, &x, &t, &prev, Some(&mut grad), &mut ws);
        adam.step(work.params_mut(), &grad).expect("the net's parameter and gradient lengths");
        l
    });
    rows.push(bench_row("smdp_toy_one_step_update", "mlp_2536_batch256", sec, "update", 1));
    for window in [4usize, 16] {
        let targets: Vec<Vec<f64>> =
            (0..window).map(|m| x.iter().map(|v| v * (1.0 + 0.01 * m as f64)).collect()).collect();
        let tw: Vec<f64> = t.iter().map(|v| v + window as f64 * sde.dt).collect();
        let sec = median_seconds(1, reps, || {
            grad.fill(0.0);
            let l = multi_step_loss(&work, &sde.drift, sde.dt, &x, &tw, &targets, false, Some(&mut grad), &mut ws);
            adam.step(work.params_mut(), &grad).expect("the net's parameter and gradient lengths");
            l
        });
        rows.push(bench_row("smdp_toy_multi_step_update", &format!("window{window}_batch256"), sec, "update", 1));
    }

    // The graded loss with the odd network (what the near expert trains): half the batch on
    // coarse steps, half on fine ones.
    let mut work = net.clone().with_odd_symmetry();
    let h: Vec<f64> = (0..256).map(|i| if i % 2 == 0 { sde.dt } else { sde.dt / 8.0 }).collect();
    let w: Vec<f64> = h.iter().map(|v| (sde.dt / v).powi(2)).collect();
    let sec = median_seconds(3, reps * 10, || {
        grad.fill(0.0);
        let l = graded_one_step_loss(&work, &sde.drift, &h, &w, &x, &t, &prev, Some(&mut grad), &mut ws);
        adam.step(work.params_mut(), &grad).expect("the net's parameter and gradient lengths");
        l
    });
    rows.push(bench_row("smdp_toy_graded_update_odd_mlp", "mlp_2536_batch256", sec, "update", 1));

    // Time against error of the whole recipe: two short expert trainings, then the posterior
    // on the graded grid against the digest's table.
    let updates = if ctx.quick { [2000, 1000, 0] } else { [20_000, 20_000, 5_000] };
    let recipe = SplitExpertRecipe { updates, ..SplitExpertRecipe::quadratic() };
    let t0 = std::time::Instant::now();
    let (experts, _) = recipe.train(&sde, 0)?;
    let train_seconds = t0.elapsed().as_secs_f64();
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
    let per_bin = if ctx.quick { 200 } else { 2000 };
    let post = posterior_plus_with(&recipe.data_sde(&sde), &experts, &ys, per_bin, recipe.sampler_options(), 5)?;
    let total: usize = updates.iter().sum();
    let mut row =
        bench_row("smdp_toy_split_experts", &format!("{total}_updates_each"), train_seconds, "run", ctx.threads);
    row.error = Some(post.iter().zip(&QUADRATIC_POSTERIOR_DT002).map(|(p, r)| (p - r.1).abs()).fold(0.0, f64::max));
    row.error_kind = "max_abs_posterior_dev_from_digest_table".into();
    rows.push(row);

    let p = HeatProblem::default();
    let fields = p.random_fields(16, DType::F32, 0)?;
    let sec = median_seconds(1, reps, || heat_step(&fields, p.dt));
    rows.push(bench_row("smdp_heat_step", "16x32x32_f32", sec, "call", 1));
    Ok(rows)
}

/// The first index at which `v` is non-finite or larger than `bound` in magnitude.
fn first_bad(v: &[f64], bound: f64) -> Option<u64> {
    v.iter().position(|x| !x.is_finite() || x.abs() > bound).map(|i| i as u64)
}

fn stress_smdp(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let mut checks = physics_checks(ctx)?;
    checks.extend(sampler_checks(ctx)?);
    Ok(checks)
}

/// Checks of the simulators alone (no training).
fn physics_checks(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let mut checks = vec![];
    // 1. Long forward integrations from |x0| <= 10 stay finite and within their start range.
    let long = ToySde { t_end: if ctx.quick { 200.0 } else { 2000.0 }, ..ToySde::paper_quadratic() };
    let x0: Vec<f64> = (0..200).map(|i| -10.0 + 20.0 * i as f64 / 199.0).collect();
    let end = long.endpoints(&x0, 1)?;
    let bad = first_bad(&end, 10.0);
    checks.push(StressCheck {
        invariant: format!("forward SDE over {} steps from |x0| <= 10 stays finite and |x| <= 10", long.steps()),
        passed: bad.is_none(),
        first_broken_step: bad,
        detail: format!("max |x_T| = {:.3e}", end.iter().fold(0.0f64, |m, v| m.max(v.abs()))),
        measure: None,
    });

    // 2. Explicit Euler on x' = -lambda |x| x overshoots past -x once lambda dt |x| > 2: stable
    //    just below |x0| = 2 / (lambda dt) = 14.3, divergent above it.
    let short = ToySde { t_end: 2.0, g: 0.0, ..ToySde::paper_quadratic() };
    let limit = 2.0 / (7.0 * short.dt);
    let below = short.endpoints(&[0.95 * limit, -0.95 * limit], 0)?;
    let above = short.endpoints(&[1.05 * limit, -1.05 * limit], 0)?;
    let ok =
        below.iter().all(|v| v.is_finite() && v.abs() < limit) && above.iter().all(|v| !v.is_finite() || v.abs() > 1e6);
    checks.push(StressCheck {
        invariant: format!("explicit Euler stability limit |x0| = 2 / (lambda dt) = {limit:.2} is where paths blow up"),
        passed: ok,
        first_broken_step: if ok { None } else { Some(0) },
        detail: format!("x_T from 0.95 limit: {below:.3?}; from 1.05 limit: {above:.3?}"),
        measure: None,
    });

    // 3. The spectral heat step damps every mode (multipliers <= 1) and keeps the k = 0 one:
    //    the energy never grows and the mean is conserved, over many steps.
    let p = HeatProblem::default();
    let mut x = (p.random_fields(8, DType::F64, 3)? + 0.25)?;
    let steps = if ctx.quick { 200 } else { 2000 };
    let energy = |t: &candle_core::Tensor| -> TaskResult<f64> { Ok(t.sqr()?.sum_all()?.to_scalar::<f64>()?) };
    let mean0 = x.mean_all()?.to_scalar::<f64>()?;
    let mut prev = energy(&x)?;
    let mut broken = None;
    let mut drift = 0.0f64;
    for k in 0..steps {
        x = heat_step(&x, p.dt)?;
        let now = energy(&x)?;
        drift = drift.max((x.mean_all()?.to_scalar::<f64>()? - mean0).abs());
        if !now.is_finite() || now > prev * (1.0 + 1e-12) || drift > 1e-12 {
            broken = Some(k as u64);
            break;
        }
        prev = now;
    }
    checks.push(StressCheck {
        invariant: format!("heat step: energy never grows, mean conserved to 1e-12, over {steps} steps"),
        passed: broken.is_none(),
        first_broken_step: broken,
        detail: format!("final energy {prev:.6e}, max mean drift {drift:.2e}"),
        measure: None,
    });
    Ok(checks)
}

/// Reverse samplers with a briefly trained score over the whole horizon.
fn sampler_checks(ctx: &TaskContext) -> TaskResult<Vec<StressCheck>> {
    let mut checks = vec![];
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    let updates = if ctx.quick { 8000 } else { 60_000 };
    let cfg = ToyTrainConfig {
        log_every: 500,
        time_sampling: TimeSampling::LogUniform,
        ..ToyTrainConfig::one_step(updates * 3 / 4, updates / 4)
    };
    train_toy(&sde, &mut net, &cfg)?;
    // The evaluation range. Beyond it the backward physics has a pole within the horizon (from
    // y it is reached after 1 / (lambda |y|) time units) that only an accurate score prevents.
    let y: Vec<f64> = (0..2000).map(|i| -0.1 + 0.2 * i as f64 / 1999.0).collect();
    for sampler in [Sampler::ProbabilityFlow, Sampler::ReverseSde] {
        let traj = sample_trajectories(&sde, &net, &y, sampler, 9)?;
        let bad = traj.iter().position(|s| s.iter().any(|v| !v.is_finite() || v.abs() > 10.0)).map(|k| k as u64);
        checks.push(StressCheck {
            invariant: format!(
                "{sampler:?} with a score trained for {updates} updates, from y in [-0.1, 0.1] over all {} steps: finite, |x| <= 10",
                sde.steps()
            ),
            passed: bad.is_none(),
            first_broken_step: bad,
            detail: format!(
                "max |x_0| = {:.3}",
                traj.last().map(|s| s.iter().fold(0.0f64, |m, v| m.max(v.abs()))).unwrap_or(f64::NAN)
            ),
         measure: None, });
    }

    Ok(checks)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(dir: &std::path::Path) -> TaskContext {
        TaskContext { out_dir: dir.to_path_buf(), quick: true, threads: rayon::current_num_threads() }
    }

    #[test]
    fn stress_physics_checks_pass_in_quick_mode() {
        let dir = tempfile::tempdir().unwrap();
        let checks = physics_checks(&ctx(dir.path())).unwrap();
        for c in &checks {
            println!("{}: {} ({})", c.invariant, c.passed, c.detail);
        }
        assert!(checks.iter().all(|c| c.passed), "{checks:?}");
    }

    #[test]
    #[ignore = "quick tour: trains the toy for 8000 updates and writes two PNGs; 27 s on a loaded 2-core machine"]
    fn tour_writes_its_plots() {
        // Kept after the run so the plots can be looked at.
        let dir = std::env::temp_dir().join("pbdl_smdp_tour");
        std::fs::create_dir_all(&dir).unwrap();
        let out = tour_toy(&ctx(&dir)).unwrap();
        println!("files: {:?}", out.files);
        for r in &out.rows {
            println!("{} | {:.2} s | {:?} {} | {}", r.item, r.seconds, r.error, r.error_kind, r.note);
        }
        for f in &out.files {
            assert!(std::fs::metadata(f).unwrap().len() > 1000, "{f:?}");
        }
        // The simulator row is checked against the digest's statistics.
        assert!(out.rows[0].error.unwrap() < 0.002, "{:?}", out.rows[0]);
    }
}
