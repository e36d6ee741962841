//! Where the time of an ACDM U-Net training step goes, in wall time and in CPU time (user +
//! system of this process, from /proc; steadier than wall time on a shared machine): the
//! whole step, forward alone, and the top-level linear attention as the network runs it (fused
//! up to dim 32) against the same layer composed from candle ops.
//! `cargo run -p pbdl-diffusion --example unet_profile -- [dim] [batch] [reps] [height] [width]`
//! (defaults 16 16 3 64 32).

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (fewer page faults).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::conv::{conv2d, Conv2dParams};
use pbdl_core::nn::softmax;
use pbdl_diffusion::unet::workload::{UnetFixture, UnetWorkload};
use pbdl_diffusion::unet::{seeded_init, Attention, AttentionKind, ConvNextBlock};
use std::time::Instant;

/// CPU seconds (user + system) used by this process so far.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which ends in ')'): utime and stime are fields 14 and 15.
    let rest = stat.rsplit(')').next().unwrap_or("");
    // rest[0] is field 3 (the state), so field k is rest[k - 3].
    let f: Vec<&str> = rest.split_whitespace().collect();
    let field = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (field(11) + field(12)) / 100.0 // clock ticks at USER_HZ = 100
}

/// Mean wall and CPU seconds per call of `f` over `reps` calls after one warm-up.
fn measure<R>(reps: usize, mut f: impl FnMut() -> R) -> (f64, f64) {
    std::hint::black_box(f());
    let (t, c) = (Instant::now(), cpu_seconds());
    for _ in 0..reps {
        std::hint::black_box(f());
    }
    (t.elapsed().as_secs_f64() / reps as f64, (cpu_seconds() - c) / reps as f64)
}

fn report(name: &str, (wall, cpu): (f64, f64)) {
    println!("{name:<48} wall {:>9.1} ms   cpu {:>9.1} ms", wall * 1e3, cpu * 1e3);
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let dim = args.first().copied().unwrap_or(16);
    let batch = args.get(1).copied().unwrap_or(16);
    let reps = args.get(2).copied().unwrap_or(3);
    let (height, width) = (args.get(3).copied().unwrap_or(64), args.get(4).copied().unwrap_or(32));
    let n = height * width;
    let w = UnetWorkload { dim, channels: 12, batch, height, width };
    let mut fx = UnetFixture::new(&w, 0)?;
    println!(
        "{} ({} parameters), {} threads, mean of {reps}",
        w.label(),
        fx.parameters(),
        rayon::current_num_threads()
    );
    report("train step", measure(reps, || fx.train_step().unwrap()));
    report("sample step (forward)", measure(reps, || fx.sample_step().unwrap()));

    let dev = Device::Cpu;
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
    let attn = Attention::new(AttentionKind::Linear, dim, 4, 32, vb.pp("a"))?;
    let block = ConvNextBlock::new(dim, dim, Some(4 * dim), 1, vb.pp("b"))?;
    seeded_init(&varmap, 1)?;
    let x = Var::from_tensor(&pbdl_core::seed::randn((batch, dim, height, width), 0.0, 1.0, DType::F32, &dev, 2)?)?;
    let temb = pbdl_core::seed::randn((batch, 4 * dim), 0.0, 1.0, DType::F32, &dev, 3)?;
    let get = |n: &str| varmap.data().lock().unwrap()[n].as_tensor().clone();
    let (wq, wo) = (get("a.to_qkv.weight"), get("a.to_out.0.weight"));
    let composed = || -> Tensor {
        let p = Conv2dParams::default();
        let qkv = conv2d(x.as_tensor(), &wq, None, &p).unwrap().reshape((batch, 3, 4, 32, n)).unwrap();
        let part = |i: usize| qkv.narrow(1, i, 1).unwrap().squeeze(1).unwrap().contiguous().unwrap();
        let q = (softmax(&part(0), 2).unwrap() / 32f64.sqrt()).unwrap();
        let k = softmax(&part(1), 3).unwrap();
        let o = k.matmul(&part(2).t().unwrap()).unwrap().t().unwrap().matmul(&q).unwrap();
        conv2d(&o.reshape((batch, 128, height, width)).unwrap(), &wo, None, &p).unwrap()
    };
    let back = |y: Tensor| y.sum_all().unwrap().backward().unwrap();
    report("linear attention top level, network path, fwd", measure(reps, || attn.forward(x.as_tensor()).unwrap()));
    report(
        "linear attention top level, network path, fwd+bwd",
        measure(reps, || back(attn.forward(x.as_tensor()).unwrap())),
    );
    report("linear attention top level, composed, fwd", measure(reps, composed));
    report("linear attention top level, composed, fwd+bwd", measure(reps, || back(composed())));
    report(
        "ConvNeXt block top level, fwd+bwd",
        measure(reps, || back(block.forward(x.as_tensor(), Some(&temb)).unwrap())),
    );
    // The pieces of a ConvNeXt block at the top level.
    let w3 = Var::from_tensor(&pbdl_core::seed::randn((dim, dim, 3, 3), 0.0, 0.1, DType::F32, &dev, 4)?)?;
    let w7 = Var::from_tensor(&pbdl_core::seed::randn((dim, 1, 7, 7), 0.0, 0.1, DType::F32, &dev, 5)?)?;
    let xt = x.as_tensor();
    let p3 = Conv2dParams::default().padding(1);
    let p7 = Conv2dParams::default().padding(3).groups(dim);
    report("  conv 3x3, fwd+bwd", measure(reps, || back(conv2d(xt, w3.as_tensor(), None, &p3).unwrap())));
    report("  depthwise conv 7x7, fwd+bwd", measure(reps, || back(conv2d(xt, w7.as_tensor(), None, &p7).unwrap())));
    report(
        "  group_norm(1), fwd+bwd",
        measure(reps, || back(pbdl_core::nn::group_norm(xt, 1, None, None, 1e-5).unwrap())),
    );
    report("  gelu_erf, fwd+bwd", measure(reps, || back(pbdl_core::nn::activation::gelu_erf(xt).unwrap())));
    Ok(())
}
