//! pbdl-nets' bench entries: the training steps of the networks the coming methods train,
//! against PyTorch CPU on the same threads (issue 17). The peer rows come from
//! `bench/peers/nets_run.sh` (`target/pbdl/bench/nets_peers.json`), which builds the same
//! networks in PyTorch from the same descriptions; `cargo xtask bench nets` merges them.
//!
//! * `training_steps`: the WeatherBench ResNet training step (Rasp & Thuerey 2021: periodic
//!   7x7 conv 117 -> 128, 19 residual blocks of two periodic 3x3 conv -> LeakyReLU 0.3 ->
//!   BatchNorm units, periodic 3x3 conv -> 3; batch 4 on 32x64, MSE, Adam), a TecoGAN generator
//!   forward + backward (51 channels at 32x32, 3x3 conv -> 64 + ReLU, 16 residual blocks, two
//!   stride-2 transposed convs, 3x3 conv -> 3, plus bicubic x4 of the LR frame; batch 4) and an
//!   LSTM over 6 latent vectors (batch 16, input = hidden = 256 and 1024) forward + backward;
//!   pbdl-weather's CPU-sized forecaster (10 inputs, width 32, 4 blocks, batch 32) one Adam step.

use crate::bench_schema::{median_seconds, BenchRow};
use crate::registry::{CrateTasks, Entry, TaskContext, TaskResult};
use candle_core::{DType, Device, Module, Tensor};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::conv::{conv_transpose_act, Conv2d, Conv2dParams, ConvLayerConfig};
use pbdl_core::nn::Activation;
use pbdl_core::sample::{resize2d, Resize};
use pbdl_core::seed;
use pbdl_core::train::{AdamConfig, OptimizerConfig};
use pbdl_nets::recurrent::{Lstm, LstmConfig};
use pbdl_weather::forecaster::{ResNetConfig, WeatherResNet};

/// The entries of `pbdl-nets`.
pub fn tasks() -> CrateTasks {
    CrateTasks {
        crate_name: "nets",
        tour: vec![],
        bench: vec![Entry {
            name: "training_steps",
            about: "WeatherBench ResNet train step, TecoGAN generator fwd+bwd, LSTM fwd+bwd (vs PyTorch CPU).",
            run: bench_training_steps,
        }],
        stress: vec![],
    }
}

fn row(case: &str, size: &str, seconds: f64, threads: usize) -> BenchRow {
    BenchRow {
        case: case.into(),
        method: "pbdl".into(),
        size: size.into(),
        seconds,
        unit: "step".into(),
        error: None,
        error_kind: String::new(),
        peer: false,
        threads,
    }
}

struct TecoGenerator {
    input: Conv2d,
    blocks: Vec<(Conv2d, Conv2d)>,
    up: [(Tensor, Tensor); 2],
    output: Conv2d,
}

impl TecoGenerator {
    fn new(vb: VarBuilder) -> TaskResult<Self> {
        let conv = |c_in, c_out, vb: VarBuilder| {
            ConvLayerConfig::<2>::new(c_in, c_out, [3, 3]).with_params(Conv2dParams::default().padding(1)).init(vb)
        };
        let input = conv(51, 64, vb.pp("in"))?;
        let blocks = (0..16)
            .map(|i| Ok((conv(64, 64, vb.pp(format!("block{i}.a")))?, conv(64, 64, vb.pp(format!("block{i}.b")))?)))
            .collect::<TaskResult<_>>()?;
        let up = |name: &str| -> TaskResult<(Tensor, Tensor)> {
            // PyTorch's ConvTranspose2d layout [in, out, ky, kx] and default init bound.
            let bound = 1.0 / ((64 * 9) as f64).sqrt();
            let init = candle_nn::Init::Uniform { lo: -bound, up: bound };
            Ok((
                vb.get_with_hints((64, 64, 3, 3), &format!("{name}.weight"), init)?,
                vb.get_with_hints(64, &format!("{name}.bias"), init)?,
            ))
        };
        let up = [up("up1")?, up("up2")?];
        let output = conv(64, 3, vb.pp("out"))?;
        Ok(Self { input, blocks, up, output })
    }

    fn forward(&self, x: &Tensor) -> TaskResult<Tensor> {
        let lr = x.narrow(1, 0, 3)?;
        let mut h = self.input.forward_act(x, Activation::Relu)?;
        for (a, b) in &self.blocks {
            h = (&h + b.forward(&a.forward_act(&h, Activation::Relu)?)?)?;
        }
        let stride2 = Conv2dParams::default().stride(2).padding(1);
        for (w, b) in &self.up {
            h = conv_transpose_act(&h, w, Some(b), &stride2, [1, 1], Activation::Relu)?;
        }
        let (_, _, hh, ww) = lr.dims4()?;
        let bicubic = resize2d(&lr, (4 * hh, 4 * ww), Resize::Bicubic { align_corners: false })?;
        Ok((self.output.forward(&h)? + bicubic)?)
    }
}

fn mse(a: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    (a - b)?.sqr()?.mean_all()
}

/// Whether the case runs: all of them, or those named in `PBDL_NETS_CASES` (comma-separated,
/// like the peer script's `--only`), for profiling one network at a time.
fn selected(case: &str) -> bool {
    std::env::var("PBDL_NETS_CASES").map_or(true, |list| list.split(',').any(|c| c.trim() == case))
}

fn bench_training_steps(ctx: &TaskContext) -> TaskResult<Vec<BenchRow>> {
    let dev = Device::Cpu;
    let reps = if ctx.quick { 2 } else { 5 };
    let mut rows = Vec::new();

    // WeatherBench ResNet: one Adam step.
    if selected("weather_resnet_train_step") {
        let varmap = VarMap::new();
        // pbdl-weather's network at full size, without dropout (as the PyTorch peer).
        let cfg = ResNetConfig { dropout: 0.0, ..ResNetConfig::full_size(117, 3) };
        let net = WeatherResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &dev))?;
        let trainable = pbdl_core::nn::batch_norm::trainable_vars(&varmap);
        let mut opt = OptimizerConfig::Adam(AdamConfig { lr: 1e-4, ..Default::default() }).build(trainable)?;
        let x = seed::randn((4, 117, 32, 64), 0.0, 1.0, DType::F32, &dev, 1)?;
        let y = seed::randn((4, 3, 32, 64), 0.0, 1.0, DType::F32, &dev, 2)?;
        let s = median_seconds(1, reps, || -> TaskResult<()> {
            let loss = mse(&net.forward(&x, true, 0)?, &y)?;
            candle_nn::Optimizer::backward_step(&mut opt, &loss)?;
            Ok(())
        });
        rows.push(row("weather_resnet_train_step", "b4_c117_w128_blocks19_32x64", s, ctx.threads));
    }

    // pbdl-weather's CPU-sized forecaster as the stand-in experiment trains it (no dropout,
    // as the peer): one Adam step at batch 32.
    if selected("weather_cpu_resnet_train_step") {
        let varmap = VarMap::new();
        let cfg = ResNetConfig { width: 32, blocks: 4, dropout: 0.0, ..ResNetConfig::cpu_size(10, 2) };
        let net = WeatherResNet::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &dev))?;
        let trainable = pbdl_core::nn::batch_norm::trainable_vars(&varmap);
        let mut opt = OptimizerConfig::Adam(AdamConfig { lr: 1e-3, ..Default::default() }).build(trainable)?;
        let x = seed::randn((32, 10, 32, 64), 0.0, 1.0, DType::F32, &dev, 7)?;
        let y = seed::randn((32, 2, 32, 64), 0.0, 1.0, DType::F32, &dev, 8)?;
        let s = median_seconds(1, reps, || -> TaskResult<()> {
            let loss = mse(&net.forward(&x, true, 0)?, &y)?;
            candle_nn::Optimizer::backward_step(&mut opt, &loss)?;
            Ok(())
        });
        rows.push(row("weather_cpu_resnet_train_step", "b32_c10_w32_blocks4_32x64", s, ctx.threads));
    }

    // TecoGAN generator: forward + backward.
    if selected("tecogan_generator_fwd_bwd") {
        let varmap = VarMap::new();
        let gen = TecoGenerator::new(VarBuilder::from_varmap(&varmap, DType::F32, &dev))?;
        let x = seed::randn((4, 51, 32, 32), 0.0, 1.0, DType::F32, &dev, 3)?;
        let y = seed::randn((4, 3, 128, 128), 0.0, 1.0, DType::F32, &dev, 4)?;
        let s = median_seconds(1, reps, || -> TaskResult<()> {
            mse(&gen.forward(&x)?, &y)?.backward()?;
            Ok(())
        });
        rows.push(row("tecogan_generator_fwd_bwd", "b4_c51_w64_blocks16_32to128", s, ctx.threads));
    }

    // LSTM over 6 latent vectors: forward + backward.
    // `PBDL_NETS_LSTM_SIZES=256` (comma-separated) profiles one size.
    let lstm_sizes: Vec<usize> = match std::env::var("PBDL_NETS_LSTM_SIZES") {
        Ok(list) => list.split(',').filter_map(|s| s.trim().parse().ok()).collect(),
        Err(_) => vec![256, 1024],
    };
    let lstm_sizes = if selected("lstm_fwd_bwd") { lstm_sizes } else { vec![] };
    for size in lstm_sizes {
        let varmap = VarMap::new();
        let lstm = Lstm::new(LstmConfig::new(size, size), VarBuilder::from_varmap(&varmap, DType::F32, &dev))?;
        let x = seed::randn((16, 6, size), 0.0, 1.0, DType::F32, &dev, 5)?;
        let y = seed::randn((16, 6, size), 0.0, 1.0, DType::F32, &dev, 6)?;
        // Milliseconds a step: more repetitions against scheduling noise.
        let s = median_seconds(2, 10 * reps, || -> TaskResult<()> {
            mse(&lstm.forward(&x, None)?.output, &y)?.backward()?;
            Ok(())
        });
        rows.push(row("lstm_fwd_bwd", &format!("b16_t6_h{size}"), s, ctx.threads));
    }
    Ok(rows)
}
