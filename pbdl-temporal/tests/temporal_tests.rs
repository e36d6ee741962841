//! Data, generator, discriminator inputs, model files and training of pbdl-temporal.

use candle_core::{DType, Device, Tensor};
use pbdl_temporal::data::{box_downsample, generate, SmokeData};
use pbdl_temporal::gan::temporal_input;
use pbdl_temporal::generator::GeneratorConfig;
use pbdl_temporal::model::{upscale_npz, ModelKind, TemporalModel};
use pbdl_temporal::train::{finetune, pretrain, PhaseSettings, TrainConfig};
use pbdl_temporal::Error;

fn tiny_data() -> SmokeData {
    SmokeData { lr_resolution: 8, train_scenes: 2, test_scenes: 1, frames: 8, warmup: 20, ..SmokeData::default() }
}

fn tiny_train() -> TrainConfig {
    TrainConfig {
        generator: GeneratorConfig { channels: 8, ..GeneratorConfig::default() },
        pretrain: PhaseSettings { steps: 40, batch: 4, lr: 2e-3 },
        finetune: PhaseSettings { steps: 6, batch: 2, lr: 2e-4 },
        discriminator_widths: vec![8, 8],
        ..TrainConfig::default()
    }
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f32 {
    (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap()
}

#[test]
fn data_shapes_units_and_box_average() -> pbdl_temporal::Result<()> {
    let cfg = tiny_data();
    let data = generate(&cfg)?;
    let c = &data.train[0];
    assert_eq!(c.hr_density.dims(), [8, 1, 32, 32]);
    assert_eq!(c.lr_density.dims(), [8, 1, 8, 8]);
    assert_eq!(c.lr_velocity.dims(), [8, 2, 8, 8]);
    // The box average keeps the mean (mass) of every frame.
    let m_hr = c.hr_density.mean((1, 2, 3))?.to_vec1::<f32>()?;
    let m_lr = c.lr_density.mean((1, 2, 3))?.to_vec1::<f32>()?;
    for (a, b) in m_hr.iter().zip(&m_lr) {
        assert!((a - b).abs() <= 1e-6 * a.abs().max(1.0), "{a} vs {b}");
    }
    // Smoke rises: the mean vertical velocity over the smoke is positive.
    let vy = c.lr_velocity.narrow(1, 1, 1)?;
    let up = (vy * &c.lr_density)?.sum_all()?.to_scalar::<f32>()?;
    assert!(up > 0.0, "smoke-weighted vertical velocity {up}");
    // Density in roughly [0, 1] with the default scale.
    let max = c.hr_density.max_all()?.to_scalar::<f32>()?;
    assert!(max > 0.05 && max < 2.0, "max density {max}");
    // Scenes differ; same seed, same data.
    assert!(max_abs_diff(&data.train[0].hr_density, &data.train[1].hr_density) > 1e-3);
    assert_eq!(
        generate(&cfg)?.test[0].hr_density.flatten_all()?.to_vec1::<f32>()?,
        data.test[0].hr_density.flatten_all()?.to_vec1::<f32>()?
    );
    // Bad settings name the field.
    let err = generate(&SmokeData { noise: 2.0, ..cfg.clone() }).unwrap_err();
    assert!(err.to_string().contains("noise"), "{err}");
    let err = box_downsample(&Tensor::zeros((1, 1, 6, 6), DType::F32, &Device::Cpu)?, 4).unwrap_err();
    assert!(err.to_string().contains("multiples"), "{err}");
    Ok(())
}

#[test]
fn advection_with_the_true_velocity_aligns_consecutive_frames() -> pbdl_temporal::Result<()> {
    // The temporal discriminator's premise: advecting frame t-1 (and t+1) to t with the
    // low-resolution velocity brings it closer to frame t than leaving it in place.
    let data = generate(&SmokeData { train_scenes: 1, steps_per_frame: 2, ..tiny_data() })?;
    let c = &data.train[0];
    let hr = c.hr_density.narrow(0, 3, 3)?;
    let vel = c.lr_velocity.narrow(0, 3, 3)?;
    let x = temporal_input(&hr, &vel, 4)?;
    // Rows above the inflow disc (>= 30% of the height): there the change between frames is
    // transport only; inside the disc new (noisy) smoke appears that no advection can explain.
    let above = |a: &Tensor| a.narrow(2, 10, 22).unwrap();
    let mid = above(&x.narrow(1, 1, 1)?);
    let err = |a: &Tensor| (above(a) - &mid).unwrap().abs().unwrap().mean_all().unwrap().to_scalar::<f32>().unwrap();
    let (adv_prev, adv_next) = (err(&x.narrow(1, 0, 1)?), err(&x.narrow(1, 2, 1)?));
    let (raw_prev, raw_next) = (err(&hr.narrow(0, 0, 1)?), err(&hr.narrow(0, 2, 1)?));
    assert!(adv_prev < 0.8 * raw_prev, "forward: advected {adv_prev} vs in place {raw_prev}");
    assert!(adv_next < 0.8 * raw_next, "backward: advected {adv_next} vs in place {raw_next}");
    Ok(())
}

#[test]
fn untrained_generator_with_zero_output_is_bicubic_and_checks_inputs() -> pbdl_temporal::Result<()> {
    let model =
        TemporalModel::untrained(ModelKind::Baseline, GeneratorConfig { channels: 4, ..Default::default() }, 1)?;
    {
        let data = model.varmap.data().lock().unwrap();
        for (name, var) in data.iter() {
            if name.starts_with("output.") {
                var.set(&var.as_tensor().zeros_like()?)?;
            }
        }
    }
    let lr = Tensor::rand(0f32, 1.0, (3, 1, 8, 8), &Device::Cpu)?;
    let bicubic =
        pbdl_core::sample::resize2d(&lr, (32, 32), pbdl_core::sample::Resize::Bicubic { align_corners: false })?;
    assert!(max_abs_diff(&model.upscale(&lr, None)?, &bicubic) < 1e-6);
    let nan = lr.broadcast_mul(&Tensor::new(&[f32::NAN], &Device::Cpu)?)?;
    match model.upscale(&nan, None) {
        Err(Error::Input { array, reason }) => assert!(array == "density" && reason.contains("non-finite"), "{reason}"),
        other => panic!("expected an input error, got {other:?}"),
    }
    let bad_v = Tensor::zeros((2, 2, 8, 8), DType::F32, &Device::Cpu)?;
    match model.upscale(&lr, Some(&bad_v)) {
        Err(Error::Input { array, .. }) => assert_eq!(array, "velocity"),
        other => panic!("expected a velocity error, got {other:?}"),
    }
    match model.upscale(&Tensor::zeros((3, 2, 8, 8), DType::F32, &Device::Cpu)?, None) {
        Err(Error::Input { array, .. }) => assert_eq!(array, "density"),
        other => panic!("expected a density error, got {other:?}"),
    }
    Ok(())
}

#[test]
fn model_files_and_npz_upscaling() -> pbdl_temporal::Result<()> {
    let dir = tempfile::tempdir().unwrap();
    let model =
        TemporalModel::untrained(ModelKind::Temporal, GeneratorConfig { channels: 4, ..Default::default() }, 3)?;
    let path = dir.path().join("m.safetensors");
    model.save(&path)?;
    let back = TemporalModel::load(&path)?;
    assert_eq!(back.info, model.info);
    let lr = Tensor::rand(0f32, 1.0, (4, 1, 8, 8), &Device::Cpu)?;
    assert_eq!(max_abs_diff(&back.upscale(&lr, None)?, &model.upscale(&lr, None)?), 0.0);
    // npz round trip, f64 input accepted.
    let input = dir.path().join("lr.npz");
    let vel = Tensor::zeros((4, 2, 8, 8), DType::F64, &Device::Cpu)?;
    pbdl_core::io::write_npz(&input, &[("density", &lr.to_dtype(DType::F64)?), ("velocity", &vel)])?;
    let out = dir.path().join("hr.npz");
    assert_eq!(upscale_npz(&back, &input, &out)?, vec![4, 1, 32, 32]);
    let hr = pbdl_core::io::read_npz_array(&out, "density")?;
    assert!(max_abs_diff(&hr, &model.upscale(&lr, None)?) < 1e-6);
    // Missing density names the array and what the file holds.
    let only_v = dir.path().join("v.npz");
    pbdl_core::io::write_npz(&only_v, &[("velocity", &vel)])?;
    match upscale_npz(&back, &only_v, &out) {
        Err(Error::Input { array, reason }) => assert!(array == "density" && reason.contains("velocity"), "{reason}"),
        other => panic!("expected a missing-density error, got {other:?}"),
    }
    // A file that is not a model.
    std::fs::write(dir.path().join("x.safetensors"), b"nonsense").unwrap();
    assert!(TemporalModel::load(&dir.path().join("x.safetensors")).is_err());
    Ok(())
}

#[test]
fn training_lowers_the_error_and_resumes_exactly() -> pbdl_temporal::Result<()> {
    let data = generate(&tiny_data())?;
    let cfg = tiny_train();
    let untrained = TemporalModel::untrained(ModelKind::Baseline, cfg.generator.clone(), cfg.seed)?;
    let l1 = |m: &TemporalModel| -> f32 {
        let c = &data.train[0];
        (m.upscale(&c.lr_density, None).unwrap() - &c.hr_density)
            .unwrap()
            .abs()
            .unwrap()
            .mean_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap()
    };
    let (start, s) = pretrain(&data, &cfg, None)?;
    assert!(s.final_loss.is_finite());
    assert!(l1(&start) < 0.9 * l1(&untrained), "pretrained {} vs untrained {}", l1(&start), l1(&untrained));
    // The temporal GAN phase: stopped after 3 updates and resumed equals one run of 6.
    let dir = tempfile::tempdir().unwrap();
    let short = TrainConfig { finetune: PhaseSettings { steps: 3, ..cfg.finetune.clone() }, ..cfg.clone() };
    let err = finetune(&data, &short, ModelKind::Temporal, &start, Some(dir.path()));
    assert!(err.is_ok(), "{err:?}");
    let (resumed, _) = finetune(&data, &cfg, ModelKind::Temporal, &start, Some(dir.path()))?;
    let (straight, _) = finetune(&data, &cfg, ModelKind::Temporal, &start, None)?;
    let lr = &data.test[0].lr_density;
    assert_eq!(max_abs_diff(&resumed.upscale(lr, None)?, &straight.upscale(lr, None)?), 0.0);
    // A run directory of other settings is refused, naming the setting.
    let other = TrainConfig { seed: 9, ..cfg.clone() };
    let err = finetune(&data, &other, ModelKind::Temporal, &start, Some(dir.path())).unwrap_err();
    assert!(err.to_string().contains("seed"), "{err}");
    Ok(())
}
