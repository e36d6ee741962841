//! Latent space subdivision at toy size (16^2, 3 training and 2 held-out scenes of 20 frames):
//! short training shrinks the split leak, the scores and the rollout run and are finite,
//! training resumes to the same weights, and bad input is a typed error.

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use pbdl_grid::{CenteredField, FluidState, MacField, ScalarBoundaries};
use pbdl_latent::data::{generate, Dataset, PlumeData};
use pbdl_latent::lss::{
    lss_rollout, param_score, reconstruction_score, split_leak, swap_score, train_lss, train_lss_autoencoder,
    LssAutoencoder, LssConfig, LssModel, LssNormalization,
};
use pbdl_latent::train::PhaseSettings;
use pbdl_latent::Error;
use std::sync::OnceLock;

fn data() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        let cfg = PlumeData { resolution: 16, train_scenes: 3, test_scenes: 2, frames: 20, ..PlumeData::default() };
        generate(&cfg).unwrap()
    })
}

fn small_config(ae_steps: u64, pred_steps: u64) -> LssConfig {
    LssConfig {
        resolution: 16,
        widths: vec![4, 8],
        latent_channels: 4,
        encoder_units: 16,
        decoder_units: 16,
        rollout: 3,
        autoencoder_training: PhaseSettings { steps: ae_steps, batch: 8, lr: 3e-3 },
        predictor_training: PhaseSettings { steps: pred_steps, batch: 4, lr: 3e-3 },
        seed: 5,
        ..LssConfig::default()
    }
}

fn model() -> &'static LssModel {
    static MODEL: OnceLock<LssModel> = OnceLock::new();
    MODEL.get_or_init(|| train_lss(data(), &small_config(150, 20), None).unwrap())
}

#[test]
fn short_training_shrinks_the_split_leak() {
    let untrained = train_lss(data(), &small_config(1, 1), None).unwrap();
    let before = split_leak(&untrained.autoencoder, &data().test).unwrap();
    let after = split_leak(&model().autoencoder, &data().test).unwrap();
    assert!(
        after.density_part_of_velocity < before.density_part_of_velocity,
        "density part of encode(velocity, 0): {before:?} -> {after:?}"
    );
    let (r0, r1) = (
        reconstruction_score(&untrained.autoencoder, &data().test).unwrap(),
        reconstruction_score(&model().autoencoder, &data().test).unwrap(),
    );
    assert!(r1.velocity < r0.velocity && r1.density < r0.density, "{r0:?} -> {r1:?}");
}

#[test]
fn scores_and_rollout_are_finite() {
    let m = model();
    let s = swap_score(&m.autoencoder, &data().test).unwrap();
    assert_eq!((s.pairs, s.frames), (2, 19));
    assert!(s.velocity_change.is_finite() && s.scene_velocity_difference.is_finite(), "{s:?}");
    let p = param_score(&m.autoencoder, &data().test).unwrap();
    assert!(p.mae.is_finite() && p.range_fraction.is_finite() && p.mae_late.is_finite(), "{p:?}");
    let seq = &data().test[0];
    let r = lss_rollout(m, &data().config.scene(seq.param), seq, 5, 8).unwrap();
    assert!(r.finite, "{r:?}");
    assert_eq!(r.density_error.len(), 8);
    assert_eq!(r.velocity_error.len(), 8);
    assert!(r.density_error.iter().chain(&r.decoded_density_error).all(|e| e.is_finite()), "{r:?}");
    // The density is advected by the solver from the true start: after one step it is close.
    assert!(r.density_error[0] < 0.5, "{r:?}");
}

/// The rollout's density transport (the scene's `step_unprojected` with the frame's velocity)
/// reproduces the data's next density exactly when given the true velocity: the frame
/// convention `rho_{t+1} = inflow(advect(rho_t, u_t))` that `lss_rollout` relies on.
#[test]
fn density_transport_matches_the_data_convention() {
    let seq = &data().test[0];
    let scene = data().config.scene(seq.param);
    let fluid = scene.fluid().unwrap();
    let (grid, bc) = (*fluid.grid(), *fluid.boundaries());
    for t in [3, 10] {
        let state = FluidState {
            velocity: MacField::new(seq.velocity.narrow(0, t, 1).unwrap(), grid, bc).unwrap(),
            density: Some(
                CenteredField::new(seq.density.narrow(0, t, 1).unwrap(), grid, ScalarBoundaries::neumann()).unwrap(),
            ),
        };
        let next = fluid.step_unprojected(&state, Some(&scene.rate().unwrap())).unwrap().density.unwrap();
        let diff = (next.values() - seq.density.narrow(0, t + 1, 1).unwrap())
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert_eq!(diff, 0.0, "frame {t}");
    }
}

#[test]
fn parameter_maps_back_and_forth() {
    let n = LssNormalization::from_data(data()).unwrap();
    for p in [0.3, 0.45, 0.7] {
        assert!((n.code_to_param(n.param_to_code(p)) - p).abs() < 1e-12);
    }
    assert!((n.param_to_code(0.3) + 1.0).abs() < 1e-12 && (n.param_to_code(0.7) - 1.0).abs() < 1e-12);
    assert!(n.velocity.iter().all(|v| *v > 0.0) && n.density > 0.0);
}

#[test]
fn training_resumes_to_the_same_weights_and_refuses_other_settings() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = small_config(20, 1);
    let full = train_lss_autoencoder(data(), &cfg, None).unwrap();
    let run = dir.path().join("ae");
    train_lss_autoencoder(data(), &cfg, Some(&run)).unwrap();
    for e in std::fs::read_dir(&run).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        let step: Option<u64> =
            name.strip_prefix("step-").and_then(|r| r.split('.').next()).and_then(|n| n.parse().ok());
        if step.is_some_and(|s| s > 10) {
            std::fs::remove_file(&p).unwrap();
        }
    }
    let resumed = train_lss_autoencoder(data(), &cfg, Some(&run)).unwrap();
    let s = &data().test[0];
    let (v, d) = (s.velocity.narrow(0, 5, 2).unwrap(), s.density.narrow(0, 5, 2).unwrap());
    let (a, b) = (full.0.encode(&v, &d).unwrap(), resumed.0.encode(&v, &d).unwrap());
    let diff = (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    assert_eq!(diff, 0.0, "resumed weights differ");
    let mut other = cfg.clone();
    other.weights.split = 2.0;
    let e = train_lss_autoencoder(data(), &other, Some(&run)).err().expect("refused");
    assert!(e.to_string().contains("split"), "{e}");
}

#[test]
fn bad_shapes_and_settings_are_typed_errors() {
    let cfg = small_config(1, 1);
    let norm = LssNormalization::from_data(data()).unwrap();
    let ae = LssAutoencoder::new(&cfg, norm, &VarMap::new(), 0).unwrap();
    let z = |d: &[usize]| Tensor::zeros(d, DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(ae.encode(&z(&[1, 2, 8, 8]), &z(&[1, 1, 8, 8])), Err(Error::Shape { .. })));
    assert!(matches!(ae.encode(&z(&[2, 2, 16, 16]), &z(&[1, 1, 16, 16])), Err(Error::Shape { .. })));
    assert!(matches!(ae.encode(&z(&[1, 3, 16, 16]), &z(&[1, 1, 16, 16])), Err(Error::Shape { .. })));
    assert!(matches!(ae.decode(&z(&[1, 15])), Err(Error::Shape { .. })));
    assert!(matches!(ae.decode_normalized(&z(&[16])), Err(Error::Shape { .. })));
    assert_eq!(ae.encode(&z(&[3, 2, 16, 16]), &z(&[3, 1, 16, 16])).unwrap().dims(), [3, 16]);
    let (v, d) = ae.decode(&z(&[2, 16])).unwrap();
    assert_eq!((v.dims(), d.dims()), (&[2, 2, 16, 16][..], &[2, 1, 16, 16][..]));

    let bad = |f: &dyn Fn(&mut LssConfig)| {
        let mut c = small_config(1, 1);
        f(&mut c);
        c.validate().expect_err("refused")
    };
    assert!(matches!(bad(&|c| c.code_size = 17), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.velocity_part = 0), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.resolution = 18), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.widths = vec![]), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.window = 0), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.weights.split = f64::NAN), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.autoencoder_training.lr = 0.0), Error::Config { .. }));
    assert!(matches!(bad(&|c| c.predictor_training.batch = 0), Error::Config { .. }));
    let e = train_lss(data(), &LssConfig { resolution: 32, ..small_config(1, 1) }, None).err().unwrap();
    assert!(e.to_string().contains("resolution"), "{e}");
    let e = train_lss(data(), &LssConfig { rollout: 40, ..small_config(1, 1) }, None).err().unwrap();
    assert!(matches!(e, Error::Config { .. }), "{e}");
    let json = r#"{"resolution": 16, "unknown": 1}"#;
    assert!(serde_json::from_str::<LssConfig>(json).is_err());

    // Score and rollout arguments.
    let m = model();
    assert!(matches!(swap_score(&m.autoencoder, &data().test[..1]), Err(Error::Config { .. })));
    let seq = &data().test[0];
    let scene = data().config.scene(seq.param);
    assert!(matches!(lss_rollout(m, &scene, seq, 0, 3), Err(Error::Config { .. })));
    assert!(matches!(lss_rollout(m, &scene, seq, 5, 30), Err(Error::Config { .. })));
    let other = PlumeData { resolution: 24, ..data().config.clone() }.scene(0.5);
    assert!(matches!(lss_rollout(m, &other, seq, 5, 3), Err(Error::Config { .. })));
}
