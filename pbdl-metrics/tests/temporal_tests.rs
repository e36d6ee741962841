//! Temporal metrics (`pbdl_metrics::temporal`): the optical-flow estimator against analytic
//! motions (sub-pixel shift, rotation, identity), its typed errors, and the sequence scores
//! (tOF, tLSiM, per-frame PSNR / SSIM / LSiM).
//!
//! The flow tests build both frames analytically (a smooth function evaluated at moved
//! coordinates, never by interpolation), so the estimator's interpolation is not also the
//! reference's. The tLSiM / LSiM tests need `LSiM.safetensors` (`../shared/weights` or
//! `$PBDL_WEIGHTS_DIR`) and are skipped with a message without it (a failure in CI).

use candle_core::{Device, Tensor};
use pbdl_core::testing::skip_or_fail;
use pbdl_metrics::temporal::{
    lsim_frames, lsim_mean, optical_flow, optical_flow_tensor, psnr, psnr_frames, ssim, ssim_frames, tlsim,
    tlsim_pairs, tof, tof_pairs, Crop, Flow, FlowOptions, TemporalOptions, TemporalScores, TofOptions,
};
use pbdl_metrics::weights::{weights_dir, LSIM_FILE};
use pbdl_metrics::Error;
use pbdl_metrics::Lsim;
use std::sync::OnceLock;

/// A smooth test field: a few sines and Gaussian blobs, all with wavelengths / widths of
/// several pixels, and gradient almost everywhere.
fn field(x: f64, y: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let blob = |cx: f64, cy: f64, s: f64| (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp();
    (tau * x / 17.0 + 0.3).sin() * (tau * y / 13.0 - 0.2).cos()
        + 0.6 * (tau * (0.6 * x + 0.8 * y) / 11.0 + 1.0).sin()
        + 0.8 * blob(20.0, 25.0, 5.0)
        - 0.7 * blob(44.0, 40.0, 6.0)
        + 0.5 * blob(30.0, 50.0, 4.0)
}

/// Frame `ny x nx` of `f` evaluated at `map(x, y)` for each pixel centre `(x, y)` (x = column).
fn frame(ny: usize, nx: usize, map: impl Fn(f64, f64) -> (f64, f64)) -> Vec<f32> {
    let mut out = Vec::with_capacity(ny * nx);
    for y in 0..ny {
        for x in 0..nx {
            let (sx, sy) = map(x as f64, y as f64);
            out.push(field(sx, sy) as f32);
        }
    }
    out
}

fn flow_of(ny: usize, nx: usize, w: impl Fn(f64, f64) -> (f64, f64)) -> Flow {
    let (mut u, mut v) = (Vec::new(), Vec::new());
    for y in 0..ny {
        for x in 0..nx {
            let (a, b) = w(x as f64, y as f64);
            u.push(a as f32);
            v.push(b as f32);
        }
    }
    Flow { ny, nx, u, v }
}

const N: usize = 64;
const BORDER: usize = 8;

/// frame1(x) = f(x - s): content moves by s, so frame1(x + s) = frame0(x) and the flow is s.
fn shift_case(sx: f64, sy: f64) -> (f64, f64, f64) {
    let f0 = frame(N, N, |x, y| (x, y));
    let f1 = frame(N, N, |x, y| (x - sx, y - sy));
    let t = std::time::Instant::now();
    let flow = optical_flow(&f0, &f1, N, N, &FlowOptions::default()).unwrap();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let err = flow.mean_endpoint_error(&flow_of(N, N, |_, _| (sx, sy)), BORDER).unwrap();
    // Also the mean flow itself in the interior.
    let (mut mu, mut mv, mut n) = (0.0, 0.0, 0.0);
    for y in BORDER..N - BORDER {
        for x in BORDER..N - BORDER {
            let (a, b) = flow.at(y, x);
            mu += f64::from(a);
            mv += f64::from(b);
            n += 1.0;
        }
    }
    eprintln!(
        "shift ({sx}, {sy}): mean flow ({:.5}, {:.5}), mean endpoint error {err:.5} px, {ms:.1} ms",
        mu / n,
        mv / n
    );
    (err, (mu / n - sx).abs(), (mv / n - sy).abs())
}

#[test]
fn flow_recovers_an_analytic_subpixel_shift() {
    for (sx, sy) in [(0.3, -0.7), (-0.45, 0.2), (1.6, 0.9)] {
        let (err, eu, ev) = shift_case(sx, sy);
        assert!(err <= 0.05, "shift ({sx}, {sy}): mean endpoint error {err} px > 0.05");
        assert!(eu <= 0.05 && ev <= 0.05, "shift ({sx}, {sy}): mean flow off by ({eu}, {ev})");
    }
}

#[test]
fn flow_recovers_an_analytic_rotation() {
    let theta = 2f64.to_radians();
    let (c, s) = (theta.cos(), theta.sin());
    let centre = (N as f64 - 1.0) / 2.0;
    // frame1(p) = f(R^-1 (p - c) + c): frame0 rotated by +theta about the centre.
    let f0 = frame(N, N, |x, y| (x, y));
    let f1 = frame(N, N, |x, y| {
        let (dx, dy) = (x - centre, y - centre);
        (c * dx + s * dy + centre, -s * dx + c * dy + centre)
    });
    // frame1(x + d) = frame0(x) for d = R (x - c) - (x - c).
    let truth = flow_of(N, N, |x, y| {
        let (dx, dy) = (x - centre, y - centre);
        (c * dx - s * dy - dx, s * dx + c * dy - dy)
    });
    let t = std::time::Instant::now();
    let flow = optical_flow(&f0, &f1, N, N, &FlowOptions::default()).unwrap();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let err = flow.mean_endpoint_error(&truth, BORDER).unwrap();
    let zero = flow_of(N, N, |_, _| (0.0, 0.0));
    let mag = truth.mean_endpoint_error(&zero, BORDER).unwrap();
    eprintln!("rotation 2 deg: mean |d| {mag:.4} px, mean endpoint error {err:.5} px, {ms:.1} ms");
    assert!(mag > 0.5, "the test motion is too small to mean anything ({mag} px)");
    assert!(err <= 0.05, "rotation: mean endpoint error {err} px > 0.05");
}

#[test]
fn flow_of_identical_frames_is_zero() {
    let f0 = frame(N, N, |x, y| (x, y));
    let flow = optical_flow(&f0, &f0, N, N, &FlowOptions::default()).unwrap();
    let max = flow.u.iter().chain(&flow.v).fold(0f32, |m, v| m.max(v.abs()));
    assert!(max < 1e-6, "identical frames gave a flow of up to {max} px");
    // Constant frames: no information, zero flow, no NaN.
    let c = vec![3.0f32; 16 * 16];
    let flow = optical_flow(&c, &c, 16, 16, &FlowOptions::default()).unwrap();
    assert!(flow.u.iter().chain(&flow.v).all(|v| *v == 0.0));
}

#[test]
fn flow_tensor_matches_the_slice_version_and_its_convention() {
    let dev = Device::Cpu;
    let f0 = frame(32, 40, |x, y| (x, y));
    let f1 = frame(32, 40, |x, y| (x - 0.5, y));
    let a = Tensor::from_vec(f0.clone(), (1, 1, 32, 40), &dev).unwrap();
    let b = Tensor::from_vec(f1.clone(), (32, 40), &dev).unwrap().to_dtype(candle_core::DType::F64).unwrap();
    let t = optical_flow_tensor(&a, &b, &FlowOptions::default()).unwrap();
    assert_eq!(t.dims(), &[2, 32, 40]);
    let s = optical_flow(&f0, &f1, 32, 40, &FlowOptions::default()).unwrap();
    let tv = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(&tv[..32 * 40], &s.u[..]);
    assert_eq!(&tv[32 * 40..], &s.v[..]);
    // Content moved right by 0.5: u = +0.5, v = 0 in the middle.
    let (u, v) = s.at(16, 20);
    assert!((u - 0.5).abs() < 0.05 && v.abs() < 0.05, "flow at the centre ({u}, {v})");
}

#[test]
fn flow_bad_input_is_a_typed_error() {
    let o = FlowOptions::default();
    let f = vec![0.5f32; 32 * 32];
    // Length does not match ny * nx, naming the argument.
    let short = vec![0.5f32; 32 * 31];
    match optical_flow(&f, &short, 32, 32, &o) {
        Err(Error::Shape { arg, .. }) => assert_eq!(arg, "frame1"),
        r => panic!("expected a shape error, got {r:?}"),
    }
    // NaN.
    let mut nan = f.clone();
    nan[40] = f32::NAN;
    match optical_flow(&nan, &f, 32, 32, &o) {
        Err(Error::NonFinite { arg, index, .. }) => assert_eq!((arg, index), ("frame0", 40)),
        r => panic!("expected a non-finite error, got {r:?}"),
    }
    // Too small.
    let tiny = vec![0.5f32; 4 * 4];
    assert!(matches!(optical_flow(&tiny, &tiny, 4, 4, &o), Err(Error::Shape { .. })));
    // Options out of range.
    for bad in [
        FlowOptions { alpha: 0.0, ..o },
        FlowOptions { omega: 2.0, ..o },
        FlowOptions { levels: 0, ..o },
        FlowOptions { presmooth: f64::NAN, ..o },
    ] {
        assert!(matches!(optical_flow(&f, &f, 32, 32, &bad), Err(Error::Invalid { .. })), "{bad:?} accepted");
    }
    // Tensors: size mismatch and wrong rank.
    let dev = Device::Cpu;
    let a = Tensor::zeros((32, 32), candle_core::DType::F32, &dev).unwrap();
    let b = Tensor::zeros((32, 30), candle_core::DType::F32, &dev).unwrap();
    assert!(matches!(optical_flow_tensor(&a, &b, &o), Err(Error::ShapeMismatch { .. })));
    let c = Tensor::zeros((2, 32, 32), candle_core::DType::F32, &dev).unwrap();
    assert!(matches!(optical_flow_tensor(&c, &c, &o), Err(Error::Shape { arg: "frame0", .. })));
}

// ------------------------------------------------------------------------------------------
// Sequence scores.

/// A sequence `[t, 1, N, N]` (f32) of the pattern moving by `(vx, vy)` pixels per frame, with the
/// intensity mapped by `gain * f + offset`.
fn moving(frames: usize, vx: f64, vy: f64, gain: f64, offset: f64) -> Tensor {
    let mut data = Vec::new();
    for t in 0..frames {
        let (sx, sy) = (vx * t as f64, vy * t as f64);
        data.extend(frame(N, N, |x, y| (x - sx, y - sy)).iter().map(|&v| (gain * f64::from(v) + offset) as f32));
    }
    Tensor::from_vec(data, (frames, 1, N, N), &Device::Cpu).unwrap()
}

#[test]
fn tof_is_zero_for_the_same_motion_and_the_flow_difference_otherwise() {
    let truth = moving(4, 0.5, 0.0, 1.0, 0.0);
    let opts = TofOptions::default();
    assert_eq!(tof(&truth, &truth, &opts).unwrap(), 0.0);
    // Same motion, other intensities: the flow is invariant to a common affine intensity change.
    let same = moving(4, 0.5, 0.0, 2.0, 3.0);
    let t_same = tof(&same, &truth, &opts).unwrap();
    // Twice the speed: the flows differ by (0.5, 0) px everywhere.
    let fast = moving(4, 1.0, 0.0, 1.0, 0.0);
    let pairs = tof_pairs(&fast, &truth, &opts).unwrap();
    eprintln!("tOF same motion {t_same:.5} px, double speed per pair {pairs:?}");
    assert!(t_same < 0.01, "tOF of the same motion {t_same}");
    assert_eq!(pairs.len(), 3);
    for p in &pairs {
        assert!((p - 0.5).abs() < 0.02, "tOF per pair {p}, expected 0.5");
    }
    // A static output against the moving truth: tOF = |truth flow| = 0.5.
    let still = moving(4, 0.0, 0.0, 1.0, 0.0);
    let t_still = tof(&still, &truth, &TofOptions { crop: Crop::Border(8), ..opts }).unwrap();
    assert!((t_still - 0.5).abs() < 0.02, "tOF of a static output {t_still}");
    // RGB with equal channels is the same as grey (the luma weights sum to 1).
    let rgb = |s: &Tensor| Tensor::cat(&[s, s, s], 1).unwrap();
    let t_rgb = tof(&rgb(&fast), &rgb(&truth), &opts).unwrap();
    let t_grey = pairs.iter().sum::<f64>() / 3.0;
    assert!((t_rgb - t_grey).abs() < 1e-4, "RGB {t_rgb} vs grey {t_grey}");
}

#[test]
fn crop_ranges_follow_tecogan() {
    assert_eq!(Crop::TecoGan.range(64), Some(16..48));
    assert_eq!(Crop::TecoGan.range(128), Some(16..112));
    assert_eq!(Crop::TecoGan.range(100), Some(18..82));
    assert_eq!(Crop::TecoGan.range(40), None);
    assert_eq!(Crop::Border(8).range(64), Some(8..56));
    assert_eq!(Crop::Border(8).range(16), None);
    assert_eq!(Crop::None.range(5), Some(0..5));
}

#[test]
fn sequence_scores_reject_bad_input_with_typed_errors() {
    let dev = Device::Cpu;
    let o = TofOptions::default();
    let seq = moving(3, 0.5, 0.0, 1.0, 0.0);
    // One frame: no pair.
    let one = seq.narrow(0, 0, 1).unwrap();
    assert!(matches!(tof(&one, &one, &o), Err(Error::Shape { arg: "output", .. })));
    // Two channels.
    let two = Tensor::cat(&[&seq, &seq], 1).unwrap();
    assert!(matches!(tof(&two, &two, &o), Err(Error::Shape { .. })));
    // Shape mismatch.
    let other = moving(4, 0.5, 0.0, 1.0, 0.0);
    assert!(matches!(tof(&seq, &other, &o), Err(Error::ShapeMismatch { .. })));
    assert!(matches!(psnr(&seq, &other, Some(1.0)), Err(Error::ShapeMismatch { .. })));
    // Rank 3.
    let r3 = seq.squeeze(1).unwrap();
    assert!(matches!(ssim(&r3, &r3, None), Err(Error::Shape { arg: "output", .. })));
    // NaN in the truth.
    let mut v = seq.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    v[7] = f32::NAN;
    let nan = Tensor::from_vec(v, seq.dims(), &dev).unwrap();
    match tof(&seq, &nan, &o) {
        Err(Error::NonFinite { arg, index, .. }) => assert_eq!((arg, index), ("truth", 7)),
        r => panic!("expected a non-finite error, got {r:?}"),
    }
    // TecoGAN's crop keeps nothing of a 32x32 frame.
    let small = seq.narrow(2, 0, 32).unwrap().narrow(3, 0, 32).unwrap();
    assert!(matches!(tof(&small, &small, &o), Err(Error::Invalid { arg: "crop", .. })));
    assert_eq!(tof(&small, &small, &TofOptions { crop: Crop::Border(4), ..o }).unwrap(), 0.0);
    // Integer input.
    let ints = seq.to_dtype(candle_core::DType::U8).unwrap();
    assert!(matches!(tof(&ints, &ints, &o), Err(Error::DType { .. })));
}

#[test]
fn psnr_per_frame_matches_the_closed_form() {
    let truth = moving(3, 0.5, 0.0, 0.1, 0.5);
    let out = (&truth + 0.1).unwrap();
    // mse = 0.01, R = 1: 10 log10(1 / 0.01) = 20 dB on every frame.
    let p = psnr_frames(&out, &truth, Some(1.0)).unwrap();
    assert_eq!(p.len(), 3);
    for v in &p {
        assert!((v - 20.0).abs() < 1e-4, "PSNR {v}");
    }
    assert!((psnr(&out, &truth, Some(1.0)).unwrap() - 20.0).abs() < 1e-4);
    assert_eq!(psnr(&truth, &truth, Some(1.0)).unwrap(), f64::INFINITY);
}

/// SSIM of one frame pair, written out directly from Wang et al. (2004): Gaussian window of 11
/// taps, sigma 1.5, valid positions, population statistics.
fn ssim_reference(a: &[f64], b: &[f64], ny: usize, nx: usize, range: f64) -> f64 {
    let g: Vec<f64> = (0..11).map(|i| (-((i as f64 - 5.0).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
    let gs: f64 = g.iter().sum();
    let (c1, c2) = ((0.01 * range).powi(2), (0.03 * range).powi(2));
    let (mut total, mut count) = (0.0, 0.0);
    for y0 in 0..=ny - 11 {
        for x0 in 0..=nx - 11 {
            let (mut ma, mut mb, mut aa, mut bb, mut ab) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for j in 0..11 {
                for i in 0..11 {
                    let w = g[j] * g[i] / (gs * gs);
                    let (p, q) = (a[(y0 + j) * nx + x0 + i], b[(y0 + j) * nx + x0 + i]);
                    ma += w * p;
                    mb += w * q;
                    aa += w * p * p;
                    bb += w * q * q;
                    ab += w * p * q;
                }
            }
            let (va, vb, cov) = (aa - ma * ma, bb - mb * mb, ab - ma * mb);
            total += (2.0 * ma * mb + c1) * (2.0 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1.0;
        }
    }
    total / count
}

#[test]
fn ssim_matches_a_direct_evaluation_and_known_values() {
    let dev = Device::Cpu;
    let (ny, nx) = (16, 19);
    let a: Vec<f64> = (0..ny * nx).map(|i| ((i * 7919) % 101) as f64 / 100.0).collect();
    let b: Vec<f64> = a.iter().enumerate().map(|(i, v)| 0.8 * v + 0.1 * ((i as f64) * 0.37).sin()).collect();
    let ta = Tensor::from_vec(a.clone(), (1, 1, ny, nx), &dev).unwrap();
    let tb = Tensor::from_vec(b.clone(), (1, 1, ny, nx), &dev).unwrap();
    let got = ssim(&ta, &tb, Some(1.0)).unwrap();
    let want = ssim_reference(&a, &b, ny, nx, 1.0);
    eprintln!("SSIM {got:.9} vs direct {want:.9}");
    assert!((got - want).abs() < 1e-9, "SSIM {got} vs the direct evaluation {want}");
    assert!(got < 0.99);
    // Identical frames: 1.
    let seq = moving(2, 0.5, 0.0, 1.0, 0.0);
    for v in ssim_frames(&seq, &seq, None).unwrap() {
        assert!((v - 1.0).abs() < 1e-6, "SSIM of identical frames {v}");
    }
    // Constant frames p and q: the contrast term is C2 / C2 = 1, so SSIM = (2pq + C1) / (p^2 + q^2 + C1).
    let (p, q) = (0.5, 0.7);
    let cp = Tensor::full(p, (2, 1, 12, 12), &dev).unwrap();
    let cq = Tensor::full(q, (2, 1, 12, 12), &dev).unwrap();
    let c1 = 0.01f64.powi(2);
    let want = (2.0 * p * q + c1) / (p * p + q * q + c1);
    for v in ssim_frames(&cp, &cq, Some(1.0)).unwrap() {
        assert!((v - want).abs() < 1e-12, "SSIM of constants {v} vs {want}");
    }
}

fn lsim() -> Option<&'static Lsim> {
    static MODEL: OnceLock<Option<Lsim>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let p = weights_dir().map(|d| d.join(LSIM_FILE)).filter(|p| p.exists());
            if p.is_none() {
                skip_or_fail(&format!("{LSIM_FILE} not found (set PBDL_WEIGHTS_DIR or put it in ../shared/weights)"));
            }
            p.map(|p| Lsim::load(p).expect("the LSiM weights load"))
        })
        .as_ref()
}

#[test]
fn tlsim_and_per_frame_lsim() {
    let Some(m) = lsim() else { return };
    let truth = moving(4, 0.7, 0.3, 1.0, 0.0);
    assert_eq!(tlsim(&truth, &truth, m).unwrap(), 0.0);
    assert_eq!(lsim_mean(&truth, &truth, m).unwrap(), 0.0);
    // A static output changes by 0 per step, so tLSiM = 100 * mean_t LSiM(truth_(t-1), truth_t).
    let first = truth.narrow(0, 0, 1).unwrap();
    let still = Tensor::cat(&[&first, &first, &first, &first], 0).unwrap();
    let pairs = tlsim_pairs(&still, &truth, m).unwrap();
    let steps = m.distance(&truth.narrow(0, 0, 3).unwrap(), &truth.narrow(0, 1, 3).unwrap()).unwrap();
    assert_eq!(pairs.len(), 3);
    for (p, d) in pairs.iter().zip(&steps) {
        assert!((p - 100.0 * d).abs() < 1e-9 && *d > 0.0, "tLSiM pair {p} vs 100 * {d}");
    }
    // Per-frame LSiM: frame 0 is exact, later frames are not.
    let per = lsim_frames(&still, &truth, m).unwrap();
    assert_eq!(per[0], 0.0);
    assert!(per[1..].iter().all(|&d| d > 0.0));
    eprintln!("tLSiM pairs of a static output {pairs:?}; per-frame LSiM {per:?}");
}

#[test]
fn temporal_scores_bundle_and_render() {
    let truth = moving(3, 0.5, 0.0, 1.0, 0.0);
    let out = moving(3, 1.0, 0.0, 1.0, 0.05); // frame 0 differs too (PSNR finite)
    let opts = TemporalOptions { data_range: Some(6.0), ..TemporalOptions::default() };
    let s = TemporalScores::compute(&out, &truth, None, &opts).unwrap();
    assert_eq!(s.lsim, None);
    assert_eq!(s.tlsim, None);
    assert!((s.tof - 0.5).abs() < 0.02, "tOF {}", s.tof);
    assert!((s.psnr - psnr(&out, &truth, Some(6.0)).unwrap()).abs() < 1e-12);
    assert!((s.ssim - ssim(&out, &truth, Some(6.0)).unwrap()).abs() < 1e-12);
    let row = s.markdown_row("double speed");
    assert!(row.starts_with("| double speed | ") && row.ends_with(" | - |"), "{row}");
    assert_eq!(
        row.matches('|').count(),
        TemporalScores::markdown_header().lines().next().unwrap().matches('|').count()
    );
    if let Some(m) = lsim() {
        let s = TemporalScores::compute(&out, &truth, Some(m), &opts).unwrap();
        assert!(s.lsim.unwrap() > 0.0 && s.tlsim.unwrap() > 0.0);
        eprintln!("{}\n{}", TemporalScores::markdown_header(), s.markdown_row("double speed"));
    }
}

#[test]
#[ignore = "timing; run with --release -- --ignored --nocapture"]
fn flow_timing() {
    for n in [64usize, 128, 256] {
        let f0: Vec<f32> = frame(n, n, |x, y| (x * 64.0 / n as f64, y * 64.0 / n as f64));
        let f1: Vec<f32> = frame(n, n, |x, y| ((x - 0.8) * 64.0 / n as f64, (y + 0.4) * 64.0 / n as f64));
        let _ = optical_flow(&f0, &f1, n, n, &FlowOptions::default()).unwrap();
        let t = std::time::Instant::now();
        let reps = 5;
        for _ in 0..reps {
            let _ = optical_flow(&f0, &f1, n, n, &FlowOptions::default()).unwrap();
        }
        eprintln!("flow {n}x{n}: {:.1} ms per pair", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    }
}
