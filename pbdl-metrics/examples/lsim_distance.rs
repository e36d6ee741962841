//! LSiM and classic metrics on the published plume example.
//!
//! ```sh
//! cargo run -p pbdl-metrics --release --example lsim_distance [WEIGHTS.safetensors] [EXAMPLE_DIR]
//! ```
//!
//! Defaults: `../shared/weights/LSiM.safetensors` and `../shared/data/lsim-example` (run from the
//! workspace root). Prints d(reference, plumeA) and d(reference, plumeB) next to the published
//! 0.3791 and 0.4433, and the classic metrics of the same pairs.

use candle_core::DType;
use pbdl_metrics::classic::{mse, pearson, psnr, ssim2d, SsimConfig};
use pbdl_metrics::lsim::hwc_to_nchw;
use pbdl_metrics::Lsim;
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let mut args = std::env::args().skip(1);
    let weights = args.next().map(PathBuf::from).unwrap_or_else(|| "../shared/weights/LSiM.safetensors".into());
    let data = args.next().map(PathBuf::from).unwrap_or_else(|| "../shared/data/lsim-example".into());
    let lsim = Lsim::load(&weights)?;
    let read = |n: &str| -> Result<candle_core::Tensor, Box<dyn std::error::Error>> {
        Ok(hwc_to_nchw(&pbdl_core::io::read_npy(data.join(format!("lsim_example_plume{n}.npy")))?)?)
    };
    let (r, a, b) = (read("Reference")?, read("A")?, read("B")?);
    println!(
        "{:<8} {:>8} {:>10} {:>10} {:>9} {:>9} {:>9}",
        "pair", "LSiM", "published", "time", "MSE", "SSIM", "Pearson"
    );
    for (name, x, published) in [("plumeA", &a, 0.3791), ("plumeB", &b, 0.4433)] {
        let t = Instant::now();
        let d = lsim.distance(&r, x)?[0];
        let secs = t.elapsed().as_secs_f64();
        let (rf, xf) = ((r.to_dtype(DType::F64)? / 255.0)?, (x.to_dtype(DType::F64)? / 255.0)?);
        let m = mse(&rf, &xf)?.to_vec1::<f64>()?[0];
        let s = ssim2d(&rf, &xf, &SsimConfig { data_range: Some(1.0), ..Default::default() })?.to_vec1::<f64>()?[0];
        let p = pearson(&rf, &xf)?.to_vec1::<f64>()?[0];
        let _ = psnr(&xf, &rf, Some(1.0))?;
        println!("{name:<8} {d:>8.4} {published:>10.4} {:>8.1}ms {m:>9.5} {s:>9.4} {p:>9.4}", secs * 1e3);
    }
    Ok(())
}
