//! Sanity check of the ACDM training signal on a small crop: prints the loss every 10 updates.
//!
//! `cargo run -p pbdl-diffusion --example acdm_sanity -- [METHOD] [DIM] [STEPS]`
use pbdl_core::train::{train_step, AdamConfig, ClipConfig, NanGuard, OptimizerConfig};
use pbdl_diffusion::acdm::data::{generate, CylinderConfig, Normalization};
use pbdl_diffusion::acdm::model::{Method, Model, ModelConfig};
use pbdl_diffusion::acdm::train::{loss, sample_windows};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let a: Vec<String> = std::env::args().skip(1).collect();
    let variant = a.first().cloned().unwrap_or_default();
    let method = if variant == "unet" { Method::Unet } else { Method::Acdm };
    let dim: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(8);
    let steps: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(200);
    let d = generate(&CylinderConfig::tiny(), &[300.0])?;
    let norm = Normalization::from_sequences(&d.sequences)?;
    let full = norm.normalize(&d.sequences[0])?;
    let seqs = vec![full.narrow(2, 8, 16)?.narrow(3, 8, 32)?];
    let model = Model::new(ModelConfig::baseline(method, dim))?;
    let vars = model.varmap().all_vars();
    let mut opt = OptimizerConfig::Adam(AdamConfig { lr: 1e-3, ..Default::default() }).build(vars.clone())?;
    let mut guard = NanGuard::new();
    let mut rng = pbdl_core::seed::rng(0);
    let len = method.history() + 1;
    let t0 = std::time::Instant::now();
    let mut acc = 0.0;
    for step in 0..steps as u64 {
        let w = sample_windows(&seqs, len, 8, &mut rng)?;
        let l = match variant.as_str() {
            // High-noise steps only: eps is almost the input, an easy identity to learn.
            "acdm_hi" => {
                let (b, _, c, h, wd) = w.dims5()?;
                let cond = w.narrow(1, 0, 2)?.reshape((b, 2 * c, h, wd))?;
                let x0 = w.narrow(1, 2, 1)?.squeeze(1)?;
                let eps = pbdl_core::seed::randn(
                    (b, 3 * c, h, wd),
                    0.0,
                    1.0,
                    candle_core::DType::F32,
                    &candle_core::Device::Cpu,
                    step,
                )?;
                let diff = model.diffusion().unwrap();
                diff.loss_at(model.unet(), &x0, Some(&cond), &vec![19; b], &eps, pbdl_diffusion::ddpm::Loss::Mse)?
            }
            _ => loss(&model, &w, step)?,
        };
        let info = train_step(step, &l, &mut opt, &vars, &ClipConfig::Norm { max_norm: 1.0 }, &mut guard)?;
        acc += info.loss;
        if (step + 1) % 10 == 0 {
            println!(
                "{} step {}: mean loss {:.4}, grad norm {:.3}, {:.1} s",
                method.name(),
                step + 1,
                acc / 10.0,
                info.grad_norm,
                t0.elapsed().as_secs_f64()
            );
            acc = 0.0;
        }
    }
    Ok(())
}
