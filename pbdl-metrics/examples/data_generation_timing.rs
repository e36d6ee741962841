//! Times the metric data generator (`pbdl_metrics::train::data::generate`, 64x64 frames: many
//! small grid and tensor operations) under the process's thread policy, for
//! `bench/thread_policy.sh`, which runs it with `PBDL_THREADS=1` and with the default policy,
//! alternating. Prints one JSON line per kind: `{"kind", "threads", "serial_below",
//! "median_s", "reps"}` (median over `reps` timed generations of `count` sequences each, after
//! one untimed warm-up).
//!
//! ```text
//! cargo run --release -p pbdl-metrics --example data_generation_timing -- [reps] [count]
//! ```

use pbdl_metrics::train::data::{generate, DataConfig, Kind};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let policy = pbdl_core::threads::init()?;
    let mut args = std::env::args().skip(1);
    let reps: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(5);
    let count: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(2);
    let cfg = DataConfig { resolution: 64, seed: 3 };
    for kind in Kind::ALL {
        generate(kind, count, &cfg)?; // warm-up: plans, caches, page faults
        let mut times: Vec<f64> = (0..reps.max(1))
            .map(|_| {
                let t = Instant::now();
                generate(kind, count, &cfg).map(|_| t.elapsed().as_secs_f64())
            })
            .collect::<Result<_, _>>()?;
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        println!(
            "{{\"kind\": \"{}\", \"threads\": {}, \"serial_below\": {}, \"median_s\": {median:.6}, \"reps\": {}}}",
            kind.short(),
            policy.threads,
            policy.serial_below,
            times.len()
        );
    }
    Ok(())
}
