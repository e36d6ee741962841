//! Metric training: losses and ground truth against hand-computed values, gradients against
//! finite differences, the calibration against a two-pass computation, the data generators, and
//! a few training steps.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, GradCheckOptions};
use pbdl_metrics::classic::spearman_values;
use pbdl_metrics::train::data::{generate, load_sequences, save_sequences, spectral_noise, DataConfig, Kind, FRAMES};
use pbdl_metrics::train::eval::{normalise_01, reference_distances, spearman_protocol, Scored};
use pbdl_metrics::train::fit::{
    augment, grouped_distances, random_crop, random_pair_groups, sequence_loss, train, PairGroup, TrainConfig,
};
use pbdl_metrics::train::loss::{
    fit2_coefficient, fit_log_coefficient, ground_truth, log_curve, metric_loss, pairs, pearson_1d, GroundTruth,
    LossConfig, FIT_RANGE,
};
use pbdl_metrics::train::model::{to_byte_range, MetricNet, MetricNetConfig};

fn v(x: &[f64]) -> Tensor {
    Tensor::from_slice(x, x.len(), &Device::Cpu).unwrap()
}

#[test]
fn pairs_put_the_reference_pairs_first() {
    let p = pairs();
    assert_eq!(p.len(), 55);
    assert_eq!(&p[..10], &(1..=10).map(|j| (0, j)).collect::<Vec<_>>()[..]);
    assert_eq!(p[10], (1, 2));
    assert_eq!(p[54], (9, 10));
}

#[test]
fn pearson_matches_a_hand_computed_value() {
    // x = [1,2,3,4], y = [2,4,5,9]: sum(xm ym) = 11, |xm| = sqrt(5), |ym| = sqrt(26).
    let r = pearson_1d(&v(&[1.0, 2.0, 3.0, 4.0]), &v(&[2.0, 4.0, 5.0, 9.0]), 1e-7).unwrap().to_scalar::<f64>().unwrap();
    assert!((r - 11.0 / 130f64.sqrt()).abs() < 1e-14, "{r}");
    // A constant input has no correlation: the epsilon keeps it finite (0).
    let r0 = pearson_1d(&v(&[1.0, 1.0, 1.0]), &v(&[1.0, 2.0, 3.0]), 1e-7).unwrap().to_scalar::<f64>().unwrap();
    assert_eq!(r0, 0.0);
}

#[test]
fn lsim_loss_matches_hand_computed_values() {
    let g: Vec<f64> = pairs().iter().map(|&(i, j)| (j - i) as f64 / 10.0).collect();
    let loss = |d: &[f64], cfg: &LossConfig| metric_loss(&v(d), &v(&g), cfg).unwrap().to_scalar::<f64>().unwrap();
    // d = g: no error, correlation 1.
    assert!(loss(&g, &LossConfig::LSIM).abs() < 1e-14);
    // d = 2 g: correlation still 1; mean g^2 = sum_m (11 - m) m^2 / 100 / 55 = 12.1 / 55 = 0.22.
    let d2: Vec<f64> = g.iter().map(|x| 2.0 * x).collect();
    assert!((loss(&d2, &LossConfig::LSIM) - 0.3 * 0.22).abs() < 1e-12);
    assert!((loss(&d2, &LossConfig::VOLSIM) - 0.22).abs() < 1e-12);
    // Reversed reference distances: correlation -1 -> 0.7 * 0.5 * 2 = 0.7 on top of the MSE.
    let mut rev = g.clone();
    for k in 0..10 {
        rev[k] = g[9 - k];
    }
    let mse = rev.iter().zip(&g).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 55.0;
    assert!((loss(&rev, &LossConfig::LSIM) - (0.3 * mse + 0.7)).abs() < 1e-12);
}

#[test]
fn loss_gradient_matches_finite_differences() {
    let g: Vec<f64> = pairs().iter().map(|&(i, j)| (j - i) as f64 / 10.0).collect();
    let d0: Vec<f64> = g.iter().enumerate().map(|(k, x)| x * 0.8 + 0.05 * ((k as f64) * 1.7).sin() + 0.1).collect();
    let gt = v(&g);
    let rep = check_grad(
        |x| Ok(metric_loss(&x[0], &gt, &LossConfig::LSIM)?),
        &[v(&d0)],
        &GradCheckOptions { max_probes: 55, ..Default::default() },
    )
    .unwrap();
    assert!(rep.max_rel_error < 1e-6, "{rep:?}");
}

#[test]
fn log_curve_matches_hand_values_and_limits() {
    assert!((log_curve(0.5, 1.0) - 6f64.ln() / 11f64.ln()).abs() < 1e-15);
    for c in [-3.0, 0.0, 2.5] {
        assert_eq!(log_curve(0.0, c), 0.0);
        assert!((log_curve(1.0, c) - 1.0).abs() < 1e-15);
    }
    // c -> -inf: linear.
    assert!((log_curve(0.3, -6.0) - 0.3).abs() < 1e-6);
}

#[test]
fn fit_recovers_the_coefficient_of_exact_data() {
    let x: Vec<f64> = (1..=10).map(|k| k as f64 / 10.0).collect();
    for c0 in [-1.0, 0.3, 1.3, 2.7] {
        let y: Vec<f64> = x.iter().map(|&t| log_curve(t, c0)).collect();
        let c = fit_log_coefficient(&x, &y).unwrap();
        assert!((c - c0).abs() < 1e-6, "fitted {c}, true {c0}");
    }
    // Linear data: the curve approaches a line as c -> -inf, so the fit ends at the lower bound.
    let c = fit_log_coefficient(&x, &x).unwrap();
    assert!((c - FIT_RANGE.0).abs() < 1e-3, "{c}");
    assert!(fit_log_coefficient(&x[..1], &x[..1]).is_err());
    assert!(fit_log_coefficient(&x, &x[..5]).is_err());
}

#[test]
fn fit2_ground_truth_of_a_sequence() {
    // Frames whose correlation distance to frame 0 follows a known curve: f_k = cos(a_k) u + sin(a_k) w
    // with orthogonal zero-mean u, w has corr(f_0, f_k) = cos(a_k); choose 1 - cos(a_k) = s * log_curve(k/10, c0).
    let n = 16;
    let u: Vec<f64> = (0..n * n).map(|i| ((i % n) as f64 * 2.0 * std::f64::consts::PI / n as f64).sin()).collect();
    let w: Vec<f64> = (0..n * n).map(|i| ((i / n) as f64 * 2.0 * std::f64::consts::PI / n as f64).sin()).collect();
    let c0 = 1.1;
    let mut frames = Vec::new();
    for k in 0..FRAMES {
        let target = 0.05 + 0.5 * log_curve(k as f64 / 10.0, c0);
        let a = if k == 0 { 0.0 } else { (1.0 - target).acos() };
        frames.extend(u.iter().zip(&w).map(|(p, q)| a.cos() * p + a.sin() * q));
    }
    let frames = Tensor::from_vec(frames, (FRAMES, 1, n, n), &Device::Cpu).unwrap();
    // The min-max normalisation maps 0.05 + 0.5 f(t) affinely onto [0, 1], which is not f itself:
    // the fitted c is the least-squares one of the normalised values, computed here independently.
    let x: Vec<f64> = (1..FRAMES).map(|k| k as f64 / 10.0).collect();
    let raw: Vec<f64> = x.iter().map(|&t| log_curve(t, c0)).collect();
    let (lo, hi) = (raw[0], raw[9]);
    let y: Vec<f64> = raw.iter().map(|r| (r - lo) / (hi - lo)).collect();
    let expected = fit_log_coefficient(&x, &y).unwrap();
    let c = fit2_coefficient(&frames).unwrap();
    assert!((c - expected).abs() < 1e-4, "{c} vs {expected}");
    let gt = ground_truth(GroundTruth::Fit2, &frames).unwrap();
    assert!((gt[0] - log_curve(0.1, c)).abs() < 1e-12 && (gt[9] - 1.0).abs() < 1e-12);
    let lin = ground_truth(GroundTruth::Linear, &frames).unwrap();
    assert_eq!(lin[10], 0.1);
}

fn tiny_net(seed: u64) -> MetricNet {
    MetricNet::new(MetricNetConfig { width: 1.0 / 16.0, seed, ..Default::default() }).unwrap()
}

#[test]
fn calibration_equals_the_two_pass_pooled_statistics() {
    let seqs = generate(Kind::Shapes, 2, &DataConfig { resolution: 48, seed: 3 }).unwrap();
    let inputs: Vec<Tensor> = seqs.iter().map(|s| to_byte_range(&s.frames).unwrap()).collect();
    let mut net = tiny_net(1);
    net.calibrate(inputs.iter()).unwrap();
    let stats = net.stats().unwrap();
    for l in 0..5 {
        // All frames' features of layer l: [22, C, h, w]; mean over frames and channels, M2 the
        // channel-averaged sum of squares around it (what the per-frame Welford update gives).
        let f = Tensor::cat(&inputs.iter().map(|x| net.features(x).unwrap()[l].clone()).collect::<Vec<_>>(), 0)
            .unwrap()
            .to_dtype(DType::F64)
            .unwrap();
        let mean = f.mean(0).unwrap().mean(0).unwrap();
        let m2 = f.broadcast_sub(&mean).unwrap().sqr().unwrap().mean(1).unwrap().sum(0).unwrap();
        let got_mean = stats[l].mean.squeeze(0).unwrap().squeeze(0).unwrap().to_dtype(DType::F64).unwrap();
        let got_m2 = stats[l].m2.squeeze(0).unwrap().squeeze(0).unwrap().to_dtype(DType::F64).unwrap();
        let rel = |a: &Tensor, b: &Tensor| {
            let d = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap();
            d / b.abs().unwrap().max_all().unwrap().to_scalar::<f64>().unwrap().max(1e-30)
        };
        assert!(rel(&got_mean, &mean) < 1e-5, "layer {l} mean");
        assert!(rel(&got_m2, &m2) < 1e-4, "layer {l} M2: {}", rel(&got_m2, &m2));
        assert_eq!(stats[l].count, 22.0);
    }
}

#[test]
fn network_loss_gradient_matches_finite_differences() {
    // The fourth shapes mode (smoothed edges, white noise): no ties between pixels, which would
    // make max pooling and the min/max mapping non-differentiable at the probed points.
    let seqs = generate(Kind::Shapes, 4, &DataConfig { resolution: 44, seed: 5 }).unwrap();
    let seqs = &seqs[3..];
    let mut net = tiny_net(2);
    net.calibrate([&to_byte_range(&seqs[0].frames).unwrap()]).unwrap();
    let net = net.to_dtype(DType::F64).unwrap();
    let gt: Vec<f64> = pairs().iter().map(|&(i, j)| (j - i) as f64 / 10.0).collect();
    let g = Tensor::from_slice(&gt, 55, &Device::Cpu).unwrap();
    let frames = seqs[0].frames.to_dtype(DType::F64).unwrap();
    let params: Vec<Tensor> = net.vars().iter().map(|v| v.as_tensor().clone()).collect();
    // With respect to every weight tensor (conv weights, biases, channel weights).
    let rep = check_grad(
        |p| Ok(metric_loss(&net.sequence_distances_with(&frames, p, &pairs())?, &g, &LossConfig::LSIM)?),
        &params,
        &GradCheckOptions { max_probes: 12, eps: 1e-5, ..Default::default() },
    )
    .unwrap();
    // Input 9, the last layer's bias, shifts the features of both frames alike and cancels in
    // their difference: its gradient is 0 up to round-off (~1e-18), where a relative error is
    // meaningless. Every other tensor is checked.
    for (i, e) in rep.per_input.iter().enumerate() {
        assert!(i == 9 || *e < 1e-5, "input {i}: {rep:?}");
    }
    // And with respect to the input frames (the metric is differentiable in its inputs).
    let rep = check_grad(
        |x| Ok(sequence_loss(&net, &x[0], &gt, &LossConfig::LSIM)?),
        std::slice::from_ref(&frames),
        &GradCheckOptions { max_probes: 24, eps: 1e-5, ..Default::default() },
    )
    .unwrap();
    assert!(rep.max_rel_error < 1e-5, "{rep:?}");
}

#[test]
fn distance_properties_of_the_trained_network() {
    let seqs = generate(Kind::Shapes, 1, &DataConfig { resolution: 48, seed: 7 }).unwrap();
    let mut net = tiny_net(3);
    net.calibrate([&to_byte_range(&seqs[0].frames).unwrap()]).unwrap();
    let d =
        net.sequence_distances(&seqs[0].frames, &[(0, 0), (0, 5), (5, 0), (3, 3)]).unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(d[0], 0.0);
    assert_eq!(d[3], 0.0);
    assert_eq!(d[1], d[2]);
    assert!(d[1] > 0.0);
    // Uncalibrated networks and bad pairs are typed errors.
    assert!(tiny_net(3).sequence_distances(&seqs[0].frames, &[(0, 1)]).is_err());
    assert!(net.sequence_distances(&seqs[0].frames, &[(0, 11)]).is_err());
    // Frames too small for the five layers (the last feature map would vanish): an error.
    let small = Tensor::zeros((FRAMES, 1, 24, 24), DType::F32, &Device::Cpu).unwrap();
    assert!(net.sequence_distances(&small, &[(0, 1)]).is_err());
}

#[test]
fn augmentation_is_the_symmetry_group_of_the_square() {
    let x = Tensor::arange(0f64, 6.0, &Device::Cpu).unwrap().reshape((1, 1, 2, 3)).unwrap();
    let r1 = augment(&x, 1).unwrap();
    // A quarter turn of [[0,1,2],[3,4,5]] (transpose, then mirror x): [[3,0],[4,1],[5,2]].
    assert_eq!(
        r1.squeeze(0).unwrap().squeeze(0).unwrap().to_vec2::<f64>().unwrap(),
        [[3.0, 0.0], [4.0, 1.0], [5.0, 2.0]]
    );
    let r4 = augment(&augment(&r1, 3).unwrap(), 0).unwrap();
    assert_eq!(r4.flatten_all().unwrap().to_vec1::<f64>().unwrap(), x.flatten_all().unwrap().to_vec1::<f64>().unwrap());
    let f = augment(&x, 4).unwrap();
    assert_eq!(f.flatten_all().unwrap().to_vec1::<f64>().unwrap(), [2.0, 1.0, 0.0, 5.0, 4.0, 3.0]);
}

#[test]
fn generated_sequences_have_the_shape_and_grow_away_from_the_reference() {
    let cfg = DataConfig { resolution: 32, seed: 11 };
    for (kind, count) in [(Kind::AdvectionDiffusion, 6), (Kind::Burgers, 6), (Kind::Smoke, 3), (Kind::Shapes, 4)] {
        let seqs = generate(kind, count, &cfg).unwrap();
        let mut mean = [0.0; 10];
        for s in &seqs {
            assert_eq!(s.frames.dims(), [FRAMES, 1, 32, 32]);
            assert_eq!(s.kind, kind);
            let d = reference_distances(Scored::L2, &s.frames).unwrap();
            let scale = d.iter().cloned().fold(0.0, f64::max);
            assert!(scale > 0.0, "{kind:?}: all variants equal the reference");
            for (m, x) in mean.iter_mut().zip(&d) {
                *m += x / scale / count as f64;
            }
        }
        // On average the L2 distance to the reference grows with the parameter change. For the
        // shapes only until they stop overlapping their start: after that L2 saturates (the
        // reason the papers' shapes are hard for L2), so there only the first half must grow.
        let k: Vec<f64> = (1..=10).map(|k| k as f64).collect();
        let part = if kind == Kind::Shapes { 5 } else { 10 };
        let rho = spearman_values(&mean[..part], &k[..part]).unwrap();
        println!("{kind:?}: mean normalised L2 curve {mean:.3?}");
        assert!(rho > 0.9, "{kind:?}: Spearman of the mean L2 curve {rho}, {mean:?}");
        assert!(mean[9] > mean[0], "{kind:?}");
    }
    // Same seed, same data.
    let a = generate(Kind::Burgers, 1, &cfg).unwrap();
    let b = generate(Kind::Burgers, 1, &cfg).unwrap();
    let diff = (&a[0].frames - &b[0].frames).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    assert_eq!(diff, 0.0);
}

#[test]
fn sequences_and_models_round_trip_through_files() {
    let dir = tempfile::tempdir().unwrap();
    let seqs = generate(Kind::Shapes, 2, &DataConfig { resolution: 48, seed: 1 }).unwrap();
    save_sequences(dir.path().join("s.npz"), &seqs).unwrap();
    let back = load_sequences(dir.path().join("s.npz")).unwrap();
    assert_eq!(back.len(), 2);
    assert_eq!(back[1].kind, Kind::Shapes);
    let mut net = tiny_net(4);
    net.calibrate(seqs.iter().map(|s| to_byte_range(&s.frames).unwrap()).collect::<Vec<_>>().iter()).unwrap();
    net.save(dir.path().join("m"), 7).unwrap();
    let loaded = MetricNet::load(dir.path().join("m")).unwrap();
    let p = pairs();
    let a = net.sequence_distances(&back[0].frames, &p).unwrap().to_vec1::<f32>().unwrap();
    let b = loaded.sequence_distances(&back[0].frames, &p).unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(a, b);
}

#[test]
fn protocol_normalisation_and_a_perfect_metric() {
    assert_eq!(normalise_01(&[2.0, 4.0, 3.0]), [0.1, 1.0, 0.55]);
    assert_eq!(normalise_01(&[2.0, 2.0]), [0.1, 0.1]);
    // A sequence whose frames move away linearly: L2 ranks it perfectly (Spearman 1).
    let frames: Vec<f64> = (0..FRAMES).flat_map(|k| (0..256).map(move |i| (i as f64).sin() + k as f64 * 0.1)).collect();
    let s = pbdl_metrics::train::Sequence {
        kind: Kind::Shapes,
        param: pbdl_metrics::train::Param::ShapeMotion,
        frames: Tensor::from_vec(frames, (FRAMES, 1, 16, 16), &Device::Cpu).unwrap(),
    };
    assert!((spearman_protocol(Scored::L2, &[s.clone(), s]).unwrap() - 1.0).abs() < 1e-12);
}

#[test]
fn a_few_training_steps_reduce_the_loss() {
    let seqs = generate(Kind::Shapes, 4, &DataConfig { resolution: 48, seed: 9 }).unwrap();
    let mut net = MetricNet::new(MetricNetConfig { width: 0.25, seed: 0, ..Default::default() }).unwrap();
    let cfg = TrainConfig {
        epochs: 4,
        adam: pbdl_core::train::AdamConfig { lr: 1e-3, ..Default::default() },
        augment: false,
        crop: 1.0,
        dropout: 0.0,
        ..Default::default()
    };
    let report = train(&mut net, &seqs, &cfg).unwrap();
    let l = &report.epoch_loss;
    assert_eq!(l.len(), 4);
    assert!(l[3] < 0.8 * l[0], "epoch losses {l:?}");
    // The channel weights stay non-negative.
    for v in net.vars().iter().skip(10) {
        assert!(v.as_tensor().min_all().unwrap().to_scalar::<f32>().unwrap() >= 0.0);
    }
}

#[test]
fn dropout_is_unbiased_for_the_squared_distance() {
    // Every element of the squared feature difference is kept with probability 1 - p and scaled
    // by 1 / (1 - p), so the mean of d^2 over many masks is the d^2 without dropout (d^2 is
    // linear in those elements); p = 0 is exactly the plain distance.
    let seqs = generate(Kind::Shapes, 4, &DataConfig { resolution: 48, seed: 4 }).unwrap();
    let mut net = tiny_net(5);
    let x = to_byte_range(&seqs[3].frames).unwrap();
    net.calibrate([&x]).unwrap();
    let feats = net.features(&x).unwrap();
    let pairs = [(0, 3), (0, 10), (2, 7)];
    let plain = net.pair_distances(&feats, &pairs).unwrap().to_vec1::<f32>().unwrap();
    let same = net.pair_distances_dropout(&feats, &pairs, 0.0, 1).unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(plain, same);
    let trials = 400;
    let mut mean = [0.0f64; 3];
    for s in 0..trials {
        let d = net.pair_distances_dropout(&feats, &pairs, 0.5, s).unwrap().to_vec1::<f32>().unwrap();
        assert_ne!(d, plain);
        for (m, x) in mean.iter_mut().zip(&d) {
            *m += (*x as f64).powi(2) / trials as f64;
        }
    }
    for (m, p) in mean.iter().zip(&plain) {
        let p2 = (*p as f64).powi(2);
        assert!((m - p2).abs() < 0.05 * p2, "mean d^2 {m} vs {p2}");
    }
    assert!(net.pair_distances_dropout(&feats, &pairs, 1.0, 0).is_err());
}

#[test]
fn spectral_noise_has_phiflows_spectrum() {
    // PhiFlow's Noise(scale=10, smoothness=1) at 128 cells: Fourier amplitude 1/kappa^2 (power
    // 1/kappa^4) for kappa above ~4.05 periods per domain, nothing below; zero mean, unit std.
    let (b, n) = (64, 32);
    let f = spectral_noise(b, 1, n, 7).unwrap().to_dtype(DType::F64).unwrap();
    assert_eq!(f.dims(), [b, 1, n, n]);
    let v = f.flatten_from(1).unwrap().to_vec2::<f64>().unwrap();
    for row in &v {
        let mean = row.iter().sum::<f64>() / row.len() as f64;
        let var = row.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / row.len() as f64;
        assert!(mean.abs() < 1e-9 && (var - 1.0).abs() < 1e-6, "mean {mean}, var {var}");
    }
    // Mean power of Fourier mode (kx, ky) over the realisations, by direct summation.
    let power = |kx: f64, ky: f64| -> f64 {
        v.iter()
            .map(|row| {
                let (mut re, mut im) = (0.0, 0.0);
                for (idx, x) in row.iter().enumerate() {
                    let a = 2.0 * std::f64::consts::PI * (kx * (idx % n) as f64 + ky * (idx / n) as f64) / n as f64;
                    re += x * a.cos();
                    im -= x * a.sin();
                }
                re * re + im * im
            })
            .sum::<f64>()
            / v.len() as f64
    };
    let p5 = (power(5.0, 0.0) + power(0.0, 5.0) + power(3.0, 4.0) + power(4.0, 3.0)) / 4.0;
    let p10 = (power(10.0, 0.0) + power(0.0, 10.0) + power(6.0, 8.0) + power(8.0, 6.0)) / 4.0;
    let ratio = p5 / p10;
    assert!((ratio / 16.0 - 1.0).abs() < 0.35, "power ratio kappa 5 / kappa 10: {ratio} (expected 16)");
    for (kx, ky) in [(1.0, 0.0), (3.0, 0.0), (2.0, 2.0), (4.0, 0.0)] {
        assert!(power(kx, ky) < 1e-9 * p5, "mode ({kx}, {ky}) below the cut has power {}", power(kx, ky));
    }
}

#[test]
fn random_crops_are_windows_of_the_frames() {
    let seqs = generate(Kind::Shapes, 1, &DataConfig { resolution: 32, seed: 2 }).unwrap();
    let f = &seqs[0].frames;
    let mut rng = pbdl_core::seed::rng(3);
    let c = random_crop(f, 28, &mut rng).unwrap();
    assert_eq!(c.dims(), [FRAMES, 1, 28, 28]);
    // The crop equals some window of the frames (searched over all offsets).
    let found = (0..=4).any(|t| {
        (0..=4).any(|l| {
            let w = f.narrow(2, t, 28).unwrap().narrow(3, l, 28).unwrap();
            (w - &c).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap() == 0.0
        })
    });
    assert!(found);
    assert!(random_crop(f, 33, &mut rng).is_err());
}

#[test]
fn bad_settings_are_typed_errors() {
    assert!(generate(Kind::Burgers, 1, &DataConfig { resolution: 8, seed: 0 }).is_err());
    assert_eq!(Kind::parse("smo").unwrap(), Kind::Smoke);
    assert!(Kind::parse("liquid").unwrap_err().to_string().contains("Adv, Bur, Smo, Sha"));
    assert!(MetricNet::new(MetricNetConfig { width: 0.0, ..Default::default() }).is_err());
    assert!(metric_loss(&v(&[0.1, 0.2]), &v(&[0.1, 0.2, 0.3]), &LossConfig::LSIM).is_err());
    let cfg = LossConfig { correlation_pairs: 20, ..LossConfig::LSIM };
    assert!(metric_loss(&v(&[0.1; 10]), &v(&[0.1; 10]), &cfg).is_err());
    assert!(train(&mut tiny_net(0), &[], &TrainConfig::default()).is_err());
    let seqs = generate(Kind::Shapes, 1, &DataConfig { resolution: 48, seed: 0 }).unwrap();
    assert!(train(&mut tiny_net(0), &seqs, &TrainConfig { crop: 0.0, ..Default::default() }).is_err());
    assert!(train(&mut tiny_net(0), &seqs, &TrainConfig { dropout: 1.0, ..Default::default() }).is_err());
}

#[test]
fn input_scale_and_second_pool_give_the_conv_arithmetic_sizes() {
    // 56 cells: conv 12/4/2 -> (56 + 4 - 12) / 4 + 1 = 13, pool 4/2 -> 5, conv 5/1/2 -> 5,
    // pool -> 1, then 1, 1. Without the second pool the last three stay 5; upsampled x2 (112):
    // 27, pool -> 12, 12, pool -> 5, 5, 5.
    let x = Tensor::zeros((2, 1, 56, 56), DType::F64, &Device::Cpu).unwrap();
    let sizes = |cfg: MetricNetConfig| -> Vec<usize> {
        let net = MetricNet::new(MetricNetConfig { width: 1.0 / 16.0, ..cfg }).unwrap();
        net.features(&x).unwrap().iter().map(|f| f.dim(2).unwrap()).collect()
    };
    assert_eq!(sizes(MetricNetConfig::default()), [13, 5, 1, 1, 1]);
    assert_eq!(sizes(MetricNetConfig { second_pool: false, ..Default::default() }), [13, 5, 5, 5, 5]);
    assert_eq!(sizes(MetricNetConfig { input_scale: 2, ..Default::default() }), [27, 12, 5, 5, 5]);
    assert!(MetricNet::new(MetricNetConfig { input_scale: 0, ..Default::default() }).is_err());
    // The options survive a save / load round trip.
    let seqs = generate(Kind::Shapes, 1, &DataConfig { resolution: 48, seed: 2 }).unwrap();
    let cfg = MetricNetConfig { width: 1.0 / 16.0, input_scale: 2, second_pool: false, ..Default::default() };
    let mut net = MetricNet::new(cfg).unwrap();
    net.calibrate([&to_byte_range(&seqs[0].frames).unwrap()]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    net.save(dir.path().join("m"), 0).unwrap();
    let back = MetricNet::load(dir.path().join("m")).unwrap();
    assert_eq!(back.config(), &cfg);
    let pairs = [(0, 4), (2, 9)];
    assert_eq!(
        net.sequence_distances(&seqs[0].frames, &pairs).unwrap().to_vec1::<f32>().unwrap(),
        back.sequence_distances(&seqs[0].frames, &pairs).unwrap().to_vec1::<f32>().unwrap()
    );
}

#[test]
fn weights_only_training_keeps_the_convs_and_recalibration_follows_them() {
    let seqs = generate(Kind::Shapes, 3, &DataConfig { resolution: 48, seed: 11 }).unwrap();
    let base = TrainConfig {
        epochs: 2,
        adam: pbdl_core::train::AdamConfig { lr: 1e-3, ..Default::default() },
        augment: false,
        crop: 1.0,
        dropout: 0.0,
        ..Default::default()
    };
    let values = |net: &MetricNet| -> Vec<Vec<f32>> {
        net.vars().iter().map(|v| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
    };
    let before = values(&tiny_net(4));
    let mut net = tiny_net(4);
    train(&mut net, &seqs, &TrainConfig { train_base: false, ..base }).unwrap();
    let after = values(&net);
    assert_eq!(before[..10], after[..10], "conv weights and biases must not move");
    assert_ne!(before[10..], after[10..], "channel weights must move");
    // Recalibrating after each epoch: the statistics are those of a fresh calibration pass with
    // the trained conv weights (crop 1.0: the same frames), not those of the initial weights.
    let mut frozen = tiny_net(4);
    train(&mut frozen, &seqs, &base).unwrap();
    let mut recal = tiny_net(4);
    train(&mut recal, &seqs, &TrainConfig { recalibrate: true, ..base }).unwrap();
    let mean0 = |n: &MetricNet| n.stats().unwrap()[0].mean.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let mut check = recal.deep_copy().unwrap();
    let inputs: Vec<Tensor> = seqs.iter().map(|s| to_byte_range(&s.frames).unwrap()).collect();
    check.calibrate(inputs.iter()).unwrap();
    assert_eq!(mean0(&recal), mean0(&check));
    assert_ne!(mean0(&recal), mean0(&frozen));
}

#[test]
fn a_deep_copy_trains_without_changing_the_original() {
    let seqs = generate(Kind::Shapes, 2, &DataConfig { resolution: 48, seed: 5 }).unwrap();
    let values = |net: &MetricNet| -> Vec<Vec<f32>> {
        net.vars().iter().map(|v| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
    };
    let cfg = TrainConfig {
        epochs: 1,
        adam: pbdl_core::train::AdamConfig { lr: 1e-2, ..Default::default() },
        augment: false,
        crop: 1.0,
        dropout: 0.0,
        ..Default::default()
    };
    let mut original = tiny_net(6);
    let inputs: Vec<Tensor> = seqs.iter().map(|s| to_byte_range(&s.frames).unwrap()).collect();
    original.calibrate(inputs.iter()).unwrap();
    let before = values(&original);
    let mut copy = original.deep_copy().unwrap();
    assert!(values(&copy) == before, "a copy starts with the same weights");
    train(&mut copy, &seqs, &cfg).unwrap();
    assert!(values(&copy) != before, "training must move the copy's weights");
    assert!(values(&original) == before, "training the copy must leave the original unchanged");
    // The other way round, by setting a variable of the original directly.
    let w = &original.vars()[0];
    w.set(&(w.as_tensor() * 2.0).unwrap()).unwrap();
    assert!(values(&original)[0] != values(&copy)[0], "changing the original must leave the copy unchanged");
    // `to_dtype` to the same dtype is a copy too; to f64 as well.
    let same = original.to_dtype(DType::F32).unwrap();
    let w = &same.vars()[1];
    w.set(&(w.as_tensor() + 1.0).unwrap()).unwrap();
    assert!(values(&same)[1] != values(&original)[1], "to_dtype must copy the variables");
}

#[test]
fn grouped_distances_equal_the_plain_ones_when_all_groups_share_a_window() {
    let seqs = generate(Kind::Shapes, 1, &DataConfig { resolution: 56, seed: 8 }).unwrap();
    let frames = &seqs[0].frames;
    let mut net = tiny_net(2);
    net.calibrate([to_byte_range(frames).unwrap()].iter()).unwrap();
    let mut rng = pbdl_core::seed::rng(3);
    let close = |a: &Tensor, b: &Tensor| {
        let (a, b) = (a.to_vec1::<f32>().unwrap(), b.to_vec1::<f32>().unwrap());
        assert_eq!(a.len(), 55);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() <= 1e-5 * y.abs().max(1.0), "{x} vs {y}");
        }
    };
    // Random groups, one shared symmetry and window: the same as transforming the whole sequence
    // first (checks the regrouping of the pairs and the order of symmetry and crop).
    for (groups, code, top, left, side) in [(1, 0, 0, 0, 56), (7, 0, 0, 0, 56), (55, 5, 3, 2, 48), (4, 3, 8, 0, 48)] {
        let plan: Vec<PairGroup> = random_pair_groups(groups, 56, side, false, &mut rng)
            .into_iter()
            .map(|g| PairGroup { symmetry: code, top, left, ..g })
            .collect();
        assert_eq!(plan.len(), groups);
        let grouped = grouped_distances(&net, frames, side, &plan, 0.0, 0).unwrap();
        let t = augment(frames, code).unwrap().narrow(2, top, side).unwrap().narrow(3, left, side).unwrap();
        let plain = net.sequence_distances(&t, &pairs()).unwrap();
        close(&grouped, &plain);
    }
    // Different windows per group do change the distances, and a plan missing a pair is an error.
    let plan = random_pair_groups(55, 56, 48, true, &mut rng);
    let mixed = grouped_distances(&net, frames, 48, &plan, 0.0, 0).unwrap().to_vec1::<f32>().unwrap();
    assert!(mixed.iter().all(|d| d.is_finite()));
    assert!(grouped_distances(&net, frames, 48, &plan[1..], 0.0, 0).is_err());
    let bad = vec![PairGroup { pairs: (0..55).collect(), symmetry: 0, top: 10, left: 0 }];
    assert!(grouped_distances(&net, frames, 48, &bad, 0.0, 0).is_err());
    // Training with grouped augmentation runs and moves the weights.
    let cfg = TrainConfig { epochs: 1, pair_groups: 5, dropout: 0.0, ..Default::default() };
    let before = net.vars()[0].as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let report = train(&mut net, &seqs, &cfg).unwrap();
    assert!(report.epoch_loss[0].is_finite());
    assert!(net.vars()[0].as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap() != before);
}
