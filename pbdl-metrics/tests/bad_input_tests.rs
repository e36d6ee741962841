//! Bad input across pbdl-metrics: mismatched shapes, NaN/Inf, empty arrays, unsupported dtypes,
//! unreadable files and weight files with missing or wrongly shaped tensors give typed errors
//! that name the problem; nothing panics. (LSiM's own cases are in `lsim_tests.rs`, the `.pth`
//! converter's in `weights_tests.rs`.) VolSiM cases are skipped with a message without weights (a failure in CI).

use candle_core::{DType, Device, Tensor};
use pbdl_metrics::classic::{
    energy_spectrum, mae, mse, pearson, psnr, rel_l2, rmse, spearman, spectral_error, ssim2d, ssim3d, SsimConfig,
};
use pbdl_metrics::files::{compare, read_field, CompareOptions, Metric};
use pbdl_metrics::{Error, Result, Volsim};
use std::path::{Path, PathBuf};

fn field(shape: &[usize], s: u64) -> Tensor {
    pbdl_core::seed::rand_uniform(shape, -1.0, 1.0, DType::F32, &Device::Cpu, s).unwrap()
}

/// `t` with `value` written at flat index `at`.
fn poisoned(t: &Tensor, at: usize, value: f32) -> Tensor {
    let mut v = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    v[at] = value;
    Tensor::from_vec(v, t.dims(), &Device::Cpu).unwrap()
}

type Pair = fn(&Tensor, &Tensor) -> Result<()>;

/// The classic pairwise metrics, each returning only whether it succeeded.
fn classic() -> Vec<(&'static str, Pair)> {
    vec![
        ("mse", |a, b| mse(a, b).map(drop)),
        ("mae", |a, b| mae(a, b).map(drop)),
        ("rmse", |a, b| rmse(a, b).map(drop)),
        ("rel_l2", |a, b| rel_l2(a, b).map(drop)),
        ("psnr", |a, b| psnr(a, b, None).map(drop)),
        ("pearson", |a, b| pearson(a, b).map(drop)),
        ("spearman", |a, b| spearman(a, b).map(drop)),
        ("spectral_error", |a, b| spectral_error(a, b).map(drop)),
        ("ssim2d", |a, b| ssim2d(a, b, &SsimConfig::default()).map(drop)),
    ]
}

#[test]
fn classic_metrics_reject_bad_input_with_typed_errors() {
    let a = field(&[2, 1, 16, 16], 1);
    for (name, f) in classic() {
        f(&a, &field(&[2, 1, 16, 16], 2)).unwrap_or_else(|e| panic!("{name} on good input: {e}"));
        let e = f(&a, &field(&[2, 1, 16, 12], 2)).unwrap_err();
        assert!(matches!(e, Error::ShapeMismatch { .. }), "{name}: {e}");
        assert!(e.to_string().contains("[2, 1, 16, 12]"), "{name}: {e}");
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let e = f(&a, &poisoned(&a, 37, bad)).unwrap_err();
            assert!(matches!(e, Error::NonFinite { index: 37, .. }), "{name} with {bad}: {e}");
        }
        let empty = Tensor::zeros((2, 1, 0, 16), DType::F32, &Device::Cpu).unwrap();
        let e = f(&empty, &empty).unwrap_err();
        assert!(matches!(e, Error::Empty { .. } | Error::Shape { .. } | Error::Invalid { .. }), "{name}: {e}");
        let empty_batch = Tensor::zeros((0, 1, 16, 16), DType::F32, &Device::Cpu).unwrap();
        assert!(f(&empty_batch, &empty_batch).is_err(), "{name}: empty batch accepted");
        for dt in [DType::U8, DType::F16, DType::BF16, DType::I64] {
            let x = a.to_dtype(dt).unwrap();
            let e = f(&x, &x).unwrap_err();
            assert!(matches!(e, Error::DType { .. }), "{name} {dt:?}: {e}");
        }
        let flat = field(&[16], 3);
        assert!(matches!(f(&flat, &flat), Err(Error::Shape { .. })), "{name}: rank 1 accepted");
    }
    // ssim3d needs three spatial axes; energy_spectrum one field.
    assert!(matches!(ssim3d(&a, &a, &SsimConfig::default()), Err(Error::Shape { .. })));
    assert!(matches!(energy_spectrum(&poisoned(&a, 3, f32::NAN)), Err(Error::NonFinite { index: 3, .. })));
}

/// Writes a version-1.0 `.npy` file with the dtype string `descr` and raw `data`.
fn write_npy(path: &Path, descr: &str, shape: &str, data: &[u8]) {
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(&(header.len() as u16).to_le_bytes());
    b.extend_from_slice(header.as_bytes());
    b.extend_from_slice(data);
    std::fs::write(path, b).unwrap();
}

#[test]
fn files_with_unsupported_dtypes_or_layouts_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    // A complex array cannot be read: pbdl-core's npy reader names the dtype.
    write_npy(&p("c.npy"), "<c16", "(2, 2)", &[0u8; 64]);
    let e = read_field(p("c.npy")).unwrap_err();
    assert!(matches!(e, Error::Core(_)) && e.to_string().contains("c16"), "{e}");
    // A string array neither.
    write_npy(&p("u.npy"), "<U2", "(2,)", &[0u8; 16]);
    assert!(matches!(read_field(p("u.npy")), Err(Error::Core(_))));
    // An int16 array is read and converted by the file-level metrics (no error there).
    write_npy(&p("i2.npy"), "<i2", "(4, 4)", &[0u8; 32]);
    let i2 = read_field(p("i2.npy")).unwrap();
    assert_eq!(compare(Metric::Mse, &i2, &i2, &CompareOptions::default()).unwrap(), [0.0]);
    // A truncated file and an unknown extension.
    write_npy(&p("short.npy"), "<f4", "(4, 4)", &[0u8; 10]);
    assert!(read_field(p("short.npy")).is_err());
    std::fs::write(p("a.txt"), "1 2 3").unwrap();
    let e = read_field(p("a.txt")).unwrap_err();
    assert!(e.to_string().contains(".txt"), "{e}");
    assert!(matches!(read_field(p("absent.npy")), Err(Error::Io { .. })));
    // compare: mismatched shapes, and a layout the learned metric cannot read.
    let (a, b) = (field(&[8, 8], 1), field(&[8, 9], 2));
    let e = compare(Metric::Mse, &a, &b, &CompareOptions::default()).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    let four = field(&[8, 8, 4], 1);
    let opts = CompareOptions { weights: Some(p("absent.safetensors")), ..Default::default() };
    let e = compare(Metric::Lsim, &four, &four, &opts).unwrap_err();
    assert!(matches!(e, Error::Shape { .. } | Error::Io { .. }), "{e}");
}

fn volsim_path() -> Option<PathBuf> {
    let p =
        pbdl_metrics::weights::weights_dir().map(|d| d.join(pbdl_metrics::weights::VOLSIM_FILE)).filter(|p| p.exists());
    if p.is_none() {
        pbdl_core::testing::skip_or_fail(
            "VolSiM weights not found (set PBDL_WEIGHTS_DIR or put them in ../shared/weights)",
        );
    }
    p
}

/// Rewrites a safetensors file with `edit` applied to its tensors, keeping the metadata.
fn rewrite(src: &Path, dst: &Path, edit: impl FnOnce(&mut Vec<(String, Tensor)>)) {
    let bytes = std::fs::read(src).unwrap();
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut tensors: Vec<(String, Tensor)> =
        candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).unwrap().into_iter().collect();
    edit(&mut tensors);
    let data: Vec<(String, Vec<u8>, Vec<usize>)> = tensors
        .iter()
        .map(|(n, t)| {
            let v = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            (n.clone(), v.iter().flat_map(|x| x.to_le_bytes()).collect(), t.dims().to_vec())
        })
        .collect();
    let views: Vec<(String, safetensors::tensor::TensorView)> = data
        .iter()
        .map(|(n, b, s)| {
            (n.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap())
        })
        .collect();
    safetensors::serialize_to_file(views, meta.metadata().clone(), dst).unwrap();
}

/// A change to the tensors of a weight file.
type Edit = Box<dyn FnOnce(&mut Vec<(String, Tensor)>)>;

#[test]
fn volsim_weight_files_with_missing_or_misshapen_tensors_are_named() {
    let Some(src) = volsim_path() else { return };
    let dir = tempfile::tempdir().unwrap();
    let dst = dir.path().join("w.safetensors");
    let cases: Vec<(&str, Edit)> = vec![
        ("model.avg5.1.weight", Box::new(|t| t.retain(|(n, _)| n != "model.avg5.1.weight"))),
        ("norm.m2.3", Box::new(|t| t.retain(|(n, _)| n != "norm.m2.3"))),
        (
            "model.basenet.slice6.0.bias",
            Box::new(|t| {
                let e = t.iter_mut().find(|(n, _)| n == "model.basenet.slice6.0.bias").unwrap();
                e.1 = Tensor::zeros(5, DType::F32, &Device::Cpu).unwrap();
            }),
        ),
        (
            "model.basenet.slice4.0.weight",
            Box::new(|t| {
                let e = t.iter_mut().find(|(n, _)| n == "model.basenet.slice4.0.weight").unwrap();
                e.1 = Tensor::zeros((8, 7, 3, 3, 3), DType::F32, &Device::Cpu).unwrap();
            }),
        ),
        (
            "norm.mean.2",
            Box::new(|t| {
                let e = t.iter_mut().find(|(n, _)| n == "norm.mean.2").unwrap();
                e.1 = Tensor::zeros((32, 32), DType::F32, &Device::Cpu).unwrap();
            }),
        ),
    ];
    for (name, edit) in cases {
        rewrite(&src, &dst, edit);
        let e = Volsim::load(&dst).err().unwrap_or_else(|| panic!("{name}: the broken file loaded"));
        assert!(matches!(e, Error::Weights { .. }), "{name}: {e}");
        assert!(e.to_string().contains(name), "{name}: {e}");
    }
    // Dropping a whole scale's last layer leaves 11 layers: not 4 per scale.
    rewrite(&src, &dst, |t| t.retain(|(n, _)| !n.starts_with("model.basenet.slice11.")));
    let e = Volsim::load(&dst).err().unwrap().to_string();
    assert!(e.contains("11 layers"), "{e}");
    // No metadata: normCount is missing.
    let tensors = candle_core::safetensors::load(&src, &Device::Cpu).unwrap();
    candle_core::safetensors::save(&tensors, &dst).unwrap();
    let e = Volsim::load(&dst).err().unwrap().to_string();
    assert!(e.contains("normCount"), "{e}");
    std::fs::write(&dst, b"junk").unwrap();
    assert!(matches!(Volsim::load(&dst), Err(Error::Weights { .. })));
}

#[test]
fn volsim_rejects_bad_volumes_and_takes_constant_and_one_channel_ones() {
    let Some(p) = volsim_path() else { return };
    let v = Volsim::load(p).unwrap();
    let dev = Device::Cpu;
    let a = field(&[1, 1, 8, 8, 8], 1);
    let e = v.distance(&a, &field(&[1, 1, 8, 8, 12], 2)).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    for bad in [f32::NAN, f32::INFINITY] {
        let e = v.distance(&a, &poisoned(&a, 100, bad)).unwrap_err();
        assert!(matches!(e, Error::NonFinite { index: 100, .. }), "{e}");
    }
    let empty = Tensor::zeros((1, 1, 0, 8, 8), DType::F32, &dev).unwrap();
    assert!(matches!(v.distance(&empty, &empty), Err(Error::Empty { .. })));
    let empty_batch = Tensor::zeros((0, 1, 8, 8, 8), DType::F32, &dev).unwrap();
    assert!(matches!(v.distance(&empty_batch, &empty_batch), Err(Error::Empty { .. })));
    for dt in [DType::F16, DType::BF16] {
        let x = a.to_dtype(dt).unwrap();
        assert!(matches!(v.distance(&x, &x), Err(Error::DType { .. })), "{dt:?}");
    }
    let two = field(&[1, 2, 8, 8, 8], 1);
    assert!(matches!(v.distance(&two, &two), Err(Error::Shape { .. })));
    // Constant volumes (1 and 3 channels) and 1-channel volumes, where the official code crashes.
    let c1 = Tensor::full(-7f32, (1, 1, 8, 8, 8), &dev).unwrap();
    let c3 = Tensor::full(-7f32, (1, 3, 8, 8, 8), &dev).unwrap();
    assert_eq!(v.distance(&c1, &c1).unwrap(), [0.0]);
    assert_eq!(v.distance(&c3, &c3).unwrap(), [0.0]);
    // A 1-channel volume equals the same volume repeated to three channels.
    let d1 = v.distance(&a, &c1).unwrap()[0];
    let d3 = v.distance(&a.repeat((1, 3, 1, 1, 1)).unwrap(), &c3).unwrap()[0];
    assert!(d1 > 0.0 && d1 == d3, "{d1} vs {d3}");
    // u8 volumes are read as values 0..255.
    let u = Tensor::from_vec((0..512u32).map(|i| (i % 251) as u8).collect::<Vec<u8>>(), (1, 1, 8, 8, 8), &dev).unwrap();
    assert!(v.distance(&u, &u).unwrap()[0] == 0.0);
}
