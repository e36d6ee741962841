//! Generates (or reads from the cache) the ACDM cylinder-flow data and prints its numbers.
//!
//! `cargo run -p pbdl-diffusion --example acdm_data -- [tiny|test] [RE ...]` (default: the
//! training settings; `test`: the 1002-frame held-out settings).
use pbdl_diffusion::acdm::data::{default_cache_dir, test_config, train_config, CylinderConfig, CylinderDataset};
use pbdl_diffusion::acdm::metrics::{mean, strouhal, temporal_stability};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let args: Vec<String> = std::env::args().skip(1).collect();
    let tiny = args.iter().any(|a| a == "tiny");
    let config = if tiny {
        CylinderConfig::tiny()
    } else if args.iter().any(|a| a == "test") {
        test_config()
    } else {
        train_config()
    };
    let mut re: Vec<f64> = args.iter().filter_map(|a| a.parse().ok()).collect();
    if re.is_empty() {
        re = vec![200.0, 500.0, 950.0];
    }
    let d = CylinderDataset::cached(&default_cache_dir(), &config, &re)?;
    println!("{config:?}: {} sequences in {:.1} s", d.sequences.len(), d.seconds);
    for s in &d.sequences {
        let st = strouhal(&s.frames, &config)?;
        let stab = mean(&temporal_stability(&s.frames, config.frame_dt())?);
        let (t, c, ny, nx) = s.frames.dims4()?;
        let max = s.frames.abs()?.max_all()?.to_scalar::<f32>()?;
        println!("Re {:>5.0}: [{t}, {c}, {ny}, {nx}] St = {st:.4}, mean |ds/dt| = {stab:.4}, max |x| = {max:.3}", s.re);
    }
    Ok(())
}
