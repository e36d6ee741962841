//! Tests of TecoGAN's networks, the ping-pong loss, the triplet input and the trainer.

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::grad_check::{check_grad, GradCheckOptions};
use pbdl_core::sample::{resize2d, Resize};
use pbdl_temporal::data::{generate, SmokeData};
use pbdl_temporal::tecogan::*;
use pbdl_temporal::Error;
use std::collections::HashMap;

type R = Result<(), Box<dyn std::error::Error>>;

fn cpu() -> Device {
    Device::Cpu
}

fn uniform(shape: &[usize], lo: f64, hi: f64, dtype: DType, seed: u64) -> Tensor {
    pbdl_core::seed::rand_uniform(shape, lo, hi, dtype, &cpu(), seed).unwrap()
}

fn max_abs(t: &Tensor) -> f64 {
    t.abs().unwrap().flatten_all().unwrap().to_dtype(DType::F64).unwrap().max(0).unwrap().to_scalar().unwrap()
}

fn model(cfg: TecoGanConfig, dtype: DType, seed: u64) -> (TecoGan, VarMap) {
    let varmap = VarMap::new();
    let m = TecoGan::new(cfg, VarBuilder::from_varmap(&varmap, dtype, &cpu())).unwrap();
    pbdl_nets::seeded_init(&varmap, seed).unwrap();
    (m, varmap)
}

fn tiny() -> TecoGanConfig {
    TecoGanConfig {
        motion: MotionNetConfig { base_width: 2, levels: 1, max_flow: 2.0 },
        generator: RecurrentGeneratorConfig { channels: 4, blocks: 1, factor: 2 },
    }
}

fn set_zero(varmap: &VarMap, name: &str) {
    let data = varmap.data().lock().unwrap();
    let v = data.get(name).unwrap_or_else(|| panic!("no variable {name}"));
    v.set(&v.zeros_like().unwrap()).unwrap();
}

#[test]
fn shapes_of_f_g_and_sequences() -> R {
    let (m, _) = model(TecoGanConfig::default(), DType::F32, 0);
    let lr = uniform(&[2, 5, 1, 16, 16], 0.0, 1.0, DType::F32, 1);
    let flow = m.motion().forward(&lr.narrow(1, 0, 2)?.squeeze(2)?)?;
    assert_eq!(flow.dims(), [2, 2, 16, 16]);
    assert!(max_abs(&flow) <= 4.0);
    assert_eq!(m.generator().forward(&lr.narrow(1, 0, 1)?.squeeze(1)?, None)?.dims(), [2, 1, 64, 64]);
    let out = m.run_batch(&lr)?;
    assert_eq!(out.hr.dims(), [2, 5, 1, 64, 64]);
    assert_eq!(out.lr_flows.as_ref().unwrap().dims(), [2, 4, 2, 16, 16]);
    assert_eq!(m.run_sequence(&lr.get(0)?)?.dims(), [5, 1, 64, 64]);
    // Three levels need sizes divisible by 8: 16 works, 12 is a typed input error.
    let cfg3 = TecoGanConfig { motion: MotionNetConfig { levels: 3, ..Default::default() }, ..Default::default() };
    let (m3, _) = model(cfg3, DType::F32, 0);
    assert_eq!(m3.run_sequence(&lr.get(0)?)?.dims(), [5, 1, 64, 64]);
    let bad = uniform(&[3, 1, 12, 12], 0.0, 1.0, DType::F32, 2);
    assert!(matches!(m3.run_sequence(&bad), Err(Error::Input { .. })));
    Ok(())
}

#[test]
fn bad_configs_are_typed_errors() {
    let vb = || VarBuilder::from_varmap(&VarMap::new(), DType::F32, &cpu());
    let cfg = |f: fn(&mut TecoGanConfig)| {
        let mut c = TecoGanConfig::default();
        f(&mut c);
        c
    };
    for c in [
        cfg(|c| c.generator.factor = 3),
        cfg(|c| c.generator.channels = 0),
        cfg(|c| c.motion.max_flow = 0.0),
        cfg(|c| c.motion.levels = 0),
        cfg(|c| c.motion.base_width = 0),
    ] {
        assert!(matches!(TecoGan::new(c, vb()), Err(Error::Config { .. })));
    }
    for t in [
        TecoTrainConfig { frames: 1, ..Default::default() },
        TecoTrainConfig { lr: -1.0, ..Default::default() },
        TecoTrainConfig { pingpong_weight: f64::NAN, ..Default::default() },
        TecoTrainConfig { pingpong_sequences: false, ..Default::default() },
        TecoTrainConfig { batch: 0, ..Default::default() },
    ] {
        assert!(matches!(t.validate(), Err(Error::Config { .. })), "{t:?}");
    }
    assert!(TecoTrainConfig { pingpong_sequences: false, pingpong_weight: 0.0, ..Default::default() }
        .validate()
        .is_ok());
}

#[test]
fn frame_zero_uses_a_zero_recurrent_input() -> R {
    let (m, _) = model(TecoGanConfig::default(), DType::F32, 3);
    let lr = uniform(&[4, 1, 16, 16], 0.0, 1.0, DType::F32, 4);
    let g = m.generator();
    let zeros = Tensor::zeros((1, 1, 64, 64), DType::F32, &cpu())?;
    let a = g.forward(&lr.narrow(0, 0, 1)?, None)?;
    assert_eq!(max_abs(&(&a - g.forward(&lr.narrow(0, 0, 1)?, Some(&zeros))?)?), 0.0);
    let seq = m.run_sequence(&lr)?;
    assert_eq!(max_abs(&(seq.get(0)?.unsqueeze(0)? - &a)?), 0.0);
    // ...and later frames do use it: a non-zero recurrent input changes the output.
    let ones = zeros.ones_like()?;
    assert!(max_abs(&(&a - g.forward(&lr.narrow(0, 0, 1)?, Some(&ones))?)?) > 1e-4);
    // The rollout (detached, frame by frame) reproduces the graph-keeping run.
    let inf = m.infer_sequence(&lr)?;
    assert!(max_abs(&(&inf - &seq)?) < 1e-5, "{}", max_abs(&(&inf - &seq)?));
    Ok(())
}

#[test]
fn zeroed_output_conv_gives_the_bicubic_upsample() -> R {
    let (m, varmap) = model(TecoGanConfig::default(), DType::F32, 5);
    let lr = uniform(&[3, 1, 16, 16], 0.0, 1.0, DType::F32, 6);
    let bicubic = resize2d(&lr, (64, 64), Resize::Bicubic { align_corners: false })?;
    // Before: the random output conv adds a visible residual.
    assert!(max_abs(&(m.run_sequence(&lr)? - &bicubic)?) > 1e-3);
    set_zero(&varmap, "generator.output.weight");
    set_zero(&varmap, "generator.output.bias");
    let err = max_abs(&(m.run_sequence(&lr)? - &bicubic)?);
    assert!(err < 1e-6, "{err}");
    Ok(())
}

#[test]
fn pingpong_order_split_and_drift() -> R {
    let x = Tensor::arange(0f32, 4.0, &cpu())?.reshape((4, 1, 1, 1))?;
    let pp = pingpong_sequence(&x)?;
    assert_eq!(pp.flatten_all()?.to_vec1::<f32>()?, [0., 1., 2., 3., 2., 1., 0.]);
    let (f, b) = split_pingpong(&pp)?;
    assert_eq!(f.flatten_all()?.to_vec1::<f32>()?, [0., 1., 2.]);
    assert_eq!(b.flatten_all()?.to_vec1::<f32>()?, [0., 1., 2.]);
    assert_eq!(pingpong_loss(&pp)?.to_scalar::<f32>()?, 0.0);
    assert_eq!(reverse_time(&x)?.flatten_all()?.to_vec1::<f32>()?, [3., 2., 1., 0.]);
    // A batched sequence [B, T, ...] extends along axis 1.
    let xb = Tensor::stack(&[&x, &(&x * 10.0)?], 0)?;
    assert_eq!(pingpong_sequence(&xb)?.dims(), [2, 7, 1, 1, 1]);
    // drift = mean |a - b|.
    let y = (&x + 0.5)?;
    assert!((drift(&x, &y)? - 0.5).abs() < 1e-7);
    assert!(matches!(split_pingpong(&x), Err(Error::Input { .. })), "an even frame count is no ping-pong output");
    Ok(())
}

#[test]
fn pingpong_loss_vanishes_for_a_generator_that_ignores_its_recurrent_input() -> R {
    let (m, varmap) = model(TecoGanConfig::default(), DType::F32, 7);
    let lr = uniform(&[5, 1, 16, 16], 0.0, 1.0, DType::F32, 8);
    let pp = pingpong_sequence(&lr)?;
    let with_memory = pingpong_loss(&m.run_sequence(&pp)?)?.to_scalar::<f32>()?;
    assert!(with_memory > 1e-4, "a recurrent generator should see the history: {with_memory}");
    // Zero the input conv's weights on the 16 space-to-depth channels (1..17).
    {
        let data = varmap.data().lock().unwrap();
        let w = &data["generator.input.weight"];
        let keep = w.narrow(1, 0, 1)?;
        let zero = w.narrow(1, 1, 16)?.zeros_like()?;
        w.set(&Tensor::cat(&[keep, zero], 1)?)?;
    }
    let without = pingpong_loss(&m.run_sequence(&pp)?)?.to_scalar::<f32>()?;
    assert!(without < 1e-7, "{without}");
    Ok(())
}

/// The ping-pong loss of a tiny F + G as a function of a few of its parameters, rebuilt from
/// tensors on every call so that finite differences can perturb them.
#[test]
fn pingpong_loss_gradient_wrt_parameters_matches_finite_differences() -> R {
    let (_, varmap) = model(tiny(), DType::F64, 11);
    let base: HashMap<String, Tensor> =
        varmap.data().lock().unwrap().iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
    let names = [
        "generator.input.weight",
        "generator.ups.0.weight",
        "generator.output.bias",
        "fnet.head.1.weight",
        "fnet.enc.0.0.bias",
    ];
    let lr = pingpong_sequence(&uniform(&[3, 1, 4, 4], 0.0, 1.0, DType::F64, 12))?;
    let f = |params: &[Tensor]| -> candle_core::Result<Tensor> {
        let mut map = base.clone();
        for (n, p) in names.iter().zip(params) {
            map.insert(n.to_string(), p.clone());
        }
        let m = TecoGan::new(tiny(), VarBuilder::from_tensors(map, DType::F64, &Device::Cpu))
            .map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        let out = m.run_sequence(&lr).map_err(|e| candle_core::Error::Msg(e.to_string()))?;
        pingpong_loss(&out).map_err(|e| candle_core::Error::Msg(e.to_string()))
    };
    let inputs: Vec<Tensor> = names.iter().map(|n| base[*n].clone()).collect();
    let r = check_grad(f, &inputs, &GradCheckOptions { eps: 1e-6, max_probes: 12, seed: 3 })?;
    r.ensure(1e-5)?;
    assert!(r.per_input.iter().all(|e| e.is_finite()), "{:?}", r.per_input);
    Ok(())
}

#[test]
fn triplet_input_has_nine_channels_zeroed_crop_and_stop_gradient_flows() -> R {
    let (b, n, f) = (2, 8, 4);
    let hr = uniform(&[b, 3, n * f, n * f], 0.5, 1.0, DType::F32, 20);
    let lr = uniform(&[b, 3, n, n], 0.0, 1.0, DType::F32, 21);
    let flows = Var::from_tensor(&Tensor::zeros((b, 4, n * f, n * f), DType::F32, &cpu())?)?;
    let x = triplet_input(&hr, &lr, flows.as_tensor())?;
    assert_eq!(x.dims(), [b, TRIPLET_CHANNELS, n * f, n * f]);
    assert_eq!(max_abs(&(x.narrow(1, 0, 3)? - &hr)?), 0.0);
    let up = resize2d(&lr, (n * f, n * f), Resize::Bilinear { align_corners: false })?;
    assert_eq!(max_abs(&(x.narrow(1, 6, 3)? - &up)?), 0.0);
    // Zero flows: the warped triplet is the triplet inside the 24^2 centre (75% of 32), 0 outside.
    let warped = x.narrow(1, 3, 3)?;
    let inside = warped.narrow(2, 4, 24)?.narrow(3, 4, 24)?;
    assert!(max_abs(&(&inside - hr.narrow(2, 4, 24)?.narrow(3, 4, 24)?)?) < 1e-6);
    let total = warped.abs()?.sum_all()?.to_scalar::<f32>()?;
    let centre = inside.abs()?.sum_all()?.to_scalar::<f32>()?;
    assert!((total - centre).abs() < 1e-3 * total, "outside the crop: {}", total - centre);
    // A shifted flow moves the outer frames; no gradient reaches the flows.
    let shift = Var::from_tensor(&Tensor::ones((b, 4, n * f, n * f), DType::F32, &cpu())?)?;
    let hv = Var::from_tensor(&hr)?;
    let y = triplet_input(hv.as_tensor(), &lr, shift.as_tensor())?;
    assert!(max_abs(&(y.narrow(1, 3, 1)? - x.narrow(1, 3, 1)?)?) > 1e-3);
    let grads = y.sum_all()?.backward()?;
    assert!(grads.get(shift.as_tensor()).is_none(), "the warp flows must be stop-gradient");
    assert!(grads.get(hv.as_tensor()).is_some());
    // D_s,t consumes it.
    let varmap = VarMap::new();
    let d = pbdl_nets::discriminator::Discriminator::new(
        spatio_temporal_discriminator(vec![8, 16]),
        VarBuilder::from_varmap(&varmap, DType::F32, &cpu()),
    )?;
    assert_eq!(d.forward(&x)?.logits.dims(), [b]);
    // The flows of F have the documented layout and carry no graph.
    let (m, _) = model(TecoGanConfig::default(), DType::F32, 22);
    let fl = triplet_flows(m.motion(), &lr, f)?;
    assert_eq!(fl.dims(), [b, 4, n * f, n * f]);
    Ok(())
}

#[test]
fn a_short_training_run_decreases_the_loss_and_is_reproducible() -> R {
    let data = generate(&SmokeData {
        lr_resolution: 8,
        train_scenes: 2,
        test_scenes: 1,
        frames: 8,
        warmup: 10,
        ..SmokeData::default()
    })?;
    let cfg = TecoTrainConfig {
        model: TecoGanConfig {
            motion: MotionNetConfig { base_width: 4, levels: 2, max_flow: 2.0 },
            generator: RecurrentGeneratorConfig { channels: 8, blocks: 1, factor: 4 },
        },
        steps: 40,
        lr: 1e-3,
        batch: 2,
        frames: 3,
        ..Default::default()
    };
    let (_, _, r) = train_tecogan(&data.train, &cfg)?;
    let first = r.losses[..4].iter().sum::<f64>() / 4.0;
    let last = r.losses[r.losses.len() - 8..].iter().sum::<f64>() / 8.0;
    assert!(last < 0.7 * first, "loss {first} -> {last}");
    assert!(r.pingpong.iter().all(|p| p.is_finite()));
    // Same seed, a few updates: bit-identical; the ping-pong weight changes the updates.
    let short = TecoTrainConfig { steps: 3, ..cfg.clone() };
    let (_, _, a) = train_tecogan(&data.train, &short)?;
    assert_eq!(a.losses, r.losses[..3]);
    let (_, _, off) = train_tecogan(&data.train, &TecoTrainConfig { pingpong_weight: 0.0, ..short })?;
    assert_eq!(off.content[0], a.content[0], "the same data and weights at step 0");
    assert_ne!(off.content[2], a.content[2]);
    Ok(())
}

/// A recurrent model file round-trips: `LoadedModel::load` recognises it, its upscale equals the
/// in-memory rollout bit for bit, `upscale_npz` writes the same frames, and the wrong loader,
/// a mismatched layout and a short input are typed errors that say what to do.
#[test]
fn recurrent_model_file_round_trip_and_upscale() -> R {
    use pbdl_temporal::model::{upscale_npz, LoadedModel, RecurrentModel, RecurrentModelInfo, TemporalModel, Upscale};
    let (m, varmap) = model(tiny(), DType::F32, 7);
    let info = RecurrentModelInfo { tecogan: tiny(), objective: "test".into(), updates: 3 };
    let rec = RecurrentModel::new(info.clone(), varmap.clone())?;
    let dir = std::env::temp_dir().join(format!("pbdl_temporal_recurrent_{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("teco.safetensors");
    rec.save(&path)?;

    let lr = uniform(&[4, 1, 8, 8], 0.0, 1.0, DType::F32, 3);
    let expected = m.infer_sequence(&lr)?;
    let loaded = LoadedModel::load(&path)?;
    assert!(matches!(&loaded, LoadedModel::Recurrent(r) if r.info == info), "{loaded:?}");
    assert_eq!(loaded.factor(), 2);
    let got = loaded.upscale(&lr, None)?;
    assert_eq!(got.dims(), [4, 1, 16, 16]);
    assert_eq!(max_abs(&(&got - &expected)?), 0.0);

    let (input, output) = (dir.join("lr.npz"), dir.join("hr.npz"));
    pbdl_core::io::write_npz(&input, &[("density", &lr)])?;
    assert_eq!(upscale_npz(&loaded, &input, &output)?, vec![4, 1, 16, 16]);
    let written = pbdl_core::io::read_npz(&output)?;
    assert_eq!(max_abs(&(&written[0].1 - &expected)?), 0.0);

    let err = TemporalModel::load(&path).unwrap_err().to_string();
    assert!(err.contains("RecurrentModel::load"), "{err}");
    let other = TecoGanConfig { generator: RecurrentGeneratorConfig { channels: 6, ..tiny().generator }, ..tiny() };
    let err = RecurrentModel::new(RecurrentModelInfo { tecogan: other, ..info }, varmap).unwrap_err().to_string();
    assert!(err.contains("shape"), "{err}");
    let err = loaded.upscale(&lr.narrow(1, 0, 1)?.squeeze(1)?, None).unwrap_err().to_string();
    assert!(err.contains("density"), "{err}");
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
