//! `pbdl_metrics::files`: reading fields from .npy/.npz/.png and comparing them (no weights
//! needed; the learned metrics are covered by lsim_tests / volsim_tests).

use candle_core::{Device, Tensor};
use pbdl_metrics::files::{compare, read_field, CompareOptions, Metric};
use pbdl_metrics::Error;

fn ramp(shape: &[usize]) -> Tensor {
    let n: usize = shape.iter().product();
    Tensor::arange(0f32, n as f32, &Device::Cpu).unwrap().reshape(shape).unwrap()
}

#[test]
fn reads_npy_npz_and_png() {
    let dir = tempfile::tempdir().unwrap();
    let a = ramp(&[6, 5]);
    pbdl_core::io::write_npy(dir.path().join("a.npy"), &a).unwrap();
    pbdl_core::io::write_npz(dir.path().join("a.npz"), &[("u", &a)]).unwrap();
    for f in ["a.npy", "a.npz"] {
        let t = read_field(dir.path().join(f)).unwrap();
        assert_eq!(t.dims(), [6, 5]);
        assert_eq!(t.to_vec2::<f32>().unwrap(), a.to_vec2::<f32>().unwrap());
    }
    // 8-bit gray -> [H, W] u8; RGB -> [H, W, 3] u8, row-major with y down as stored.
    let gray = image::GrayImage::from_fn(4, 3, |x, y| image::Luma([(10 * y + x) as u8]));
    gray.save(dir.path().join("g.png")).unwrap();
    let t = read_field(dir.path().join("g.png")).unwrap();
    assert_eq!(t.dims(), [3, 4]);
    assert_eq!(t.to_vec2::<u8>().unwrap()[2], [20, 21, 22, 23]);
    let rgb = image::RgbImage::from_fn(4, 3, |x, y| image::Rgb([x as u8, y as u8, 7]));
    rgb.save(dir.path().join("c.png")).unwrap();
    let t = read_field(dir.path().join("c.png")).unwrap();
    assert_eq!(t.dims(), [3, 4, 3]);
    assert_eq!(t.to_vec3::<u8>().unwrap()[2][3], [3, 2, 7]);
}

#[test]
fn bad_files_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = read_field(dir.path().join("nope.npy")).unwrap_err();
    assert!(matches!(missing, Error::Io { .. }), "{missing}");
    std::fs::write(dir.path().join("a.txt"), "1 2 3").unwrap();
    let e = read_field(dir.path().join("a.txt")).unwrap_err();
    assert!(matches!(e, Error::Invalid { .. }) && e.to_string().contains("unknown file type"), "{e}");
    std::fs::write(dir.path().join("bad.png"), "not a png").unwrap();
    let e = read_field(dir.path().join("bad.png")).unwrap_err();
    assert!(matches!(e, Error::Invalid { .. }), "{e}");
    let a = ramp(&[4]);
    pbdl_core::io::write_npz(dir.path().join("two.npz"), &[("u", &a), ("v", &a)]).unwrap();
    let e = read_field(dir.path().join("two.npz")).unwrap_err();
    assert!(e.to_string().contains("2 arrays [u, v]"), "{e}");
}

#[test]
fn compares_classic_metrics_and_rejects_bad_shapes() {
    let a = ramp(&[16, 16]);
    let b = (&a + 2.0).unwrap();
    let opts = CompareOptions::default();
    assert_eq!(compare(Metric::Mse, &a, &b, &opts).unwrap(), [4.0]);
    assert_eq!(compare(Metric::Mae, &a, &b, &opts).unwrap(), [2.0]);
    let r = compare("pearson".parse().unwrap(), &a, &b, &opts).unwrap()[0];
    assert!((r - 1.0).abs() < 1e-12);
    let s = compare(Metric::Ssim, &a, &a, &opts).unwrap()[0];
    assert!((s - 1.0).abs() < 1e-12);
    let s3 = compare(Metric::Ssim, &ramp(&[12, 12, 12]), &ramp(&[12, 12, 12]), &opts).unwrap()[0];
    assert!((s3 - 1.0).abs() < 1e-12);
    // [H, W, 3] is an RGB image (SSIM 2D over 3 channels), not a 3D field with 3 cells along x.
    let img = ramp(&[16, 16, 3]);
    let s = compare(Metric::Ssim, &img, &img, &opts).unwrap()[0];
    assert!((s - 1.0).abs() < 1e-12);
    // Different shapes, unusable ranks, learned-only options, unknown names.
    let e = compare(Metric::Mse, &a, &ramp(&[16, 8]), &opts).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    let e = compare(Metric::Ssim, &ramp(&[16]), &ramp(&[16]), &opts).unwrap_err();
    assert!(matches!(e, Error::Shape { .. }), "{e}");
    let e = compare(Metric::Mse, &ramp(&[2, 2, 2, 2]), &ramp(&[2, 2, 2, 2]), &opts).unwrap_err();
    assert!(matches!(e, Error::Shape { .. }), "{e}");
    let native = CompareOptions { native: true, ..Default::default() };
    assert!(matches!(compare(Metric::Mse, &a, &b, &native), Err(Error::Invalid { .. })));
    let resize = CompareOptions { resize64: true, ..Default::default() };
    assert!(matches!(compare(Metric::Mse, &a, &b, &resize), Err(Error::Invalid { .. })));
    // --resize64 is VolSiM's option; LSiM refuses it before loading any weights.
    let e = compare(Metric::Lsim, &ramp(&[8, 8]), &ramp(&[8, 8]), &resize).unwrap_err();
    assert!(matches!(e, Error::Invalid { .. }) && e.to_string().contains("volsim"), "{e}");
    let e = "foo".parse::<Metric>().unwrap_err();
    assert!(e.to_string().contains("unknown metric `foo`") && e.to_string().contains("lsim"), "{e}");
}

#[test]
fn learned_metrics_check_the_layout_before_loading_weights() {
    // A 4-channel image is no LSiM input; the shape error must come first, even with a bogus
    // weight path, so that no weights are needed here.
    let opts = CompareOptions { weights: Some("/nonexistent/LSiM.safetensors".into()), ..Default::default() };
    let x = ramp(&[8, 8, 4]);
    let e = compare(Metric::Lsim, &x, &x, &opts).unwrap_err();
    assert!(matches!(e, Error::Shape { .. }), "{e}");
    let v = ramp(&[8, 8]);
    let e = compare(Metric::Volsim, &v, &v, &opts).unwrap_err();
    assert!(matches!(e, Error::Shape { .. }), "{e}");
}
