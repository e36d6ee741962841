//! Trains the SMDP toy score network (quadratic drift) with the 1-step loss and prints the
//! forward-simulator statistics, the reverse-SDE posterior against the digest's table and the
//! hit rates of both samplers.
//!
//! `cargo run -p pbdl-diffusion --example smdp_toy -- [updates]` (default 20000).

use pbdl_diffusion::smdp::analytic::QUADRATIC_POSTERIOR_DT002;
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::sampler::{hit_rates, posterior_plus};
use pbdl_diffusion::smdp::sde::{mean_std, ToySde};
use pbdl_diffusion::smdp::toy::{train_toy, ToyTrainConfig};

fn main() -> pbdl_diffusion::Result<()> {
    let updates: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(20_000);
    let sde = ToySde::paper_quadratic();
    let (m, s) = mean_std(&sde.endpoints(&vec![1.0; 100_000], 1)?);
    println!("forward SDE from +1: x_T mean {m:.5}, std {s:.5} (digest 0.0036, 0.0351)");
    let mut net = ScoreMlp::paper(0);
    let cfg = ToyTrainConfig { log_every: 1000, ..ToyTrainConfig::one_step(updates / 2, updates - updates / 2) };
    let rep = train_toy(&sde, &mut net, &cfg)?;
    println!(
        "{updates} updates in {:.1} s, last loss {:.4e}",
        rep.seconds,
        rep.losses.last().map_or(f64::NAN, |l| l.1)
    );
    let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
    let post = posterior_plus(&sde, &net, &ys, 2000, 5)?;
    for ((y, r), p) in QUADRATIC_POSTERIOR_DT002.iter().zip(&post) {
        println!("y {y:+.3}: P(+1|y) = {p:.3} (digest {r:.2})");
    }
    println!("{:?}", hit_rates(&sde, &net, 1000, 0.01, 6)?);
    Ok(())
}
