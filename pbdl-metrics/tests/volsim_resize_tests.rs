//! VolSiM's cubic B-spline resize to 64^3 (`Volsim::with_resize`, `pbdl_core::sample::spline_zoom`).
//!
//! * Against scipy: `tests/data/spline_*_{in,out}.npy` were written by
//!   `tests/data/make_spline_reference.py` with `scipy.ndimage.zoom(order=3)` (scipy 1.17.1).
//! * In VolSiM (skipped with a message without the weights; a failure in CI): a 64^3 input is unchanged by the
//!   resize, sides that the network cannot take natively work, constant and 1-channel volumes work,
//!   and the distance of two smooth fields sampled at 40^3 and resized is close to the one at 64^3.

use candle_core::{DType, Device, Tensor};
use pbdl_core::sample::spline_zoom;
use pbdl_metrics::Volsim;
use std::path::PathBuf;
use std::sync::OnceLock;

fn data(name: &str) -> Tensor {
    pbdl_core::io::read_npy(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)).unwrap()
}

/// Max |a - b| / max |b|.
fn rel_err(a: &Tensor, b: &Tensor) -> f64 {
    let a = a.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    let b = b.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1::<f64>().unwrap();
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f64, |m, v| m.max(v.abs()));
    a.iter().zip(&b).fold(0f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

#[test]
fn spline_zoom_matches_scipy_zoom_order_3() {
    for name in ["9_to_12", "12_to_7", "aniso"] {
        let (x, want) = (data(&format!("spline_{name}_in.npy")), data(&format!("spline_{name}_out.npy")));
        let size = want.dims().to_vec();
        let y = spline_zoom(&x, &size).unwrap();
        assert_eq!(y.dims(), want.dims());
        let e64 = rel_err(&y, &want);
        let y32 = spline_zoom(&x.to_dtype(DType::F32).unwrap(), &size).unwrap();
        let e32 = rel_err(&y32, &want);
        eprintln!(
            "spline zoom {name} {:?} -> {size:?}: max rel. error vs scipy f64 {e64:.2e}, f32 {e32:.2e}",
            x.dims()
        );
        assert!(e64 < 1e-12, "{name}: {e64:e}");
        assert!(e32 < 1e-6, "{name}: {e32:e}");
    }
}

fn volsim() -> Option<&'static Volsim> {
    static MODEL: OnceLock<Option<Volsim>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let p = pbdl_metrics::weights::weights_dir()
                .map(|d| d.join(pbdl_metrics::weights::VOLSIM_FILE))
                .filter(|p| p.exists());
            let Some(p) = p else {
                pbdl_core::testing::skip_or_fail(
                    "VolSiM weights not found (set PBDL_WEIGHTS_DIR or put them in ../shared/weights)",
                );
                return None;
            };
            Some(Volsim::load(&p).expect("the shared VolSiM weights load"))
        })
        .as_ref()
}

/// Samples of sin(2 pi x) cos(2 pi y) + 0.5 sin(4 pi z) (+ eps sin(16 pi (x+y+z))) on n^3 points
/// spanning [0, 1] corner to corner (the grid that `grid_mode=False` zoom preserves).
fn smooth(n: usize, eps: f64) -> Tensor {
    let h = 1.0 / (n - 1) as f64;
    let tau = 2.0 * std::f64::consts::PI;
    let v: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = ((i % n) as f64 * h, ((i / n) % n) as f64 * h, (i / (n * n)) as f64 * h);
            let f = (tau * x).sin() * (tau * y).cos() + 0.5 * (2.0 * tau * z).sin();
            (f + eps * (8.0 * tau * (x + y + z)).sin()) as f32
        })
        .collect();
    Tensor::from_vec(v, (1, 1, n, n, n), &Device::Cpu).unwrap()
}

#[test]
fn resize_to_64_in_volsim() {
    let Some(v) = volsim() else { return };
    let r = v.clone().with_resize(Some(64)).unwrap();
    assert_eq!(r.resize(), Some(64));
    // At 64^3 the resize is the identity: the same distance as the native path.
    let (a, b) = (smooth(64, 0.0), smooth(64, 0.2));
    let (dn, dr) = (v.distance(&a, &b).unwrap()[0], r.distance(&a, &b).unwrap()[0]);
    assert_eq!(dn, dr);
    // The same pair of fields sampled at 40^3 and resized to 64^3: close to the native 64^3 distance.
    let (ca, cb) = (smooth(40, 0.0), smooth(40, 0.2));
    let dc = r.distance(&ca, &cb).unwrap()[0];
    eprintln!(
        "VolSiM: d at 64^3 native = {dn:.5}, from 40^3 resized to 64^3 = {dc:.5} (rel. diff {:.2e})",
        (dc - dn).abs() / dn
    );
    assert!((dc - dn).abs() < 0.1 * dn, "{dc} vs {dn}");
    // Sides the network cannot take natively (not multiples of 4) work after the resize.
    let odd = pbdl_core::seed::rand_uniform((1, 1, 10, 13, 7), -1.0, 1.0, DType::F32, &Device::Cpu, 5).unwrap();
    let odd2 = pbdl_core::seed::rand_uniform((1, 1, 10, 13, 7), -1.0, 1.0, DType::F32, &Device::Cpu, 6).unwrap();
    assert!(v.distance(&odd, &odd2).is_err());
    let d = r.distance(&odd, &odd2).unwrap();
    assert!(d.iter().all(|x| x.is_finite() && *x > 0.0), "{d:?}");
    // A constant 1-channel volume (the official code raises an IndexError on it).
    let c = Tensor::full(2f32, (1, 1, 6, 6, 6), &Device::Cpu).unwrap();
    assert_eq!(r.distance(&c, &c).unwrap(), [0.0]);
    // Sizes the network cannot take are refused.
    assert!(v.clone().with_resize(Some(30)).is_err());
    assert!(v.clone().with_resize(Some(0)).is_err());
}
