//! SMDP toy problem: simulator statistics, analytic formulas, samplers and short training.
//! The full acceptance runs (training to acceptance) are `#[ignore]`d and print their numbers.

use pbdl_diffusion::smdp::analytic::{AffineMixture, QUADRATIC_POSTERIOR_DT002};
use pbdl_diffusion::smdp::loss::{multi_step_loss, LossWorkspace};
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::physics::ToyDrift;
use pbdl_diffusion::smdp::sampler::{hit_rates, posterior_plus, AnalyticScore, HitReport};
use pbdl_diffusion::smdp::sde::{mean_std, two_point_starts, ToySde};
use pbdl_diffusion::smdp::toy::{affine_score_error, train_toy, TimeSampling, ToyLoss, ToyStage, ToyTrainConfig};
use std::time::Instant;

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

/// The official affine config's three learning rates (1e-3, 1e-4, 1e-5), shortened to 50k
/// updates each (the official runs are epochs of ~5000 updates).
fn accept_config() -> ToyTrainConfig {
    let mut cfg = ToyTrainConfig { log_every: 10_000, ..ToyTrainConfig::one_step(50_000, 50_000) };
    cfg.stages.push(ToyStage { loss: ToyLoss::OneStep, lr: 1e-5, updates: 50_000 });
    cfg
}

/// Acceptance (i): in the affine case the learned score is within 10% (relative L2, pooled over
/// the region p_t > 1% of its maximum) of the analytic score for t in [0.5, 10].
///
/// Measured: 0.108 after 100k updates (1e-3, 1e-4), 0.110 after 150k (1e-3, 1e-4, 1e-5): a
/// miss; the largest errors are at t = 4 (0.22), where the two modes separate, and t = 0.5.
#[test]
#[ignore = "acceptance run: trains the toy score for 150k updates; 8 minutes on a loaded 2-core machine"]
fn affine_learned_score_matches_the_analytic_score() {
    let sde = ToySde::paper_affine();
    let mut net = ScoreMlp::paper(0);
    let rep = train_toy(&sde, &mut net, &accept_config()).unwrap();
    println!("trained in {:.1} s; losses {:?}", rep.seconds, rep.losses);
    let ts: Vec<f64> = (0..20).map(|i| 0.5 + 9.5 * i as f64 / 19.0).collect();
    let cont = affine_score_error(&net, &AffineMixture::continuous(0.5, 0.04), &ts, 400);
    let eul = affine_score_error(&net, &AffineMixture::euler(0.5, 0.04, 0.02), &ts, 400);
    for ((t, e), (_, e2)) in cont.per_t.iter().zip(&eul.per_t) {
        println!("t {t:5.2}: rel. L2 error vs continuous {e:.4}, vs Euler-chain law {e2:.4}");
    }
    println!("pooled: vs continuous {:.4}, vs Euler-chain law {:.4}", cont.pooled, eul.pooled);
    assert!(cont.pooled < 0.10, "pooled relative error {}", cont.pooled);
}

/// Experiment: the affine case trained like the quadratic acceptance model (log-uniform times);
/// prints the same numbers as the acceptance test and asserts nothing.
#[test]
#[ignore = "experiment: 150k 1-step updates with log-uniform times; 8 minutes on a loaded 2-core machine"]
fn affine_with_log_uniform_times() {
    let sde = ToySde::paper_affine();
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { time_sampling: TimeSampling::LogUniform, ..accept_config() };
    let rep = train_toy(&sde, &mut net, &cfg).unwrap();
    println!("trained in {:.1} s", rep.seconds);
    let ts: Vec<f64> = (0..20).map(|i| 0.5 + 9.5 * i as f64 / 19.0).collect();
    let cont = affine_score_error(&net, &AffineMixture::continuous(0.5, 0.04), &ts, 400);
    for (t, e) in &cont.per_t {
        println!("t {t:5.2}: rel. L2 error vs continuous {e:.4}");
    }
    println!("pooled vs continuous {:.4}", cont.pooled);
}

fn report_quadratic(name: &str, sde: &ToySde, net: &ScoreMlp) -> (f64, HitReport) {
    let t0 = Instant::now();
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
    let post = posterior_plus(sde, net, &ys, 2000, 5).unwrap();
    let hits = hit_rates(sde, net, 1000, 0.01, 6).unwrap();
    let mut worst: f64 = 0.0;
    for ((y, reference), p) in QUADRATIC_POSTERIOR_DT002.iter().zip(&post) {
        println!("{name}: y {y:+.3}: P(+1|y) reverse SDE {p:.3}, digest (dt = 0.02) {reference:.2}");
        worst = worst.max((p - reference).abs());
    }
    println!("{name}: {hits:?}; evaluated in {:.1} s", t0.elapsed().as_secs_f64());
    (worst, hits)
}

/// Acceptance (ii) and (iii) on the quadratic toy. Two models:
/// * `L`: the 1-step loss with its regulariser (an exact score) and log-uniform training times;
///   judged on the reverse-SDE posterior (within 0.05 per bin of the digest's dt = 0.02 Monte
///   Carlo table, 2000 samples per bin) and on the SDE hit rate (>= 95% within 1% of +-1).
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
#[ignore = "acceptance run: 150k 1-step + 10k multi-step updates; 8-15 minutes on a loaded 2-core machine"]
fn quadratic_posterior_and_hit_rates() {
    let sde = ToySde::paper_quadratic();
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { time_sampling: TimeSampling::LogUniform, ..accept_config() };
    let rep = train_toy(&sde, &mut net, &cfg).unwrap();
    println!("L trained in {:.1} s; losses {:?}", rep.seconds, rep.losses);
    let (worst_l, hits_l) = report_quadratic("L", &sde, &net);
    let mut fine = ToyTrainConfig::sliding_window(4, 2, 5, 2000, 1e-4);
    fine.log_every = 1000;
    fine.time_sampling = TimeSampling::LogUniform;
    let rep = train_toy(&sde, &mut net, &fine).unwrap();
    println!("M fine-tuned in {:.1} s; losses {:?}", rep.seconds, rep.losses);
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
    let rep = train_toy(&sde, &mut net, &accept_config()).unwrap();
    println!("U trained in {:.1} s", rep.seconds);
    let (worst, hits) = report_quadratic("U", &sde, &net);
    println!("U: worst posterior error {worst:.3}; {hits:?}");
}
