//! Evaluates a trained checkpoint on the held-out Reynolds numbers (1000-step rollouts by default).
//!
//! `cargo run -p pbdl-diffusion --example acdm_eval -- METHOD DIM CHECKPOINT_DIR [STEPS] [SAMPLER] [SAMPLES]`
//! (METHOD as in `acdm_train`; SAMPLER `ddpm` or `ddimK`). Prints one markdown row per Re.

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (fewer page faults).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use pbdl_diffusion::acdm::benchmark::Benchmark;
use pbdl_diffusion::acdm::data::TEST_RE;
use pbdl_diffusion::acdm::eval::{evaluate, EvalConfig, EvalReport};
use pbdl_diffusion::acdm::model::{Method, Model, ModelConfig, Sampler};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let a: Vec<String> = std::env::args().skip(1).collect();
    let method = match a.first().map(String::as_str).unwrap_or("unet") {
        "acdm" => Method::Acdm,
        "acdm_ncn" => Method::AcdmNcn,
        "unet_ut8" => Method::UnetUnrolled { m: 8 },
        "unet_tn" => Method::UnetNoise { sigma: 0.01 },
        _ => Method::Unet,
    };
    let dim: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(16);
    let dir = std::path::PathBuf::from(a.get(2).ok_or("give the checkpoint directory")?);
    let steps: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(1000);
    let samples: usize = a.get(5).and_then(|s| s.parse().ok()).unwrap_or(1);
    let b = Benchmark::default_full()?;
    let mut model = Model::new(ModelConfig { method, dim, diffusion_steps: 20 })?;
    let ckpt = pbdl_core::io::latest_checkpoint(&dir)?.ok_or("no checkpoint in the directory")?;
    let step = model.load(&ckpt)?;
    if let Some(s) = a.get(4) {
        if let Some(k) = s.strip_prefix("ddim") {
            model.set_sampler(Sampler::Ddim(k.parse()?))?;
        }
    }
    let lsim = pbdl_diffusion::acdm::eval::load_lsim();
    println!(
        "{} after {step} updates ({} parameters), LSiM loaded: {}",
        dir.display(),
        model.parameters(),
        lsim.is_some()
    );
    println!("{}", EvalReport::markdown_header());
    let cfg = EvalConfig { steps, samples, seed: 5, lsim_every: 10 };
    for re in TEST_RE {
        let r = evaluate(
            &model,
            b.held_out(re).ok_or("held-out Re missing")?,
            &b.norm,
            &b.test.config,
            &cfg,
            lsim.as_ref(),
        )?;
        println!("{}", r.markdown_row());
    }
    Ok(())
}
