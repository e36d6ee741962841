//! DDPM and DDIM with the exact noise predictor for Gaussian data: how close the samples' mean
//! and variance come to the data's for a few step counts.
//!
//! `cargo run -p pbdl-diffusion --example ddpm_gaussian`

use candle_core::{DType, Device};
use pbdl_diffusion::ddpm::{Conditioning, Diffusion, GaussianOracle};
use pbdl_diffusion::schedule::{NoiseSchedule, COSINE_S};

fn moments(x: &candle_core::Tensor) -> pbdl_diffusion::Result<(f64, f64)> {
    let v = x.to_dtype(DType::F64)?.flatten_all()?.to_vec1::<f64>()?;
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    Ok((m, v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)))
}

fn main() -> pbdl_diffusion::Result<()> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let (mu, sd) = (1.5, 0.5);
    let x_start = Diffusion::noise(&[64, 1, 32, 32], DType::F32, &Device::Cpu, 0)?;
    println!("data: mean {mu}, variance {}; {} samples", sd * sd, x_start.elem_count());
    for r in [20, 200, 1000] {
        let s = NoiseSchedule::cosine(r, COSINE_S)?;
        let oracle = GaussianOracle::diagonal(s.clone(), &[mu], &[sd])?;
        let d = Diffusion::new(s, Conditioning::Clean);
        let t = std::time::Instant::now();
        let (m, v) = moments(&d.sample_ddpm(&oracle, None, &x_start, 1)?)?;
        println!("DDPM R = {r:>4}: mean {m:.4} variance {v:.4} ({:.2} s)", t.elapsed().as_secs_f64());
    }
    let s = NoiseSchedule::cosine(1000, COSINE_S)?;
    let oracle = GaussianOracle::diagonal(s.clone(), &[mu], &[sd])?;
    let d = Diffusion::new(s, Conditioning::Clean);
    for k in [5, 10, 20, 50, 200] {
        let t = std::time::Instant::now();
        let (m, v) = moments(&d.sample_ddim(&oracle, None, &x_start, &d.ddim_steps(k)?, 0.0, 1)?)?;
        println!("DDIM k = {k:>4} of T = 1000: mean {m:.4} variance {v:.4} ({:.2} s)", t.elapsed().as_secs_f64());
    }
    Ok(())
}
