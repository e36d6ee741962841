//! ACDM rollout mechanics, evaluation and training plumbing with tiny untrained models and
//! exact stand-in predictors; typed errors for mismatched conditioning shapes.

use candle_core::{DType, Device, Tensor};
use pbdl_diffusion::acdm::data::{generate, CylinderConfig, CylinderDataset, Normalization, Sequence};
use pbdl_diffusion::acdm::eval::{evaluate, EvalConfig};
use pbdl_diffusion::acdm::model::{Method, Model, ModelConfig, Sampler};
use pbdl_diffusion::acdm::rollout::{rollout, FramePredictor};
use pbdl_diffusion::acdm::train::{loss, sample_windows, train, TrainConfig};
use pbdl_diffusion::{Error, Result};
use std::sync::OnceLock;

fn tiny() -> &'static (CylinderDataset, Normalization) {
    static D: OnceLock<(CylinderDataset, Normalization)> = OnceLock::new();
    D.get_or_init(|| {
        let d = generate(&CylinderConfig { frames: 120, ..CylinderConfig::tiny() }, &[300.0]).expect("tiny data");
        let n = Normalization::from_sequences(&d.sequences).expect("stats");
        (d, n)
    })
}

/// Replays the ground truth: the frame after the conditioning window, found by matching the
/// window's last frame against the sequence.
struct Replay {
    truth: Tensor,
    history: usize,
}

impl FramePredictor for Replay {
    fn history(&self) -> usize {
        self.history
    }
    fn predict(&self, prev: &Tensor, _seed: u64) -> Result<Tensor> {
        let (b, h, ..) = prev.dims5()?;
        let last = prev.narrow(1, h - 1, 1)?.squeeze(1)?.narrow(0, 0, 1)?;
        let t = self.truth.dim(0)?;
        for k in 0..t - 1 {
            let d = (self.truth.narrow(0, k, 1)? - &last)?.abs()?.max_all()?.to_scalar::<f32>()?;
            if d == 0.0 {
                return Ok(self.truth.narrow(0, k + 1, 1)?.repeat((b, 1, 1, 1))?);
            }
        }
        Err(Error::shape("replay", "a frame of the sequence", "an unknown frame"))
    }
    fn name(&self) -> String {
        "replay".into()
    }
}

/// Returns NaN from step `bad` on.
struct Breaks {
    bad: std::cell::Cell<usize>,
}

impl FramePredictor for Breaks {
    fn history(&self) -> usize {
        1
    }
    fn predict(&self, prev: &Tensor, _seed: u64) -> Result<Tensor> {
        let left = self.bad.get();
        self.bad.set(left.saturating_sub(1));
        let x = prev.narrow(1, 0, 1)?.squeeze(1)?;
        Ok(if left <= 1 { (x * f64::NAN)? } else { (x * 2.0)? })
    }
    fn name(&self) -> String {
        "breaks".into()
    }
}

#[test]
fn replaying_the_truth_scores_perfectly() {
    let (d, norm) = tiny();
    let seq = &d.sequences[0];
    let truth = norm.normalize(seq).unwrap();
    let model = Replay { truth, history: 2 };
    let cfg = EvalConfig { steps: 100, samples: 2, seed: 0, lsim_every: 50 };
    // LSiM of identical fields is exactly 0.
    let lsim = pbdl_diffusion::acdm::eval::load_lsim();
    let r = evaluate(&model, seq, norm, &d.config, &cfg, lsim.as_ref()).unwrap();
    match lsim {
        Some(_) => assert_eq!(r.lsim, [0.0; 3]),
        None => pbdl_core::testing::skip_or_fail("LSiM weights not found: the LSiM part of the evaluation"),
    }
    println!("{r:?}");
    assert_eq!((r.steps, r.first_non_finite), (100, None));
    assert!(r.mse < 1e-12, "{}", r.mse);
    assert!((r.stability_ratio() - 1.0).abs() < 1e-9);
    assert!(r.strouhal_error() < 1e-9 && r.strouhal_truth > 0.2);
    assert!(r.spread.unwrap() < 1e-12);
}

#[test]
fn rollout_resets_the_re_channel_and_stops_at_the_first_non_finite_frame() {
    let init = Tensor::ones((2, 1, 4, 8, 16), DType::F32, &Device::Cpu).unwrap();
    let model = Breaks { bad: std::cell::Cell::new(3) };
    let r = rollout(&model, &init, &[0.5, -0.25], 10, 0).unwrap();
    assert_eq!(r.first_non_finite, Some(3));
    assert_eq!(r.frames.dims(), &[2, 2, 4, 8, 16]);
    // Fields double each step; the Re channel is overwritten with the given values.
    let f = r.frames.narrow(2, 0, 1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert!(f[..256].iter().all(|&x| x == 2.0) && f[256..].iter().all(|&x| x == 4.0));
    let re = r.frames.narrow(2, 3, 1).unwrap().narrow(1, 1, 1).unwrap().flatten_all().unwrap();
    assert!(re.to_vec1::<f32>().unwrap().iter().all(|&x| x == -0.25));
}

#[test]
fn mismatched_conditioning_shapes_are_typed_errors() {
    let model = Model::new(ModelConfig::baseline(Method::Unet, 4)).unwrap();
    let acdm = Model::new(ModelConfig { dim: 4, ..ModelConfig::acdm(4) }).unwrap();
    let cases = [
        (&model, Tensor::zeros((1, 2, 4, 32, 64), DType::F32, &Device::Cpu).unwrap()), // 2 frames for a 1-frame model
        (&acdm, Tensor::zeros((1, 1, 4, 32, 64), DType::F32, &Device::Cpu).unwrap()),  // 1 frame for ACDM
        (&acdm, Tensor::zeros((1, 2, 3, 32, 64), DType::F32, &Device::Cpu).unwrap()),  // no Re channel
        (&acdm, Tensor::zeros((2, 4, 32, 64), DType::F32, &Device::Cpu).unwrap()),     // rank 4
    ];
    for (m, x) in cases {
        let e = m.predict(&x, 0).unwrap_err();
        println!("{e}");
        assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    }
    let init = Tensor::zeros((2, 1, 4, 32, 64), DType::F32, &Device::Cpu).unwrap();
    let e = rollout(&model, &init, &[0.0], 3, 0).unwrap_err();
    assert!(matches!(e, Error::ShapeMismatch { .. }), "{e}");
    // Bad method and sampler settings.
    assert!(matches!(
        Model::new(ModelConfig::baseline(Method::UnetUnrolled { m: 0 }, 4)),
        Err(Error::InvalidConfig { .. })
    ));
    assert!(matches!(
        Model::new(ModelConfig::baseline(Method::UnetNoise { sigma: f64::NAN }, 4)),
        Err(Error::InvalidConfig { .. })
    ));
    let mut m2 = Model::new(ModelConfig::baseline(Method::Unet, 4)).unwrap();
    assert!(m2.set_sampler(Sampler::Ddim(5)).is_err());
    let mut a2 = Model::new(ModelConfig::acdm(4)).unwrap();
    assert!(a2.set_sampler(Sampler::Ddim(21)).is_err());
    assert!(a2.set_sampler(Sampler::Ddim(5)).is_ok());
}

#[test]
fn untrained_acdm_samples_are_finite_and_spread() {
    let (d, norm) = tiny();
    let seq = Sequence { re: d.sequences[0].re, frames: d.sequences[0].frames.narrow(0, 0, 6).unwrap() };
    let mut m = Model::new(ModelConfig::acdm(4)).unwrap();
    m.set_sampler(Sampler::Ddim(1)).unwrap();
    let cfg = EvalConfig { steps: 2, samples: 2, seed: 7, lsim_every: 0 };
    let r = evaluate(&m, &seq, norm, &d.config, &cfg, None).unwrap();
    println!("{r:?}");
    assert_eq!(r.first_non_finite, None);
    assert!(r.spread.unwrap() > 1e-3, "{:?}", r.spread);
    // Same seed, same samples.
    let r2 = evaluate(&m, &seq, norm, &d.config, &cfg, None).unwrap();
    assert_eq!(r.mse, r2.mse);
}

#[test]
fn every_method_trains_one_step_and_resumes_from_its_checkpoint() {
    let (d, norm) = tiny();
    // A 16x32 crop keeps the plumbing test cheap (the U-Net needs multiples of 4).
    let full = norm.normalize(&d.sequences[0]).unwrap();
    let seqs = vec![full.narrow(0, 0, 12).unwrap().narrow(2, 8, 16).unwrap().narrow(3, 0, 32).unwrap()];
    for method in
        [Method::Acdm, Method::AcdmNcn, Method::Unet, Method::UnetUnrolled { m: 2 }, Method::UnetNoise { sigma: 0.01 }]
    {
        let dir = tempfile::tempdir().unwrap();
        let model = Model::new(ModelConfig::baseline(method, 4)).unwrap();
        let cfg = TrainConfig { steps: 1, batch: 2, checkpoint_every: 1, ..Default::default() };
        let r = train(&model, &seqs, &cfg, Some(dir.path())).unwrap();
        assert_eq!(r.losses.len(), 1);
        assert!(r.losses[0].1.is_finite() && r.losses[0].1 > 0.0, "{method:?}: {:?}", r.losses);
        // A second model resumes at step 1 and runs the remaining step.
        let again = Model::new(ModelConfig::baseline(method, 4)).unwrap();
        let r2 = train(&again, &seqs, &TrainConfig { steps: 2, ..cfg.clone() }, Some(dir.path())).unwrap();
        assert_eq!((r2.resumed_from, r2.losses.len()), (1, 1), "{method:?}");
        println!("{}: loss {:.4}, {:.3} s/step", method.name(), r.losses[0].1, r.seconds_per_step);
    }
    // The unrolled loss needs m + 1 frames per window.
    let model = Model::new(ModelConfig::baseline(Method::UnetUnrolled { m: 3 }, 4)).unwrap();
    let w = sample_windows(&seqs, 2, 1, &mut pbdl_core::seed::rng(0)).unwrap();
    assert!(matches!(loss(&model, &w, 0), Err(Error::ShapeMismatch { .. })));
}

#[test]
fn learning_rate_drops_to_the_late_rate_and_bad_rates_are_refused() {
    let cfg = TrainConfig { lr: 1e-3, lr_late_from: 3, lr_late: 1e-4, ..Default::default() };
    let rates: Vec<f64> = (0..5).map(|s| cfg.lr_at(s)).collect();
    assert_eq!(rates, vec![1e-3, 1e-3, 1e-3, 1e-4, 1e-4]);
    let never = TrainConfig { lr_late_from: 0, ..cfg.clone() };
    assert_eq!(never.lr_at(1_000_000), 1e-3);
    // Within one run: at a late rate of 1e-30 Adam's steps vanish in f32, so the weights stop
    // changing exactly where the late rate begins.
    let (d, norm) = tiny();
    let full = norm.normalize(&d.sequences[0]).unwrap();
    let seqs = vec![full.narrow(0, 0, 12).unwrap().narrow(2, 8, 16).unwrap().narrow(3, 0, 32).unwrap()];
    let weights = |m: &Model| -> Vec<f32> {
        let mut v: Vec<(String, Vec<f32>)> = m
            .varmap()
            .data()
            .lock()
            .unwrap()
            .iter()
            .map(|(k, var)| (k.clone(), var.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()))
            .collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v.into_iter().flat_map(|(_, w)| w).collect()
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg =
        TrainConfig { steps: 4, batch: 2, lr_late_from: 2, lr_late: 1e-30, checkpoint_every: 1, ..Default::default() };
    train(&Model::new(ModelConfig::baseline(Method::Unet, 4)).unwrap(), &seqs, &cfg, Some(dir.path())).unwrap();
    let at = |step: usize| {
        let m = Model::new(ModelConfig::baseline(Method::Unet, 4)).unwrap();
        pbdl_core::io::load_varmap(dir.path().join(format!("step-{step}.safetensors")), m.varmap()).unwrap();
        weights(&m)
    };
    let max_diff = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    let moved = max_diff(&at(1), &at(2));
    let frozen = max_diff(&at(2), &at(4));
    assert!(moved > 1e-4, "update 2 runs at lr 1e-3 and must move the weights ({moved:e})");
    assert!(frozen == 0.0, "updates 3 and 4 run at the late rate 1e-30: weights moved by {frozen:e}");
    let bad = TrainConfig { steps: 1, batch: 2, lr_late_from: 1, lr_late: f64::NAN, ..Default::default() };
    let model = Model::new(ModelConfig::baseline(Method::Unet, 4)).unwrap();
    assert!(matches!(train(&model, &seqs, &bad, None), Err(Error::InvalidConfig { name: "lr_late", .. })));
}

/// The initial weights come from the seed: equal for equal seeds, different otherwise (they
/// were drawn from candle's unseeded generator before, so no two runs started alike).
#[test]
fn model_weights_are_reproducible_from_the_seed() {
    let weights = |seed: u64| -> Vec<f32> {
        let m = Model::with_seed(ModelConfig::acdm(4), seed).unwrap();
        let data = m.varmap().data().lock().unwrap();
        let mut named: Vec<_> = data.iter().collect();
        named.sort_by(|a, b| a.0.cmp(b.0));
        named.iter().flat_map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
    };
    let (a, b, c) = (weights(3), weights(3), weights(4));
    assert_eq!(a, b);
    assert_ne!(a, c);
    let again = weights(0);
    let via_new: Vec<f32> = {
        let m = Model::new(ModelConfig::acdm(4)).unwrap();
        let data = m.varmap().data().lock().unwrap();
        let mut named: Vec<_> = data.iter().collect();
        named.sort_by(|x, y| x.0.cmp(y.0));
        named.iter().flat_map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
    };
    assert_eq!(again, via_new, "Model::new uses seed 0");
}
