//! The acceptance run of the wake surrogate (ignored: simulation plus CPU training).
//!
//! Issue acceptance: on unseen Reynolds numbers, mean-field relative error < 5%, correlation of
//! predicted and true std fields > 0.8, mean std (`sigma_{y,a}`) against Re within 20%.
//! Setup (the paper's split): 5 training Re x 25 snapshots, 6 test Re; ground truth from 100
//! snapshots per Re; AifNet 16 * [1, 2, 4, 4] (the paper's 32x32 network) with clean
//! conditioning, cosine schedule T = 200, epsilon-MSE.
//!
//! Last run (2026-11-22, reduced: 16 x 16 by 2 x 2 pooling, AifNet 8 * [1, 2, 2] without
//! attention, 72k parameters, `PBDL_WAKE_POOL=2 PBDL_WAKE_NET=small PBDL_WAKE_STEPS=4000
//! PBDL_WAKE_SAMPLES=50`, release, nice 19 beside other jobs: 4000 steps of batch 25 in 2527 s,
//! loss of the last 200 steps 0.017; total 2945 s): **passes** at all 6 test Re: mean-field
//! relative error 0.013-0.039 (< 0.05), std-field correlation 0.994-0.997 (> 0.8), mean std
//! ratio 1.000-1.066 (within 20%). Two caveats: relative to the velocity *deficit* (the field
//! minus the free stream) the mean error is 0.057-0.182, and copying the nearest training Re's
//! statistics still has a lower mean error at 5 of 6 Re (0.003-0.030; std ratio 0.81-1.04).
//! The run before (1000 steps) failed: mean error 0.039-0.082, std ratio 1.13-1.61. The
//! full-size network at 32 x 32 (AifNet 16 * [1, 2, 4, 4]) has not been trained: ~13 s per
//! step under load on 2 cores.
//!
//! `PBDL_WAKE_STEPS` (default 4000) and `PBDL_WAKE_SAMPLES` (default 50) shorten or lengthen
//! the run; `PBDL_WAKE_CKPT=path` saves the trained weights, `PBDL_WAKE_LOAD=path` samples from
//! them without training; `PBDL_WAKE_POOL=2` and `PBDL_WAKE_NET=small` shrink the problem.

use candle_core::{DType, Device};
use pbdl_diffusion::uncertainty::{
    compare, condition, diffusion, predict_stats, simulate_wake, train, Dataset, FieldStats, Normalizer, SampleConfig,
    TrainConfig, WakeCase, WakeConfig,
};
use pbdl_diffusion::unet::{count_parameters, AifNet, AifNetConfig};
use std::time::Instant;

mod common;
use common::build_seeded;

const TRAIN_RE: [f64; 5] = [100.0, 150.0, 200.0, 250.0, 300.0];
const TEST_RE: [f64; 6] = [120.0, 140.0, 180.0, 220.0, 260.0, 280.0];
const RE_SCALE: f64 = 300.0;

fn env(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// The paper's 32x32 AifNet (16 * [1, 2, 4, 4], attention at levels 2 and 3) for the wake:
/// 3 condition and 2 noisy target channels in, the 2 target fields out.
fn wake_net() -> AifNetConfig {
    AifNetConfig { in_channels: 5, out_channels: 2, ..AifNetConfig::airfoil_32() }
}

/// [`wake_net`] narrowed to `dim_basic * dim_multipliers`, without attention.
fn small_wake_net(dim_basic: usize, dim_multipliers: Vec<usize>) -> AifNetConfig {
    AifNetConfig { dim_basic, dim_multipliers, attention_layers: vec![], ..wake_net() }
}

#[test]
#[ignore = "acceptance run, hours at the default size (AifNet-16 at 32x32: ~13 s/step measured under load ~19 on 2 cores); the reduced run PBDL_WAKE_POOL=2 PBDL_WAKE_NET=small PBDL_WAKE_STEPS=4000 PBDL_WAKE_SAMPLES=50 took 49 min and passes (see the file docs)"]
fn wake_surrogate_predicts_mean_and_spread_on_unseen_reynolds_numbers() {
    let dev = Device::Cpu;
    // PBDL_WAKE_POOL=2 pools to 16 x 16 and PBDL_WAKE_NET=small takes AifNet 8 * [1, 2, 2]
    // without attention (for a loaded machine).
    let pool = env("PBDL_WAKE_POOL", 1);
    let cfg = WakeConfig { pool, out_size: [32 / pool, 32 / pool], ..Default::default() };
    let small = std::env::var("PBDL_WAKE_NET").is_ok_and(|v| v == "small");
    let mask = cfg.mask();
    let t0 = Instant::now();
    let sim = |re: &f64| simulate_wake(&cfg, *re).unwrap();
    let train_cases: Vec<WakeCase> = TRAIN_RE.iter().map(sim).collect();
    let test_cases: Vec<WakeCase> = TEST_RE.iter().map(sim).collect();
    println!("simulated {} Re x {} snapshots in {:.1} s", 11, cfg.snapshots, t0.elapsed().as_secs_f64());

    let norm = Normalizer::fit(&train_cases.iter().map(|c| &c.snapshots).collect::<Vec<_>>()).unwrap();
    let data = Dataset::new(&cfg, &train_cases, 25, RE_SCALE, &norm, 0).unwrap();
    let net_cfg = if small { small_wake_net(8, vec![1, 2, 2]) } else { wake_net() };
    let net_name = format!(
        "AifNet {} x {:?}, attention {:?}",
        net_cfg.dim_basic, net_cfg.dim_multipliers, net_cfg.attention_layers
    );
    let (varmap, net) = build_seeded(DType::F32, 0, |vb| AifNet::new(net_cfg, vb));
    let d = diffusion().unwrap();
    let steps = env("PBDL_WAKE_STEPS", 4000);
    let tc = TrainConfig { steps, batch: 25, lr: 1e-3, seed: 1 };
    let t1 = Instant::now();
    if let Ok(path) = std::env::var("PBDL_WAKE_LOAD") {
        // Sampling only, from a checkpoint written with PBDL_WAKE_CKPT by the same configuration.
        pbdl_core::io::load_varmap(&path, &varmap).unwrap();
        println!("{net_name}: weights from {path}");
    } else {
        let losses = train(&net, varmap.all_vars(), &d, &data, &tc, |k, l| {
            if k % 50 == 0 || k < 3 || k + 1 == steps {
                println!("  step {k:>5}: loss {l:.4} ({:.0} s)", t1.elapsed().as_secs_f64());
            }
        })
        .unwrap();
        let train_s = t1.elapsed().as_secs_f64();
        let tail = &losses[losses.len().saturating_sub(200)..];
        println!(
            "{net_name} ({} parameters), {}x{}: {steps} steps, batch 25, in {train_s:.0} s ({:.0} ms/step); \
             mean loss of the last {} steps {:.4}",
            count_parameters(&varmap),
            cfg.out_size[0],
            cfg.out_size[1],
            1e3 * train_s / steps as f64,
            tail.len(),
            tail.iter().sum::<f64>() / tail.len() as f64
        );
        if let Ok(path) = std::env::var("PBDL_WAKE_CKPT") {
            let meta = pbdl_core::io::CheckpointMeta { step: steps as u64, seed: Some(1), config: Default::default() };
            pbdl_core::io::save_varmap(&path, &varmap, &meta).unwrap();
        }
    }

    let n = env("PBDL_WAKE_SAMPLES", 50);
    println!(
        "| Re | mean rel. err | (vs deficit) | std corr. | mean std pred | true | ratio | 25-snapshot std corr. | \
         nearest-train-Re: mean err, std corr, std ratio |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut worst = (0.0f64, 1.0f64, 0.0f64);
    for (k, case) in test_cases.iter().enumerate() {
        let t2 = Instant::now();
        let truth = FieldStats::of(&case.snapshots).unwrap();
        let cond = condition(&cfg, case.re, RE_SCALE, &dev).unwrap();
        let pred = predict_stats(&net, &d, &cond, &norm, &SampleConfig { n, batch: 25, seed: 100 + k as u64 }).unwrap();
        let s = compare(&pred, &truth, &mask).unwrap();
        // References: the statistics of only 25 snapshots (sampling noise of a 25-member
        // estimate), and copying the nearest training case.
        let few = FieldStats::of(&case.snapshots.narrow(0, 0, 25).unwrap()).unwrap();
        let few_s = compare(&few, &truth, &mask).unwrap();
        let nearest =
            train_cases.iter().min_by(|a, b| (a.re - case.re).abs().total_cmp(&(b.re - case.re).abs())).unwrap();
        let near_s = compare(&FieldStats::of(&nearest.snapshots).unwrap(), &truth, &mask).unwrap();
        let ratio = s.mean_std_pred / s.mean_std_true;
        println!(
            "| {} | {:.4} | {:.3} | {:.3} | {:.4} | {:.4} | {ratio:.3} | {:.3} | {:.4}, {:.3}, {:.3} | ({:.0} s)",
            case.re,
            s.mean_rel_error,
            s.mean_rel_error_vs_deficit,
            s.std_correlation,
            s.mean_std_pred,
            s.mean_std_true,
            few_s.std_correlation,
            near_s.mean_rel_error,
            near_s.std_correlation,
            near_s.mean_std_pred / near_s.mean_std_true,
            t2.elapsed().as_secs_f64()
        );
        worst = (worst.0.max(s.mean_rel_error), worst.1.min(s.std_correlation), worst.2.max((ratio - 1.0).abs()));
    }
    println!(
        "worst over the 6 test Re: mean rel. error {:.4} (< 0.05), std correlation {:.3} (> 0.8), |mean std ratio - 1| \
         {:.3} (< 0.2); total {:.0} s",
        worst.0,
        worst.1,
        worst.2,
        t0.elapsed().as_secs_f64()
    );
    println!(
        "ACCEPTANCE: wake_surrogate measured=worst mean rel. error {:.4}, std correlation {:.3}, |std ratio - 1| {:.3} \
         bar=< 0.05, > 0.8, < 0.2 at every test Re",
        worst.0,
        worst.1,
        worst.2
    );
    assert!(worst.0 < 0.05, "mean-field relative error {}", worst.0);
    assert!(worst.1 > 0.8, "std-field correlation {}", worst.1);
    assert!(worst.2 < 0.2, "mean std off by {}", worst.2);
}

#[test]
#[ignore = "timing of candidate networks: one training step each"]
fn network_step_times() {
    use pbdl_diffusion::unet::{AcdmUnet, AcdmUnetConfig};
    let dev = Device::Cpu;
    let cfg = WakeConfig::default();
    let s = (candle_core::Tensor::ones((30, 2, 32, 32), DType::F32, &dev).unwrap() * 0.5).unwrap();
    let s = (s + pbdl_core::seed::randn((30, 2, 32, 32), 0.0, 0.1, DType::F32, &dev, 0).unwrap()).unwrap();
    let cases = vec![WakeCase { re: 100.0, snapshots: s }];
    let norm = Normalizer::fit(&[&cases[0].snapshots]).unwrap();
    let data = Dataset::new(&cfg, &cases, 25, RE_SCALE, &norm, 0).unwrap();
    let d = diffusion().unwrap();
    let tc = TrainConfig { steps: 3, batch: 25, lr: 1e-3, seed: 1 };
    let nets: Vec<(&str, AifNetConfig)> = vec![
        ("aifnet 8x[1,2,2] no attn", small_wake_net(8, vec![1, 2, 2])),
        ("aifnet 16x[1,2,4] no attn", small_wake_net(16, vec![1, 2, 4])),
        ("aifnet 16x[1,2,4,4] attn 2,3", wake_net()),
    ];
    for (name, c) in nets {
        let (varmap, net) = build_seeded(DType::F32, 0, |vb| AifNet::new(c, vb));
        let t = Instant::now();
        train(&net, varmap.all_vars(), &d, &data, &tc, |k, _| {
            println!("  {name} step {k}: {:.2} s", t.elapsed().as_secs_f64())
        })
        .unwrap();
        println!("{name} ({} params): {:.2} s/step", count_parameters(&varmap), t.elapsed().as_secs_f64() / 3.0);
    }
    let c = AcdmUnetConfig { dim_mults: vec![1, 2, 2], in_channels: 5, out_channels: 2, ..AcdmUnetConfig::acdm(16, 5) };
    let (varmap, net) = build_seeded(DType::F32, 0, |vb| AcdmUnet::new(c, vb));
    let t = Instant::now();
    train(&net, varmap.all_vars(), &d, &data, &tc, |_, _| {}).unwrap();
    println!(
        "acdm unet 16x[1,2,2] ({} params): {:.2} s/step",
        count_parameters(&varmap),
        t.elapsed().as_secs_f64() / 3.0
    );
}
