//! Classic metrics against hand-computed values, reference numbers and known properties.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_metrics::classic::*;
use pbdl_metrics::Error;
use std::f64::consts::PI;

fn t(v: Vec<f64>, shape: &[usize]) -> Tensor {
    Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
}

fn v1(x: &Tensor) -> Vec<f64> {
    x.to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
}

/// The fields of `the reference script` (quoted below): 20x24 in 2D, 13x12x14 in 3D.
fn fields_2d() -> (Tensor, Tensor) {
    let (mut a, mut b) = (vec![], vec![]);
    for i in 0..20 {
        for j in 0..24 {
            let (fi, fj) = (i as f64, j as f64);
            let v = (0.3 * fi).sin() + (0.2 * fj).cos();
            a.push(v);
            b.push(v + 0.3 * (0.05 * fi * fj).sin());
        }
    }
    (t(a, &[1, 1, 20, 24]), t(b, &[1, 1, 20, 24]))
}

fn fields_3d() -> (Tensor, Tensor) {
    let (mut a, mut b) = (vec![], vec![]);
    for z in 0..13 {
        for y in 0..12 {
            for x in 0..14 {
                let (fz, fy, fx) = (z as f64, y as f64, x as f64);
                let v = (0.3 * fx).sin() + (0.2 * fy).cos() * (0.4 * fz).sin();
                a.push(v);
                b.push(v + 0.3 * (0.1 * fx * fy + 0.2 * fz).cos());
            }
        }
    }
    (t(a, &[1, 1, 13, 12, 14]), t(b, &[1, 1, 13, 12, 14]))
}

#[test]
fn pointwise_metrics_match_hand_computed_values() {
    // Sample 0: a = [1, 2, 3, 4], b = 1; sample 1: a = b = [0, 1, 0, 1] shifted by one.
    let a = t(vec![1., 2., 3., 4., 1., 2., 1., 2.], &[2, 1, 4]);
    let b = t(vec![1., 1., 1., 1., 0., 1., 0., 1.], &[2, 1, 4]);
    assert_eq!(v1(&mse(&a, &b).unwrap()), [3.5, 1.0]);
    assert_eq!(v1(&mae(&a, &b).unwrap()), [1.5, 1.0]);
    assert_eq!(v1(&rmse(&a, &b).unwrap()), [3.5f64.sqrt(), 1.0]);
    // ||a - b|| / ||b||: sqrt(14) / 2 and 2 / sqrt(2).
    let r = v1(&rel_l2(&a, &b).unwrap());
    assert!((r[0] - 14f64.sqrt() / 2.0).abs() < 1e-15 && (r[1] - 2f64.sqrt()).abs() < 1e-15, "{r:?}");
    let p = v1(&psnr(&a, &b, Some(4.0)).unwrap());
    assert!((p[0] - 10.0 * (16.0f64 / 3.5).log10()).abs() < 1e-12, "{p:?}");
    assert!((p[1] - 10.0 * 16f64.log10()).abs() < 1e-12, "{p:?}");
    // Default range: peak-to-peak of the target (0 for sample 0 -> error, 1 for sample 1).
    assert!(psnr(&a, &b, None).unwrap_err().to_string().contains("constant"));
    assert_eq!(v1(&psnr(&a, &a, Some(1.0)).unwrap()), [f64::INFINITY, f64::INFINITY]);
}

#[test]
fn ssim_matches_the_reference_script_and_its_properties() {
    // Reference: the reference script (numpy), the module's definition written out:
    //   g = exp(-(arange(11)-5)^2 / (2 1.5^2)); g /= g.sum(); valid separable filtering;
    //   C1 = (0.01 R)^2, C2 = (0.03 R)^2, R = joint peak-to-peak (or given); mean of the map.
    //   i, j = meshgrid(arange(20), arange(24), 'ij'); a = sin(.3 i) + cos(.2 j);
    //   b = a + .3 sin(.05 i j)  ->  0.7534067277084171 (R auto), 0.7500605416586384 (R = 4)
    //   3D: z, y, x = meshgrid(arange(13), arange(12), arange(14), 'ij');
    //   a = sin(.3x) + cos(.2y) sin(.4z); b = a + .3 cos(.1 x y + .2 z)  ->  0.8089009547796492
    let (a, b) = fields_2d();
    let cfg = SsimConfig::default();
    let s = v1(&ssim2d(&a, &b, &cfg).unwrap())[0];
    assert!((s - 0.7534067277084171).abs() < 1e-12, "{s}");
    let s4 = v1(&ssim2d(&a, &b, &SsimConfig { data_range: Some(4.0), ..cfg }).unwrap())[0];
    assert!((s4 - 0.7500605416586384).abs() < 1e-12, "{s4}");
    assert_eq!(v1(&ssim2d(&b, &a, &cfg).unwrap())[0], s, "symmetric");
    assert!((v1(&ssim2d(&a, &a, &cfg).unwrap())[0] - 1.0).abs() < 1e-14);
    let (a3, b3) = fields_3d();
    let s3 = v1(&ssim3d(&a3, &b3, &cfg).unwrap())[0];
    assert!((s3 - 0.8089009547796492).abs() < 1e-12, "{s3}");
    assert!((v1(&ssim3d(&b3, &b3, &cfg).unwrap())[0] - 1.0).abs() < 1e-14);
    // Constant equal fields: SSIM 1 (the range falls back to 1), not NaN.
    let c = Tensor::full(3.0f64, (1, 2, 12, 12), &Device::Cpu).unwrap();
    assert!((v1(&ssim2d(&c, &c, &cfg).unwrap())[0] - 1.0).abs() < 1e-14);
    // f32 agrees with f64.
    let s32 = v1(&ssim2d(&a.to_dtype(DType::F32).unwrap(), &b.to_dtype(DType::F32).unwrap(), &cfg).unwrap())[0];
    assert!((s32 - s).abs() < 1e-5, "{s32} vs {s}");
    // A window larger than the field is an error that says what to do.
    let small = Tensor::zeros((1, 1, 8, 8), DType::F64, &Device::Cpu).unwrap();
    let e = ssim2d(&small, &small, &cfg).unwrap_err().to_string();
    assert!(e.contains("window"), "{e}");
    assert!(ssim2d(&a3, &b3, &cfg).is_err(), "ssim2d refuses 3D fields");
}

#[test]
fn pearson_is_one_for_linear_maps_and_matches_numpy() {
    let (a, b) = fields_2d();
    let up = ((&a * 3.0).unwrap() + 7.0).unwrap();
    let down = ((&a * -0.5).unwrap() + 1.0).unwrap();
    assert!((v1(&pearson(&a, &up).unwrap())[0] - 1.0).abs() < 1e-14);
    assert!((v1(&pearson(&a, &down).unwrap())[0] + 1.0).abs() < 1e-14);
    // numpy: np.corrcoef(a.ravel(), b.ravel())[0, 1] = 0.9831109659891313
    assert!((v1(&pearson(&a, &b).unwrap())[0] - 0.9831109659891313).abs() < 1e-12);
    // Spearman: a monotone nonlinear map gives exactly 1.
    let cubed = (&a.powf(3.0).unwrap() + &a).unwrap();
    assert_eq!(spearman(&a, &cubed).unwrap(), [1.0]);
    let c = Tensor::ones((1, 1, 4, 4), DType::F64, &Device::Cpu).unwrap();
    let x = t((0..16).map(f64::from).collect(), &[1, 1, 4, 4]);
    assert!(matches!(pearson(&c, &x), Err(Error::Invalid { .. })));
}

#[test]
fn spectrum_of_a_single_mode_peaks_at_its_wavenumber() {
    let n = 32;
    // 2D: cos(2 pi (3 x + 4 y) / n) has |k| = 5 and energy 0.5 * mean(cos^2) = 0.25.
    let v: Vec<f64> =
        (0..n * n).map(|i| (2.0 * PI * (3.0 * (i % n) as f64 + 4.0 * (i / n) as f64) / n as f64).cos()).collect();
    let s = energy_spectrum(&t(v, &[1, 1, n, n])).unwrap();
    let e = &s.energy[0];
    let peak = (0..e.len()).max_by(|&i, &j| e[i].total_cmp(&e[j])).unwrap();
    assert_eq!(peak, 5);
    assert!((e[5] - 0.25).abs() < 1e-12, "{}", e[5]);
    assert!(e.iter().enumerate().all(|(k, &v)| k == 5 || v < 1e-20));
    assert_eq!(s.last_complete_shell, 15);
    // 3D, two channels (a velocity): mode (1, 2, 2) has |k| = 3; each channel adds 0.25 * amp^2.
    let m = 12;
    let mut v = Vec::new();
    for amp in [1.0, 2.0] {
        for i in 0..m * m * m {
            let (x, y, z) = ((i % m) as f64, ((i / m) % m) as f64, (i / (m * m)) as f64);
            v.push(amp * (2.0 * PI * (x + 2.0 * y + 2.0 * z) / m as f64).sin());
        }
    }
    let e = &energy_spectrum(&t(v, &[1, 2, m, m, m])).unwrap().energy[0];
    assert!((e[3] - 0.25 * 5.0).abs() < 1e-12, "{}", e[3]);
    // Parseval on random data: sum_k E(k) = 0.5 mean(u^2) summed over channels.
    let r = seed::randn((2, 3, 20), 0.0, 1.0, DType::F64, &Device::Cpu, 5).unwrap();
    let s = energy_spectrum(&r).unwrap();
    let direct = r.sqr().unwrap().sum(1).unwrap().mean(1).unwrap();
    for (e, d) in s.energy.iter().zip(v1(&direct)) {
        assert!((e.iter().sum::<f64>() - 0.5 * d).abs() < 1e-12);
    }
}

#[test]
fn spectral_error_is_zero_for_equal_spectra_and_log10_of_the_energy_ratio() {
    let a = seed::randn((2, 1, 16, 16), 0.0, 1.0, DType::F64, &Device::Cpu, 7).unwrap();
    assert_eq!(spectral_error(&a, &a).unwrap(), [0.0, 0.0]);
    // 2a has 4x the energy in every shell: log10(4).
    let e = spectral_error(&(&a * 2.0).unwrap(), &a).unwrap();
    assert!(e.iter().all(|e| (e - 4f64.log10()).abs() < 1e-9), "{e:?}");
    // A shift in space does not change the spectrum (periodic grid).
    let rolled = Tensor::cat(&[a.narrow(3, 5, 11).unwrap(), a.narrow(3, 0, 5).unwrap()], 3).unwrap();
    assert!(spectral_error(&rolled, &a).unwrap().iter().all(|e| *e < 1e-9));
}

#[test]
fn temporal_stability_of_a_linear_drift_is_its_rate() {
    // s_t = t * c with c = [1, -2, 3] (mean |c| = 2), dt = 0.5 -> change 4 at every step.
    let v: Vec<f64> = (0..5).flat_map(|t| [1.0, -2.0, 3.0].map(|c| t as f64 * c)).collect();
    let s = t(v, &[5, 1, 1, 3]);
    assert_eq!(v1(&temporal_change(&s, 0.5).unwrap()), [4.0; 4]);
    assert_eq!(temporal_stability(&s, 0.5).unwrap(), 4.0);
    assert!(temporal_stability(&s.narrow(0, 0, 1).unwrap(), 0.5).is_err());
    assert!(temporal_stability(&s, 0.0).is_err());
}

#[test]
fn differentiable_metrics_pass_a_finite_difference_check() {
    let dev = Device::Cpu;
    let a = seed::randn((2, 2, 12, 13), 0.0, 1.0, DType::F64, &dev, 1).unwrap();
    let b = seed::randn((2, 2, 12, 13), 0.0, 1.0, DType::F64, &dev, 2).unwrap();
    let opts = GradCheckOptions::default();
    let cfg = SsimConfig { window: 7, data_range: Some(4.0), ..Default::default() };
    type F = fn(&Tensor, &Tensor) -> pbdl_metrics::Result<Tensor>;
    let cases: [(&str, F); 4] = [("mse", mse), ("mae", mae), ("rel_l2", rel_l2), ("pearson", pearson)];
    for (name, f) in cases {
        let r =
            check_grad(|x| f(&x[0], &x[1]).map_err(candle_core::Error::wrap), &[a.clone(), b.clone()], &opts).unwrap();
        assert!(r.max_rel_error < 1e-7, "{name}: {r:?}");
    }
    let r = check_grad(|x| ssim2d(&x[0], &x[1], &cfg).map_err(candle_core::Error::wrap), &[a, b], &opts).unwrap();
    assert!(r.max_rel_error < 1e-7, "ssim2d: {r:?}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let dev = Device::Cpu;
    let a = Tensor::zeros((1, 1, 4, 4), DType::F32, &dev).unwrap();
    let b = Tensor::zeros((1, 1, 4, 5), DType::F32, &dev).unwrap();
    assert!(matches!(mse(&a, &b), Err(Error::ShapeMismatch { .. })));
    let nan = Tensor::new(&[[[[f32::NAN]]]], &dev).unwrap();
    let one = Tensor::new(&[[[[1f32]]]], &dev).unwrap();
    assert!(matches!(mae(&nan, &one), Err(Error::NonFinite { index: 0, .. })));
    let empty = Tensor::zeros((0, 1, 4), DType::F32, &dev).unwrap();
    assert!(matches!(mse(&empty, &empty), Err(Error::Empty { .. })));
    let ints = Tensor::zeros((1, 1, 4), DType::U8, &dev).unwrap();
    assert!(matches!(mse(&ints, &ints), Err(Error::DType { .. })));
    let flat = Tensor::zeros(4, DType::F32, &dev).unwrap();
    assert!(matches!(rmse(&flat, &flat), Err(Error::Shape { .. })));
    let zero = Tensor::zeros((1, 1, 4), DType::F64, &dev).unwrap();
    assert!(matches!(rel_l2(&zero, &zero), Err(Error::Invalid { .. })));
}
