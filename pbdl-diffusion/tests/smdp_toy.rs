//! SMDP toy problem: simulator statistics, analytic formulas, samplers and short training.
//! The full acceptance runs (training to acceptance) are `#[ignore]`d and print their numbers.

use pbdl_diffusion::smdp::analytic::{AffineMixture, QUADRATIC_POSTERIOR_DT002, QUADRATIC_POSTERIOR_DT002_4M};
use pbdl_diffusion::smdp::loss::{multi_step_loss, LossWorkspace};
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::physics::ToyDrift;
use pbdl_diffusion::smdp::sampler::{hit_rates, posterior_plus, AnalyticScore, HitReport};
use pbdl_diffusion::smdp::sde::{mean_std, two_point_starts, ToySde};
use pbdl_diffusion::smdp::toy::{
    affine_one_step_target, affine_score_error, score_error_against, train_toy, TimeSampling, ToyLoss, ToyStage,
    ToyTrainConfig,
};
use std::time::Instant;

mod common;
use common::{one_directional_strides, quadratic_reg_config, train_logged};

/// The digest's anchor: 400k paths give mean 0.0036 and std 0.0351 at dt = 0.02.
#[test]
fn quadratic_forward_simulator_matches_the_reference_statistics() {
    let sde = ToySde::paper_quadratic();
    let t0 = Instant::now();
    let end = sde.endpoints(&vec![1.0; 200_000], 11).unwrap();
    let (m, s) = mean_std(&end);
    let below = end.iter().filter(|&&v| v < 0.0).count() as f64 / end.len() as f64;
    println!("quadratic x_T from +1: mean {m:.5} std {s:.5} P(x_T<0) {below:.4} ({:.2} s)", t0.elapsed().as_secs_f64());
    assert!((m - 0.0036).abs() < 0.0005, "mean {m}");
    assert!((s - 0.035).abs() < 0.001, "std {s}");
    // Digest: P(x_T < 0 | x0 = +1) = 0.456 (at dt = 0.01); 4 standard errors of slack.
    assert!((below - 0.456).abs() < 0.01, "P(x_T<0) {below}");
}

/// The affine chain has an exact law: mean c^k, variance g^2 dt (1 - c^2k) / (1 - c^2), c = 1 - a dt.
#[test]
fn affine_forward_simulator_matches_its_exact_law() {
    let sde = ToySde::paper_affine();
    let n = 100_000;
    let paths = sde.simulate(&vec![1.0; n], 3).unwrap();
    let law = AffineMixture::euler(0.5, 0.04, 0.02);
    for k in [25, 100, 500] {
        let (m, s) = mean_std(&paths.at_step(k));
        let (mu, sig) = law.moments(k as f64 * 0.02);
        let se = sig / (n as f64).sqrt();
        assert!((m - mu).abs() < 5.0 * se, "step {k}: mean {m} vs {mu}");
        assert!((s / sig - 1.0).abs() < 5.0 / (2.0 * n as f64).sqrt(), "step {k}: std {s} vs {sig}");
    }
}

#[test]
fn simulator_is_seeded_and_rejects_bad_settings() {
    let sde = ToySde::paper_quadratic();
    let a = sde.endpoints(&[1.0; 1000], 5).unwrap();
    assert_eq!(a, sde.endpoints(&[1.0; 1000], 5).unwrap());
    assert_ne!(a, sde.endpoints(&[1.0; 1000], 6).unwrap());
    let bad = ToySde { dt: 0.0, ..sde };
    let e = bad.endpoints(&[1.0], 0).unwrap_err().to_string();
    assert!(e.contains("dt"), "{e}");
}

/// The reverse SDE with the exact score recovers the analytic posterior sigmoid(8.42 y).
#[test]
fn reverse_sde_with_the_exact_affine_score_gives_the_analytic_posterior() {
    let sde = ToySde::paper_affine();
    let score = AnalyticScore { law: AffineMixture::continuous(0.5, 0.04) };
    let ys = [-0.2, -0.05, 0.0, 0.05, 0.2];
    let t0 = Instant::now();
    let p = posterior_plus(&sde, &score, &ys, 2000, 1).unwrap();
    for (y, p) in ys.iter().zip(&p) {
        let exact = 1.0 / (1.0 + (-8.42 * y).exp());
        println!("affine posterior y {y:+.3}: reverse SDE {p:.3} analytic {exact:.3}");
        assert!((p - exact).abs() < 0.05, "y {y}: {p} vs {exact}");
    }
    let hits = hit_rates(&sde, &score, 1000, 0.01, 2).unwrap();
    println!("exact affine score: {hits:?} ({:.2} s)", t0.elapsed().as_secs_f64());
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95, "{hits:?}");
}

/// Mean loss of `net` on a fixed set of `n` transitions (windows) of fresh paths.
fn held_out_loss(sde: &ToySde, net: &ScoreMlp, window: usize, n: usize) -> f64 {
    let paths = sde.simulate(&two_point_starts(n), 999).unwrap();
    let steps = sde.steps();
    let mut x = vec![];
    let mut t = vec![];
    let mut targets = vec![vec![]; window];
    for p in 0..n {
        // A deterministic spread of times over the whole interval.
        let k = window + (p * 7919) % (steps + 1 - window);
        x.push(paths.path(p)[k]);
        t.push(k as f64 * sde.dt);
        for (m, tg) in targets.iter_mut().enumerate() {
            tg.push(paths.path(p)[k - 1 - m]);
        }
    }
    multi_step_loss(net, &sde.drift, sde.dt, &x, &t, &targets, window == 1, None, &mut LossWorkspace::default())
}

/// A few thousand updates of each loss must lower its held-out value. The 1-step loss is
/// dominated by the irreducible noise term (about g^2 dt), so the drop is small but, on 40k
/// held-out transitions, far outside the estimate's noise; in the affine case the learned score
/// must also move towards the analytic one.
#[test]
fn short_training_reduces_both_losses() {
    const UPDATES: usize = 1500;
    for (sde, loss) in [
        (ToySde::paper_quadratic(), ToyLoss::OneStep),
        (ToySde::paper_quadratic(), ToyLoss::MultiStep(4)),
        (ToySde::paper_affine(), ToyLoss::OneStep),
    ] {
        let window = match loss {
            ToyLoss::OneStep => 1,
            ToyLoss::MultiStep(w) => w,
            ToyLoss::Strided { stride, .. } | ToyLoss::Graded { stride, .. } => stride,
        };
        let mut net = ScoreMlp::paper(0);
        let before = held_out_loss(&sde, &net, window, 40_000);
        let law = AffineMixture::continuous(0.5, 0.04);
        let ts = [0.5, 1.0, 2.0, 5.0, 10.0];
        let err_before = affine_score_error(&net, &law, &ts, 200).pooled;
        let cfg = ToyTrainConfig {
            n_paths: 500,
            stages: vec![ToyStage { loss, lr: 1e-3, updates: UPDATES }],
            ..ToyTrainConfig::one_step(0, 0)
        };
        let rep = train_toy(&sde, &mut net, &cfg).unwrap();
        let after = held_out_loss(&sde, &net, window, 40_000);
        println!(
            "{:?} {loss:?}: held-out loss {before:.5e} -> {after:.5e}; {:.2} s ({:.0} us/update)",
            sde.drift,
            rep.seconds,
            1e6 * (rep.seconds - rep.simulate_seconds) / UPDATES as f64
        );
        assert!(after < 0.97 * before, "{loss:?}: {before} -> {after}");
        if matches!(sde.drift, ToyDrift::Affine(_)) {
            let err_after = affine_score_error(&net, &law, &ts, 200).pooled;
            println!("affine score error vs analytic: {err_before:.3} -> {err_after:.3}");
            assert!(err_after < 0.5 * err_before, "{err_before} -> {err_after}");
        }
    }
}

/// Acceptance (i): in the affine case the learned score is within 10% (relative L2 over the
/// region p_t > 1% of its maximum) of the analytic score for t in [0.5, 10]. Two bars, both
/// asserted: pooled over all t, and at every t of the grid (the claim says "for t in
/// [0.5, 10]", so a pooled pass alone does not meet it).
///
/// Recipe: the official `affine_reg_mlp_big` config's stages (regularised 1-step loss; every 5th
/// point at lr 1e-3, then every point at 1e-4, then 1e-5), shortened to 100k + 150k + 50k
/// updates (the official run is 250k + 1.25M + 3.75M), on data of our dt = 0.02 simulator and
/// the official time grid.
///
/// Measured (209 s): pooled 0.0714 against the continuous law (pass), 0.0808 against the exact
/// law of the Euler chain that generated the data, 0.0748 against the exact minimiser of the
/// loss on that chain ([`affine_one_step_target`], which is itself 1.5% from g^2 grad log p).
/// The error sits at t = 2.5..4 (0.10..0.12), where the two modes separate and the score has a
/// steep tanh step between them; by density band: 0.081 where p_t is 1-10% of its maximum,
/// 0.045 at 10-50%, 0.076 at 50-100%. A second seed (1; the `smdp_toy` example) gives 0.0929
/// (t = 4: 0.213, t = 10: 0.140): a pass with little margin. The first attempt (1-step loss
/// only, 50k updates per learning rate, no stride-5 stage) measured 0.108-0.110. Per t the
/// claim is NOT met (seed 0: up to 0.12 at t = 2.5..4; seed 1: 0.213 at t = 4), so this test
/// fails on its second assertion.
#[test]
#[ignore = "acceptance run: 300k regularised 1-step updates; 3.5 minutes (pooled 0.071 met; per-t max 0.10-0.12 at t = 2.5..4: NOT met, fails)"]
fn affine_learned_score_matches_the_analytic_score() {
    let sde = ToySde::paper_affine();
    let mut net = ScoreMlp::paper(0);
    let mut cfg = ToyTrainConfig { log_every: 50_000, sim_substeps: 1, ..ToyTrainConfig::official(100_000, 150_000) };
    cfg.stages.push(ToyStage { loss: ToyLoss::Strided { stride: 1, bidirectional: false }, lr: 1e-5, updates: 50_000 });
    one_directional_strides(&mut cfg);
    train_logged(&sde, &mut net, &cfg, "trained");
    let ts: Vec<f64> = (0..20).map(|i| 0.5 + 9.5 * i as f64 / 19.0).collect();
    let euler = AffineMixture::euler(0.5, 0.04, 0.02);
    let cont = affine_score_error(&net, &AffineMixture::continuous(0.5, 0.04), &ts, 400);
    let eul = affine_score_error(&net, &euler, &ts, 400);
    let tgt = score_error_against(&net, &euler, &ts, 400, |x, t| affine_one_step_target(&euler, 0.02, 1, x, t));
    for ((t, e), (_, e2)) in cont.per_t.iter().zip(&eul.per_t) {
        println!("t {t:5.2}: rel. L2 error vs continuous {e:.4}, vs Euler-chain law {e2:.4}");
    }
    println!("by density band (vs continuous): {:?}", cont.by_band);
    println!(
        "pooled: vs continuous {:.4}, vs Euler-chain law {:.4}, vs the loss minimiser {:.4}",
        cont.pooled, eul.pooled, tgt.pooled
    );
    let (t_worst, worst) = cont.per_t.iter().fold((0.0, 0.0), |w, &(t, e)| if e > w.1 { (t, e) } else { w });
    println!(
        "ACCEPTANCE: smdp_affine_score measured=pooled {:.4}, worst {worst:.4} at t = {t_worst:.2} \
         bar=pooled < 0.10 and < 0.10 at every t",
        cont.pooled
    );
    assert!(cont.pooled < 0.10, "pooled relative error {}", cont.pooled);
    assert!(worst < 0.10, "relative error {worst:.4} at t = {t_worst:.2} (bar 0.10 at every t)");
}

/// The first attempt's config: the three learning rates of the official affine config with the
/// 1-step loss only, 50k updates each (kept for the log-uniform experiment below).
fn accept_config() -> ToyTrainConfig {
    let mut cfg = ToyTrainConfig { log_every: 10_000, ..ToyTrainConfig::one_step(50_000, 50_000) };
    cfg.stages.push(ToyStage { loss: ToyLoss::OneStep, lr: 1e-5, updates: 50_000 });
    cfg
}

/// Experiment: the affine case trained like the quadratic acceptance model (log-uniform times);
/// prints the same numbers as the acceptance test and asserts nothing.
#[test]
#[ignore = "experiment: 150k 1-step updates with log-uniform times; 8 minutes on a loaded 2-core machine"]
fn affine_with_log_uniform_times() {
    let sde = ToySde::paper_affine();
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { time_sampling: TimeSampling::LogUniform, ..accept_config() };
    train_logged(&sde, &mut net, &cfg, "trained");
    let ts: Vec<f64> = (0..20).map(|i| 0.5 + 9.5 * i as f64 / 19.0).collect();
    let cont = affine_score_error(&net, &AffineMixture::continuous(0.5, 0.04), &ts, 400);
    for (t, e) in &cont.per_t {
        println!("t {t:5.2}: rel. L2 error vs continuous {e:.4}");
    }
    println!("pooled vs continuous {:.4}", cont.pooled);
}

/// Prints the reverse-SDE posterior against both reference tables and the hit rates; returns
/// the worst posterior error against the 4M-path table and the hit rates.
fn report_quadratic(name: &str, sde: &ToySde, net: &ScoreMlp) -> (f64, HitReport) {
    let t0 = Instant::now();
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
    let post = posterior_plus(sde, net, &ys, 2000, 5).unwrap();
    let hits = hit_rates(sde, net, 1000, 0.01, 6).unwrap();
    let (mut worst, mut worst_digest): (f64, f64) = (0.0, 0.0);
    for (((y, digest), (_, mc, se)), p) in
        QUADRATIC_POSTERIOR_DT002.iter().zip(&QUADRATIC_POSTERIOR_DT002_4M).zip(&post)
    {
        println!("{name}: y {y:+.3}: P(+1|y) reverse SDE {p:.3}, 4M-path MC {mc:.3} +- {se:.3}, digest {digest:.2}");
        worst = worst.max((p - mc).abs());
        worst_digest = worst_digest.max((p - digest).abs());
    }
    println!("{name}: worst posterior error vs 4M MC {worst:.3}, vs digest table {worst_digest:.3}");
    println!("{name}: {hits:?}; evaluated in {:.1} s", t0.elapsed().as_secs_f64());
    (worst, hits)
}

/// The 4M-path posterior table (computed with numpy) reproduced by this crate's simulator:
/// every bin within 4 standard errors (of both estimates combined).
#[test]
#[ignore = "reference check: 4M quadratic paths; 18 s (measured: all bins within 2.3 standard errors)"]
fn posterior_reference_table_is_reproduced_by_our_simulator() {
    let sde = ToySde::paper_quadratic();
    let n = 4_000_000;
    let x0 = two_point_starts(n);
    let end = sde.endpoints(&x0, 2024).unwrap();
    for &(y, p_ref, se_ref) in &QUADRATIC_POSTERIOR_DT002_4M {
        let (mut count, mut plus) = (0usize, 0usize);
        for (e, s) in end.iter().zip(&x0) {
            if (e - y).abs() < 0.005 {
                count += 1;
                plus += usize::from(*s > 0.0);
            }
        }
        let p = plus as f64 / count as f64;
        let se = (p * (1.0 - p) / count as f64).sqrt();
        println!("y {y:+.3}: {p:.4} +- {se:.4} ({count} paths) vs {p_ref:.4} +- {se_ref:.4}");
        assert!((p - p_ref).abs() < 4.0 * (se * se + se_ref * se_ref).sqrt(), "y {y}: {p} vs {p_ref}");
    }
}

/// Acceptance (ii) and (iii) on the quadratic toy. Two models:
/// * `L`: the 1-step loss with its regulariser (an exact score) and log-uniform training times;
///   judged on the reverse-SDE posterior (within 0.05 per bin of the dt = 0.02 Monte Carlo
///   table; the numbers below were measured against the digest's table, the assertion now uses
///   the 4M-path one, 2000 samples per bin) and on the SDE hit rate (>= 95% within 1% of +-1).
/// * `M`: `L` fine-tuned with the multi-step loss over growing windows 4, 6, ..., 12; judged on
///   the ODE hit rate (>= 95%) and on the ODE keeping the sign of x_T (>= 99%).
///
/// Measured: L posterior within 0.036 of the table, SDE hits 100% (50/50 split), ODE hits 0.1%;
/// M ODE hits 100%, SDE hits 0%, but M's ODE keeps the sign of x_T for only 95.5% of the start
/// points (the switch point sits at |y| ~ 0.009), so the last assertion fails.
/// With uniform training times (the first attempt, kept in the report) the 1-step model missed:
/// posterior off by 0.06 in the y = +0.095 bin, SDE hits 65%. Neither model reaches both hit
/// rates: the regularised score corrects only half of the Euler error in an ODE step, and the
/// ODE-calibrated multi-step score over-corrects in an SDE step (both numbers are printed).
#[test]
#[ignore = "earlier attempt (superseded by smdp_exact::quadratic_split_experts_*), FAILS the last assertion (ODE sign kept 95.5%): 150k 1-step + 10k multi-step updates; 8-15 minutes on a loaded 2-core machine"]
fn quadratic_posterior_and_hit_rates() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { time_sampling: TimeSampling::LogUniform, ..accept_config() };
    train_logged(&sde, &mut net, &cfg, "L trained");
    let (worst_l, hits_l) = report_quadratic("L", &sde, &net);
    let mut fine = ToyTrainConfig::sliding_window(4, 2, 5, 2000, 1e-4);
    fine.log_every = 1000;
    fine.time_sampling = TimeSampling::LogUniform;
    train_logged(&sde, &mut net, &fine, "M fine-tuned");
    let (worst_m, hits_m) = report_quadratic("M", &sde, &net);
    println!("worst posterior error: L {worst_l:.3}, M {worst_m:.3}; hits L {hits_l:?}, M {hits_m:?}");
    assert!(worst_l <= 0.05, "posterior of L off by {worst_l}");
    assert!(hits_l.sde_hits >= 0.95, "{hits_l:?}");
    assert!(hits_m.ode_hits >= 0.95, "{hits_m:?}");
    assert!(hits_m.ode_sign_kept >= 0.99, "{hits_m:?}");
}

/// Record of the first attempt: the quadratic toy with uniform training times (prints the same
/// numbers as the acceptance test; asserts nothing, it documents the miss).
#[test]
#[ignore = "experiment: 150k 1-step updates with uniform times; 8 minutes on a loaded 2-core machine"]
fn quadratic_with_uniform_times() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    train_logged(&sde, &mut net, &accept_config(), "U trained");
    let (worst, hits) = report_quadratic("U", &sde, &net);
    println!("U: worst posterior error {worst:.3}; {hits:?}");
}

/// Acceptance (ii)-(iv) with the official notebook's recipe (`ToyTrainConfig::official`): data
/// integrated at dt/2 and stored every dt = 0.02, the 1-step loss trained in both time
/// directions, 250k updates on every 5th point (step 0.1, lr 1e-3) then 250k on every point
/// (lr 1e-4), Adam (0.9, 0.99), batch 256, 2500 paths. The notebook samples with step 0.01
/// (half the data step); the criteria are judged there and the data step 0.02 is printed too.
///
/// Measured (1125 s of training under load; final loss 3.8e-5 per update, i.e. 0.019 summed
/// over the 500 windows of an official epoch, against the notebook's 0.016): forward x_T mean
/// 0.00343, std 0.03518 (pass); step 0.01: posterior within 0.059 of the 4M-path table (0.060
/// of the digest's; every bin is low, P(+1 | y = -0.025) = 0.402 vs 0.4605), ODE hits 2.4%,
/// SDE hits 43.1%, ODE keeps the sign for 89.5%; step 0.02: 0.057 (0.077), 0.5%, 58.5%, 96.8%;
/// steps 0.005 / 0.0025 (same model): ODE hits 64.7% / 61.8%, SDE hits 10.4% / 3.5%. Fails (ii)
/// and (iii).
#[test]
#[ignore = "earlier attempt (superseded by smdp_exact::quadratic_split_experts_*), FAILS (ii) and (iii): 500k bidirectional updates, 19 minutes under load; posterior off by 0.059, ODE hits 2.4%, SDE hits 43% (measured)"]
fn quadratic_official_recipe() {
    let sde = ToySde::paper_quadratic();
    let (m, s) = mean_std(&sde.endpoints(&vec![1.0; 200_000], 11).unwrap());
    println!("forward: x_T from +1 mean {m:.5}, std {s:.5} (digest 0.0036 +- 0.0005, 0.035 +- 0.001)");
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { log_every: 50_000, ..ToyTrainConfig::official(250_000, 250_000) };
    train_logged(&sde, &mut net, &cfg, "trained");
    let (worst02, hits02) = report_quadratic("data step 0.02", &sde, &net);
    let (worst, hits) = report_quadratic("notebook step 0.01", &ToySde { dt: 0.01, ..sde }, &net);
    println!("worst posterior error: step 0.02 {worst02:.3}, step 0.01 {worst:.3}; hits {hits02:?} / {hits:?}");
    assert!((m - 0.0036).abs() < 0.0005 && (s - 0.035).abs() < 0.001, "forward statistics {m} {s}");
    assert!(worst <= 0.05, "posterior off by {worst}");
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95, "{hits:?}");
    assert!(hits.ode_sign_kept >= 0.99, "{hits:?}");
}

/// Acceptance (ii)-(iii) with the official regularised config (`smdp_reg_mlp_paper`: 1-step
/// loss with the (1/4) h^2 ||s||^2 term, every 5th point at lr 1e-3, then every point at lr
/// 1e-4, 250k + 250k updates) on data from our dt = 0.02 simulator (the chain the digest's
/// posterior table describes), log-uniform training times; SDE sampled at the data step 0.02,
/// ODE at the notebook's 0.01.
///
/// The hypothesis this tested: on an Euler chain with step h the loss's minimiser is
/// `s = g^2 grad log p + h P'(x) P(x) + O(h^2)`, whose second term is the correction that the
/// Euler inverse step `x - h P(x)` needs (`h^2 P'P` per step, 0.04 at x = 1 for h = 0.02); the
/// SDE (weight 1) gets it in full at step h, the ODE (weight 1/2) at step h/2. Measured (415 s):
/// SDE hits 100%, posterior within 0.038 of the 4M-path table (pass; y = +0.095 gives 0.556 vs
/// 0.594 +- 0.007; against the digest's 0.62 it is 0.064), but ODE hits 0.4% (sign kept 91.2%),
/// so (iii) fails. The hypothesis is
/// wrong for the ODE: at step h/2 it inverts an Euler-(h/2) flow, while the data follow the
/// Euler-h chain, which moves faster near x = 1 (one step from 1 reaches 0.860, the exact flow
/// 0.877), so the ODE ends a few percent short of +-1. A score that serves the ODE at the data
/// step must carry twice this correction (what the multi-step loss learns), and then the SDE
/// over-corrects: on this toy one network cannot give both samplers 95% hits at one step.
///
/// Checked against the exact law of the chain (`tests/smdp_exact.rs`, `smdp::euler_law`): the
/// trained net is within 1-2% of the exact 1-step minimiser for t <= 0.1, and the exact
/// minimiser itself gives ODE 0% / SDE 100% with these explicit steps, so the ODE miss is the
/// sampler's step, not the network. The exact score (no Euler correction) gives 0% / 0%.
#[test]
#[ignore = "earlier attempt (superseded by smdp_exact::quadratic_split_experts_*), FAILS (iii) for the ODE: 500k regularised 1-step updates, 7 minutes; posterior within 0.038 and SDE hits 100% (pass), ODE hits 0.4% (measured)"]
fn quadratic_reg_recipe_with_consistent_sampler_steps() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    train_logged(&sde, &mut net, &quadratic_reg_config(), "trained");
    let (worst, sde_hits) = report_quadratic("SDE step 0.02", &sde, &net);
    let (_, ode_hits) = report_quadratic("ODE step 0.01", &ToySde { dt: 0.01, ..sde }, &net);
    println!("posterior worst {worst:.3}; SDE hits (step 0.02) {sde_hits:?}; ODE hits (step 0.01) {ode_hits:?}");
    assert!(worst <= 0.05, "posterior off by {worst}");
    assert!(sde_hits.sde_hits >= 0.95, "{sde_hits:?}");
    assert!(ode_hits.ode_hits >= 0.95 && ode_hits.ode_sign_kept >= 0.99, "{ode_hits:?}");
}

/// The brief's full recipe: the official 1-step stages (as in [`quadratic_official_recipe`]),
/// then the multi-step loss over sliding windows 4, 6, ..., 40 (19 windows, 1000 updates each at
/// lr 1e-4; the notebook's function defaults are 4 + 2 per stage, 18 increases, 20 epochs per
/// window, i.e. about 100k updates per window, which is out of reach here).
///
/// Measured (1125 s + 493 s): step 0.02: ODE hits 100% but ODE keeps the sign of x_T for only
/// 91.4%, SDE hits 0%, and the posterior is flat (0.556..0.587 over y = -0.095..+0.095, worst
/// error 0.16 against the 4M-path table, 0.176 against the digest's); step 0.01: ODE hits 0%,
/// SDE hits 0%. The multi-step loss calibrates the score for
/// ODE steps of the data step and destroys the posterior information at large t.
#[test]
#[ignore = "earlier attempt (superseded by smdp_exact::quadratic_split_experts_*), FAILS: 500k 1-step + 19k multi-step updates, 27 minutes under load; ODE hits 100% but SDE hits 0% and posterior off by 0.18 (measured)"]
fn quadratic_official_recipe_then_sliding_windows() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    let mut cfg = ToyTrainConfig { log_every: 50_000, ..ToyTrainConfig::official(250_000, 250_000) };
    for i in 0..19 {
        cfg.stages.push(ToyStage { loss: ToyLoss::MultiStep(4 + 2 * i), lr: 1e-4, updates: 1000 });
    }
    train_logged(&sde, &mut net, &cfg, "trained");
    let (worst, hits) = report_quadratic("step 0.02", &sde, &net);
    let (_, hits01) = report_quadratic("step 0.01", &ToySde { dt: 0.01, ..sde }, &net);
    println!("posterior worst {worst:.3}; hits step 0.02 {hits:?}; step 0.01 {hits01:?}");
    assert!(worst <= 0.05, "posterior off by {worst}");
    assert!(hits.ode_hits >= 0.95 && hits.sde_hits >= 0.95 && hits.ode_sign_kept >= 0.99, "{hits:?}");
}
