//! scratch probe (to be deleted)
use faer::{MatRef, Par};
use pbdl_optim::hig::{composed_jacobian, Decomposition, HalfInverse, HigConfig};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Oscillators};
fn main() -> pbdl_optim::Result<()> {
    let physics = Oscillators::nonlinear();
    let data = Dataset::return_to_start(128, 4, 1);
    let net = Mlp::new(&[4, 20, 20, 20, 96], Activation::Relu, 2)?;
    let (jac, y) = composed_jacobian(&net, &physics, data.all())?;
    let (rows, cols) = (y.len(), net.n_params());
    let j = MatRef::from_row_major_slice(&jac, rows, cols);
    let g: Vec<f64> = y.iter().zip(data.all().targets).map(|(a, t)| 2.0 * (a - t) / 128.0).collect();
    for tau in [1e-6, 1e-5, 1e-4, 1e-3] {
        let cfg = HigConfig::hig(1.0, tau);
        let (mut a, mut b) = (vec![0.0; cols], vec![0.0; cols]);
        let ia = HalfInverse::new(rows, cols, Par::rayon(0)).solve(&cfg, j, &g, &mut a)?;
        let ib = HalfInverse::new(rows, cols, Par::rayon(0)).solve(
            &cfg.with_decomposition(Decomposition::Eigen),
            j,
            &g,
            &mut b,
        )?;
        let num: f64 = a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt();
        let den: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        println!(
            "tau {tau:e}: rank svd {} eig {}, smin {:e}/{:e}, s_max {:e}, rel diff {:e}",
            ia.rank,
            ib.rank,
            ia.s_min_kept,
            ib.s_min_kept,
            ia.s_max,
            num / den
        );
    }
    Ok(())
}
