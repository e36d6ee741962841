//! Decaying 2D turbulence with the pseudo-spectral solver: `cargo run --release -p pbdl-grid
//! --example spectral_turbulence -- [n] [steps]` prints the time per step and the energy and
//! enstrophy decay (`dE/dt = -2 nu Z`).

use candle_core::{DType, Device, Tensor};
use pbdl_grid::spectral::{SpectralConfig, SpectralNavierStokes};
use pbdl_grid::Grid;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    pbdl_core::threads::init()?;
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(128);
    let steps: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(200);
    let grid = Grid::square(n, 2.0 * std::f64::consts::PI)?;
    let dt = 0.5 * grid.dx() / 3.0;
    let ns = SpectralNavierStokes::new(grid, SpectralConfig { nu: 1e-3, dt, scheme: Default::default(), drag: 0.0 })?;
    // A smooth vorticity with every Fourier mode present (zero mean).
    let mut w: Vec<f64> = (0..grid.cells())
        .map(|k| {
            let (x, y) = (((k % n) as f64 + 0.5) * grid.dx(), ((k / n) as f64 + 0.5) * grid.dy());
            (1.5 * x.cos() + (y + 0.3).sin()).exp() - (1.2 * (x - 2.0 * y).sin()).exp() + (3.0 * x + y).cos()
        })
        .collect();
    let mean = w.iter().sum::<f64>() / w.len() as f64;
    w.iter_mut().for_each(|v| *v -= mean);
    let w = Tensor::from_vec(w, (n, n), &Device::Cpu)?.to_dtype(DType::F32)?;
    let mut state = ns.state_from_vorticity(&w, [0.0, 0.0])?;
    let (e0, z0) = (ns.energy(&state)?, ns.enstrophy(&state)?);
    let start = Instant::now();
    ns.advance(&mut state, steps)?;
    let per_step = start.elapsed().as_secs_f64() / steps as f64;
    println!("{n}^2 f32, {steps} steps of dt = {dt:.3e}: {:.3} ms/step", 1e3 * per_step);
    println!("energy {e0:.5} -> {:.5}, enstrophy {z0:.4} -> {:.4}", ns.energy(&state)?, ns.enstrophy(&state)?);
    Ok(())
}
