//! The trained ACDM acceptance run (ignored: it trains for a long time on 2 cores).
//!
//! `cargo test -p pbdl-diffusion --test acdm_acceptance -- --ignored --nocapture`
//!
//! Environment: `PBDL_ACDM_TRAIN_STEPS` (default 3425 updates of batch 16, the measured run;
//! ACDM 48 wide, the baselines 16 wide, see the xtask entry `acdm_cylinder` for why), `PBDL_ACDM_BASELINE_STEPS`
//! (the baselines' updates, default 1000, the measured run),
//! `PBDL_ACDM_ROLLOUT` (default 1000 steps), `PBDL_ACDM_SAMPLER` (`ddpm` default, or `ddimK`),
//! `PBDL_ACDM_BASELINES` (`unet` default; a comma list of `unet`, `unet_tn`, `unet_ut8`).
//! Models are cached (resumable) under `target/pbdl/acdm/runs/full/`.
//!
//! Acceptance (the issue): on held-out Re, ACDM stays finite over the rollout, its mean
//! |ds/dt| stays within 0.5-2x of the truth and its Strouhal number within 10%; the small
//! one-step U-Net drifts or damps (fails one of these); 5 posterior samples have non-zero spread.
//!
//! Measured (2026-11-22, release, `RAYON_NUM_THREADS=2`): ACDM 48 wide, 1000 updates at Adam
//! 1e-3, then 2425 at the official 1e-4 (3425 in all, ~2.0 s each on the idle machine; epsilon
//! loss 0.019 at 1000, 0.004-0.008 at 3400); DDPM (R = 20) rollouts of 1000 frames at ~1.0 s per
//! frame. **PASSES**: Re 100 finite, |ds/dt| ratio 1.85 (0.69 vs 0.38), Strouhal 0.280 vs 0.299
//! (6.5%), MSE 0.37, LSiM 0.41 / 0.41 / 0.28; Re 950 finite, ratio 1.19, Strouhal 2.1%, MSE 1.27,
//! LSiM 0.53 / 0.44 / 0.34; spread of 5 samples over 20 frames 0.066. The one-step U-Net (16 wide,
//! 1000 updates at 1e-3, `PBDL_ACDM_BASELINE_STEPS=1000`) fails as the issue expects: finite,
//! ratio 1.43 / 0.98, but its shedding slows (Strouhal 58% / 67% off); MSE 0.87 / 1.58.
//! The same ACDM after 1000 updates at 1e-3 only failed (ratio 5.6 / 2.3, Strouhal 22.6% / 5.4%):
//! the learning-rate drop, not the extra updates alone, fixed the per-frame sampling noise (the
//! one-step error fell from 0.43 to 0.14 in the first 100 updates at 1e-4; `examples/acdm_onestep.rs`).
//! Command: `PBDL_ACDM_TRAIN_STEPS=3425 PBDL_ACDM_BASELINE_STEPS=1000 cargo test --release -p
//! pbdl-diffusion --test acdm_acceptance -- --ignored --nocapture acdm_beats` (2210 s of evaluation
//! with the cached models).

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (fewer page faults).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use pbdl_diffusion::acdm::benchmark::Benchmark;
use pbdl_diffusion::acdm::data::TEST_RE;
use pbdl_diffusion::acdm::eval::{evaluate, EvalConfig, EvalReport};
use pbdl_diffusion::acdm::model::{Method, Sampler};

fn env(name: &str) -> Option<String> {
    std::env::var(name).ok()
}

fn passes(r: &EvalReport) -> bool {
    r.first_non_finite.is_none() && (0.5..=2.0).contains(&r.stability_ratio()) && r.strouhal_error() < 0.1
}

#[test]
#[ignore = "trains ACDM and U-Nets on 2 cores (about 2 h for 3425 ACDM updates, 37 min of rollouts); prints every number"]
fn acdm_beats_one_step_unet_on_held_out_reynolds_numbers() {
    let b = Benchmark::default_full().unwrap();
    println!("data: train {:.1} s, test {:.1} s (0 = cached)", b.train.seconds, b.test.seconds);
    let steps: usize = env("PBDL_ACDM_TRAIN_STEPS").and_then(|s| s.parse().ok()).unwrap_or(3425);
    let baseline_steps: usize = env("PBDL_ACDM_BASELINE_STEPS").and_then(|s| s.parse().ok()).unwrap_or(1000);
    let n: usize = env("PBDL_ACDM_ROLLOUT").and_then(|s| s.parse().ok()).unwrap_or(1000);
    let sampler = match env("PBDL_ACDM_SAMPLER").as_deref() {
        Some(s) if s.starts_with("ddim") => Sampler::Ddim(s[4..].parse().unwrap()),
        _ => Sampler::Ddpm,
    };
    let (mut acdm, rep) = b.model(Method::Acdm, 48, steps, 16).unwrap();
    if let Some(r) = rep {
        println!("acdm trained {}..{steps}: {:.2} s/update", r.resumed_from, r.seconds_per_step);
    }
    acdm.set_sampler(sampler).unwrap();
    let lsim = pbdl_diffusion::acdm::eval::load_lsim();
    println!("{}", EvalReport::markdown_header());
    let cfg = EvalConfig { steps: n, samples: 1, seed: 5, lsim_every: 10 };
    let mut acdm_ok = true;
    for re in TEST_RE {
        let r = evaluate(&acdm, b.held_out(re).unwrap(), &b.norm, &b.test.config, &cfg, lsim.as_ref()).unwrap();
        println!("{}", r.markdown_row());
        println!(
            "ACCEPTANCE: acdm_re{re} measured=finite {}, |ds/dt| ratio {:.2}, Strouhal error {:.1}% \
             bar=finite, ratio in [0.5, 2], Strouhal error < 10%",
            r.first_non_finite.is_none(),
            r.stability_ratio(),
            100.0 * r.strouhal_error()
        );
        acdm_ok &= passes(&r);
    }
    // Posterior spread: 5 samples over a short horizon.
    let short = EvalConfig { steps: 20, samples: 5, seed: 9, lsim_every: 0 };
    let r = evaluate(&acdm, b.held_out(TEST_RE[1]).unwrap(), &b.norm, &b.test.config, &short, None).unwrap();
    println!("{}", r.markdown_row());
    let spread = r.spread.unwrap();
    let baselines = env("PBDL_ACDM_BASELINES").unwrap_or_else(|| "unet".into());
    let mut unet_fails = true;
    for name in baselines.split(',') {
        let method = match name {
            "unet_tn" => Method::UnetNoise { sigma: 0.01 },
            "unet_ut8" => Method::UnetUnrolled { m: 8 },
            _ => Method::Unet,
        };
        let (m, rep) = b.model(method, 16, baseline_steps, 16).unwrap();
        if let Some(r) = rep {
            println!("{} trained {}..{baseline_steps}: {:.2} s/update", name, r.resumed_from, r.seconds_per_step);
        }
        for re in TEST_RE {
            let r = evaluate(&m, b.held_out(re).unwrap(), &b.norm, &b.test.config, &cfg, lsim.as_ref()).unwrap();
            println!("{}", r.markdown_row());
            if method == Method::Unet {
                println!(
                    "ACCEPTANCE: unet_re{re} measured=finite {}, ratio {:.2}, Strouhal error {:.1}% \
                     bar=misses the ACDM band",
                    r.first_non_finite.is_none(),
                    r.stability_ratio(),
                    100.0 * r.strouhal_error()
                );
                unet_fails &= !passes(&r);
            }
        }
    }
    println!(
        "ACDM passes on all held-out Re: {acdm_ok}; one-step U-Net fails on all: {unet_fails}; spread {spread:.4}"
    );
    println!("ACCEPTANCE: acdm_spread measured={spread:.4} bar=> 0");
    assert!(spread > 0.0);
    assert!(acdm_ok, "ACDM misses the acceptance band (numbers above)");
    assert!(unet_fails, "the one-step U-Net did not drift or damp (numbers above)");
}
