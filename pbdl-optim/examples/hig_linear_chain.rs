//! HIG against Adam on the pbdl-book linear chain, one epoch each, printed as a table.
//!
//! `cargo run --release -p pbdl-optim --example hig_linear_chain`

use pbdl_optim::hig::{run_curve, Budget, HigConfig, Method};
use pbdl_optim::mlp::{Activation, Mlp};
use pbdl_optim::physics::{Dataset, Oscillators};

fn main() -> pbdl_optim::Result<()> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let physics = Oscillators::linear_chain();
    let train = Dataset::return_to_start(4096, 4, 1);
    let test = Dataset::return_to_start(1024, 4, 2);
    let net0 = Mlp::new(&[4, 20, 20, 20, 24], Activation::Tanh, 0)?;
    println!("| optimiser | batch | steps | seconds | test loss |\n|---|---:|---:|---:|---:|");
    for (name, method, batch) in [
        ("HIG", Method::Hig(HigConfig::hig(1.0, 1e-10)), 32),
        ("Gauss-Newton", Method::Hig(HigConfig::gauss_newton(1.0, 1e-10)), 32),
        ("Adam", Method::Adam { lr: 1e-3 }, 256),
    ] {
        let mut net = net0.clone();
        let budget = Budget { seconds: f64::INFINITY, max_steps: (4096 / batch) as u64 };
        let c = run_curve(&mut net, &physics, method, &train, &test, batch, budget, u64::MAX)?;
        println!(
            "| {name} | {batch} | {} | {:.2} | {:.3e} |",
            c.steps.last().unwrap(),
            c.seconds.last().unwrap(),
            c.final_loss()
        );
    }
    Ok(())
}
