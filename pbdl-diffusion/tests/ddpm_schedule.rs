//! Noise schedules against published anchors and closed forms.

use pbdl_diffusion::schedule::{NoiseSchedule, COSINE_MAX_BETA, COSINE_S};

#[test]
fn acdm_schedule_at_r20_matches_the_papers_anchor() {
    let s = NoiseSchedule::acdm(20).unwrap();
    // Digest §4/§6 C: sqrt(abar_R) = 0.04484 for R = 20; beta from 0.0025 to 0.5.
    let last = s.sqrt_alpha_bar(19);
    println!("ACDM R=20: sqrt(abar_19) = {last:.6}, beta {} .. {}", s.beta(0), s.beta(19));
    assert!((last - 0.04484).abs() < 5e-6, "sqrt(abar_19) = {last}");
    assert!((s.beta(0) - 0.0025).abs() < 1e-15 && (s.beta(19) - 0.5).abs() < 1e-15);
    // Linear in between: equal increments of (0.5 - 0.0025) / 19.
    for w in s.betas().windows(2) {
        assert!((w[1] - w[0] - 0.4975 / 19.0).abs() < 1e-14);
    }
}

#[test]
fn acdm_schedule_clips_to_its_range() {
    // R = 5: 0.02 * 100 = 2 would exceed 1; clipped at 0.9999. R = 10000: 1e-4 * 0.05 below 1e-4.
    let short = NoiseSchedule::acdm(5).unwrap();
    assert_eq!(short.beta(4), 0.9999);
    assert!((short.beta(0) - 0.01).abs() < 1e-15);
    let long = NoiseSchedule::acdm(10_000).unwrap();
    assert_eq!(long.beta(0), 1e-4);
    assert!((long.beta(9999) - 0.001).abs() < 1e-15);
    // At R = 500 the schedule is the classic DDPM 1e-4 .. 0.02, unclipped.
    let base = NoiseSchedule::acdm(500).unwrap();
    let lin = NoiseSchedule::linear(500, 1e-4, 0.02).unwrap();
    for (a, b) in base.betas().iter().zip(lin.betas()) {
        assert!((a - b).abs() < 1e-15);
    }
}

#[test]
fn linear_ddpm_schedule_reproduces_the_known_final_alpha_bar() {
    // Ho et al.'s schedule (T = 1000, 1e-4 .. 0.02): abar_T = 4.0358e-5 (sqrt 0.00635), a widely
    // quoted value; and abar from a log-sum, computed independently of the running product.
    let s = NoiseSchedule::linear(1000, 1e-4, 0.02).unwrap();
    let last = s.alpha_bar(999);
    println!("linear T=1000: abar_T = {last:.6e}");
    assert!((last / 4.0358e-5 - 1.0).abs() < 1e-3, "{last}");
    let mut log_sum = 0.0;
    for i in 0..1000 {
        let beta = 1e-4 + (0.02 - 1e-4) * i as f64 / 999.0;
        log_sum += (-beta).ln_1p();
        assert!((s.alpha_bar(i) / log_sum.exp() - 1.0).abs() < 1e-12, "step {i}");
        assert!((s.alpha(i) + s.beta(i) - 1.0).abs() < 1e-15);
    }
}

#[test]
fn cosine_schedule_matches_the_closed_form_and_the_airfoil_anchor() {
    let t = 200;
    let s = NoiseSchedule::cosine(t, COSINE_S).unwrap();
    assert_eq!(s.len(), t);
    let f = |x: f64| ((x / t as f64 + COSINE_S) / (1.0 + COSINE_S) * std::f64::consts::FRAC_PI_2).cos().powi(2);
    // Before the clip takes over, abar_i is the closed form f(i + 1) / f(0) exactly.
    for i in 0..t - 1 {
        let closed = f((i + 1) as f64) / f(0.0);
        assert!((s.alpha_bar(i) / closed - 1.0).abs() < 1e-10, "step {i}: {} vs {closed}", s.alpha_bar(i));
    }
    // The last beta would be 1 (f(T) = 0) and is clipped; digest: abar_200 = 6e-8.
    assert_eq!(s.beta(t - 1), COSINE_MAX_BETA);
    let last = s.alpha_bar(t - 1);
    println!("cosine T=200: abar_T = {last:.4e}, beta_0 = {:.4e}", s.beta(0));
    assert!((5.5e-8..6.5e-8).contains(&last), "abar_T = {last}");
    assert!(s.betas().iter().all(|&b| b > 0.0 && b <= COSINE_MAX_BETA));
}

#[test]
fn posterior_variance_is_between_zero_and_beta() {
    for s in [NoiseSchedule::acdm(20).unwrap(), NoiseSchedule::cosine(50, COSINE_S).unwrap()] {
        assert_eq!(s.posterior_variance(0), 0.0);
        assert_eq!(s.alpha_bar_prev(0), 1.0);
        for i in 1..s.len() {
            let v = s.posterior_variance(i);
            assert!(v > 0.0 && v < s.beta(i));
            // Closed form: 1 / (1 / (1 - abar_{i-1}) + alpha_i / beta_i), the posterior precision sum.
            let closed = 1.0 / (1.0 / (1.0 - s.alpha_bar(i - 1)) + s.alpha(i) / s.beta(i));
            assert!((v / closed - 1.0).abs() < 1e-12);
        }
    }
}
