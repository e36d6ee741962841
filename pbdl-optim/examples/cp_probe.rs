//! scratch probe (to be deleted)
use pbdl_optim::bptt::GradientMode;
use pbdl_optim::cartpole::{train, CartPoleConfig};
fn main() -> pbdl_optim::Result<()> {
    let iters: usize = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(20);
    for nc in 1..=4 {
        for mode in [GradientMode::F, GradientMode::P, GradientMode::C] {
            let mut cfg = CartPoleConfig::new(nc, mode, iters);
            cfg.lr = std::env::var("LR").map(|s| s.parse().unwrap()).unwrap_or(1e-3);
            cfg.eval_every = iters / 5;
            let r = train(&cfg)?;
            println!(
                "nc {nc} {mode:?}: {:.2} s/step  loss {:?} agree {:?}",
                r.seconds / iters as f64,
                r.test_loss.iter().map(|x| format!("{x:.3}")).collect::<Vec<_>>(),
                r.agreement
            );
        }
    }
    Ok(())
}
