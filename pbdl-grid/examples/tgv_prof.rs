//! Temporary profiling harness (not committed).
use candle_core::DType;
use pbdl_grid::{Boundaries, Grid, MacField, NavierStokes, NavierStokesConfig, Scheme};
use std::f64::consts::PI;
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;
fn main() {
    let n: usize = std::env::args().nth(1).unwrap().parse().unwrap();
    let reps: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let grid = Grid::square(n, 2.0 * PI).unwrap();
    let bc = Boundaries::periodic();
    let ns = NavierStokes::new(grid, bc, NavierStokesConfig { nu: 0.01, dt: 0.5 * grid.dx(), scheme: Scheme::Rk4 }).unwrap();
    let u0 = MacField::from_fn(grid, bc, DType::F32, |x, y| [x.sin() * y.cos(), -x.cos() * y.sin()]).unwrap();
    let mut ts = vec![];
    for _ in 0..reps {
        let t = std::time::Instant::now();
        let _u = ns.step(&u0).unwrap();
        ts.push(t.elapsed().as_secs_f64());
    }
    ts.sort_by(|a, b| a.partial_cmp(b).unwrap());
    println!("n={n} median {:.3} ms min {:.3} ms", ts[ts.len() / 2] * 1e3, ts[0] * 1e3);
}
