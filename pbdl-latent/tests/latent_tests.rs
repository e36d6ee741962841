//! pbdl-latent end to end at toy size: the hybrid loop with interval 1 is the solver exactly,
//! a short training lowers both errors and gives finite hybrid rollouts, training resumes to the
//! same weights, and bad input (shapes, settings, corrupt files) is a typed error.

use candle_core::{DType, Device, Tensor};
use pbdl_core::stepper::Stepper;
use pbdl_latent::autoencoder::AutoencoderConfig;
use pbdl_latent::data::{generate, Dataset, PlumeData};
use pbdl_latent::eval::{autoencoder_error, prediction_error, relative_l2, rollout};
use pbdl_latent::hybrid::{HybridSmoke, HybridState, PressureSource, Schedule};
use pbdl_latent::model::LatentModel;
use pbdl_latent::predictor::PredictorConfig;
use pbdl_latent::train::{train, train_autoencoder, LatentTrainConfig, PhaseSettings};
use pbdl_latent::Error;
use std::sync::OnceLock;

fn data() -> &'static Dataset {
    static DATA: OnceLock<Dataset> = OnceLock::new();
    DATA.get_or_init(|| {
        let cfg = PlumeData { resolution: 16, train_scenes: 3, test_scenes: 1, frames: 40, ..PlumeData::default() };
        generate(&cfg).unwrap()
    })
}

fn small_config(ae_steps: u64, lstm_steps: u64) -> LatentTrainConfig {
    LatentTrainConfig {
        autoencoder: AutoencoderConfig {
            resolution: 16,
            widths: vec![8, 16],
            latent_channels: 4,
            ..Default::default()
        },
        predictor: PredictorConfig { window: 4, encoder_units: 32, decoder_units: 32, ..Default::default() },
        autoencoder_training: PhaseSettings { steps: ae_steps, batch: 8, lr: 2e-3 },
        predictor_training: PhaseSettings { steps: lstm_steps, batch: 8, lr: 2e-3 },
        seed: 3,
        gradient_loss_weight: 0.0,
    }
}

fn model() -> &'static LatentModel {
    static MODEL: OnceLock<LatentModel> = OnceLock::new();
    MODEL.get_or_init(|| train(data(), &small_config(300, 300), None).unwrap())
}

#[test]
fn schedule_solves_through_the_warmup_then_every_interval() {
    let s = Schedule { warmup: 3, interval: 4 };
    let solved: Vec<u64> = (0..12).filter(|&k| s.solves(k)).collect();
    assert_eq!(solved, [0, 1, 2, 3, 7, 11]);
}

#[test]
fn interval_one_is_the_solver_exactly() {
    let scene = data().config.scene(data().test[0].param);
    let fluid = scene.fluid().unwrap();
    let rate = scene.rate().unwrap();
    let hybrid =
        HybridSmoke::new(scene.fluid().unwrap(), rate.clone(), model(), Schedule { warmup: 4, interval: 1 }).unwrap();
    assert!(hybrid.operators().contains(&"latent.lstm(pressure)"));
    assert!(hybrid.operators().iter().any(|o| o.starts_with("pressure.") && *o != "pressure.correct(predicted)"));
    let mut a = scene.start(&fluid).unwrap();
    let mut h = HybridState::new(a.clone());
    for _ in 0..25 {
        a = fluid.step(&a, Some(&rate)).unwrap();
        h = hybrid.step(&h).unwrap();
        assert_eq!(h.last, Some(PressureSource::Solver));
    }
    let d = relative_l2(h.fluid.density.as_ref().unwrap().values(), a.density.as_ref().unwrap().values()).unwrap();
    assert_eq!(d, 0.0);
    assert_eq!(h.history.len(), 4);
}

#[test]
fn short_training_learns_and_hybrid_rollouts_stay_finite() {
    let untrained = train(data(), &small_config(1, 1), None).unwrap();
    let (before, after) =
        (autoencoder_error(&untrained, &data().test).unwrap(), autoencoder_error(model(), &data().test).unwrap());
    // Training must cut the reconstruction error well below the untrained network's (which
    // is about the field's own norm).
    assert!(after < 0.5 * before && after < 0.5, "AE error {before} -> {after}");
    let p = prediction_error(model(), &data().test).unwrap();
    assert!(p.predicted.is_finite() && p.floor > 0.0 && p.ratio >= 0.9, "{p:?}");
    let scene = data().config.scene(data().test[0].param);
    let r = rollout(model(), &scene, Schedule { warmup: 10, interval: 2 }, 40).unwrap();
    assert!(r.finite, "{r:?}");
    assert_eq!(r.predicted_steps, 15);
    assert!(r.density_error_max < 1.0 && r.divergence_ratio_max.is_finite(), "{r:?}");
}

#[test]
fn training_resumes_to_the_same_weights_and_refuses_other_settings() {
    let dir = tempfile::tempdir().unwrap();
    let full = train_autoencoder(data(), &small_config(20, 1), None).unwrap();
    // A run of 20 updates (checkpoints every 2) that lost its checkpoints after update 10.
    let run = dir.path().join("ae");
    train_autoencoder(data(), &small_config(20, 1), Some(&run)).unwrap();
    for e in std::fs::read_dir(&run).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        let step: Option<u64> =
            name.strip_prefix("step-").and_then(|r| r.split('.').next()).and_then(|n| n.parse().ok());
        if step.is_some_and(|s| s > 10) {
            std::fs::remove_file(&p).unwrap();
        }
    }
    let resumed = train_autoencoder(data(), &small_config(20, 1), Some(&run)).unwrap();
    let x = data().test[0].pressure.narrow(0, 5, 2).unwrap();
    let (a, b) = (full.0.reconstruct(&x).unwrap(), resumed.0.reconstruct(&x).unwrap());
    assert_eq!(relative_l2(&a, &b).unwrap(), 0.0, "resumed weights differ");
    // Other settings in the same directory: refused, naming the setting.
    let mut other = small_config(20, 1);
    other.autoencoder_training.lr = 1e-3;
    let e = train_autoencoder(data(), &other, Some(&run)).err().expect("refused");
    assert!(e.to_string().contains("lr"), "{e}");
    let other = LatentTrainConfig { gradient_loss_weight: 0.5, ..small_config(20, 1) };
    let e = train_autoencoder(data(), &other, Some(&run)).err().expect("refused");
    assert!(e.to_string().contains("gradient_loss_weight"), "{e}");
}

#[test]
fn bad_input_gives_typed_errors() {
    let m = model();
    let wrong = Tensor::zeros((1, 1, 8, 8), DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(m.autoencoder.encode(&wrong), Err(Error::Shape { .. })));
    let wrong = Tensor::zeros((1, 3, 7), DType::F32, &Device::Cpu).unwrap();
    assert!(matches!(m.predict(&wrong), Err(Error::Shape { .. })));
    let scene = data().config.scene(0.5);
    let e = HybridSmoke::new(scene.fluid().unwrap(), scene.rate().unwrap(), m, Schedule { warmup: 2, interval: 2 })
        .err()
        .unwrap();
    assert!(e.to_string().contains("warmup"), "{e}");
    let other = PlumeData { resolution: 24, ..data().config.clone() }.scene(0.5);
    let e = HybridSmoke::new(other.fluid().unwrap(), other.rate().unwrap(), m, Schedule { warmup: 6, interval: 2 })
        .err()
        .unwrap();
    assert!(e.to_string().contains("resolution"), "{e}");
    assert!(PlumeData { source_x: [0.0, 0.5], ..PlumeData::default() }.validate().is_err());
    // Save, load (same numbers), then corrupt the file: a typed error, no panic.
    let dir = tempfile::tempdir().unwrap();
    m.save(dir.path()).unwrap();
    let back = LatentModel::load(dir.path()).unwrap();
    let x = data().test[0].pressure.narrow(0, 5, 1).unwrap();
    let (a, b) = (m.encode_pressure(&x).unwrap(), back.encode_pressure(&x).unwrap());
    assert_eq!(relative_l2(&a, &b).unwrap(), 0.0);
    let f = dir.path().join("predictor.safetensors");
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() / 2]).unwrap();
    assert!(LatentModel::load(dir.path()).is_err());
}
