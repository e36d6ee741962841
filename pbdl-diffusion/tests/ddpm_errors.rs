//! Bad input to the objective and the samplers gives typed errors that name the problem.

use candle_core::{DType, Device, Tensor};
use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle, Loss, NoisePredictor};
use pbdl_diffusion::schedule::NoiseSchedule;
use pbdl_diffusion::{Error, Result};

fn zeros(shape: &[usize]) -> Tensor {
    Tensor::zeros(shape, DType::F32, &Device::Cpu).unwrap()
}

/// A model that returns the wrong number of channels.
struct WrongOutput;
impl NoisePredictor for WrongOutput {
    fn predict(&self, x: &Tensor, _t: &Tensor) -> Result<Tensor> {
        Ok(x.narrow(1, 0, 1)?)
    }
}

#[test]
fn mismatched_conditions_are_shape_errors() {
    let s = NoiseSchedule::acdm(10).unwrap();
    // The model expects 1 condition + 1 target channel.
    let joint = GaussianOracle::joint(s.clone(), vec![0.0, 0.0], vec![1.0, 0.5, 0.5, 1.0]).unwrap();
    let clean = joint.clone().with_clean_condition(1).unwrap();
    let x = zeros(&[2, 1, 4, 4]);
    for (mode, model) in [(Conditioning::Noisy, &joint), (Conditioning::Clean, &clean)] {
        let d = Diffusion::new(s.clone(), mode);
        for (what, c) in [
            ("batch", zeros(&[3, 1, 4, 4])),
            ("height", zeros(&[2, 1, 5, 4])),
            ("width", zeros(&[2, 1, 4, 3])),
            ("channels vs model", zeros(&[2, 2, 4, 4])),
            ("rank", zeros(&[2, 1, 16])),
        ] {
            let ddpm = d.sample_ddpm(model, Some(&c), &x, 0);
            let ddim = d.sample_ddim(model, Some(&c), &x, &[0, 9], 0.0, 0);
            let loss = d.loss(model, &x, Some(&c), Loss::Mse, 0);
            for r in [ddpm, ddim, loss] {
                match r {
                    Err(Error::ShapeMismatch { what: w, .. }) => {
                        assert!(!w.is_empty(), "{mode:?} {what}")
                    }
                    other => panic!("{mode:?} {what}: expected ShapeMismatch, got {other:?}"),
                }
            }
        }
        // Without the condition the model sees too few channels.
        assert!(matches!(d.sample_ddpm(model, None, &x, 0), Err(Error::ShapeMismatch { .. })));
        // The right shapes work.
        assert!(d.sample_ddpm(model, Some(&zeros(&[2, 1, 4, 4])), &x, 0).is_ok());
    }
    let d = Diffusion::new(s, Conditioning::Clean);
    let e = d.sample_ddpm(&WrongOutput, None, &zeros(&[2, 2, 4, 4]), 0).unwrap_err();
    assert!(e.to_string().contains("model output"), "{e}");
}

#[test]
fn bad_sampler_settings_are_config_errors() {
    let s = NoiseSchedule::acdm(10).unwrap();
    let o = GaussianOracle::diagonal(s.clone(), &[0.0], &[1.0]).unwrap();
    let d = Diffusion::new(s, Conditioning::Clean);
    let x = zeros(&[1, 1, 2, 2]);
    for steps in [vec![], vec![3, 3], vec![5, 2], vec![0, 10]] {
        assert!(
            matches!(d.sample_ddim(&o, None, &x, &steps, 0.0, 0), Err(Error::InvalidConfig { .. })),
            "steps {steps:?}"
        );
    }
    for eta in [-0.1, f64::NAN] {
        assert!(matches!(d.sample_ddim(&o, None, &x, &[0, 9], eta, 0), Err(Error::InvalidConfig { .. })));
    }
    assert!(matches!(d.ddim_steps(0), Err(Error::InvalidConfig { .. })));
    assert!(matches!(d.ddim_steps(11), Err(Error::InvalidConfig { .. })));
    assert_eq!(d.ddim_steps(10).unwrap(), (0..10).collect::<Vec<_>>());
    assert_eq!(d.ddim_steps(1).unwrap(), vec![9]);
    assert_eq!(d.ddim_steps(4).unwrap(), vec![0, 3, 6, 9]);
    assert!(matches!(d.sample_ddpm_step(&o, None, &x, 10, 0), Err(Error::InvalidConfig { .. })));
    assert!(matches!(d.q_sample(&x, &[10], &x), Err(Error::InvalidConfig { .. })));
    assert!(matches!(d.q_sample(&x, &[1, 2], &x), Err(Error::ShapeMismatch { .. })));
    // Oracle settings.
    let s = NoiseSchedule::acdm(10).unwrap();
    assert!(GaussianOracle::diagonal(s.clone(), &[0.0], &[1.0, 2.0]).is_err());
    assert!(matches!(
        GaussianOracle::joint(s.clone(), vec![0.0, 0.0], vec![1.0, 2.0, 2.0, 1.0]),
        Err(Error::InvalidConfig { .. })
    ));
    assert!(GaussianOracle::diagonal(s, &[0.0], &[1.0]).unwrap().with_clean_condition(1).is_err());
    // Loss shapes.
    assert!(matches!(Loss::Huber.compute(&zeros(&[2]), &zeros(&[3])), Err(Error::ShapeMismatch { .. })));
}

#[test]
fn same_seed_same_sample() {
    let s = NoiseSchedule::acdm(10).unwrap();
    let joint = GaussianOracle::joint(s.clone(), vec![0.0, 1.0], vec![1.0, 0.5, 0.5, 1.0]).unwrap();
    let d = Diffusion::new(s, Conditioning::Noisy);
    let c = pbdl_core::seed::randn((2, 1, 3, 3), 0.0, 1.0, DType::F32, &Device::Cpu, 1).unwrap();
    let x = Diffusion::noise(&[2, 1, 3, 3], DType::F32, &Device::Cpu, 2).unwrap();
    let v = |seed| d.sample_ddpm(&joint, Some(&c), &x, seed).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(v(5), v(5));
    assert_ne!(v(5), v(6));
    let l = |seed| d.loss(&joint, &x, Some(&c), Loss::Huber, seed).unwrap().to_scalar::<f32>().unwrap();
    assert_eq!(l(1), l(1));
    assert_ne!(l(1), l(2));
}
