//! Trains the SMDP toy score network and prints what the acceptance criteria look at: the
//! forward-simulator statistics, the reverse-SDE posterior against the digest's table and the
//! hit rates of both samplers (quadratic drift), or the score error against the analytic score
//! (affine drift). Samplers are run with the data step (0.02) and with the official notebook's
//! inference step (0.01).
//!
//! ```text
//! cargo run -p pbdl-diffusion --example smdp_toy -- [options]
//!   --drift quadratic|affine     (default quadratic)
//!   --recipe official|reg        official: bidirectional 1-step, stride 5 then 1 (default);
//!                                reg: the regularised 1-step loss, stride 5 then 1
//!   --updates HI,LO              updates of the two stages (default 20000,20000)
//!   --fine N                     then N updates at lr 1e-5, stride 1 (the affine config's third stage)
//!   --times log                  log-uniform training times instead of the official grid
//!   --substeps N                 simulation sub-steps per data step (default 2, as the official data)
//!   --multi PER_WINDOW,STAGES    then sliding windows 4, 6, ... at lr 1e-4 (default none)
//!   --save FILE / --load FILE    raw little-endian f64 parameters (--load skips training)
//!   --seed N                     seed of the initial weights, the data and the batches (default 0)
//!   --init FILE                  start training from saved parameters
//!   --sample-dts A,B,...         sampler steps to evaluate (default 0.02,0.01)
//! ```

use pbdl_diffusion::smdp::analytic::{AffineMixture, QUADRATIC_POSTERIOR_DT002};
use pbdl_diffusion::smdp::mlp::ScoreMlp;
use pbdl_diffusion::smdp::sampler::{hit_rates, posterior_plus};
use pbdl_diffusion::smdp::sde::{mean_std, ToySde};
use pbdl_diffusion::smdp::toy::{
    affine_one_step_target, affine_score_error, score_error_against, train_toy, TimeSampling, ToyLoss, ToyStage,
    ToyTrainConfig,
};

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1).cloned())
}

fn pair(name: &str, default: (usize, usize)) -> (usize, usize) {
    arg(name)
        .and_then(|v| {
            let mut it = v.split(',').map(|x| x.parse::<usize>().ok());
            Some((it.next()??, it.next()??))
        })
        .unwrap_or(default)
}

fn main() -> pbdl_diffusion::Result<()> {
    pbdl_core::threads::init().expect("PBDL_THREADS / PBDL_SERIAL_BELOW must be numbers"); // one thread policy for rayon, candle and gemm
    let affine = arg("--drift").as_deref() == Some("affine");
    let sde = if affine { ToySde::paper_affine() } else { ToySde::paper_quadratic() };
    let seed: u64 = arg("--seed").and_then(|v| v.parse().ok()).unwrap_or(0);
    let mut net = ScoreMlp::paper(seed);
    if let Some(path) = arg("--load") {
        let bytes = std::fs::read(&path).expect("readable parameter file");
        for (p, c) in net.params_mut().iter_mut().zip(bytes.chunks_exact(8)) {
            *p = f64::from_le_bytes(c.try_into().expect("8 bytes"));
        }
        println!("loaded {path}");
    } else {
        if let Some(path) = arg("--init") {
            let bytes = std::fs::read(&path).expect("readable parameter file");
            for (p, c) in net.params_mut().iter_mut().zip(bytes.chunks_exact(8)) {
                *p = f64::from_le_bytes(c.try_into().expect("8 bytes"));
            }
            println!("initialised from {path}");
        }
        let (hi, lo) = pair("--updates", (20_000, 20_000));
        let bidirectional = arg("--recipe").as_deref() != Some("reg");
        let mut cfg = ToyTrainConfig { log_every: 10_000, seed, ..ToyTrainConfig::official(hi, lo) };
        for s in &mut cfg.stages {
            if let ToyLoss::Strided { stride, .. } = s.loss {
                s.loss = ToyLoss::Strided { stride, bidirectional };
            }
        }
        if let Some(n) = arg("--fine").and_then(|v| v.parse().ok()) {
            let loss = ToyLoss::Strided { stride: 1, bidirectional };
            cfg.stages.push(ToyStage { loss, lr: 1e-5, updates: n });
        }
        if arg("--times").as_deref() == Some("log") {
            cfg.time_sampling = TimeSampling::LogUniform;
        }
        if let Some(n) = arg("--substeps").and_then(|v| v.parse().ok()) {
            cfg.sim_substeps = n;
        }
        let (per_window, windows) = pair("--multi", (0, 0));
        for i in 0..windows {
            cfg.stages.push(ToyStage { loss: ToyLoss::MultiStep(4 + 2 * i), lr: 1e-4, updates: per_window });
        }
        println!("config: {cfg:?}");
        let rep = train_toy(&sde, &mut net, &cfg)?;
        println!("trained in {:.1} s (simulation {:.1} s)", rep.seconds, rep.simulate_seconds);
        for (u, l, s) in &rep.losses {
            println!("  update {u:7} stage {s:2}: mean loss {l:.5e}");
        }
        if let Some(path) = arg("--save") {
            let bytes: Vec<u8> = net.params().iter().flat_map(|p| p.to_le_bytes()).collect();
            std::fs::write(&path, bytes).expect("writable parameter file");
            println!("saved {path}");
        }
    }
    if affine {
        let ts: Vec<f64> = (0..20).map(|i| 0.5 + 9.5 * i as f64 / 19.0).collect();
        for (name, law) in [
            ("continuous", AffineMixture::continuous(0.5, 0.04)),
            ("Euler chain", AffineMixture::euler(0.5, 0.04, 0.02)),
        ] {
            let e = affine_score_error(&net, &law, &ts, 400);
            let per_t: Vec<String> = e.per_t.iter().map(|(t, v)| format!("{t:.2}:{v:.3}")).collect();
            println!(
                "score error vs g^2 score of the {name} law: pooled {:.4}; by density band {:?}",
                e.pooled, e.by_band
            );
            println!("  per t {}", per_t.join(" "));
        }
        // What the regularised 1-step loss converges to on the data chain, and how far that is
        // from the analytic score: separates the network's error from the target's.
        let eul = AffineMixture::euler(0.5, 0.04, 0.02);
        let tgt = |x: f64, t: f64| affine_one_step_target(&eul, 0.02, 1, x, t);
        let e = score_error_against(&net, &eul, &ts, 400, tgt);
        println!("score error vs the 1-step loss minimiser: pooled {:.4}; by band {:?}", e.pooled, e.by_band);
        let mut num = 0.0;
        let mut den = 0.0;
        for &t in &ts {
            let (mu, s) = eul.moments(t);
            for i in 0..400 {
                let x = -(mu + 5.0 * s) + 2.0 * (mu + 5.0 * s) * i as f64 / 399.0;
                if eul.density(x, t) > 0.01 * eul.density(mu, t).max(eul.density(0.0, t)) {
                    let (a, b) = (tgt(x, t), 0.0016 * eul.score(x, t));
                    num += (a - b) * (a - b);
                    den += b * b;
                }
            }
        }
        println!("1-step loss minimiser vs g^2 score (Euler law): relative L2 {:.4}", (num / den).sqrt());
        return Ok(());
    }
    let (m, s) = mean_std(&sde.endpoints(&vec![1.0; 200_000], 1)?);
    println!("forward SDE from +1 (200k paths): x_T mean {m:.5}, std {s:.5} (digest 0.0036, 0.0351)");
    let dts: Vec<f64> = arg("--sample-dts")
        .map(|v| v.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![0.02, 0.01]);
    for dt in dts {
        let inf = ToySde { dt, ..sde };
        let ys: Vec<f64> = QUADRATIC_POSTERIOR_DT002.iter().map(|p| p.0).collect();
        let post = posterior_plus(&inf, &net, &ys, 2000, 5)?;
        let mut worst: f64 = 0.0;
        for ((y, r), p) in QUADRATIC_POSTERIOR_DT002.iter().zip(&post) {
            println!("sampler dt {dt}: y {y:+.3}: P(+1|y) = {p:.3} (digest {r:.2})");
            worst = worst.max((p - r).abs());
        }
        println!("sampler dt {dt}: worst posterior error {worst:.3}");
        println!("sampler dt {dt}: {:?}", hit_rates(&inf, &net, 1000, 0.01, 6)?);
    }
    Ok(())
}
