//! The trained ACDM acceptance run (ignored: it trains for a long time on 2 cores).
//!
//! `cargo test -p pbdl-diffusion --test acdm_acceptance -- --ignored --nocapture`
//!
//! Environment: `PBDL_ACDM_TRAIN_STEPS` (default 1000 updates of batch 16; ACDM 48 wide, the
//! baselines 16 wide, see `acdm::entries` for why), `PBDL_ACDM_BASELINE_STEPS` (the baselines'
//! updates, default the same),
//! `PBDL_ACDM_ROLLOUT` (default 1000 steps), `PBDL_ACDM_SAMPLER` (`ddpm` default, or `ddimK`),
//! `PBDL_ACDM_BASELINES` (`unet` default; a comma list of `unet`, `unet_tn`, `unet_ut8`).
//! Models are cached (resumable) under `target/pbdl/acdm/runs/full/`.
//!
//! Acceptance (the issue): on held-out Re, ACDM stays finite over the rollout, its mean
//! |ds/dt| stays within 0.5-2x of the truth and its Strouhal number within 10%; the small
//! one-step U-Net drifts or damps (fails one of these); 5 posterior samples have non-zero spread.
//!
//! First complete ACDM training (2026-11-22, release, idle machine, `RAYON_NUM_THREADS=2`):
//! ACDM 48 wide, updates 100..1000 at 1.60 s each, epsilon loss 0.30 -> 0.019; DDPM (R = 20)
//! rollouts of 1000 frames at ~1.05 s per frame. **FAILS**: Re 100 finite, |ds/dt| ratio 5.6
//! (2.11 vs 0.38), Strouhal 0.367 vs 0.299 (22.6%); Re 950 finite, ratio 2.30, Strouhal 5.4%;
//! spread of 5 samples over 20 frames 0.27 (non-zero: passes). The rollouts are finite but too
//! unsteady: 1000 updates of batch 16 are far from the official training length. The one-step
//! U-Net (16 wide, 1000 updates at 0.50 s) fails as the issue expects: finite, |ds/dt| ratio
//! 1.43 / 0.98, but Strouhal 58% / 67% off (its shedding slows to 0.125 / 0.097); its MSE is
//! lower (0.87 / 1.58 vs 2.75 / 2.32), its LSiM higher (0.59-1.03 vs 0.51-0.74).

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
#[ignore = "trains ACDM and U-Nets on 2 cores (hours at 1000 updates under load); prints every number"]
fn acdm_beats_one_step_unet_on_held_out_reynolds_numbers() {
    let b = Benchmark::default_full().unwrap();
    println!("data: train {:.1} s, test {:.1} s (0 = cached)", b.train.seconds, b.test.seconds);
    let steps: usize = env("PBDL_ACDM_TRAIN_STEPS").and_then(|s| s.parse().ok()).unwrap_or(1000);
    let baseline_steps: usize = env("PBDL_ACDM_BASELINE_STEPS").and_then(|s| s.parse().ok()).unwrap_or(steps);
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
                unet_fails &= !passes(&r);
            }
        }
    }
    println!(
        "ACDM passes on all held-out Re: {acdm_ok}; one-step U-Net fails on all: {unet_fails}; spread {spread:.4}"
    );
    assert!(spread > 0.0);
    assert!(acdm_ok, "ACDM misses the acceptance band (numbers above)");
    assert!(unet_fails, "the one-step U-Net did not drift or damp (numbers above)");
}

/// Runs this part's `cargo xtask` entries in quick mode (plumbing only; trains a few updates).
#[test]
#[ignore = "quick tour/bench/stress smoke: trains 4 models for 4 updates on the tiny data (minutes under load)"]
fn quick_entries_run() {
    let tasks = pbdl_diffusion::tasks();
    let dir = tempfile::tempdir().unwrap();
    let ctx = pbdl_core::registry::TaskContext { out_dir: dir.path().to_path_buf(), quick: true, threads: 2 };
    let tour = tasks.tour.iter().find(|e| e.name == "acdm_cylinder").unwrap();
    let out = (tour.run)(&ctx).unwrap();
    println!("{}", out.markdown);
    assert!(out.files.iter().all(|f| f.exists()));
    let bench = tasks.bench.iter().find(|e| e.name == "acdm_samplers").unwrap();
    for r in (bench.run)(&ctx).unwrap() {
        println!("{r:?}");
    }
    let stress = tasks.stress.iter().find(|e| e.name == "acdm_long_rollout").unwrap();
    let checks = (stress.run)(&ctx).unwrap();
    for c in &checks {
        println!("{c:?}");
    }
    assert!(checks.last().unwrap().passed, "typed-error check");
}
