//! racecar's one-layer "MNIST" model on procedural digits: the digit renderer (determinism,
//! range, the 20x20 box, distinguishable digits, typed errors), the loss against a hand
//! computation and finite differences, and the SVD alignment experiment on three seeds.

use candle_core::{DType, Device, Tensor};
use pbdl_core::{check_grad, GradCheckOptions};
use pbdl_optim::racecar::digits::{digit_images, render_digit, DigitJitter, DigitStyle, BOX, BOX_START, SIDE};
use pbdl_optim::racecar::mnist::{linear_racecar_loss, mnist_alignment_experiment, MnistConfig, MnistExperiment};
use pbdl_optim::Error;

const ALL: [u8; 10] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9];

fn rows(t: &Tensor) -> Vec<Vec<f64>> {
    t.to_vec2::<f64>().unwrap()
}

/// Same seed, same images; another seed, other images.
#[test]
fn digits_are_deterministic_per_seed() {
    let j = DigitJitter::default();
    let a = rows(&digit_images(&ALL, &j, 7).unwrap());
    let b = rows(&digit_images(&ALL, &j, 7).unwrap());
    let c = rows(&digit_images(&ALL, &j, 8).unwrap());
    assert_eq!(a, b);
    for (x, y) in a.iter().zip(&c) {
        let diff: f64 = x.iter().zip(y).map(|(p, q)| (p - q).abs()).sum();
        assert!(diff > 1.0, "seeds 7 and 8 drew (nearly) the same image: L1 difference {diff}");
    }
}

/// Values in `[0, 1]`, no ink outside the 20x20 box, the ink's longer side is the drawn size
/// (at least 16 of the box's 20 pixels), and the stroke core is fully inked.
#[test]
fn digits_lie_in_unit_range_with_ink_inside_the_box() {
    let j = DigitJitter::default();
    let mut min_peak = f64::INFINITY;
    for seed in 0..10 {
        let imgs = rows(&digit_images(&ALL, &j, seed).unwrap());
        for (d, img) in imgs.iter().enumerate() {
            assert_eq!(img.len(), SIDE * SIDE);
            let (mut lo, mut hi) = ([SIDE; 2], [0usize; 2]);
            for y in 0..SIDE {
                for x in 0..SIDE {
                    let v = img[y * SIDE + x];
                    assert!((0.0..=1.0).contains(&v), "digit {d} seed {seed}: pixel ({y}, {x}) = {v}");
                    let inside = (BOX_START..BOX_START + BOX).contains(&y) && (BOX_START..BOX_START + BOX).contains(&x);
                    if !inside {
                        assert_eq!(v, 0.0, "digit {d} seed {seed}: ink {v} outside the box at ({y}, {x})");
                    }
                    if v > 0.0 {
                        lo = [lo[0].min(y), lo[1].min(x)];
                        hi = [hi[0].max(y), hi[1].max(x)];
                    }
                }
            }
            let extent = (hi[0] - lo[0] + 1).max(hi[1] - lo[1] + 1);
            assert!(extent >= 16, "digit {d} seed {seed}: ink spans only {extent} pixels");
            min_peak = min_peak.min(img.iter().copied().fold(0.0, f64::max));
        }
    }
    println!("smallest peak pixel value over 100 digits: {min_peak:.3}");
    assert!(min_peak > 0.99, "stroke cores not fully inked: peak {min_peak}");
}

/// The ten skeletons are different shapes: jittered digits are classified by the largest
/// normalised correlation with the unjittered templates, and most are classified correctly.
#[test]
fn jittered_digits_match_their_templates() {
    let templates: Vec<Vec<f64>> = ALL.iter().map(|&d| render_digit(d, &DigitStyle::default()).unwrap()).collect();
    let corr = |a: &[f64], b: &[f64]| {
        let dot: f64 = a.iter().zip(b).map(|(p, q)| p * q).sum();
        dot / (a.iter().map(|p| p * p).sum::<f64>() * b.iter().map(|q| q * q).sum::<f64>()).sqrt()
    };
    // Templates differ from each other.
    let mut max_cross = 0.0f64;
    for i in 0..10 {
        for k in i + 1..10 {
            max_cross = max_cross.max(corr(&templates[i], &templates[k]));
        }
    }
    let (mut right, mut total) = (0, 0);
    for seed in 0..20 {
        let imgs = rows(&digit_images(&ALL, &DigitJitter::default(), 100 + seed).unwrap());
        for (d, img) in imgs.iter().enumerate() {
            let best = (0..10).max_by(|&a, &b| corr(img, &templates[a]).total_cmp(&corr(img, &templates[b]))).unwrap();
            right += usize::from(best == d);
            total += 1;
        }
    }
    let acc = right as f64 / total as f64;
    println!("largest correlation between two templates {max_cross:.3}; nearest-template accuracy {acc:.3} of {total}");
    assert!(max_cross < 0.9, "two digit templates correlate {max_cross}");
    assert!(acc > 0.6, "nearest-template accuracy {acc}");
}

/// Bad digits, styles, jitter ranges and experiment settings are typed errors.
#[test]
fn bad_digit_input_is_a_typed_error() {
    let style = DigitStyle::default();
    assert!(matches!(render_digit(10, &style), Err(Error::InvalidConfig { name: "digit", .. })));
    for bad in [
        DigitStyle { thickness: 0.0, ..style },
        DigitStyle { size: 21.0, ..style },
        DigitStyle { shift: [0.5, 1.5], ..style },
        DigitStyle { stretch: f64::NAN, ..style },
    ] {
        assert!(matches!(render_digit(3, &bad), Err(Error::InvalidConfig { .. })), "{bad:?} accepted");
    }
    assert!(matches!(digit_images(&[], &DigitJitter::default(), 0), Err(Error::ShapeMismatch { .. })));
    let inverted = DigitJitter { size: (20.0, 17.0), ..Default::default() };
    assert!(matches!(digit_images(&[1], &inverted, 0), Err(Error::InvalidConfig { .. })));
    let same = MnistConfig { digits: [3, 3], ..Default::default() };
    assert!(matches!(mnist_alignment_experiment(&same), Err(Error::InvalidConfig { .. })));
    let scale = MnistConfig { pixel_scale: 0.0, ..Default::default() };
    assert!(matches!(mnist_alignment_experiment(&scale), Err(Error::InvalidConfig { .. })));
    let x = Tensor::zeros((2, 5), DType::F64, &Device::Cpu).unwrap();
    let oh = Tensor::zeros((2, 3), DType::F64, &Device::Cpu).unwrap();
    let w = Tensor::zeros((4, 3), DType::F64, &Device::Cpu).unwrap();
    let b = Tensor::zeros((1, 3), DType::F64, &Device::Cpu).unwrap();
    assert!(matches!(linear_racecar_loss(&x, &oh, &w, &b, 1.0), Err(Error::ShapeMismatch { .. })));
}

fn small_problem() -> [Tensor; 4] {
    let cpu = Device::Cpu;
    let u =
        |shape: (usize, usize), seed| pbdl_core::seed::rand_uniform(shape, -1.0, 1.0, DType::F64, &cpu, seed).unwrap();
    let onehot = Tensor::new(&[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], &cpu).unwrap();
    [u((2, 5), 1), onehot, u((5, 3), 2), u((1, 3), 3)]
}

/// The loss against plain loops: `CE = -1/n sum log softmax(x w + b)_label`,
/// `rec = 1/2 sum ((x w + b - b) w^T - x)^2`, `total = CE + lambda rec`.
#[test]
fn linear_racecar_loss_matches_a_hand_computation() {
    let [x, oh, w, b] = small_problem();
    let (xv, ohv, wv, bv) = (rows(&x), rows(&oh), rows(&w), rows(&b));
    let (mut ce, mut rec) = (0.0, 0.0);
    for n in 0..2 {
        let logits: Vec<f64> = (0..3).map(|c| (0..5).map(|i| xv[n][i] * wv[i][c]).sum::<f64>() + bv[0][c]).collect();
        let lse = logits.iter().map(|l| l.exp()).sum::<f64>().ln();
        ce -= (0..3).map(|c| ohv[n][c] * (logits[c] - lse)).sum::<f64>() / 2.0;
        for i in 0..5 {
            let back: f64 = (0..3).map(|c| (logits[c] - bv[0][c]) * wv[i][c]).sum();
            rec += 0.5 * (back - xv[n][i]).powi(2);
        }
    }
    let lambda = 0.3;
    let l = linear_racecar_loss(&x, &oh, &w, &b, lambda).unwrap();
    let got = |t: &Tensor| t.to_scalar::<f64>().unwrap();
    assert!((got(&l.task) - ce).abs() < 1e-12, "{} vs {ce}", got(&l.task));
    assert!((got(&l.reconstruction) - rec).abs() < 1e-12, "{} vs {rec}", got(&l.reconstruction));
    assert!((got(&l.total) - (ce + lambda * rec)).abs() < 1e-12);
    let plain = linear_racecar_loss(&x, &oh, &w, &b, 0.0).unwrap();
    assert!((got(&plain.total) - ce).abs() < 1e-12);
}

/// candle's gradient of the loss (in `x`, `w`, `b`) against central differences, in `f64`.
#[test]
fn linear_racecar_loss_gradient_matches_finite_differences() {
    let [x, oh, w, b] = small_problem();
    let f = |t: &[Tensor]| -> candle_core::Result<Tensor> {
        let l =
            linear_racecar_loss(&t[0], &oh, &t[1], &t[2], 0.3).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        Ok(l.total)
    };
    let r = check_grad(f, &[x, w, b], &GradCheckOptions::default()).unwrap();
    println!("linear racecar loss FD check: max rel error {:.2e}, per input {:?}", r.max_rel_error, r.per_input);
    r.ensure(1e-6).unwrap();
}

fn fmt(v: &[f64]) -> String {
    v.iter().map(|c| format!("{c:.3}")).collect::<Vec<_>>().join(", ")
}

fn run(cfg: &MnistConfig) -> MnistExperiment {
    let e = mnist_alignment_experiment(cfg).unwrap();
    for (name, r) in [("racecar", &e.racecar), ("plain", &e.plain)] {
        println!(
            "seed {} init x{} {name:8}: |cos| all [{}], singular values [{}], CE {:.2e}, acc {}, rec {:.3e}, {:.2} s",
            cfg.seed,
            cfg.init_scale,
            fmt(&r.cos_all),
            fmt(&r.singular_values),
            r.task_loss,
            r.accuracy,
            r.reconstruction,
            r.seconds
        );
        assert_eq!(r.span_dim, 2);
        assert_eq!(r.accuracy, 1.0, "{name} did not fit its two images");
    }
    e
}

/// The experiment with the official settings (Glorot init, lambda 1e-5, Adam 1e-4, 1000 steps,
/// pixels 0..255, digits 0 and 1), seeds 0, 1, 2. racecar: two singular vectors lie in the span
/// of the two training images (`|cos| > 0.9`) with singular value 1 (`W W^T` is the identity
/// there); the plain model has no singular vector with `|cos| > 0.9`. The claim that
/// these are the *leading* singular vectors does not hold with this init: the other singular
/// values stay near the init's 1.4, so the span directions are the two trailing ones, and the
/// leading two have `|cos| < 0.9`. This asserts what is measured; see the next test for the init
/// under which the claim holds.
#[test]
fn racecar_mnist_span_directions_with_official_settings() {
    for seed in 0..3 {
        let cfg = MnistConfig { seed, ..Default::default() };
        let e = run(&cfg);
        let best = e.racecar.best_aligned(2);
        println!(
            "seed {seed}: racecar leading |cos| [{}], plain leading |cos| [{}]",
            fmt(&e.racecar.cos),
            fmt(&e.plain.cos)
        );
        for &(i, c) in &best {
            let s = e.racecar.singular_values[i];
            assert!(c > 0.9, "seed {seed}: racecar singular vector {i} has |cos| {c}");
            assert!((s - 1.0).abs() < 0.05, "seed {seed}: span direction {i} has singular value {s}, not ~1");
        }
        let plain_best = e.plain.best_aligned(1)[0].1;
        assert!(plain_best < 0.9, "seed {seed}: a plain singular vector has |cos| {plain_best}");
        // The claim on the *leading* vectors fails here (documented above).
        assert!(e.racecar.max_cos() < 0.9, "seed {seed}: leading racecar |cos| {:?} now above 0.9", e.racecar.cos);
    }
}

/// The same with the initial weights at half the Glorot scale (singular values about 0.7 < 1):
/// now racecar's two *leading* singular vectors have `|cos| > 0.9` with the span and the plain
/// model's do not. Not the official init; it checks the explanation of the test above.
#[test]
fn racecar_mnist_leading_vectors_align_when_init_singular_values_are_below_one() {
    for seed in 0..3 {
        let cfg = MnistConfig { seed, init_scale: 0.5, ..Default::default() };
        let e = run(&cfg);
        println!(
            "seed {seed}: racecar leading |cos| [{}], plain leading |cos| [{}]",
            fmt(&e.racecar.cos),
            fmt(&e.plain.cos)
        );
        assert!(e.racecar.min_cos() > 0.9, "seed {seed}: racecar leading |cos| {:?}", e.racecar.cos);
        assert!(e.plain.max_cos() < 0.9, "seed {seed}: plain leading |cos| {:?}", e.plain.cos);
    }
}
