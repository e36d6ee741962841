//! Property tests (proptest) of the metric axioms, on random fields of random shapes:
//!
//! * pointwise distances (`mse`, `mae`, `rmse`): `d(a, a) = 0`, `d(a, b) = d(b, a)` exactly
//!   (`a - b` and `b - a` differ only in sign in IEEE arithmetic), `d >= 0`; the triangle
//!   inequality for the two that are metrics (`rmse`, `mae`); `rel_l2(a, a) = 0`, `rel_l2 >= 0`;
//! * SSIM (1D/2D/3D): `ssim(a, a) = 1`, symmetric, at most 1, so `1 - ssim` is a non-negative,
//!   symmetric dissimilarity with `d(a, a) = 0`;
//! * Pearson and Spearman correlation: symmetric, `r(a, a) = 1`, `|r| <= 1`;
//!   log-spectral error: `d(a, a) = 0`, symmetric, `>= 0`;
//! * the learned LSiM (2D) and VolSiM (3D) from their published weights: `d(a, a) = 0`,
//!   symmetric, `d > 0` for different fields. Skipped with a visible message when the weights
//!   are absent (`$PBDL_WEIGHTS_DIR` or `../shared/weights`), a failure instead in CI
//!   (`pbdl_core::testing::skip_or_fail`, as the other learned-metric tests).
//!
//! The proptest seed is fixed (deterministic CI) unless `PROPTEST_RNG_SEED` is set;
//! `PROPTEST_CASES` overrides the case counts.

use candle_core::{DType, Device, Tensor};
use pbdl_core::seed;
use pbdl_core::testing::skip_or_fail;
use pbdl_metrics::classic::{mae, mse, pearson, rel_l2, rmse, spearman, spectral_error, ssim_nd, SsimConfig};
use pbdl_metrics::weights::{weights_dir, LSIM_FILE, VOLSIM_FILE};
use pbdl_metrics::{Lsim, LsimOptions, LsimSize, Volsim};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use std::sync::OnceLock;

/// `cases` random cases (or `PROPTEST_CASES`), a fixed seed (or `PROPTEST_RNG_SEED`), and no
/// regression files written into the source tree (a failure prints its minimal input).
fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::default();
    if std::env::var_os("PROPTEST_CASES").is_none() {
        c.cases = cases;
    }
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x5eed_0025);
    }
    c.failure_persistence = None;
    c
}

fn field(shape: &[usize], s: u64) -> Tensor {
    seed::randn(shape, 0.0, 1.0, DType::F64, &Device::Cpu, s).unwrap()
}

fn vals(t: Tensor) -> Vec<f64> {
    t.to_dtype(DType::F64).unwrap().to_vec1::<f64>().unwrap()
}

/// A random shape `[batch, channel, spatial...]` with `dims` spatial axes of the given sizes.
fn shape(batch: usize, channels: usize, sizes: &[usize], dims: usize) -> Vec<usize> {
    let mut s = vec![batch, channels];
    s.extend(&sizes[..dims]);
    s
}

/// The weight file `name`, or `None` after [`skip_or_fail`]: a visible skip on a machine without
/// the weights, a failure in CI (which has `../shared`) or with `PBDL_REQUIRE_DATA=1`.
fn weight_file(name: &str) -> Option<std::path::PathBuf> {
    let p = weights_dir().map(|d| d.join(name)).filter(|p| p.exists());
    if p.is_none() {
        skip_or_fail(&format!("{name} not found (set PBDL_WEIGHTS_DIR or put it in ../shared/weights)"));
    }
    p
}

fn lsim() -> Option<&'static Lsim> {
    static MODEL: OnceLock<Option<Lsim>> = OnceLock::new();
    MODEL.get_or_init(|| weight_file(LSIM_FILE).map(|p| Lsim::load(p).expect("the LSiM weights load"))).as_ref()
}

fn volsim() -> Option<&'static Volsim> {
    static MODEL: OnceLock<Option<Volsim>> = OnceLock::new();
    MODEL.get_or_init(|| weight_file(VOLSIM_FILE).map(|p| Volsim::load(p).expect("the VolSiM weights load"))).as_ref()
}

proptest! {
    #![proptest_config(config(64))]

    /// Pointwise distances on 1D/2D/3D fields. Identity and symmetry are exact; the triangle
    /// inequality holds to 1e-12 relative (the sums of squares/absolute values are rounded).
    #[test]
    fn pointwise_distances_are_metrics(
        batch in 1usize..3, channels in 1usize..3, sizes in prop::array::uniform3(1usize..9),
        dims in 1usize..4, s in any::<u64>(),
    ) {
        let sh = shape(batch, channels, &sizes, dims);
        let (a, b, c) = (field(&sh, s), field(&sh, s ^ 1), field(&sh, s ^ 2));
        type Distance = fn(&Tensor, &Tensor) -> pbdl_metrics::Result<Tensor>;
        for (name, d) in [("mse", mse as Distance), ("mae", mae), ("rmse", rmse)] {
            let dab = vals(d(&a, &b).unwrap());
            prop_assert!(vals(d(&a, &a).unwrap()).iter().all(|&v| v == 0.0), "{name}(a, a) != 0");
            prop_assert_eq!(&vals(d(&b, &a).unwrap()), &dab, "{} not symmetric", name);
            prop_assert!(dab.iter().all(|&v| v >= 0.0 && v.is_finite()), "{name} = {dab:?}");
            if name != "mse" {
                let (dac, dcb) = (vals(d(&a, &c).unwrap()), vals(d(&c, &b).unwrap()));
                for i in 0..batch {
                    let (ab, ac, cb) = (dab[i], dac[i], dcb[i]);
                    prop_assert!(ab <= (ac + cb) * (1.0 + 1e-12), "{name} triangle: {ab} > {ac} + {cb}");
                }
            }
        }
        prop_assert!(vals(rel_l2(&a, &a).unwrap()).iter().all(|&v| v == 0.0), "rel_l2(a, a) != 0");
        prop_assert!(vals(rel_l2(&a, &b).unwrap()).iter().all(|&v| v >= 0.0), "rel_l2 < 0");
    }

    /// SSIM with random windows and constants: `ssim(a, a) = 1` (1e-12: the map is
    /// `(2 mu^2 + C1)(2 s^2 + C2) / ((2 mu^2 + C1)(2 s^2 + C2))`, a quotient of equal roundings),
    /// symmetric to 1e-12 relative, and at most 1 (+1e-12).
    #[test]
    fn ssim_is_a_similarity(
        batch in 1usize..3, channels in 1usize..3, extra in prop::array::uniform3(0usize..6),
        dims in 1usize..4, half_window in 0usize..4, sigma in 0.5f64..3.0, range in prop::option::of(0.5f64..10.0),
        s in any::<u64>(),
    ) {
        let window = 2 * half_window + 1;
        let sizes = extra.map(|e| window + e);
        let sh = shape(batch, channels, &sizes, dims);
        let (a, b) = (field(&sh, s), field(&sh, s ^ 1));
        let cfg = SsimConfig { window, sigma, data_range: range, ..Default::default() };
        let saa = vals(ssim_nd(&a, &a, &cfg).unwrap());
        prop_assert!(saa.iter().all(|&v| (v - 1.0).abs() < 1e-12), "ssim(a, a) = {saa:?}");
        let (sab, sba) = (vals(ssim_nd(&a, &b, &cfg).unwrap()), vals(ssim_nd(&b, &a, &cfg).unwrap()));
        for i in 0..batch {
            let (ab, ba) = (sab[i], sba[i]);
            prop_assert!((ab - ba).abs() <= 1e-12 * ab.abs().max(1.0), "ssim not symmetric: {ab} vs {ba}");
            prop_assert!(sab[i] <= 1.0 + 1e-12 && sab[i].is_finite(), "ssim = {}", sab[i]);
        }
    }

    /// Correlations: symmetric (1e-12), `r(a, a) = 1` (1e-12), `|r| <= 1` (+1e-12); the
    /// log-spectral error: `d(a, a) = 0` exactly (the same spectrum twice), symmetric (1e-12),
    /// `>= 0`.
    #[test]
    fn correlations_and_spectral_error(
        batch in 1usize..3, sizes in prop::array::uniform3(3usize..10), dims in 1usize..4, s in any::<u64>(),
    ) {
        let sh = shape(batch, 1, &sizes, dims);
        let (a, b) = (field(&sh, s), field(&sh, s ^ 1));
        let (pab, pba) = (vals(pearson(&a, &b).unwrap()), vals(pearson(&b, &a).unwrap()));
        let paa = vals(pearson(&a, &a).unwrap());
        let (sab, sba) = (spearman(&a, &b).unwrap(), spearman(&b, &a).unwrap());
        let saa = spearman(&a, &a).unwrap();
        for i in 0..batch {
            let (ab, ba) = (pab[i], pba[i]);
            prop_assert!((ab - ba).abs() < 1e-12 && ab.abs() <= 1.0 + 1e-12, "pearson {ab} {ba}");
            prop_assert!((paa[i] - 1.0).abs() < 1e-12, "pearson(a, a) = {}", paa[i]);
            let (ab, ba) = (sab[i], sba[i]);
            prop_assert!((ab - ba).abs() < 1e-12 && ab.abs() <= 1.0 + 1e-12, "spearman {ab} {ba}");
            prop_assert!((saa[i] - 1.0).abs() < 1e-12, "spearman(a, a) = {}", saa[i]);
        }
        let (eab, eba) = (spectral_error(&a, &b).unwrap(), spectral_error(&b, &a).unwrap());
        prop_assert!(spectral_error(&a, &a).unwrap().iter().all(|&v| v == 0.0), "spectral_error(a, a) != 0");
        for i in 0..batch {
            let (ab, ba) = (eab[i], eba[i]);
            prop_assert!(ab >= 0.0 && (ab - ba).abs() <= 1e-12 * ab.max(1e-300), "spectral error {ab} {ba}");
        }
    }
}

// The learned metrics run a VGG-like network per case (~0.1-1 s in the test profile): 6 cases.
// The weights are looked up once, before the cases, so a missing file skips (or fails) once.

/// LSiM at native size (44-60 pixels a side, the smallest the network takes) and the default
/// 224 path: `d(a, a) = 0` exactly (the same features twice), symmetric to 1e-5 relative (f32
/// network; the two inputs swap places in one batched forward pass, so only the summation order
/// of the final sums can change), and `d > 0` for independent noise.
#[test]
fn lsim_axioms() {
    let Some(lsim) = lsim() else { return };
    proptest!(config(6), |(h in 44usize..61, w in 44usize..61, native in any::<bool>(), s in any::<u64>())| {
        let size = if native { LsimSize::Native } else { LsimSize::Resize224 };
        let opts = LsimOptions { size, ..Default::default() };
        let f = |s| seed::rand_uniform((2, 1, h, w), -1.0, 3.0, DType::F32, &Device::Cpu, s).unwrap();
        let (a, b) = (f(s), f(s ^ 1));
        let d = |x: &Tensor, y: &Tensor| vals(lsim.distance_with(x, y, &opts).unwrap());
        prop_assert_eq!(d(&a, &a), vec![0.0, 0.0]);
        let (dab, dba) = (d(&a, &b), d(&b, &a));
        for i in 0..2 {
            let (ab, ba) = (dab[i], dba[i]);
            prop_assert!(ab > 0.0 && ab.is_finite(), "LSiM = {ab}");
            prop_assert!((ab - ba).abs() <= 1e-5 * ab, "LSiM not symmetric: {ab} vs {ba}");
        }
    });
}

/// VolSiM (3 scales: sides multiples of 4) at native size: the same axioms and tolerances.
#[test]
fn volsim_axioms() {
    let Some(volsim) = volsim() else { return };
    proptest!(config(6), |(n in prop::array::uniform3(3usize..5), s in any::<u64>())| {
        let (z, y, x) = (4 * n[0], 4 * n[1], 4 * n[2]);
        let f = |s| seed::rand_uniform((1, 1, z, y, x), -2.0, 5.0, DType::F32, &Device::Cpu, s).unwrap();
        let (a, b) = (f(s), f(s ^ 1));
        prop_assert_eq!(volsim.distance(&a, &a).unwrap(), vec![0.0]);
        let (dab, dba) = (volsim.distance(&a, &b).unwrap()[0], volsim.distance(&b, &a).unwrap()[0]);
        prop_assert!(dab > 0.0 && dab.is_finite(), "VolSiM = {dab}");
        prop_assert!((dab - dba).abs() <= 1e-5 * dab, "VolSiM not symmetric: {dab} vs {dba}");
    });
}
