//! LSiM against the published example, its metric properties, gradients and bad input.
//!
//! Tests that need the weights or the example images read `../shared/` beside the checkout (or
//! `$PBDL_WEIGHTS_DIR` for the weights) and are skipped with a message when they are absent (and fail in CI, see `pbdl_core::testing`).

use candle_core::{DType, Device, Tensor};
use pbdl_core::testing::skip_or_fail;
use pbdl_core::{check_grad, seed, GradCheckOptions};
use pbdl_metrics::lsim::{hwc_to_nchw, MIN_NATIVE_SIDE};
use pbdl_metrics::{Error, Lsim, LsimOptions, LsimSize, NormScope};
use std::path::PathBuf;
use std::sync::OnceLock;

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}

fn weights_path() -> PathBuf {
    match std::env::var_os(pbdl_metrics::weights::WEIGHTS_DIR_ENV) {
        Some(d) => PathBuf::from(d).join(pbdl_metrics::weights::LSIM_FILE),
        None => shared().join("weights").join(pbdl_metrics::weights::LSIM_FILE),
    }
}

/// The model, loaded once per test binary; `None` (with a message) when the weights are absent.
fn lsim() -> Option<&'static Lsim> {
    static MODEL: OnceLock<Option<Lsim>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let p = weights_path();
            if !p.exists() {
                skip_or_fail(&format!("LSiM weights not found at {} (set PBDL_WEIGHTS_DIR)", p.display()));
                return None;
            }
            Some(Lsim::load(&p).expect("the shared LSiM weights load"))
        })
        .as_ref()
}

fn example() -> Option<[Tensor; 3]> {
    let dir = shared().join("data/lsim-example");
    if !dir.is_dir() {
        skip_or_fail(&format!("{} not found", dir.display()));
        return None;
    }
    let read = |n: &str| {
        hwc_to_nchw(&pbdl_core::io::read_npy(dir.join(format!("lsim_example_plume{n}.npy"))).unwrap()).unwrap()
    };
    Some([read("Reference"), read("A"), read("B")])
}

fn field(seed_: u64, shape: (usize, usize, usize, usize)) -> Tensor {
    seed::rand_uniform(shape, -1.0, 3.0, DType::F32, &Device::Cpu, seed_).unwrap()
}

#[test]
fn reproduces_the_published_plume_distances() {
    let (Some(lsim), Some([r, a, b])) = (lsim(), example()) else { return };
    assert_eq!(r.dtype(), DType::U8);
    let da = lsim.distance(&r, &a).unwrap()[0];
    let db = lsim.distance(&r, &b).unwrap()[0];
    eprintln!(
        "LSiM d(reference, plumeA) = {da:.6} (published 0.3791), d(reference, plumeB) = {db:.6} (published 0.4433)"
    );
    // The published values are printed with 4 decimals ("%0.4f").
    assert!((da - 0.3791).abs() <= 5e-5, "d(ref, A) = {da}");
    assert!((db - 0.4433).abs() <= 5e-5, "d(ref, B) = {db}");
    // Both pairs in one batched call: per-pair normalisation gives the same distances.
    let batched = lsim.distance(&Tensor::cat(&[&r, &r], 0).unwrap(), &Tensor::cat(&[&a, &b], 0).unwrap()).unwrap();
    assert!((batched[0] - da).abs() < 1e-6 && (batched[1] - db).abs() < 1e-6, "{batched:?}");
    // u8 input and its f32 conversion give the same distance.
    let af = lsim.distance(&r.to_dtype(DType::F32).unwrap(), &a.to_dtype(DType::F32).unwrap()).unwrap()[0];
    assert_eq!(af, da);
}

#[test]
fn metric_properties_hold() {
    let Some(lsim) = lsim() else { return };
    let a = field(1, (2, 1, 96, 80));
    let b = field(2, (2, 1, 96, 80));
    for size in [LsimSize::Resize224, LsimSize::Native] {
        let o = LsimOptions { size, ..Default::default() };
        let d = |x: &Tensor, y: &Tensor| -> Vec<f64> {
            lsim.distance_with(x, y, &o).unwrap().to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
        };
        let dab = d(&a, &b);
        assert_eq!(d(&a, &a), [0.0, 0.0], "{size:?}: d(a, a) = 0 exactly");
        assert_eq!(d(&b, &a), dab, "{size:?}: symmetric exactly");
        assert!(dab.iter().all(|&v| v > 0.0 && v.is_finite()), "{size:?}: {dab:?}");
        // A common positive scale and offset changes nothing (beyond f32 rounding of the inputs).
        let t = |x: &Tensor| ((x * 3.5).unwrap() + 100.0).unwrap();
        let scaled = d(&t(&a), &t(&b));
        for (s, v) in scaled.iter().zip(&dab) {
            assert!((s - v).abs() < 1e-4 * v, "{size:?}: {s} vs {v}");
        }
    }
}

#[test]
fn batch_normalisation_modes_differ_only_in_batches() {
    let Some(lsim) = lsim() else { return };
    let a = field(3, (1, 1, 64, 64));
    let b = field(4, (1, 1, 64, 64));
    // A second pair with a 10x larger range.
    let c = (field(5, (1, 1, 64, 64)) * 10.0).unwrap();
    let e = (field(6, (1, 1, 64, 64)) * 10.0).unwrap();
    let joint = LsimOptions { norm: NormScope::JointBatch, ..Default::default() };
    let single = lsim.distance(&a, &b).unwrap()[0];
    let single_joint = lsim.distance_with(&a, &b, &joint).unwrap().to_vec1::<f32>().unwrap()[0] as f64;
    assert_eq!(single, single_joint, "one pair: both modes agree");
    let (x, y) = (Tensor::cat(&[&a, &c], 0).unwrap(), Tensor::cat(&[&b, &e], 0).unwrap());
    let per_pair = lsim.distance(&x, &y).unwrap();
    let official = lsim.distance_with(&x, &y, &joint).unwrap().to_vec1::<f32>().unwrap();
    assert!((per_pair[0] - single).abs() < 1e-6, "per pair: batching does not change a pair");
    assert!(
        (official[0] as f64 - single).abs() > 1e-3,
        "joint: the other pair changes it ({} vs {single})",
        official[0]
    );
}

#[test]
fn one_channel_is_three_equal_channels_and_224_native_is_the_default_path() {
    let Some(lsim) = lsim() else { return };
    let a = field(7, (1, 1, 224, 224));
    let b = field(8, (1, 1, 224, 224));
    let d1 = lsim.distance(&a, &b).unwrap();
    let d3 = lsim.distance(&a.repeat((1, 3, 1, 1)).unwrap(), &b.repeat((1, 3, 1, 1)).unwrap()).unwrap();
    assert_eq!(d1, d3);
    let native = LsimOptions { size: LsimSize::Native, ..Default::default() };
    let dn = lsim.distance_with(&a, &b, &native).unwrap().to_vec1::<f32>().unwrap()[0] as f64;
    assert_eq!(dn, d1[0]);
}

#[test]
fn gradient_flows_through_the_network_to_the_inputs() {
    let Some(lsim) = lsim() else { return };
    let lsim64 = lsim.to_dtype(DType::F64).unwrap();
    let native = LsimOptions { size: LsimSize::Native, ..Default::default() };
    let a = seed::rand_uniform((1, 1, 48, 48), 0.0, 1.0, DType::F64, &Device::Cpu, 9).unwrap();
    let b = seed::rand_uniform((1, 1, 48, 48), 0.0, 1.0, DType::F64, &Device::Cpu, 10).unwrap();
    let opts = GradCheckOptions { eps: 1e-6, max_probes: 24, seed: 0 };
    let f = |x: &[Tensor]| lsim64.distance_with(&x[0], &x[1], &native).map_err(candle_core::Error::wrap);
    let r = check_grad(f, &[a, b], &opts).unwrap();
    eprintln!("LSiM native 48x48 f64 gradient check: max rel error {:.2e}", r.max_rel_error);
    assert!(r.max_rel_error < 1e-5, "{r:?}");
}

#[test]
fn bad_input_is_a_typed_error() {
    let Some(lsim) = lsim() else { return };
    let dev = Device::Cpu;
    let a = field(1, (1, 1, 64, 64));
    let wrong = field(1, (1, 1, 64, 60));
    assert!(matches!(lsim.distance(&a, &wrong), Err(Error::ShapeMismatch { .. })));
    let two = field(1, (1, 2, 64, 64));
    assert!(matches!(lsim.distance(&two, &two), Err(Error::Shape { .. })));
    let mut v = vec![0f32; 64 * 64];
    v[17] = f32::INFINITY;
    let inf = Tensor::from_vec(v, (1, 1, 64, 64), &dev).unwrap();
    assert!(matches!(lsim.distance(&a, &inf), Err(Error::NonFinite { index: 17, .. })));
    let empty = Tensor::zeros((0, 1, 64, 64), DType::F32, &dev).unwrap();
    assert!(matches!(lsim.distance(&empty, &empty), Err(Error::Empty { .. })));
    let half = a.to_dtype(DType::F16).unwrap();
    assert!(matches!(lsim.distance(&half, &half), Err(Error::DType { .. })));
    let native = LsimOptions { size: LsimSize::Native, ..Default::default() };
    let small = field(1, (1, 1, MIN_NATIVE_SIDE - 1, 64));
    let e = lsim.distance_with(&small, &small, &native).unwrap_err().to_string();
    assert!(e.contains("Resize224"), "{e}");
    // Constant inputs work (only shifted), and give 0 when equal.
    let c = Tensor::full(5f32, (1, 1, 64, 64), &dev).unwrap();
    assert_eq!(lsim.distance(&c, &c).unwrap(), [0.0]);
}

#[test]
fn weight_files_with_missing_or_misshapen_tensors_are_rejected() {
    let p = weights_path();
    if !p.exists() {
        skip_or_fail(&format!("LSiM weights not found at {}", p.display()));
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut tensors = candle_core::safetensors::load(&p, &Device::Cpu).unwrap();
    // No metadata: normCount is missing.
    let path = dir.path().join("no_meta.safetensors");
    candle_core::safetensors::save(&tensors, &path).unwrap();
    let e = Lsim::load(&path).err().unwrap().to_string();
    assert!(e.contains("normCount"), "{e}");
    tensors.remove("model.lin3.1.weight");
    candle_core::safetensors::save(&tensors, &path).unwrap();
    let e = Lsim::load(&path).err().unwrap().to_string();
    assert!(e.contains("model.lin3.1.weight") && e.contains("missing"), "{e}");
    tensors.insert("model.lin3.1.weight".into(), Tensor::zeros((1, 64, 1, 1), DType::F32, &Device::Cpu).unwrap());
    candle_core::safetensors::save(&tensors, &path).unwrap();
    let e = Lsim::load(&path).err().unwrap().to_string();
    assert!(e.contains("[1, 64, 1, 1]"), "{e}");
    let junk = dir.path().join("junk.safetensors");
    std::fs::write(&junk, b"not a weight file").unwrap();
    assert!(matches!(Lsim::load(&junk), Err(Error::Weights { .. })));
    assert!(matches!(Lsim::load(dir.path().join("absent.safetensors")), Err(Error::Io { .. })));
}
