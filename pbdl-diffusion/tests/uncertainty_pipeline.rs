//! Mechanics of the wake surrogate: statistics with known answers, the simulated data, and a
//! pipeline run with a tiny network (the acceptance run is `uncertainty_wake`, ignored).

use candle_core::{DType, Device, Tensor};
use pbdl_diffusion::uncertainty::{
    compare, condition, diffusion, predict_stats, simulate_wake, train, Dataset, FieldStats, Normalizer, SampleConfig,
    TrainConfig, WakeCase, WakeConfig,
};
use pbdl_diffusion::unet::{AcdmUnet, AcdmUnetConfig};
use pbdl_diffusion::Error;

mod common;

/// Snapshots `m + s sin(2 pi n / N + phase)`: over whole periods the mean is `m` and the
/// population standard deviation `s / sqrt(2)` exactly.
fn synthetic(n: usize, mean: [f32; 2], amp: [f32; 2]) -> Tensor {
    let (h, w) = (4, 4);
    let mut v = vec![0f32; n * 2 * h * w];
    for k in 0..n {
        for c in 0..2 {
            for p in 0..h * w {
                let phase = p as f32 * 0.3;
                let s = (2.0 * std::f32::consts::PI * k as f32 / n as f32 + phase).sin();
                v[((k * 2 + c) * h * w) + p] = mean[c] + amp[c] * (1.0 + p as f32 / 16.0) * s;
            }
        }
    }
    Tensor::from_vec(v, (n, 2, h, w), &Device::Cpu).unwrap()
}

#[test]
fn field_statistics_of_synthetic_snapshots_are_exact() {
    let s = synthetic(24, [1.0, -0.5], [0.2, 0.4]);
    let st = FieldStats::of(&s).unwrap();
    let mean = st.mean.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let std = st.std.flatten_all().unwrap().to_vec1::<f64>().unwrap();
    for c in 0..2 {
        for p in 0..16 {
            let amp = [0.2, 0.4][c] * (1.0 + p as f64 / 16.0);
            assert!((mean[c * 16 + p] - [1.0, -0.5][c]).abs() < 1e-6);
            assert!((std[c * 16 + p] - amp / 2f64.sqrt()).abs() < 1e-6);
        }
    }
    // The scores: a perfect prediction, and one whose std is scaled (correlation stays 1).
    let mask = vec![0f32; 16];
    let perfect = compare(&st, &st, &mask).unwrap();
    assert_eq!(perfect.mean_rel_error, 0.0);
    assert!((perfect.std_correlation - 1.0).abs() < 1e-12);
    let scaled = FieldStats { mean: st.mean.clone(), std: (&st.std * 2.0).unwrap() };
    let sc = compare(&scaled, &st, &mask).unwrap();
    assert!((sc.std_correlation - 1.0).abs() < 1e-12 && (sc.mean_std_pred / sc.mean_std_true - 2.0).abs() < 1e-12);
    assert!(matches!(FieldStats::of(&s.narrow(0, 0, 1).unwrap()), Err(Error::ShapeMismatch { .. })));
    // The normaliser maps the snapshots to zero mean, unit variance per channel and back.
    let norm = Normalizer::fit(&[&s]).unwrap();
    let z = norm.normalize(&s).unwrap();
    let zs = z.transpose(0, 1).unwrap().flatten_from(1).unwrap();
    let zm = zs.mean(1).unwrap().to_vec1::<f32>().unwrap();
    assert!(zm.iter().all(|m| m.abs() < 1e-5));
    let back = norm.denormalize(&z).unwrap();
    let diff = (back - &s).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    assert!(diff < 1e-5);
}

#[test]
fn the_wake_simulation_gives_windowed_snapshots_and_a_mask() {
    // A short run: 3 snapshots after 4 D/U (the wake has not started to shed yet).
    let cfg = WakeConfig { warmup: 4.0, snapshots: 3, interval: 0.5, ..Default::default() };
    let case = simulate_wake(&cfg, 100.0).unwrap();
    assert_eq!(case.snapshots.dims(), [3, 2, 32, 32]);
    let mask = cfg.mask();
    // 4 cells per diameter: the staircase disc has pi (D / dx)^2 / 4 ~ 12.6 cells; ours has 12.
    let inside = mask.iter().filter(|&&m| m == 1.0).count();
    assert_eq!(inside, 12);
    let u = case.snapshots.narrow(1, 0, 1).unwrap().mean(0).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    // Inside the cylinder the fluid is at rest; beside it (y = 1 D from the wall) it moves at ~U.
    let solid: f32 = (0..1024).filter(|&p| mask[p] == 1.0).map(|p| u[p].abs()).sum::<f32>() / inside as f32;
    assert!(solid < 0.1, "mean |u| in the cylinder {solid}");
    assert!((u[4 * 32] - 1.0).abs() < 0.3, "u near the lower wall {}", u[4 * 32]);
    // 2 x 2 pooling keeps the solid area: the pooled mask sums to a quarter of the cell count.
    let pooled = WakeConfig { pool: 2, out_size: [16, 16], ..cfg.clone() };
    assert!((pooled.mask().iter().sum::<f32>() * 4.0 - inside as f32).abs() < 1e-5);
    let c = condition(&cfg, 150.0, 300.0, &Device::Cpu).unwrap();
    assert_eq!(c.dims(), [3, 32, 32]);
    assert_eq!(c.narrow(0, 1, 1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap(), mask);
    assert!(simulate_wake(&cfg, -1.0).is_err());
    assert!(simulate_wake(&WakeConfig { out_size: [64, 64], ..cfg }, 100.0).is_err());
}

#[test]
fn a_briefly_trained_surrogate_gives_finite_statistics() {
    // Synthetic 8 x 8 cases; a tiny ACDM U-Net (clean conditioning: 3 + 2 channels in, 2 out).
    let dev = Device::Cpu;
    let cfg = WakeConfig { out_size: [8, 8], window_origin: [2.0, 2.0], ..Default::default() };
    let cases: Vec<WakeCase> = [100.0, 200.0]
        .iter()
        .map(|&re| {
            let s = synthetic(8, [1.0, 0.0], [0.1 * re as f32 / 100.0, 0.2]);
            let s = Tensor::cat(&[&s, &s], 2).unwrap();
            WakeCase { re, snapshots: Tensor::cat(&[&s, &s], 3).unwrap() }
        })
        .collect();
    let norm = Normalizer::fit(&cases.iter().map(|c| &c.snapshots).collect::<Vec<_>>()).unwrap();
    let data = Dataset::new(&cfg, &cases, 5, 300.0, &norm, 0).unwrap();
    assert_eq!((data.cond.dims(), data.target.dims()), ([10, 3, 8, 8].as_slice(), [10, 2, 8, 8].as_slice()));
    let config =
        AcdmUnetConfig { dim_mults: vec![1, 1], in_channels: 5, out_channels: 2, ..AcdmUnetConfig::acdm(8, 5) };
    let (varmap, net) = common::build_seeded(DType::F32, 0, |vb| AcdmUnet::new(config, vb));
    let d = diffusion().unwrap();
    let tc = TrainConfig { steps: 3, batch: 4, lr: 1e-3, seed: 1 };
    let losses = train(&net, varmap.all_vars(), &d, &data, &tc, |_, _| {}).unwrap();
    assert_eq!(losses.len(), 3);
    assert!(losses.iter().all(|l| l.is_finite() && *l > 0.0));
    let cond = condition(&cfg, 150.0, 300.0, &dev).unwrap();
    let st = predict_stats(&net, &d, &cond, &norm, &SampleConfig { n: 3, batch: 3, seed: 2 }).unwrap();
    assert_eq!(st.mean.dims(), [2, 8, 8]);
    let all = Tensor::cat(&[st.mean.flatten_all().unwrap(), st.std.flatten_all().unwrap()], 0).unwrap();
    assert!(all.to_vec1::<f64>().unwrap().iter().all(|v| v.is_finite()));
    // Bad settings are typed errors.
    let one = SampleConfig { n: 1, batch: 1, seed: 0 };
    assert!(matches!(predict_stats(&net, &d, &cond, &norm, &one), Err(Error::InvalidConfig { .. })));
    let bad = TrainConfig { steps: 0, ..tc };
    assert!(matches!(train(&net, varmap.all_vars(), &d, &data, &bad, |_, _| {}), Err(Error::InvalidConfig { .. })));
}
