//! Trains one ACDM benchmark model on the cached cylinder data and prints its step time.
//!
//! `cargo run -p pbdl-diffusion --example acdm_train -- METHOD DIM STEPS [BATCH]`, METHOD one of
//! `acdm`, `acdm_ncn`, `unet`, `unet_ut8`, `unet_tn`. Checkpoints: `target/pbdl/acdm/runs/<name>_d<DIM>/`
//! (or `PBDL_ACDM_RUN_DIR`); Adam at 1e-3 for 1000 updates, then 1e-4 (`TrainConfig::default`).

// candle allocates every op output afresh; mimalloc keeps those blocks out of mmap (fewer page faults).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use pbdl_diffusion::acdm::data::{default_cache_dir, train_config, CylinderDataset, Normalization, TRAIN_RE};
use pbdl_diffusion::acdm::model::{Method, Model, ModelConfig};
use pbdl_diffusion::acdm::train::{train, TrainConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let a: Vec<String> = std::env::args().skip(1).collect();
    let method = match a.first().map(String::as_str).unwrap_or("acdm") {
        "acdm" => Method::Acdm,
        "acdm_ncn" => Method::AcdmNcn,
        "unet" => Method::Unet,
        "unet_ut8" => Method::UnetUnrolled { m: 8 },
        "unet_tn" => Method::UnetNoise { sigma: 0.01 },
        m => return Err(format!("unknown method {m}").into()),
    };
    let dim: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(16);
    let steps: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    let batch: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(16);
    if a.get(4).map(String::as_str) == Some("bench") {
        let model = Model::new(ModelConfig { method, dim, diffusion_steps: 20 })?;
        let c = model.config().unet().in_channels;
        let x = candle_core::Tensor::randn(0f32, 1.0, (batch, c, 32, 64), &candle_core::Device::Cpu)?;
        let t = candle_core::Tensor::ones(batch, candle_core::DType::F32, &candle_core::Device::Cpu)?;
        let tt = model.config().method.is_diffusion().then_some(&t);
        for _ in 0..2 {
            let t0 = std::time::Instant::now();
            let y = model.unet().forward(&x, tt)?;
            let f = t0.elapsed().as_secs_f64();
            let g = y.sqr()?.mean_all()?.backward()?;
            println!(
                "forward {f:.3} s, backward {:.3} s ({} grads)",
                t0.elapsed().as_secs_f64() - f,
                g.get_ids().count()
            );
        }
        return Ok(());
    }
    let data = CylinderDataset::cached(&default_cache_dir(), &train_config(), &TRAIN_RE)?;
    let norm = Normalization::from_sequences(&data.sequences)?;
    let seqs = data.sequences.iter().map(|s| norm.normalize(s)).collect::<Result<Vec<_>, _>>()?;
    let model = Model::new(ModelConfig { method, dim, diffusion_steps: 20 })?;
    let dir = default_cache_dir().join("runs").join(format!("{}_d{dim}", method.name()));
    let cfg = TrainConfig { steps, batch, checkpoint_every: 25, ..Default::default() };
    let dir = match std::env::var("PBDL_ACDM_RUN_DIR") {
        Ok(d) => std::path::PathBuf::from(d),
        Err(_) => dir,
    };
    let r = train(&model, &seqs, &cfg, Some(&dir))?;
    let first = r.losses.iter().take(20).map(|l| l.1).sum::<f64>() / r.losses.len().clamp(1, 20) as f64;
    let last = r.losses.iter().rev().take(50).map(|l| l.1).sum::<f64>() / r.losses.len().clamp(1, 50) as f64;
    println!(
        "{} dim {dim} ({} params) batch {batch}: steps {}..{} in {:.1} s, {:.3} s/step; loss first-20 {first:.4e}, last-50 {last:.4e}; data sim {:.1} s",
        method.name(), model.parameters(), r.resumed_from, steps, r.seconds, r.seconds_per_step, data.seconds
    );
    Ok(())
}
