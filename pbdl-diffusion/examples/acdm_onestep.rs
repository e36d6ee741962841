//! One-step diagnostic of a trained checkpoint: from true conditioning frames, how far is the
//! predicted next frame from the truth, and how large is its change against the true change?
//! A ratio well above 1 means per-frame sampling noise (it shows as |ds/dt| too large in rollouts).
//!
//! `cargo run --release -p pbdl-diffusion --example acdm_onestep -- METHOD DIM CHECKPOINT_DIR [SAMPLER]`

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use candle_core::Tensor;
use pbdl_diffusion::acdm::benchmark::Benchmark;
use pbdl_diffusion::acdm::data::{FIELDS, TEST_RE};
use pbdl_diffusion::acdm::model::{Method, Model, ModelConfig, Sampler};
use pbdl_diffusion::acdm::rollout::FramePredictor;

fn mean_abs(x: &Tensor) -> Result<f64, Box<dyn std::error::Error>> {
    Ok(x.abs()?.mean_all()?.to_scalar::<f32>()? as f64)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let a: Vec<String> = std::env::args().skip(1).collect();
    let method = if a.first().map(String::as_str) == Some("unet") { Method::Unet } else { Method::Acdm };
    let dim: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(48);
    let dir = std::path::PathBuf::from(a.get(2).ok_or("give the checkpoint directory")?);
    let b = Benchmark::default_full()?;
    let mut model = Model::new(ModelConfig { method, dim, diffusion_steps: 20 })?;
    let ckpt = pbdl_core::io::latest_checkpoint(&dir)?.ok_or("no checkpoint")?;
    let step = model.load(&ckpt)?;
    if let Some(k) = a.get(3).and_then(|s| s.strip_prefix("ddim")) {
        model.set_sampler(Sampler::Ddim(k.parse()?))?;
    }
    println!("{} after {step} updates, sampler {}", model.name(), model.sampler().name());
    let h = model.history();
    let times = [20usize, 90, 160, 230, 300, 370];
    let mut cases: Vec<(f64, Tensor)> = vec![(300.0, b.seqs[3].clone())];
    for re in TEST_RE {
        cases.push((
            re,
            b.norm.normalize(
                b.held_out(re).ok_or("held-out ground truth missing: generate it with the acdm_data example")?,
            )?,
        ));
    }
    for (re, seq) in cases {
        let prev: Vec<Tensor> = times.iter().map(|&t| seq.narrow(0, t - h, h)).collect::<Result<_, _>>()?;
        let prev = Tensor::stack(&prev, 0)?;
        let last: Vec<Tensor> = times.iter().map(|&t| seq.get(t - 1)).collect::<Result<_, _>>()?;
        let next: Vec<Tensor> = times.iter().map(|&t| seq.get(t)).collect::<Result<_, _>>()?;
        let last = Tensor::stack(&last, 0)?.narrow(1, 0, FIELDS)?;
        let next = Tensor::stack(&next, 0)?.narrow(1, 0, FIELDS)?;
        let t0 = std::time::Instant::now();
        let pred = model.predict(&prev, 7)?.narrow(1, 0, FIELDS)?;
        let secs = t0.elapsed().as_secs_f64();
        let true_change = mean_abs(&(&next - &last)?)?;
        let pred_change = mean_abs(&(&pred - &last)?)?;
        let err = mean_abs(&(&pred - &next)?)?;
        println!(
            "Re {re:>4}: mean |pred - next| {err:.4}, change pred {pred_change:.4} vs true {true_change:.4} (ratio {:.2}), {secs:.1} s for {}",
            pred_change / true_change,
            times.len()
        );
        if let Some(diff) = model.diffusion() {
            // Denoising quality per step: x0 estimate from one eps prediction (target channels).
            use pbdl_diffusion::ddpm::{Diffusion, NoisePredictor};
            let cond = prev.reshape((times.len(), h * 4, seq.dim(2)?, seq.dim(3)?))?;
            let x0 = Tensor::stack(&times.iter().map(|&t| seq.get(t)).collect::<Result<Vec<_>, _>>()?, 0)?;
            let cc = cond.dim(1)?;
            let eps = Diffusion::noise(
                &[times.len(), cc + 4, seq.dim(2)?, seq.dim(3)?],
                candle_core::DType::F32,
                &candle_core::Device::Cpu,
                3,
            )?;
            let mut line = String::new();
            for i in [0usize, 2, 5, 10, 15, 19] {
                let xi = diff.q_sample(&Tensor::cat(&[&cond, &x0], 1)?, &vec![i; times.len()], &eps)?;
                let tt = Diffusion::step_tensor(&vec![i; times.len()], &candle_core::Device::Cpu)?;
                let e = model.unet().predict(&xi, &tt)?.narrow(1, cc, FIELDS)?;
                let e_true = eps.narrow(1, cc, FIELDS)?;
                let s = diff.schedule();
                let x0_hat =
                    ((xi.narrow(1, cc, FIELDS)? - (&e * s.sqrt_one_minus_alpha_bar(i))?)? / s.sqrt_alpha_bar(i))?;
                let ex0 = mean_abs(&(&x0_hat - x0.narrow(1, 0, FIELDS)?)?)?;
                let ee = mean_abs(&(&e - &e_true)?)?;
                line += &format!(" i{i}: eps {ee:.3} x0 {ex0:.3};");
            }
            println!("   per step |eps err|, |x0 err|:{line}");
        }
    }
    Ok(())
}
