//! SMDP quadratic toy against its exact Euler-chain law: the exact score, samplers driven by it,
//! and trained models compared with it.

use pbdl_diffusion::smdp::analytic::QUADRATIC_POSTERIOR_DT002_4M;
use pbdl_diffusion::smdp::euler_law::{EulerChainLaw, GridScore, GridScoreKind};
use pbdl_diffusion::smdp::experts::{SplitExpertRecipe, SplitScore};
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::sampler::{
    hit_rates_with, posterior_plus_with, sample_trajectories_with, sample_with, HitReport, OdeWeight, Sampler,
    SamplerOptions, ScalarScore, StepScheme,
};
use pbdl_diffusion::smdp::sde::ToySde;
use pbdl_diffusion::smdp::toy::ToyTrainConfig;
use std::path::PathBuf;
use std::time::Instant;

mod common;
use common::{quadratic_reg_config, train_logged};

/// The exact law of the quadratic chain reproduces the Monte Carlo statistics: `x_T` from `+1`
/// (digest: mean 0.0036 +- 0.0005, std 0.035 +- 0.001, P(x_T < 0) = 0.456 at dt = 0.01; our
/// 200k-path run at dt = 0.02 gives 0.456 too) and every bin of the 4M-path posterior table within
/// 3 of its standard errors. Also: the mass stays 1 and a coarser grid gives the same numbers.
#[test]
fn euler_law_reproduces_the_monte_carlo_statistics() {
    let t0 = Instant::now();
    let law = EulerChainLaw::paper_quadratic().unwrap();
    println!("law on {} nodes in {:.2} s", law.nodes(), t0.elapsed().as_secs_f64());
    let (m, s, neg) = law.end_stats_from_plus();
    println!("exact chain law, x_T from +1: mean {m:.5} std {s:.5} P(x_T<0) {neg:.4}");
    assert!((m - 0.0036).abs() < 0.0005, "mean {m}");
    assert!((s - 0.035).abs() < 0.001, "std {s}");
    assert!((neg - 0.456).abs() < 0.01, "P(x_T<0) {neg}");
    for k in [1, 10, 100, law.steps()] {
        assert!((law.mass(k) - 1.0).abs() < 1e-9, "mass at step {k}: {}", law.mass(k));
    }
    for &(y, p_mc, se) in &QUADRATIC_POSTERIOR_DT002_4M {
        let p = law.posterior_plus_bin(y, 0.005);
        println!("y {y:+.3}: exact {p:.4}, 4M-path MC {p_mc:.4} +- {se:.4}");
        assert!((p - p_mc).abs() < 3.0 * se, "y {y}: {p} vs {p_mc} +- {se}");
    }
    let coarse = EulerChainLaw::new(&ToySde::paper_quadratic(), 3.0, 1.2).unwrap();
    let (mc, sc, _) = coarse.end_stats_from_plus();
    assert!((mc - m).abs() < 1e-8 && (sc - s).abs() < 1e-8, "grid dependence: {mc} {sc} vs {m} {s}");
    for k in [1, 25, 250] {
        for x in [0.2, 0.5, 0.86] {
            let (a, b) = (law.score(k, x), coarse.score(k, x));
            if law.density(k, x) > 1e-3 * law.density(k, 0.0).max(law.density(k, x)) {
                assert!((a - b).abs() < 1e-2 * (1.0 + a.abs()), "k {k} x {x}: score {a} vs {b}");
            }
        }
    }
}

/// The key finding as a regression test: with the exact 1-step loss minimiser of the chain (a
/// perfect regularised 1-step network), the paper's explicit ODE step misses `+-1` (it corrects
/// only half of the Euler error near t = 0) while the SDE hits; with the exact inverse of the
/// physics step and the Gaussian ODE weight both samplers hit.
#[test]
fn exact_minimiser_needs_the_implicit_gaussian_ode_step() {
    let sde = ToySde::paper_quadratic();
    let law = EulerChainLaw::paper_quadratic().unwrap();
    let target = GridScore { law: &law, kind: GridScoreKind::OneStepTarget };
    let explicit = hit_rates_with(&sde, &target, 200, 0.01, SamplerOptions::default(), 1).unwrap();
    let opts = SamplerOptions {
        scheme: StepScheme::ImplicitOneStep,
        substeps: 1,
        ode_weight: OdeWeight::Gaussian,
        coarse: None,
    };
    let fixed = hit_rates_with(&sde, &target, 200, 0.01, opts, 1).unwrap();
    println!("explicit {explicit:?}\nimplicit + Gaussian {fixed:?}");
    assert!(explicit.ode_hits < 0.05 && explicit.sde_hits >= 0.95, "{explicit:?}");
    assert!(fixed.ode_hits >= 0.95 && fixed.sde_hits >= 0.95 && fixed.ode_sign_kept >= 0.99, "{fixed:?}");
}

/// One line per discretisation: ODE hits, SDE hits, SDE posterior against the 4M-path table.
fn report(name: &str, sde: &ToySde, score: &impl ScalarScore, opts: SamplerOptions) -> (HitReport, f64) {
    let t0 = Instant::now();
    let hits = hit_rates_with(sde, score, 1000, 0.01, opts, 6).unwrap();
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002_4M.iter().map(|p| p.0).collect();
    let post = posterior_plus_with(sde, score, &ys, 2000, opts, 5).unwrap();
    let worst = post.iter().zip(&QUADRATIC_POSTERIOR_DT002_4M).map(|(p, r)| (p - r.1).abs()).fold(0.0, f64::max);
    println!(
        "{name:52} ODE hits {:6.1}% (sign kept {:5.1}%)  SDE hits {:6.1}% (+1: {:5.1}%)  posterior worst {worst:.3} {post:.3?} ({:.1} s)",
        100.0 * hits.ode_hits,
        100.0 * hits.ode_sign_kept,
        100.0 * hits.sde_hits,
        100.0 * hits.sde_plus,
        t0.elapsed().as_secs_f64()
    );
    (hits, worst)
}

/// The samplers driven by the exact functions of the chain's law (no network): the exact score
/// and the exact minimiser of the regularised 1-step loss, for each step scheme and 1, 2, 4
/// sub-steps (between chain steps the tables are interpolated linearly in time).
#[test]
#[ignore = "experiment, ~1 minute; measured ODE/SDE hits: exact score explicit 0%/0%, implicit 70%/100%, implicit + Gaussian weight 100%/100%; exact 1-step minimiser explicit 0%/100%, implicit one-step 70%/100%, + Gaussian weight 100%/100%; sub-steps with time-interpolated chain tables 0%/0%"]
fn exact_score_sampler_hits() {
    let sde = ToySde::paper_quadratic();
    let law = EulerChainLaw::paper_quadratic().unwrap();
    let score = GridScore { law: &law, kind: GridScoreKind::Score };
    let target = GridScore { law: &law, kind: GridScoreKind::OneStepTarget };
    for sub in [1, 2, 4] {
        for scheme in [StepScheme::Explicit, StepScheme::ImplicitScore] {
            let opts = SamplerOptions { scheme, substeps: sub, ..Default::default() };
            report(&format!("exact score, {scheme:?}, {sub} sub-steps"), &sde, &score, opts);
        }
        for scheme in [StepScheme::Explicit, StepScheme::ImplicitOneStep] {
            let opts = SamplerOptions { scheme, substeps: sub, ..Default::default() };
            report(&format!("1-step minimiser, {scheme:?}, {sub} sub-steps"), &sde, &target, opts);
        }
    }
    let gauss = |scheme| SamplerOptions { scheme, substeps: 1, ode_weight: OdeWeight::Gaussian, coarse: None };
    report("exact score, ImplicitScore, Gaussian ODE weight", &sde, &score, gauss(StepScheme::ImplicitScore));
    report("1-step minimiser, ImplicitOneStep, Gaussian ODE weight", &sde, &target, gauss(StepScheme::ImplicitOneStep));
}

/// Where the trained quadratic model of [`train_and_save_quadratic_reg_model`] is kept.
fn model_path() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("smdp_quadratic_reg_seed0.txt")
}

fn save(net: &ScoreMlp, path: &PathBuf) {
    let text: Vec<String> = net.params().iter().map(|p| format!("{p:?}")).collect();
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text.join("\n")).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

fn load(path: &PathBuf) -> Option<ScoreMlp> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut net = ScoreMlp::paper(0);
    let vals: Vec<f64> = text.lines().map(|l| l.parse().unwrap()).collect();
    if vals.len() != net.num_params() {
        return None;
    }
    net.params_mut().copy_from_slice(&vals);
    Some(net)
}

/// The regularised 1-step model of `seed` trained on `n_paths` paths with the config of
/// `quadratic_reg_recipe_with_consistent_sampler_steps` ([`quadratic_reg_config`]); the default
/// model (seed 0, 2500 paths) is loaded from [`model_path`] if saved there, else trained and saved.
fn reg_model(sde: &ToySde, seed: u64, n_paths: usize) -> ScoreMlp {
    let default = seed == 0 && n_paths == 2500;
    (if default { load(&model_path()) } else { None }).unwrap_or_else(|| {
        let mut net = ScoreMlp::paper(seed);
        let cfg = ToyTrainConfig { seed, n_paths, ..quadratic_reg_config() };
        train_logged(sde, &mut net, &cfg, &format!("seed {seed}, {n_paths} paths: trained"));
        if default {
            save(&net, &model_path());
        }
        net
    })
}

/// Trains the regularised 1-step model and saves its parameters (text, one per line) for the
/// comparisons below.
#[test]
#[ignore = "training run: 500k regularised 1-step updates, 7-25 minutes; writes target/tmp/smdp_quadratic_reg_seed0.txt"]
fn train_and_save_quadratic_reg_model() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    train_logged(&sde, &mut net, &quadratic_reg_config(), "trained");
    save(&net, &model_path());
    println!("saved to {}", model_path().display());
}

/// The trained regularised 1-step model (loaded from [`train_and_save_quadratic_reg_model`]'s
/// file, or trained here) against the exact score and the exact 1-step minimiser of the chain,
/// and its hits with each step scheme.
#[test]
#[ignore = "experiment: needs the saved model (else trains it, 7-25 minutes); measured: net within 0.8-2.4% of the exact 1-step minimiser for t <= 0.1, 5-14% for t >= 0.2, 500% from the exact score at t = 0.02; ODE/SDE hits explicit 0%/100%, implicit one-step 64%/100%, + Gaussian weight 90.2%/100%"]
fn trained_model_against_the_exact_law() {
    let sde = ToySde::paper_quadratic();
    let net = reg_model(&sde, 0, 2500);
    let law = EulerChainLaw::paper_quadratic().unwrap();
    let ks: Vec<usize> = vec![1, 2, 3, 5, 10, 25, 50, 100, 250, 500];
    let vs_score = law.compare(&net, GridScoreKind::Score, &ks);
    let vs_target = law.compare(&net, GridScoreKind::OneStepTarget, &ks);
    let target = GridScore { law: &law, kind: GridScoreKind::OneStepTarget };
    let target_vs_score = law.compare(&target, GridScoreKind::Score, &ks);
    for i in 0..ks.len() {
        println!(
            "t {:6.2}: rel. L2 error of the net vs exact score {:.4}, vs exact 1-step minimiser {:.4}; minimiser vs score {:.4}",
            vs_score.per_t[i].0, vs_score.per_t[i].1, vs_target.per_t[i].1, target_vs_score.per_t[i].1
        );
    }
    println!(
        "pooled: vs score {:.4} (bands {:?}), vs minimiser {:.4} (bands {:?})",
        vs_score.pooled, vs_score.by_band, vs_target.pooled, vs_target.by_band
    );
    // Pointwise at the mean path near t = 0 (where the ODE's end point is decided).
    for k in [1usize, 2, 3, 5, 10] {
        let t = k as f64 * sde.dt;
        // The mode of p_k on the positive side.
        let j = (0..law.nodes())
            .filter(|&j| law.node(j) > 0.0)
            .max_by(|&a, &b| law.density(k, law.node(a)).total_cmp(&law.density(k, law.node(b))))
            .unwrap();
        let x = law.node(j);
        let sn = net.eval(&[x], &[t])[0];
        println!(
            "k {k}: mode x {x:.4}: net {sn:.4}, exact score {:.4}, exact minimiser {:.4}",
            law.score(k, x),
            law.one_step_target(k, x)
        );
    }
    for scheme in [StepScheme::Explicit, StepScheme::ImplicitOneStep, StepScheme::ImplicitScore] {
        report(
            &format!("trained net, {scheme:?}"),
            &sde,
            &net,
            SamplerOptions { scheme, substeps: 1, ..Default::default() },
        );
    }
    let opts = SamplerOptions {
        scheme: StepScheme::ImplicitOneStep,
        substeps: 1,
        ode_weight: OdeWeight::Gaussian,
        coarse: None,
    };
    report("trained net, ImplicitOneStep, Gaussian ODE weight", &sde, &net, opts);
    // Where the ODE misses: start points and end points of the misses, and the end points of
    // the same start points with the exact 1-step minimiser.
    let y: Vec<f64> = (0..1000).map(|i| -0.1 + 0.2 * i as f64 / 999.0).collect();
    let ends = sample_with(&sde, &net, &y, Sampler::ProbabilityFlow, opts, 0).unwrap();
    let exact_ends = sample_with(&sde, &target, &y, Sampler::ProbabilityFlow, opts, 0).unwrap();
    let misses: Vec<usize> = (0..y.len()).filter(|&i| ((ends[i] as f64).abs() - 1.0).abs() > 0.01).collect();
    if let (Some(&a), Some(&b)) = (misses.first(), misses.last()) {
        println!("ODE misses: {} starts in y [{:.4}, {:.4}]", misses.len(), y[a], y[b]);
        for &i in misses.iter().step_by((misses.len() / 12).max(1)) {
            println!("  y {:+.4}: net end {:+.4}, exact-minimiser end {:+.4}", y[i], ends[i], exact_ends[i]);
        }
        let hits_elsewhere: Vec<String> = (0..y.len())
            .filter(|&i| !misses.contains(&i))
            .step_by(100)
            .map(|i| format!("{:+.3}->{:+.4}", y[i], ends[i]))
            .collect();
        println!("  hits (every 100th): {hits_elsewhere:?}");
    }
    let ys = [-0.09, -0.07, 0.07, 0.09];
    let tn = sample_trajectories_with(&sde, &net, &ys, Sampler::ProbabilityFlow, opts, 0).unwrap();
    let te = sample_trajectories_with(&sde, &target, &ys, Sampler::ProbabilityFlow, opts, 0).unwrap();
    for k in [0usize, 250, 400, 450, 475, 490, 495, 497, 498, 499, 500] {
        let t = (500 - k) as f64 * sde.dt;
        println!("t {t:5.2}: net {:+.4?} exact minimiser {:+.4?}", tn[k], te[k]);
    }
}

/// As [`exact_score_sampler_hits`] for chains integrated with `dt / m` and observed every
/// `dt = 0.02` (m = 2: the official data set; m = 8: close to the continuous SDE). The score is
/// then tabulated at every fine step, so sampler sub-steps up to `m` use exact values.
#[test]
#[ignore = "experiment, ~1 minute; measured ODE/SDE hits with the dt/8 chain's exact score: explicit at step 0.02 0%/0%, 2 sub-steps 0%/100%, 8 sub-steps 100%/100%; dt/2 chain, implicit, 2 sub-steps 100%/100%; 1-step minimiser at dt 0.02, explicit: 0%/100%"]
fn fine_chain_exact_score_sampler_hits() {
    let sde = ToySde::paper_quadratic();
    for m in [2usize, 8] {
        let t0 = Instant::now();
        let law = EulerChainLaw::with_substeps(&sde, m, 4.0, 1.2).unwrap();
        let (mean, std, neg) = law.end_stats_from_plus();
        println!(
            "chain dt/{m}: {} nodes, {:.1} s; x_T from +1: mean {mean:.5} std {std:.5} P(x_T<0) {neg:.4}",
            law.nodes(),
            t0.elapsed().as_secs_f64()
        );
        let score = GridScore { law: &law, kind: GridScoreKind::Score };
        let target = GridScore { law: &law, kind: GridScoreKind::OneStepTarget };
        for sub in [1, 2, m] {
            for scheme in [StepScheme::Explicit, StepScheme::ImplicitScore] {
                let opts = SamplerOptions { scheme, substeps: sub, ..Default::default() };
                report(&format!("dt/{m} chain: exact score, {scheme:?}, {sub} sub-steps"), &sde, &score, opts);
            }
        }
        for scheme in [StepScheme::Explicit, StepScheme::ImplicitOneStep] {
            let opts = SamplerOptions { scheme, substeps: 1, ..Default::default() };
            report(&format!("dt/{m} chain: 1-step minimiser, {scheme:?}"), &sde, &target, opts);
        }
    }
}

/// The fix, acceptance (ii)-(iii): the regularised 1-step model of `seed` (the 500k-update
/// recipe of [`train_and_save_quadratic_reg_model`]; seed 0 is loaded from its file if present)
/// sampled at the data step 0.02 with [`StepScheme::ImplicitOneStep`]: the model is read as the
/// 1-step loss minimiser it was trained to be, the physics step is inverted exactly, and the ODE
/// removes the step's noise with the Gaussian (DDIM-type) weight [`OdeWeight::Gaussian`]; the
/// SDE step is then the paper's explicit one. Returns (hits, worst posterior error).
fn implicit_gaussian_acceptance(seed: u64, n_paths: usize) -> (HitReport, f64) {
    let sde = ToySde::paper_quadratic();
    let net = reg_model(&sde, seed, n_paths);
    let law = EulerChainLaw::paper_quadratic().unwrap();
    let ks = [1usize, 10, 50, 100, 250, 500];
    let err = law.compare(&net, GridScoreKind::OneStepTarget, &ks);
    println!("seed {seed}: vs the exact 1-step minimiser: pooled {:.4}, per t {:.4?}", err.pooled, err.per_t);
    let opts = SamplerOptions {
        scheme: StepScheme::ImplicitOneStep,
        substeps: 1,
        ode_weight: OdeWeight::Gaussian,
        coarse: None,
    };
    let (hits, worst) = report(&format!("seed {seed}: implicit + Gaussian ODE weight"), &sde, &net, opts);
    report(&format!("seed {seed}: paper's explicit steps"), &sde, &net, SamplerOptions::default());
    // Which times decide the ODE misses: the net below t_s, the exact minimiser above, and back.
    let target = GridScore { law: &law, kind: GridScoreKind::OneStepTarget };
    for t_s in [0.5, 2.0] {
        let low = SplitScore { near: &net, far: &target, split: t_s };
        report(&format!("seed {seed}: net for t < {t_s}, exact above"), &sde, &low, opts);
        let high = SplitScore { near: &target, far: &net, split: t_s };
        report(&format!("seed {seed}: exact for t < {t_s}, net above"), &sde, &high, opts);
    }
    (hits, worst)
}

#[test]
#[ignore = "earlier attempt (superseded by smdp_exact::quadratic_split_experts_*), FAILS (iii) for the ODE: 500k regularised 1-step updates (or the saved model), implicit + Gaussian sampler; ODE hits 90.2%, SDE hits 100%, posterior within 0.038 (measured)"]
fn quadratic_reg_model_with_implicit_gaussian_sampler() {
    let (hits, worst) = implicit_gaussian_acceptance(0, 2500);
    assert!(worst <= 0.05, "posterior off by {worst}");
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95, "{hits:?}");
}

#[test]
#[ignore = "earlier attempt, second seed, FAILS (ii): trains 500k updates (10 minutes under load); ODE hits 100% (sign kept 94.6%), SDE hits 100%, posterior off by 0.070 (measured); with the exact minimiser for t >= 2 the posterior is within 0.016"]
fn quadratic_reg_model_with_implicit_gaussian_sampler_seed1() {
    let (hits, worst) = implicit_gaussian_acceptance(1, 2500);
    assert!(worst <= 0.05, "posterior off by {worst}");
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95, "{hits:?}");
}

/// Experiment: the same recipe on 10x the paper's data (25k paths): does the ODE's remaining
/// miss (the net's error at t = 2..10, amplified by the backward-unstable ODE) shrink with data?
/// Measured: the ODE now hits, but the net's error at t = 10 stays 12% and the posterior is off
/// by 0.094 (biased to -1), so the large-t error is not (only) the data set's size.
#[test]
#[ignore = "experiment: 500k regularised 1-step updates on 25k paths (6 minutes); measured ODE hits 100% (sign kept 98.6%), SDE hits 100%, posterior off by 0.094 (P(+1) 0.41 overall; with the exact minimiser for t >= 2: 0.016)"]
fn quadratic_reg_model_25k_paths_with_implicit_gaussian_sampler() {
    let (hits, worst) = implicit_gaussian_acceptance(0, 25_000);
    println!("25k paths: {hits:?}, posterior worst {worst:.3}");
}

/// The graded grid with perfect models: data refined 8x (`dt / 8`), the paper's explicit steps of
/// `dt` above `fine_below` and of `dt / 8` below, driven by the exact 1-step minimisers of the
/// refined chain (for the coarse step above, the fine step below).
#[test]
#[ignore = "experiment, ~40 s in release; measured ODE/SDE hits: fine_below 0 (all coarse) 0%/100%; 0.02, 0.06, 0.1, 0.2, 0.5: 100%/100%, posterior within 0.016 of the 4M-path table"]
fn graded_grid_with_exact_minimisers_hits() {
    let recipe = SplitExpertRecipe::quadratic();
    let base = ToySde::paper_quadratic();
    let fine = recipe.data_sde(&base);
    let m = recipe.stride;
    let law_f = EulerChainLaw::new(&fine, 4.0, 1.2).unwrap();
    let law_c = EulerChainLaw::with_substeps(&base, m, 4.0, 1.2).unwrap();
    let near = GridScore { law: &law_f, kind: GridScoreKind::OneStepTarget };
    let far = GridScore { law: &law_c, kind: GridScoreKind::OneStepTarget };
    for fine_below in [0.0, 0.02, 0.06, 0.1, 0.2, 0.5] {
        let r = SplitExpertRecipe { fine_below, ..recipe.clone() };
        // The first coarse step (from the top) that would end below `fine_below` is fine.
        let exact = SplitScore { near: &near, far: &far, split: fine_below + base.dt - 0.5 * fine.dt };
        let (hits, worst) =
            report(&format!("exact minimisers, fine below {fine_below}"), &fine, &exact, r.sampler_options());
        if fine_below > 0.0 {
            assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95 && worst <= 0.05, "{hits:?} {worst}");
        }
    }
}

/// Acceptance (ii)-(iii) with [`SplitExpertRecipe::quadratic`]: two experts of the paper's MLP
/// trained on the 8x refined chain, sampled with the paper's explicit steps on the graded grid.
/// The posterior is checked against the digest's table (dt 0.01 Monte Carlo, the acceptance) and
/// printed against the refined chain's exact law (the digest: "use the dt of your simulator")
/// and our 4M-path table (dt 0.02).
fn split_experts_acceptance(seed: u64, odd: bool) {
    let recipe = SplitExpertRecipe { odd, ..SplitExpertRecipe::quadratic() };
    let base = ToySde::paper_quadratic();
    let t0 = Instant::now();
    let (score, reps) = recipe.train(&base, seed).unwrap();
    println!(
        "seed {seed}: experts trained in {:.0} s; final losses near {:?}, far {:?}",
        t0.elapsed().as_secs_f64(),
        reps[0].losses.last(),
        reps[1].losses.last()
    );
    let fine = recipe.data_sde(&base);
    let (hits, worst) =
        report(&format!("seed {seed}: split experts, graded grid"), &fine, &score, recipe.sampler_options());
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002_4M.iter().map(|p| p.0).collect();
    let post = posterior_plus_with(&fine, &score, &ys, 2000, recipe.sampler_options(), 5).unwrap();
    let worst_digest = post.iter().zip(&DIGEST_POSTERIOR).map(|(p, r)| (p - r).abs()).fold(0.0, f64::max);
    let law = EulerChainLaw::new(&fine, 4.0, 1.2).unwrap();
    let exact: Vec<f64> = ys.iter().map(|&y| law.posterior_plus_bin(y, 0.005)).collect();
    let worst_exact = post.iter().zip(&exact).map(|(p, r)| (p - r).abs()).fold(0.0, f64::max);
    println!(
        "seed {seed}: posterior {post:.3?}; worst vs the digest's {DIGEST_POSTERIOR:?} {worst_digest:.3}, \
         vs the refined chain's exact {exact:.3?} {worst_exact:.3}, vs the 4M-path dt 0.02 table {worst:.3}"
    );
    println!(
        "ACCEPTANCE: smdp_{}_experts_seed{seed} measured=ODE hits {:.1}%, SDE hits {:.1}%, ODE sign kept {:.1}%, \
         posterior within {worst_digest:.3} of the digest bar=hits >= 95%, sign kept >= 99%, posterior within 0.05",
        if odd { "odd" } else { "plain" },
        100.0 * hits.ode_hits,
        100.0 * hits.sde_hits,
        100.0 * hits.ode_sign_kept
    );
    assert!(worst_digest <= 0.05, "posterior off the digest's table by {worst_digest}");
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95, "{hits:?}");
    // The bar of this claim everywhere in the crate (smdp_toy.rs states it first): 99%.
    assert!(hits.ode_sign_kept >= 0.99, "the ODE should keep the sign of x_T: {hits:?}");
}

/// The digest's `P(+1 | y)` at `y = -0.095, -0.025, -0.005, 0.005, 0.025, 0.095`.
const DIGEST_POSTERIOR: [f64; 6] = [0.41, 0.46, 0.49, 0.51, 0.54, 0.59];

#[test]
#[ignore = "acceptance run, seed 0: two odd experts x 600k updates in parallel, 19 minutes beside other jobs; measured: ODE hits 99.8% (sign kept 100%), SDE 100%, posterior within 0.014 of the digest's table (0.017 of the 4M-path table, 0.028 of the refined chain's exact law): passes"]
fn quadratic_split_experts_seed0() {
    split_experts_acceptance(0, true);
}

#[test]
#[ignore = "acceptance run, seed 1: two odd experts x 600k updates in parallel, 19 minutes beside other jobs; measured: ODE hits 99.0% (sign kept 100%), SDE 100%, posterior within 0.013 of the digest's table (0.014 / 0.020): passes"]
fn quadratic_split_experts_seed1() {
    split_experts_acceptance(1, true);
}

#[test]
#[ignore = "plain (not odd) experts, seed 0, FAILS (iii) narrowly: ODE hits 94.6% (sign kept 94.7%), SDE 100%, posterior within 0.019 of the digest's table (measured)"]
fn quadratic_split_plain_experts_seed0() {
    split_experts_acceptance(0, false);
}

#[test]
#[ignore = "plain (not odd) experts, seed 1: passes, ODE hits 100% (sign kept 98.0%), SDE 100%, posterior within 0.021 (measured)"]
fn quadratic_split_plain_experts_seed1() {
    split_experts_acceptance(1, false);
}
