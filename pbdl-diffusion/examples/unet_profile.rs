//! Where the time of an ACDM U-Net training step goes: the whole step split into forward,
//! backward and Adam update, then each building block (forward + backward) at the top level's
//! size. `cargo run -p pbdl-diffusion --example unet_profile -- [dim] [batch]`.

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use pbdl_core::bench::{format_seconds, median_seconds};
use pbdl_core::conv::{conv2d, Conv2dParams};
use pbdl_core::nn::activation::gelu_erf;
use pbdl_core::nn::group_norm;
use pbdl_diffusion::unet::workload::{smooth_l1, UnetFixture, UnetWorkload};
use pbdl_diffusion::unet::{AttentionKind, ConvNextBlock, ResidualAttention};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let dim = args.first().copied().unwrap_or(16);
    let batch = args.get(1).copied().unwrap_or(16);
    let reps = args.get(2).copied().unwrap_or(3);
    let w = UnetWorkload { dim, channels: 12, batch, height: 64, width: 32 };
    let mut fx = UnetFixture::new(&w, 0)?;
    println!("{} ({} parameters), median of {reps}", w.label(), fx.parameters());
    let dev = Device::Cpu;
    let x = pbdl_core::seed::randn((batch, 12, 64, 32), 0.0, 1.0, DType::F32, &dev, 1)?;
    let t = Tensor::from_vec((0..batch).map(|i| i as f32).collect::<Vec<_>>(), batch, &dev)?;
    let target = x.clone();
    let fwd = median_seconds(1, reps, || fx.net.forward(&x, Some(&t)).unwrap());
    let fwd_bwd = median_seconds(1, reps, || {
        let loss = smooth_l1(&fx.net.forward(&x, Some(&t)).unwrap(), &target).unwrap();
        loss.backward().unwrap()
    });
    let step = median_seconds(1, reps, || fx.train_step().unwrap());
    let grads = smooth_l1(&fx.net.forward(&x, Some(&t))?, &target)?.backward()?;
    let mut opt = candle_nn::AdamW::new(fx.varmap.all_vars(), candle_nn::ParamsAdamW::default())?;
    let adam = median_seconds(1, reps, || opt.step(&grads).unwrap());
    println!(
        "forward {}  forward+backward {}  train step {}  adam update {}",
        format_seconds(fwd),
        format_seconds(fwd_bwd),
        format_seconds(step),
        format_seconds(adam)
    );

    // Blocks at the top level: [batch, dim, 64, 32].
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let block = ConvNextBlock::new(dim, dim, Some(4 * dim), 1, vb.pp("b"))?;
    let lin = ResidualAttention::new(AttentionKind::Linear, dim, 4, 32, vb.pp("l"))?;
    let full_small = ResidualAttention::new(AttentionKind::Full, dim, 4, 32, vb.pp("f"))?;
    let h = Var::from_tensor(&pbdl_core::seed::randn((batch, dim, 64, 32), 0.0, 1.0, DType::F32, &dev, 2)?)?;
    let hm = Var::from_tensor(&pbdl_core::seed::randn((batch, dim, 16, 8), 0.0, 1.0, DType::F32, &dev, 3)?)?;
    let temb = pbdl_core::seed::randn((batch, 4 * dim), 0.0, 1.0, DType::F32, &dev, 4)?;
    let w3 = Var::from_tensor(&pbdl_core::seed::randn((dim, dim, 3, 3), 0.0, 0.1, DType::F32, &dev, 5)?)?;
    let w7 = Var::from_tensor(&pbdl_core::seed::randn((dim, 1, 7, 7), 0.0, 0.1, DType::F32, &dev, 6)?)?;
    let time = |name: &str, f: &dyn Fn() -> Tensor| {
        let fwd = median_seconds(1, reps, f);
        let both = median_seconds(1, reps, || f().sqr().unwrap().sum_all().unwrap().backward().unwrap());
        println!("{name:<40} fwd {:>10}  fwd+bwd {:>10}", format_seconds(fwd), format_seconds(both));
    };
    let ht = h.as_tensor();
    time("ConvNeXt block (top level)", &|| block.forward(ht, Some(&temb)).unwrap());
    time("residual linear attention (top level)", &|| lin.forward(ht).unwrap());
    time("residual full attention (16x8)", &|| full_small.forward(hm.as_tensor()).unwrap());
    time("conv 3x3", &|| conv2d(ht, w3.as_tensor(), None, &Conv2dParams::default().padding(1)).unwrap());
    time("depthwise conv 7x7", &|| {
        conv2d(ht, w7.as_tensor(), None, &Conv2dParams::default().padding(3).groups(dim)).unwrap()
    });
    time("group_norm(1)", &|| group_norm(ht, 1, None, None, 1e-5).unwrap());
    time("gelu_erf", &|| gelu_erf(ht).unwrap());
    let qkv_w = Var::from_tensor(&pbdl_core::seed::randn((384, dim, 1, 1), 0.0, 0.1, DType::F32, &dev, 7)?)?;
    let time_sum = |name: &str, f: &dyn Fn() -> Tensor| {
        let both = median_seconds(1, reps, || f().sum_all().unwrap().backward().unwrap());
        println!("{name:<40} fwd+bwd(sum) {:>10}", format_seconds(both));
    };
    time("to_qkv 1x1 conv", &|| conv2d(ht, qkv_w.as_tensor(), None, &Conv2dParams::default()).unwrap());
    time_sum("to_qkv 1x1 conv", &|| conv2d(ht, qkv_w.as_tensor(), None, &Conv2dParams::default()).unwrap());
    let w2 = qkv_w.as_tensor().reshape((384, dim))?;
    time_sum("to_qkv as candle matmul", &|| w2.broadcast_matmul(&ht.reshape((batch, dim, 64 * 32)).unwrap()).unwrap());
    let q = Var::from_tensor(&pbdl_core::seed::randn((batch, 4, 32, 2048), 0.0, 1.0, DType::F32, &dev, 8)?)?;
    time("softmax over d (dim 2) of q", &|| pbdl_core::nn::softmax(q.as_tensor(), 2).unwrap());
    time("softmax over n (dim 3) of k", &|| pbdl_core::nn::softmax(q.as_tensor(), 3).unwrap());
    Ok(())
}
