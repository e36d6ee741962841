//! Pins of the SMDP training loops (`train_toy`, `train_heat`) on short runs: the exact f64 bits
//! of the reported mean losses and a hash of the trained parameters. The values were recorded
//! before the loops moved onto `pbdl_core::train::TrainLoop` (issue 16) and must not change.

use candle_core::{DType, Device, Tensor};
use pbdl_core::train::{AdamConfig, OptimizerConfig};
use pbdl_diffusion::smdp::heat::HeatProblem;
use pbdl_diffusion::smdp::heat_net::HeatScoreNet;
use pbdl_diffusion::smdp::heat_train::{heat_one_step_loss, train_heat, HeatTrainConfig};
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::sde::ToySde;
use pbdl_diffusion::smdp::toy::{train_toy, TimeSampling, ToyLoss, ToyStage, ToyTrainConfig};

/// FNV-1a over the bits of `values`: one number that changes with any parameter.
fn fnv(values: impl IntoIterator<Item = u64>) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for v in values {
        for byte in v.to_le_bytes() {
            h ^= byte as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// Trains a fresh paper network on `sde` with `cfg`; returns `(update, loss bits, stage)` of the
/// report and the hash of the trained parameters, printed for recording.
fn toy_pin(name: &str, sde: &ToySde, cfg: &ToyTrainConfig) -> (Vec<(usize, u64, usize)>, u64) {
    let mut net = ScoreMlp::paper(0);
    let rep = train_toy(sde, &mut net, cfg).unwrap();
    let losses: Vec<(usize, u64, usize)> = rep.losses.iter().map(|&(u, l, s)| (u, l.to_bits(), s)).collect();
    let hash = fnv(net.params().iter().map(|p| p.to_bits()));
    let lit: Vec<String> = losses.iter().map(|(u, l, s)| format!("({u}, {l:#018x}, {s})")).collect();
    println!("PIN {name}: losses [{}] params {hash:#018x}", lit.join(", "));
    (losses, hash)
}

fn small(stages: Vec<ToyStage>) -> ToyTrainConfig {
    ToyTrainConfig { n_paths: 64, batch: 16, stages, seed: 3, log_every: 10, ..ToyTrainConfig::one_step(0, 0) }
}

/// The 1-step loss, then the multi-step loss over a window of 3, on the quadratic toy.
#[test]
fn toy_one_step_then_multi_step_is_pinned() {
    let cfg = small(vec![
        ToyStage { loss: ToyLoss::OneStep, lr: 1e-3, updates: 30 },
        ToyStage { loss: ToyLoss::MultiStep(3), lr: 1e-4, updates: 25 },
    ]);
    let (losses, hash) = toy_pin("one+multi", &ToySde::paper_quadratic(), &cfg);
    // Recorded before the port onto TrainLoop.
    assert_eq!(
        losses,
        [
            (10, 0x3f100c83fc6a8caa, 0),
            (20, 0x3efe84f07ba8e9b6, 0),
            (30, 0x3efb884fa102c8f0, 0),
            (40, 0x3f24c4895a5d599e, 1),
            (50, 0x3f20f5b3a16478be, 1)
        ]
    );
    assert_eq!(hash, 0x289dca2d7b94db32);
}

/// The official recipe (both time directions on the strided grid, data at dt / 2).
#[test]
fn toy_official_bidirectional_is_pinned() {
    let cfg = ToyTrainConfig { n_paths: 64, batch: 16, seed: 5, log_every: 10, ..ToyTrainConfig::official(30, 20) };
    let (losses, hash) = toy_pin("official", &ToySde::paper_quadratic(), &cfg);
    // Recorded before the port onto TrainLoop.
    assert_eq!(
        losses,
        [
            (10, 0x3f621852badcf286, 0),
            (20, 0x3f51199bc61e6552, 0),
            (30, 0x3f510a357f1e2b2b, 0),
            (40, 0x3f045ab34d77a897, 1),
            (50, 0x3f055c377a26f833, 1)
        ]
    );
    assert_eq!(hash, 0x20374e3fa2403d01);
}

/// Graded and one-directional strided stages with log-uniform times in a time range, on the
/// affine toy.
#[test]
fn toy_graded_and_strided_log_uniform_in_a_time_range_is_pinned() {
    let cfg = ToyTrainConfig {
        time_sampling: TimeSampling::LogUniform,
        time_range: (0.1, 4.0),
        ..small(vec![
            ToyStage { loss: ToyLoss::Graded { stride: 4, fine_below: 1.0, fine_weight: 2.0 }, lr: 1e-3, updates: 30 },
            ToyStage { loss: ToyLoss::Strided { stride: 2, bidirectional: false }, lr: 3e-4, updates: 20 },
        ])
    };
    let (losses, hash) = toy_pin("graded+strided", &ToySde::paper_affine(), &cfg);
    // Recorded before the port onto TrainLoop.
    assert_eq!(
        losses,
        [
            (10, 0x3f215375304f783a, 0),
            (20, 0x3f205ce76f2e95aa, 0),
            (30, 0x3f201aabbe2b2846, 0),
            (40, 0x3f10fc46a0cf65ca, 1),
            (50, 0x3f1084db77765f06, 1)
        ]
    );
    assert_eq!(hash, 0x0a09e11a4df80438);
}

/// `train_heat`'s loop as it was before the port onto `TrainLoop` (seeded batches, the 1-step
/// loss, candle's Adam through `backward_step`), over data the same as `train_heat`'s: the
/// reference for the trained parameters, whose last bits depend on candle's CPU thread count
/// (odd and even counts differ), so they are compared in-process rather than hard-coded.
fn heat_reference_loop(problem: &HeatProblem, net: &HeatScoreNet, cfg: &HeatTrainConfig) -> Vec<(usize, f64)> {
    use candle_nn::Optimizer;
    use rand::{Rng, SeedableRng};
    let dtype = net.vars()[0].dtype();
    let x0 = problem.random_fields(cfg.n_train, dtype, cfg.seed).unwrap();
    let all = Tensor::cat(&problem.simulate(&x0, cfg.seed ^ 0x5EED).unwrap(), 0).unwrap();
    let adam = OptimizerConfig::Adam(AdamConfig { lr: cfg.lr, beta1: 0.9, beta2: 0.99, ..Default::default() });
    let mut opt = adam.build(net.vars()).unwrap();
    // `smdp::sde::chunk_rng(cfg.seed ^ 0xB47C, 3)`.
    let mut rng = rand::rngs::StdRng::seed_from_u64(
        (cfg.seed ^ 0xB47C) ^ 3u64.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0x2545_F491),
    );
    let steps = problem.steps();
    let (mut losses, mut acc) = (Vec::new(), 0.0);
    for u in 0..cfg.updates {
        let (mut cur, mut prev, mut t) = (vec![], vec![], vec![]);
        for _ in 0..cfg.batch {
            let i = rng.random_range(0..cfg.n_train);
            let k = rng.random_range(1..=steps);
            cur.push((k * cfg.n_train + i) as u32);
            prev.push(((k - 1) * cfg.n_train + i) as u32);
            t.push(k as f64 * problem.dt);
        }
        let pick = |idx: &[u32]| all.index_select(&Tensor::new(idx, &Device::Cpu).unwrap(), 0).unwrap();
        let loss = heat_one_step_loss(problem, net, &pick(&cur), &t, &pick(&prev)).unwrap();
        acc += loss.to_dtype(DType::F64).unwrap().to_scalar::<f64>().unwrap();
        opt.backward_step(&loss).unwrap();
        if (u + 1) % cfg.log_every == 0 {
            losses.push((u + 1, acc / cfg.log_every as f64));
            acc = 0.0;
        }
    }
    losses
}

fn heat_params(net: &HeatScoreNet) -> Vec<u64> {
    let flat = |v: candle_core::Var| v.as_tensor().flatten_all().unwrap().to_dtype(DType::F64).unwrap();
    net.vars().into_iter().flat_map(|v| flat(v).to_vec1::<f64>().unwrap()).map(f64::to_bits).collect()
}

/// A few Adam updates of a small heat score net (f32 and f64): the mean losses hard-coded
/// (identical with 1 to 4 threads), the trained parameters bit-identical to the old loop's.
#[test]
fn heat_training_is_pinned() {
    let p = HeatProblem { n: 8, ..Default::default() };
    let cfg = HeatTrainConfig { n_train: 16, batch: 4, updates: 12, lr: 3e-3, seed: 1, log_every: 4 };
    for dtype in [DType::F32, DType::F64] {
        let net = HeatScoreNet::new(4, 1, p.t1, dtype, 0).unwrap();
        let rep = train_heat(&p, &net, &cfg).unwrap();
        let losses: Vec<(usize, u64)> = rep.losses.iter().map(|&(u, l)| (u, l.to_bits())).collect();
        let lit: Vec<String> = losses.iter().map(|(u, l)| format!("({u}, {l:#018x})")).collect();
        println!("PIN heat {dtype:?}: losses [{}] params {:#018x}", lit.join(", "), fnv(heat_params(&net)));
        // Recorded before the port onto TrainLoop. The f32 loss after 12 updates moved by one
        // f32 rounding (0x3f215addfc -> 0x3f215addf8, 1.5e-8 relative) when convolutions got
        // their own bias-gradient sum (per channel, instead of candle's strided reduction).
        let want: &[(usize, u64)] = match dtype {
            DType::F32 => &[(4, 0x3f20028678000000), (8, 0x3f209d65ac000000), (12, 0x3f215addf8000000)],
            _ => &[(4, 0x3f200286678cdf09), (8, 0x3f209d66292e7533), (12, 0x3f215ade8ac057e5)],
        };
        assert_eq!(losses, want, "{dtype:?}");
        let reference = HeatScoreNet::new(4, 1, p.t1, dtype, 0).unwrap();
        let ref_losses = heat_reference_loop(&p, &reference, &cfg);
        assert_eq!(rep.losses, ref_losses, "{dtype:?}");
        assert!(heat_params(&net) == heat_params(&reference), "{dtype:?}: trained parameters differ");
    }
}
