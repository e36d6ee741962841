//! racecar with batch norm and conv nets: the reverse pass against a hand computation, the
//! conv reverse pass as the adjoint of the conv, finite-difference gradients of the
//! reconstruction losses, the power iteration of the orthogonality baseline, and the SVD
//! alignment experiment on peak images.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, GradCheckOptions};
use pbdl_optim::racecar::batch_norm::{BatchNorm, ReverseStats};
use pbdl_optim::racecar::bn_mlp::BnMlp;
use pbdl_optim::racecar::conv_net::{conv_reverse, BnConvNet, ConvSpec};
use pbdl_optim::racecar::ortho::PowerIteration;
use pbdl_optim::racecar::peak::peak_images;
use pbdl_optim::racecar::peak_experiment::{peak_alignment_experiment, PeakConfig, PeakNet, Regularizer};
use pbdl_optim::racecar::svd::{principal_alignment, Subspace};

type M = Vec<Vec<f64>>;

fn t2(m: &M) -> Tensor {
    Tensor::new(m.clone(), &Device::Cpu).unwrap()
}

fn t1(v: &[f64]) -> Tensor {
    Tensor::new(v, &Device::Cpu).unwrap()
}

fn matmul(a: &M, b: &M) -> M {
    (0..a.len()).map(|i| (0..b[0].len()).map(|j| (0..b.len()).map(|k| a[i][k] * b[k][j]).sum()).collect()).collect()
}

fn transpose(a: &M) -> M {
    (0..a[0].len()).map(|j| (0..a.len()).map(|i| a[i][j]).collect()).collect()
}

/// Per-column batch mean and biased variance.
fn col_stats(a: &M) -> (Vec<f64>, Vec<f64>) {
    let n = a.len() as f64;
    let mean: Vec<f64> = (0..a[0].len()).map(|j| a.iter().map(|r| r[j]).sum::<f64>() / n).collect();
    let var = (0..a[0].len()).map(|j| a.iter().map(|r| (r[j] - mean[j]).powi(2)).sum::<f64>() / n).collect();
    (mean, var)
}

/// `ReLU(gamma (a - mean) / sqrt(var + 1e-3) + beta)` per column.
fn bn_relu(a: &M, stats: &(Vec<f64>, Vec<f64>), gamma: &[f64], beta: &[f64]) -> M {
    a.iter()
        .map(|r| {
            r.iter()
                .enumerate()
                .map(|(j, v)| (gamma[j] * (v - stats.0[j]) / (stats.1[j] + 1e-3).sqrt() + beta[j]).max(0.0))
                .collect()
        })
        .collect()
}

fn sub_row(a: &M, b: &[f64]) -> M {
    a.iter().map(|r| r.iter().zip(b).map(|(x, y)| x - y).collect()).collect()
}

fn add_row(a: &M, b: &[f64]) -> M {
    a.iter().map(|r| r.iter().zip(b).map(|(x, y)| x + y).collect()).collect()
}

fn half_sq(a: &M, b: &M) -> f64 {
    a.iter().flatten().zip(b.iter().flatten()).map(|(x, y)| 0.5 * (x - y).powi(2)).sum()
}

/// Tiny `3 -> 2 -> 2` BN + ReLU net, batch 3: the reverse pass and loss against a hand
/// computation with plain loops, for both choices of the reverse batch statistics.
#[test]
fn bn_reverse_pass_matches_hand_computation() {
    let x: M = vec![vec![0.3, -1.2, 0.8], vec![1.1, 0.4, -0.5], vec![-0.7, 0.9, 0.2]];
    let w0: M = vec![vec![0.5, -0.3], vec![0.2, 0.7], vec![-0.6, 0.4]];
    let w1: M = vec![vec![0.9, -0.4], vec![0.3, 0.8]];
    let (b0, b1) = ([0.1, -0.2], [0.05, 0.3]);
    let (g0, be0, g1, be1) = ([1.3, 0.7], [0.9, 0.8], [0.8, 1.1], [0.5, 0.3]);
    let bn = |g: &[f64], b: &[f64]| BatchNorm::from_tensors(t1(g), t1(b), 1e-3);
    let net = BnMlp::from_tensors(vec![t2(&w0), t2(&w1)], vec![t1(&b0), t1(&b1)], vec![bn(&g0, &be0), bn(&g1, &be1)])
        .unwrap();
    // Forward by hand.
    let z1 = add_row(&matmul(&x, &w0), &b0);
    let s1 = col_stats(&z1);
    let d1 = bn_relu(&z1, &s1, &g0, &be0);
    let z2 = add_row(&matmul(&d1, &w1), &b1);
    let d2 = bn_relu(&z2, &col_stats(&z2), &g1, &be1);
    let pass = net.forward(&t2(&x)).unwrap();
    for mode in [ReverseStats::Own, ReverseStats::Forward] {
        let back1 = matmul(&sub_row(&d2, &b1), &transpose(&w1));
        let stats = if mode == ReverseStats::Own { col_stats(&back1) } else { s1.clone() };
        let r1 = bn_relu(&back1, &stats, &g0, &be0);
        let r0 = matmul(&sub_row(&r1, &b0), &transpose(&w0));
        let expect = (half_sq(&r0, &x) + half_sq(&r1, &d1)) / 3.0;
        let rec = net.reverse(&pass, mode).unwrap();
        let got0 = rec[0].to_vec2::<f64>().unwrap();
        let got1 = rec[1].to_vec2::<f64>().unwrap();
        let err = half_sq(&got0, &r0).max(half_sq(&got1, &r1)).sqrt();
        assert!(err < 1e-13, "{mode:?}: reverse pass off by {err}");
        // Some ReLUs must be active or the comparison is vacuous.
        assert!(r1.iter().flatten().filter(|v| **v > 0.0).count() >= 3, "{r1:?}");
        let loss = net.reconstruction_loss(&pass, mode).unwrap().to_scalar::<f64>().unwrap();
        assert!((loss - expect).abs() < 1e-13 * expect, "{mode:?}: {loss} vs {expect}");
    }
}

fn randn(shape: &[usize], seed: u64) -> Tensor {
    pbdl_core::seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, seed).unwrap()
}

fn dot(a: &Tensor, b: &Tensor) -> f64 {
    (a * b).unwrap().sum_all().unwrap().to_scalar::<f64>().unwrap()
}

/// `<conv(x, w), y> = <x, conv_reverse(y, w)>`: the reverse pass of a conv layer is its adjoint,
/// for non-overlapping patches and for an overlapping, padded, strided conv with output padding.
#[test]
fn conv_reverse_is_the_adjoint_of_the_conv() {
    for spec in [
        ConvSpec { side: 28, channels: 8, kernel: 4, stride: 4, padding: 0, outputs: 2 },
        ConvSpec { side: 8, channels: 3, kernel: 3, stride: 2, padding: 1, outputs: 2 },
    ] {
        let h = spec.out_side().unwrap();
        let x = randn(&[2, 1, spec.side, spec.side], 1);
        let w = randn(&[spec.channels, 1, spec.kernel, spec.kernel], 2);
        let y = randn(&[2, spec.channels, h, h], 3);
        let zero = Tensor::zeros(spec.channels, DType::F64, &Device::Cpu).unwrap();
        let cx = pbdl_core::conv::conv2d(&x, &w, None, &spec.params()).unwrap();
        let cty = conv_reverse(&y, &w, &zero, &spec).unwrap();
        assert_eq!(cty.dims(), x.dims());
        let (l, r) = (dot(&cx, &y), dot(&x, &cty));
        assert!((l - r).abs() < 1e-12 * l.abs().max(1.0), "{spec:?}: {l} vs {r}");
    }
}

/// Finite differences of the conv net's reconstruction loss (both reverse statistics) with
/// respect to the input and every parameter.
#[test]
fn conv_reconstruction_loss_gradient_matches_finite_differences() {
    let spec = ConvSpec { side: 8, channels: 3, kernel: 3, stride: 2, padding: 1, outputs: 2 };
    let h = spec.out_side().unwrap();
    let inputs = vec![
        randn(&[4, 64], 1),
        (randn(&[3, 1, 3, 3], 2) * 0.5).unwrap(),
        (randn(&[3], 3) * 0.1).unwrap(),
        (randn(&[3 * h * h, 2], 4) * 0.3).unwrap(),
        (randn(&[2], 5) * 0.1).unwrap(),
        randn(&[3], 6).affine(0.2, 1.0).unwrap(),
        randn(&[3], 7).affine(0.2, 0.3).unwrap(),
        randn(&[2], 8).affine(0.2, 1.0).unwrap(),
        randn(&[2], 9).affine(0.2, 0.3).unwrap(),
    ];
    for mode in [ReverseStats::Own, ReverseStats::Forward] {
        let f = |t: &[Tensor]| -> candle_core::Result<Tensor> {
            let bn1 = BatchNorm::from_tensors(t[5].clone(), t[6].clone(), 1e-3);
            let bn2 = BatchNorm::from_tensors(t[7].clone(), t[8].clone(), 1e-3);
            let net =
                BnConvNet::from_tensors(spec, (t[1].clone(), t[2].clone(), bn1), (t[3].clone(), t[4].clone(), bn2))
                    .map_err(|e| candle_core::Error::Msg(e.to_string()))?;
            let pass = net.forward(&t[0]).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
            net.reconstruction_loss(&pass, mode).map_err(|e| candle_core::Error::Msg(e.to_string()))
        };
        let r = check_grad(f, &inputs, &GradCheckOptions { max_probes: 24, ..Default::default() }).unwrap();
        println!(
            "conv reconstruction FD check {mode:?}: max rel error {:.2e}, per input {:?}",
            r.max_rel_error, r.per_input
        );
        r.ensure(1e-6).unwrap();
    }
}

/// The same for the dense BN + ReLU net. With the reverse pass's own statistics the loss does
/// not depend on the last bias at all (`(d_2 - b_2) W^T` shifts each column by a constant that
/// the batch norm removes): checked directly, and that bias is left out of the FD check there.
#[test]
fn bn_mlp_reconstruction_loss_gradient_matches_finite_differences() {
    let inputs = vec![
        randn(&[5, 6], 1),
        (randn(&[6, 4], 2) * 0.5).unwrap(),
        (randn(&[4, 3], 3) * 0.5).unwrap(),
        (randn(&[4], 4) * 0.1).unwrap(),
        randn(&[4], 6).affine(0.2, 1.0).unwrap(),
        randn(&[4], 7).affine(0.2, 0.3).unwrap(),
        randn(&[3], 8).affine(0.2, 1.0).unwrap(),
        randn(&[3], 9).affine(0.2, 0.3).unwrap(),
        (randn(&[3], 5) * 0.1).unwrap(),
    ];
    let loss = |t: &[Tensor], b2: &Tensor, mode| -> candle_core::Result<Tensor> {
        let norms = vec![
            BatchNorm::from_tensors(t[4].clone(), t[5].clone(), 1e-3),
            BatchNorm::from_tensors(t[6].clone(), t[7].clone(), 1e-3),
        ];
        let net = BnMlp::from_tensors(vec![t[1].clone(), t[2].clone()], vec![t[3].clone(), b2.clone()], norms)
            .map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        let pass = net.forward(&t[0]).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        net.reconstruction_loss(&pass, mode).map_err(|e| candle_core::Error::Msg(e.to_string()))
    };
    let b2 = inputs[8].clone();
    let own = |b: &Tensor| loss(&inputs, b, ReverseStats::Own).unwrap().to_scalar::<f64>().unwrap();
    let (l0, l1) = (own(&b2), own(&(&b2 + 1.0).unwrap()));
    assert!((l0 - l1).abs() < 1e-12 * l0, "{l0} vs {l1}");
    let r = check_grad(|t| loss(t, &b2, ReverseStats::Own), &inputs[..8], &GradCheckOptions::default()).unwrap();
    println!("BN-MLP reconstruction FD check Own: max rel error {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
    let r = check_grad(|t| loss(t, &t[8], ReverseStats::Forward), &inputs, &GradCheckOptions::default()).unwrap();
    println!("BN-MLP reconstruction FD check Forward: max rel error {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
}

/// Power iteration on `W^T W - I` converges to its largest singular value: a diagonal case
/// (`W^T W = diag(4, 0.25, 1.5625)`, `M = diag(3, -0.75, 0.5625)`, `sigma_max = 3`) and one
/// whose largest-magnitude eigenvalue is negative (`diag(0.01, 0.64)` -> `|-0.99|`).
#[test]
fn power_iteration_converges_to_sigma_max() {
    let cases: [(M, f64); 2] = [
        (vec![vec![2.0, 0.0, 0.0], vec![0.0, 0.5, 0.0], vec![0.0, 0.0, 1.25], vec![0.0, 0.0, 0.0]], 3.0),
        (vec![vec![0.1, 0.0], vec![0.0, 0.8]], 0.99),
    ];
    for (w, want) in cases {
        let w = t2(&w);
        let mut p = PowerIteration::new(w.dim(1).unwrap(), 3).unwrap();
        let mut sigma = 0.0;
        for _ in 0..60 {
            sigma = p.sigma(&w).unwrap().to_scalar::<f64>().unwrap();
        }
        assert!((sigma.abs() - want).abs() < 1e-10, "{sigma} vs {want}");
    }
    // A random 20x6 matrix: the estimate approaches sigma_max of M from faer's SVD.
    let w = randn(&[20, 6], 4);
    let m = (w.t().unwrap().matmul(&w).unwrap() - Tensor::eye(6, DType::F64, &Device::Cpu).unwrap()).unwrap();
    let mv = m.to_vec2::<f64>().unwrap();
    let svd = faer::Mat::from_fn(6, 6, |i, j| mv[i][j]).thin_svd().unwrap();
    let want = svd.S().column_vector()[0];
    let mut p = PowerIteration::new(6, 5).unwrap();
    let mut sigma = 0.0;
    for _ in 0..200 {
        sigma = p.sigma(&w).unwrap().to_scalar::<f64>().unwrap();
    }
    assert!((sigma.abs() - want).abs() < 1e-9 * want, "{sigma} vs {want}");
}

/// Principal subspaces of a known data set: rows along e_0 (scale 10) and e_1 (scale 1).
#[test]
fn principal_alignment_picks_the_leading_directions() {
    let data = t2(&vec![vec![10.0, 0.0, 0.0], vec![0.0, 1.0, 0.0], vec![-10.0, 0.0, 0.0]]);
    // W's leading left singular vector is e_1 (sigma 3), then e_0 (sigma 2).
    let w = t2(&vec![vec![2.0, 0.0], vec![0.0, 3.0], vec![0.0, 0.0]]);
    let (c, r) = principal_alignment(&w, &data, 2, Subspace::Rank(1)).unwrap();
    assert_eq!(r, 1);
    assert!(c[0].abs() < 1e-6 && (c[1] - 1.0).abs() < 1e-6, "{c:?}");
    let (c, r) = principal_alignment(&w, &data, 2, Subspace::Span).unwrap();
    assert_eq!(r, 2);
    assert!((c[0] - 1.0).abs() < 1e-12 && (c[1] - 1.0).abs() < 1e-12, "{c:?}");
    // 200 of 201 energy lies along e_0.
    let (_, r) = principal_alignment(&w, &data, 2, Subspace::Energy(0.99)).unwrap();
    assert_eq!(r, 1);
    assert!(principal_alignment(&w, &data, 2, Subspace::Energy(1.5)).is_err());
}

/// Peak images: values in [0, 255], class sizes, reproducible, and a class-1 image holds about
/// twice the mass of a class-0 image (mean of the Gaussian integrals `255 2 pi w^2`,
/// `E[w^2] = 7.58` for `w ~ U[1.5, 3.5]`: 12.1e3 per peak, less where peaks overlap or clip).
#[test]
fn peak_images_have_one_or_two_peaks() {
    let (x, y) = peak_images(50, 28, DType::F64, 7).unwrap();
    assert_eq!(x.dims(), &[100, 784]);
    let v = x.to_vec2::<f64>().unwrap();
    assert!(v.iter().flatten().all(|p| (0.0..=255.0).contains(p)));
    assert_eq!(y.to_vec1::<u32>().unwrap().iter().filter(|c| **c == 1).count(), 50);
    let mass = |rows: &[Vec<f64>]| rows.iter().map(|r| r.iter().sum::<f64>()).sum::<f64>() / rows.len() as f64;
    let (m0, m1) = (mass(&v[..50]), mass(&v[50..]));
    let per_peak = 255.0 * 2.0 * std::f64::consts::PI * (3.5f64.powi(3) - 1.5f64.powi(3)) / 3.0 / 2.0;
    println!("peak mass: class 0 {m0:.0}, class 1 {m1:.0}, one peak expected {per_peak:.0}");
    assert!((m0 / per_peak - 1.0).abs() < 0.15, "{m0} vs {per_peak}");
    assert!(m1 / m0 > 1.6 && m1 / m0 < 2.1, "{m1} / {m0}");
    let (x2, _) = peak_images(50, 28, DType::F64, 7).unwrap();
    assert_eq!(x2.to_vec2::<f64>().unwrap(), v);
}

fn print_runs(runs: &[pbdl_optim::racecar::peak_experiment::PeakRun]) {
    for r in runs {
        println!(
            "{:?} {:>13}: |cos| {:?} (subspace {} of {}), CE {:.4}, acc {:.2}, recon {:.4e}, {:.1} s",
            r.net,
            r.regularizer.name(),
            r.cos.iter().map(|c| format!("{c:.3}")).collect::<Vec<_>>(),
            r.subspace_dim,
            r.ambient_dim,
            r.task_loss,
            r.accuracy,
            r.reconstruction,
            r.seconds
        );
    }
}

fn check_alignment(net: PeakNet) {
    let cfg = PeakConfig::default();
    let regs = [Regularizer::Plain, Regularizer::Orthogonality, Regularizer::Racecar];
    let runs = peak_alignment_experiment(&cfg, &[net], &regs).unwrap();
    print_runs(&runs);
    for r in &runs {
        println!(
            "ACCEPTANCE: racecar_peak_{:?}_{} measured=min |cos| {:.3} bar=> 0.9 for racecar, < 0.9 for the baselines",
            r.net,
            r.regularizer.name(),
            r.min_cos()
        );
        match r.regularizer {
            Regularizer::Racecar => assert!(r.min_cos() > 0.9, "{r:?}"),
            _ => assert!(r.min_cos() < 0.9, "{r:?}"),
        }
    }
}

/// The paper's peak experiment (BN + ReLU `784 -> 128 -> 2`, 5000 full-batch Adam steps): the
/// first layer's 4 leading singular vectors lie in the span of the 100 training images
/// (|cos| > 0.9) after racecar training; after plain or orthogonality training they do not
/// (a random direction has |cos| ~ sqrt(100/784) = 0.36). Measured (2-core machine under load
/// ~7, 2026-11-21, 10 min): racecar 1.000 0.994 0.995 0.990, plain 0.32 0.31 0.39 0.38,
/// orthogonality 0.43 0.42 0.40 0.41; seed 1: racecar 1.000 0.996 0.985 0.983, plain 0.34 0.40
/// 0.33 0.34, orthogonality 0.41 0.40 0.41 0.41.
#[test]
#[ignore = "trains 3 nets for 5000 steps: ~10 min on the loaded 2-core machine"]
fn peak_mlp_racecar_aligns_and_baselines_do_not() {
    check_alignment(PeakNet::Mlp);
}

/// The same for the conv net (8 filters 4x4, stride 4), unfolded filters `[16, 8]` against the 8
/// leading principal directions of the image patches (random: |cos| ~ sqrt(8/16) = 0.71).
/// FAILS as measured (2026-11-21, 4 min): racecar 0.999 0.820 0.802 0.813 (only the leading
/// vector aligns), plain 0.84 0.84 0.68 0.66, orthogonality 0.82 0.78 0.58 0.65; seed 1:
/// racecar 0.999 0.55 0.72 0.73, plain 0.53 0.76 0.61 0.77; seed 0 with 15000 steps: racecar
/// 1.000 0.82 0.82 0.85 (reconstruction loss 1.02e6 -> 5.8e5, still falling). Kept as the open
/// acceptance check.
#[test]
#[ignore = "FAILS (racecar conv: only the leading singular vector aligns, see the doc); trains 3 nets, ~4 min"]
fn peak_conv_racecar_aligns_and_baselines_do_not() {
    check_alignment(PeakNet::Conv);
}

/// Once the power iteration has converged, the gradient of `sigma` with the vectors held
/// constant equals the full derivative (finite differences recompute the vectors): `u`, `v`
/// are unit vectors with `M v = sigma u`, so their first-order change does not move `sigma`.
#[test]
fn orthogonality_penalty_gradient_matches_finite_differences() {
    let w = randn(&[12, 5], 11);
    let mut p = PowerIteration::new(5, 12).unwrap();
    for _ in 0..300 {
        p.sigma(&w).unwrap();
    }
    let f = |t: &[Tensor]| p.clone().penalty(&t[0], 0.1);
    let r = check_grad(f, &[w], &GradCheckOptions::default()).unwrap();
    println!("orthogonality penalty FD check: max rel error {:.2e}", r.max_rel_error);
    r.ensure(1e-6).unwrap();
}

/// Bad sizes are typed errors, not panics.
#[test]
fn bad_sizes_are_errors() {
    assert!(peak_images(10, 3, DType::F64, 0).is_err());
    assert!(peak_images(0, 28, DType::F64, 0).is_err());
    let bad = ConvSpec { side: 4, channels: 2, kernel: 7, stride: 1, padding: 0, outputs: 2 };
    assert!(BnConvNet::new(bad, DType::F64, 0).is_err());
    assert!(BnMlp::new(&[4], DType::F64, 0).is_err());
}
