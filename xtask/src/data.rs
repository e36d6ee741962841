//! `cargo xtask data`: training data generated in shards (`--shard i/n`) that any scheduler can
//! run on any machine, and the check that a directory of shards is one whole data set.
//!
//! ```text
//! cargo xtask data metric --kind Adv --count 64 --shard 2/4 --out data/adv   # job 2 of 4
//! cargo xtask data acdm --shard 0/5 --out data/acdm                          # 2 of 10 Re
//! cargo xtask data check data/adv                                            # all there?
//! ```
//!
//! Item `k` depends on the settings and `k` only, so 4 shards write the same files as one run
//! (`xtask/tests/data_shards.rs` and `data_shards_grid_weather.rs` show it); each shard commits
//! `manifest-<i>-of-<n>.json` with SHA-256 hashes last (see [`pbdl_core::shard`]).
//!
//! The other sharded generators live with their commands, and `data check` checks them all:
//!
//! | command | item `k` | generator in the manifest | read by |
//! |---|---|---|---|
//! | `sim grid SCENE --seeds N --shard i/n` | the scene with its random inputs' seeds + `k` (`Scene::with_seed_offset`) | `pbdl-grid/sim` | any `.npz` reader (same arrays as `sim grid`) |
//! | `sim particles SCENE --seeds N --shard i/n` | the noise scene with seed + `k` | `pbdl-particles/sim` | any `.npz` reader |
//! | `weather generate --shard i/n` | 0: the truth run, 1: the biased climate run | `pbdl-weather/standin` | `weather train` / `eval --data DIR` |

use anyhow::Context as _;
use pbdl_core::shard::{generate_shard, open_shards, Shard};
use std::path::PathBuf;

/// The generators.
#[derive(clap::Subcommand, Debug)]
pub enum DataCommand {
    /// Metric-learning sequences of pbdl-metrics (11 frames each; item k = sequence k).
    Metric {
        /// Adv, Bur, Smo or Sha.
        #[arg(long)]
        kind: String,
        /// Sequences in the whole data set.
        #[arg(long)]
        count: usize,
        /// Base seed (item k's noise derives from it and k).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Cells per side.
        #[arg(long, default_value_t = 64)]
        resolution: usize,
        /// This job's part, `i/n` (0-based); default the whole set.
        #[arg(long, default_value = "0/1")]
        shard: Shard,
        /// Output directory (shared by all shards of one data set).
        #[arg(long)]
        out: PathBuf,
    },
    /// ACDM cylinder flows of pbdl-diffusion (item k = Reynolds number k of --re).
    Acdm {
        /// Reynolds numbers, comma-separated (default: the benchmark's 10 training values).
        #[arg(long, value_delimiter = ',')]
        re: Vec<f64>,
        /// The small test configuration (32x16 stored frames) instead of the benchmark's.
        #[arg(long)]
        tiny: bool,
        /// This job's part, `i/n` (0-based).
        #[arg(long, default_value = "0/1")]
        shard: Shard,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
    /// Check a directory of shards: same generator and settings, every item once, hashes.
    Check {
        /// The directory.
        dir: PathBuf,
    },
}

/// Runs a `data` command.
pub fn run(cmd: DataCommand) -> anyhow::Result<()> {
    match cmd {
        DataCommand::Metric { kind, count, seed, resolution, shard, out } => {
            use pbdl_metrics::train::data::{generate_items, save_sequences, shard_generator, DataConfig};
            let kind = pbdl_metrics::train::Kind::parse(&kind)?;
            let cfg = DataConfig { resolution, seed };
            let config =
                serde_json::json!({ "kind": kind.short(), "count": count, "seed": seed, "resolution": resolution });
            let m = generate_shard(&out, &shard_generator(kind), &config, count, shard, |k, path| {
                let seqs = generate_items(kind, k..k + 1, &cfg).map_err(core_error)?;
                save_sequences(path, &seqs).map_err(core_error)
            })?;
            report(&out, &m);
        }
        DataCommand::Acdm { re, tiny, shard, out } => {
            use pbdl_diffusion::acdm::data::{simulate, train_config, CylinderConfig, CylinderDataset, TRAIN_RE};
            let re = if re.is_empty() { TRAIN_RE.to_vec() } else { re };
            let config = if tiny { CylinderConfig::tiny() } else { train_config() };
            config.validate()?;
            let json = serde_json::json!({ "cylinder": config, "re": re });
            let m = generate_shard(&out, "pbdl-diffusion/acdm-cylinder", &json, re.len(), shard, |k, path| {
                let seq = simulate(&config, re[k]).map_err(diffusion_error)?;
                CylinderDataset { config: config.clone(), sequences: vec![seq], seconds: 0.0 }
                    .save(path)
                    .map_err(diffusion_error)
            })?;
            report(&out, &m);
        }
        DataCommand::Check { dir } => {
            let set = open_shards(&dir).with_context(|| format!("checking {}", dir.display()))?;
            println!(
                "{}: {} items of `{}` from {} shard manifests, all present once, hashes match; config {}",
                dir.display(),
                set.files.len(),
                set.generator,
                set.manifests.len(),
                set.config
            );
        }
    }
    Ok(())
}

fn report(out: &std::path::Path, m: &pbdl_core::shard::ShardManifest) {
    let items = m.shard.items(m.total_items);
    println!(
        "shard {}: items {}..{} of {} written to {} ({})",
        m.shard,
        items.start,
        items.end,
        m.total_items,
        out.display(),
        m.shard.manifest_name()
    );
}

/// The shard writer's callback speaks pbdl-core's error; the generators' own errors pass
/// through it with their message.
fn core_error(e: pbdl_metrics::Error) -> pbdl_core::Error {
    match e {
        pbdl_metrics::Error::Core(e) => e,
        other => pbdl_core::Error::invalid("data metric", "generator", other.to_string()),
    }
}

fn diffusion_error(e: pbdl_diffusion::Error) -> pbdl_core::Error {
    pbdl_core::Error::invalid("data acdm", "generator", e.to_string())
}
