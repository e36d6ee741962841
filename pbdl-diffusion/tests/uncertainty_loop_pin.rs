//! Pins `uncertainty::train` (AdamW, cosine learning rate, clipping at global norm 1, NaN guard)
//! to exact `f64` bits: the loss of each of 5 steps of a tiny ACDM U-Net on synthetic 8 x 8
//! data. The values were recorded on the c5f1131-equivalent code (the loop before it ran on
//! `pbdl_core::train::TrainLoop`); a port of the loop must reproduce them. Run with
//! `--nocapture` to print the bits.

use candle_core::{DType, Var};
use pbdl_diffusion::uncertainty::{diffusion, train, Dataset, Normalizer, TrainConfig, WakeConfig};
use pbdl_diffusion::unet::{AcdmUnet, AcdmUnetConfig};
use pbdl_diffusion::Error;

mod common;

#[test]
fn five_training_steps_are_bit_identical() {
    let cfg = WakeConfig { out_size: [8, 8], window_origin: [2.0, 2.0], ..Default::default() };
    let cases = common::synthetic_wake_cases();
    let norm = Normalizer::fit(&cases.iter().map(|c| &c.snapshots).collect::<Vec<_>>()).unwrap();
    let data = Dataset::new(&cfg, &cases, 5, 300.0, &norm, 0).unwrap();
    let config =
        AcdmUnetConfig { dim_mults: vec![1, 1], in_channels: 5, out_channels: 2, ..AcdmUnetConfig::acdm(8, 5) };
    let (varmap, net) = common::build_seeded(DType::F32, 0, |vb| AcdmUnet::new(config, vb));
    // Sorted by name: the global gradient norm (clipping at 1) sums in this order.
    let mut named: Vec<(String, Var)> =
        varmap.data().lock().unwrap().iter().map(|(k, v)| (k.clone(), v.clone())).collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let vars: Vec<Var> = named.into_iter().map(|(_, v)| v).collect();
    let d = diffusion().unwrap();
    let tc = TrainConfig { steps: 5, batch: 4, lr: 2e-3, seed: 1 };
    let mut seen = Vec::new();
    let losses = train(&net, vars.clone(), &d, &data, &tc, |step, loss| seen.push((step, loss))).unwrap();
    let bits: Vec<u64> = losses.iter().map(|l| l.to_bits()).collect();
    let hex: Vec<String> = bits.iter().map(|b| format!("{b:#018x}")).collect();
    // The weights after the last update (which no loss sees): a sum of |w| in name order.
    let weights: f64 = vars
        .iter()
        .flat_map(|v| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap())
        .map(|w| f64::from(w.abs()))
        .sum();
    println!("losses {losses:?}\nbits [{}]\nweights {weights} {:#018x}", hex.join(", "), weights.to_bits());
    assert_eq!(seen, losses.iter().copied().enumerate().collect::<Vec<_>>(), "on_step sees every step in order");
    // Recorded on c5f1131-equivalent code, then re-recorded once when convolutions got their
    // own bias-gradient sum (per channel instead of candle's strided reduction): losses 3 and
    // 5 moved by one f32 ulp (were 0x3ff113c7c0000000 and 0x3ff1ba59a0000000), the weight sum
    // by 1e-11 relative (was 0x40aef4ac79c4108c); the transposed convolutions' bias gradient
    // moved it by another 2e-14 (was 0x40aef4ac79eaa8a0). Re-recorded 2026-11-29 when the
    // fused GELU's derivative and the linear attention's softmax took pbdl_core::vmath::exp
    // (vectorised, within 3 ulp of libm's expf) instead of libm: the first loss is unchanged,
    // losses 2-5 moved by at most 2.3e-6 relative (were 0x3fede75bc0000000, 0x3ff113c7e0000000,
    // 0x3ff31239c0000000, 0x3ff1ba59c0000000), the weight sum by 5e-8 (was 0x40aef4ac79ed67f0).
    assert_eq!(
        bits,
        [0x3ff2508980000000, 0x3fede76020000000, 0x3ff113ca00000000, 0x3ff3123a80000000, 0x3ff1ba5c20000000]
    );
    assert_eq!(weights.to_bits(), 0x40aef4ac5dbf2d44);

    // A non-finite loss stops training at its step with the guard's error.
    let mut bad = data.clone();
    bad.target = (&bad.target * f64::NAN).unwrap();
    let e = train(&net, vars, &d, &bad, &tc, |_, _| {}).unwrap_err();
    println!("{e}");
    assert!(matches!(e, Error::Core(pbdl_core::Error::Diverged { step: 0, .. })), "{e}");
}
