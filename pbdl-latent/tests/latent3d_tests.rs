//! The 3D part of latent-space physics at toy size (8^3): data shapes and the pressure split,
//! autoencoder shapes, training lowers the held-out error, typed errors for bad configurations
//! and shapes, and the resume guard of the run directory.

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use pbdl_latent::autoencoder3d::{
    autoencoder3d_error, train_autoencoder3d, upsample_nearest3d, Autoencoder3dConfig, Autoencoder3dTrainConfig,
    LatentAutoencoder3d,
};
use pbdl_latent::data3d::{generate3d, PlumeData3d};
use pbdl_latent::train::PhaseSettings;
use pbdl_latent::Error;

fn toy_data() -> PlumeData3d {
    PlumeData3d { resolution: 8, train_scenes: 2, test_scenes: 1, frames: 10, ..PlumeData3d::default() }
}

fn toy_ae() -> Autoencoder3dConfig {
    Autoencoder3dConfig { resolution: 8, widths: vec![4, 8], latent_channels: 4, ..Autoencoder3dConfig::default() }
}

#[test]
fn data_keeps_the_pressure_of_every_step() {
    let data = generate3d(&toy_data()).unwrap();
    assert_eq!(data.train.len(), 2);
    let s = &data.test[0];
    assert_eq!(s.pressure.dims(), [10, 1, 8, 8, 8]);
    assert_eq!(s.velocity.dims(), [10, 3, 8, 8, 8]);
    assert_eq!(s.density.dims(), [10, 1, 8, 8, 8]);
    let p_last = s.pressure.narrow(0, 9, 1).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
    assert!(p_last > 0.0 && p_last.is_finite());
    // Frame t+1 of the sequence is the solver's step from frame t.
    let scene = data.config.scene(s.param);
    let smoke = scene.smoke().unwrap();
    let state = pbdl_grid::grid3d::Smoke3dState {
        velocity: pbdl_grid::grid3d::MacField3d::new(s.velocity.narrow(0, 4, 1).unwrap(), *smoke.grid()).unwrap(),
        density: s.density.narrow(0, 4, 1).unwrap(),
    };
    let next = smoke.step(&state, None).unwrap();
    let d = (next.velocity.values() - s.velocity.narrow(0, 5, 1).unwrap()).unwrap().abs().unwrap().max_all().unwrap();
    assert_eq!(d.to_scalar::<f32>().unwrap(), 0.0);
}

#[test]
fn autoencoder_shapes_and_upsampling() {
    let varmap = VarMap::new();
    let ae = LatentAutoencoder3d::new(toy_ae(), &varmap, 3).unwrap();
    assert_eq!(ae.code_size(), 4 * 2 * 2 * 2);
    let x = Tensor::randn(0f32, 1.0, (2, 1, 8, 8, 8), &Device::Cpu).unwrap();
    let z = ae.encode(&x).unwrap();
    assert_eq!(z.dims(), [2, 32]);
    assert_eq!(ae.decode(&z).unwrap().dims(), [2, 1, 8, 8, 8]);
    // The first kernel is the paper's 4^3, the others 2^3.
    let names: Vec<String> = varmap.data().lock().unwrap().keys().cloned().collect();
    assert!(names.contains(&"enc0.weight".to_string()), "{names:?}");
    assert_eq!(varmap.data().lock().unwrap()["enc0.weight"].dims(), [4, 1, 4, 4, 4]);
    assert_eq!(varmap.data().lock().unwrap()["enc1.weight"].dims(), [8, 4, 2, 2, 2]);
    let a = Tensor::arange(0f32, 8.0, &Device::Cpu).unwrap().reshape((1, 1, 2, 2, 2)).unwrap();
    let u = upsample_nearest3d(&a).unwrap();
    assert_eq!(u.dims(), [1, 1, 4, 4, 4]);
    let v: Vec<f32> = u.flatten_all().unwrap().to_vec1().unwrap();
    for k in 0..4 {
        for j in 0..4 {
            for i in 0..4 {
                assert_eq!(v[(k * 4 + j) * 4 + i], ((k / 2 * 2 + j / 2) * 2 + i / 2) as f32);
            }
        }
    }
}

#[test]
fn bad_configurations_and_shapes_are_typed_errors() {
    let varmap = VarMap::new();
    for bad in [
        Autoencoder3dConfig { resolution: 12, widths: vec![4, 8, 8], ..toy_ae() },
        Autoencoder3dConfig { widths: vec![], ..toy_ae() },
        Autoencoder3dConfig { first_kernel: 3, ..toy_ae() },
        Autoencoder3dConfig { latent_channels: 0, ..toy_ae() },
    ] {
        assert!(matches!(LatentAutoencoder3d::new(bad, &varmap, 0), Err(Error::Config { .. })));
    }
    let ae = LatentAutoencoder3d::new(toy_ae(), &VarMap::new(), 0).unwrap();
    for dims in [vec![1usize, 1, 8, 8], vec![1, 2, 8, 8, 8], vec![1, 1, 8, 8, 4]] {
        let x = Tensor::zeros(dims, DType::F32, &Device::Cpu).unwrap();
        assert!(matches!(ae.encode(&x), Err(Error::Shape { .. })));
    }
    let f64_input = Tensor::zeros((1, 1, 8, 8, 8), DType::F64, &Device::Cpu).unwrap();
    assert!(matches!(ae.encode(&f64_input), Err(Error::Shape { .. })));
    assert!(matches!(ae.decode(&Tensor::zeros((1, 31), DType::F32, &Device::Cpu).unwrap()), Err(Error::Shape { .. })));
    assert!(matches!(
        upsample_nearest3d(&Tensor::zeros((1, 2, 2), DType::F32, &Device::Cpu).unwrap()),
        Err(Error::Shape { .. })
    ));
    for bad in [
        PlumeData3d { resolution: 4, ..toy_data() },
        PlumeData3d { frames: 1, ..toy_data() },
        PlumeData3d { source_x: [0.0, 0.5], ..toy_data() },
        PlumeData3d { rate: -1.0, ..toy_data() },
    ] {
        assert!(matches!(generate3d(&bad), Err(Error::Config { .. })));
    }
}

#[test]
fn training_lowers_the_held_out_error_and_the_run_dir_guards_resume() {
    let data = generate3d(&toy_data()).unwrap();
    let cfg = |steps| Autoencoder3dTrainConfig {
        autoencoder: toy_ae(),
        training: PhaseSettings { steps, batch: 4, lr: 3e-3 },
        seed: 1,
    };
    let untrained = train_autoencoder3d(&data, &cfg(1), None).unwrap();
    let e0 = autoencoder3d_error(&untrained, &data.test).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let trained = train_autoencoder3d(&data, &cfg(150), Some(dir.path())).unwrap();
    let e1 = autoencoder3d_error(&trained, &data.test).unwrap();
    assert!(e1.is_finite() && e1 < 0.7 * e0, "held-out rel L2 {e0:.4} -> {e1:.4}");
    assert!(dir.path().join("loss.csv").exists());
    // Other settings in the same run directory: a typed error naming the setting.
    let mut other = cfg(150);
    other.training.lr = 1e-3;
    let e = train_autoencoder3d(&data, &other, Some(dir.path())).unwrap_err();
    assert!(matches!(e, Error::Core(_)), "{e}");
    assert!(e.to_string().contains("lr"), "{e}");
    // Wrong resolution, bad settings.
    let mut wrong = cfg(10);
    wrong.autoencoder.resolution = 16;
    assert!(matches!(train_autoencoder3d(&data, &wrong, None), Err(Error::Config { .. })));
    let mut zero = cfg(10);
    zero.training.batch = 0;
    assert!(matches!(train_autoencoder3d(&data, &zero, None), Err(Error::Config { .. })));
}
